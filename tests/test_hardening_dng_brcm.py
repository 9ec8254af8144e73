"""Hardening of the DNG and legacy JPEG+BRCM readers: whatever the bytes, picamcal's own one-line errors.

Property tests mutate real files written by picamcal (byte changes, truncation, IFD tag type/count/value
rewrites, EXIF and BRCM header rewrites) and fail on any exception that is not a ``PicamcalError`` and on any
byte written to the process's stderr; table tests pin what each malformed tag gives; memory tests measure the
peak resident memory of the command line refusing forged sizes; a subprocess test checks that LibRaw's own
messages end up in the one error line.
"""

from __future__ import annotations

import io
import json
import math
import os
import struct
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import imagecodecs
import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import run_measured
from picamcal.calibrate import calibrate
from picamcal.errors import CalibrationFileError, PicamcalError, PicamcalWarning, RawFormatError
from picamcal.raw import RawImage, write_brcm, write_dng
from picamcal.raw.brcm import read_brcm
from picamcal.raw.dng import read_dng
from picamcal.sensors import SENSORS
from picamcal.simulate import make_camera, simulate_references
from test_cli import assert_bad_input, run
from test_dng import _MINIMAL_TAGS as MINIMAL_TAGS  # another writer's minimal BGGR DNG tags

WIDTH, HEIGHT = 64, 48
META = {
    "exposure_time_s": 0.01,
    "analogue_gain": 2.0,
    "colour_gains": [1.9, 1.6],
    "colour_correction_matrix": [1.5, -0.3, -0.2, -0.3, 1.6, -0.3, -0.1, -0.5, 1.6],
    "timestamp": "2024:05:06 07:08:09",
}
FUZZ = settings(
    max_examples=200,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
TIFF_TYPES = [*range(19), 99, 0xFFFF]
INTERESTING = [0, 1, 2, 3, 4, 8, 9, 16, 255, 0xFFFF, 0x10000, 2**31 - 1, 2**31, 2**32 - 1, 16000, 34000]


def _mosaic(height: int = HEIGHT, width: int = WIDTH, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(64, 1023, (height, width), dtype=np.uint16)


def ifd_entries(data: bytes, offset: int, order: str = "<", base: int = 0) -> dict[int, int]:
    """Byte offset in ``data`` of each entry of the IFD at ``offset`` (relative to ``base``), by tag code."""
    (count,) = struct.unpack_from(order + "H", data, base + offset)
    at = [base + offset + 2 + 12 * i for i in range(count)]
    return {struct.unpack_from(order + "H", data, a)[0]: a for a in at}


def dng_entries(data: bytes) -> dict[int, int]:
    """Entries of IFD 0 and of the EXIF IFD of a picamcal DNG (little-endian; no tag code is in both)."""
    entries = ifd_entries(data, struct.unpack_from("<I", data, 4)[0])
    if 34665 in entries:
        entries.update(ifd_entries(data, struct.unpack_from("<I", data, entries[34665] + 8)[0]))
    return entries


def rewrite(data: bytes, at: int, *, kind: int | None = None, count: int | None = None, value: int | None = None):
    """``data`` with the IFD entry at byte ``at`` given another field type, count or value field."""
    out = bytearray(data)
    for field, offset, code in ((kind, 2, "<H"), (count, 4, "<I"), (value, 8, "<I")):
        if field is not None:
            struct.pack_into(code, out, at + offset, field)
    return bytes(out)


def outcome(read, path: Path, capfd) -> RawImage | PicamcalError:
    """Read ``path``: the image or picamcal's error (one line, naming the file); nothing else may escape.

    Only PicamcalWarnings may be issued, and nothing may reach file descriptor 2 (LibRaw writes there).
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = read(path)
        except PicamcalError as exc:
            assert exc.path == str(path) and "\n" not in str(exc), str(exc)
            result = exc
        else:
            assert result.bayer.dtype == np.uint16 and result.bayer.ndim == 2
    assert all(issubclass(w.category, PicamcalWarning) for w in caught), [str(w.message) for w in caught]
    assert all("\n" not in str(w.message) for w in caught)
    assert capfd.readouterr().err == ""
    return result


# --- the files mutated ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dngs(tmp_path_factory) -> dict[str, bytes]:
    """picamcal's DNG of a small frame with full metadata, and the same mosaic as a lossless-JPEG DNG."""
    folder = tmp_path_factory.mktemp("dngs")
    raw = RawImage(_mosaic(), "BGGR", (64,) * 4, 1023, 10, "imx219", dict(META))
    ljpeg = folder / "ljpeg.dng"
    tifffile.imwrite(
        ljpeg,
        iter([imagecodecs.ljpeg_encode(raw.bayer, bitspersample=10)]),
        shape=raw.bayer.shape,
        dtype=np.uint16,
        photometric=32803,
        compression=7,  # lossless JPEG, as most cameras' DNGs
        extratags=MINIMAL_TAGS,
        metadata=None,
    )
    np.testing.assert_array_equal(read_dng(ljpeg).bayer, raw.bayer)  # LibRaw decodes it bit-exactly
    return {"uncompressed": write_dng(folder / "plain.dng", raw).read_bytes(), "ljpeg": ljpeg.read_bytes()}


@pytest.fixture(scope="module")
def brcm(tmp_path_factory) -> bytes:
    """picamcal's legacy JPEG+raw file of the IMX219's smallest mode (640x480), with EXIF exposure and gain."""
    mode = next(m for m in SENSORS["imx219"].legacy_modes if (m.width, m.height) == (640, 480))
    raw = RawImage(_mosaic(mode.height, mode.width), "BGGR", (64,) * 4, 1023, 10, "imx219", dict(META))
    return write_brcm(tmp_path_factory.mktemp("brcm") / "small.jpg", raw).read_bytes()


def _strip_start(data: bytes) -> int:
    entries = dng_entries(data)
    return struct.unpack_from("<I", data, entries[273] + 8)[0]


# --- DNG: property tests ----------------------------------------------------------------------------------------


@pytest.mark.slow
@FUZZ
@given(data=st.data(), kind=st.sampled_from(["uncompressed", "ljpeg"]))
def test_dng_byte_changes_give_only_picamcal_errors(tmp_path, capfd, dngs, data, kind):
    original = dngs[kind]
    header = _strip_start(original) if kind == "uncompressed" else len(original)
    offsets = st.one_of(st.integers(0, header - 1), st.integers(0, len(original) - 1))
    changes = data.draw(st.lists(st.tuples(offsets, st.integers(0, 255)), min_size=1, max_size=12))
    mutated = bytearray(original)
    for offset, value in changes:
        mutated[offset] = value
    path = tmp_path / "flipped.dng"
    path.write_bytes(bytes(mutated))
    outcome(read_dng, path, capfd)


@FUZZ
@given(data=st.data(), kind=st.sampled_from(["uncompressed", "ljpeg"]))
def test_dng_truncation_gives_only_picamcal_errors(tmp_path, capfd, dngs, data, kind):
    original = dngs[kind]
    path = tmp_path / "cut.dng"
    path.write_bytes(original[: data.draw(st.integers(0, len(original) - 1))])
    assert isinstance(outcome(read_dng, path, capfd), RawFormatError)  # every byte counts in these two files


@FUZZ
@given(data=st.data(), kind=st.sampled_from(["uncompressed", "ljpeg"]))
def test_dng_tag_type_count_and_value_rewrites_give_only_picamcal_errors(tmp_path, capfd, dngs, data, kind):
    original = dngs[kind]
    entries = sorted(dng_entries(original).values())
    mutated = original
    for _ in range(data.draw(st.integers(1, 3))):
        at = data.draw(st.sampled_from(entries))
        field = data.draw(st.sampled_from(["kind", "count", "value"]))
        if field == "kind":
            mutated = rewrite(mutated, at, kind=data.draw(st.sampled_from(TIFF_TYPES)))
        else:
            number = data.draw(st.one_of(st.sampled_from(INTERESTING), st.integers(0, 2**32 - 1)))
            mutated = rewrite(mutated, at, **{field: number})
    path = tmp_path / "tags.dng"
    path.write_bytes(mutated)
    outcome(read_dng, path, capfd)


JSON_SCALARS = st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=8)
JSON_VALUES = st.recursive(
    JSON_SCALARS, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner, max_size=4)
)
RECORD_KEYS = ["sensor", "exposure_time_s", "analogue_gain", "iso", "colour_gains", "colour_correction_matrix"]
RECORD_KEYS += ["timestamp", "make", "model", "colour_temperature", "sensor_size", "lux", "scene"]


@FUZZ
@given(
    record=st.one_of(
        st.dictionaries(st.sampled_from(RECORD_KEYS) | st.text(max_size=6), JSON_VALUES, max_size=6),
        JSON_VALUES,
    ),
    deep=st.sampled_from([0, 40, 10000]),
)
@pytest.mark.slow
def test_dng_description_json_is_checked(tmp_path, capfd, record, deep):
    # picamcal's own record in ImageDescription, replaced by any JSON: wrong kinds, not an object, 10000 deep.
    if deep and isinstance(record, dict):
        record = {**record, "nested": "@nested@"}
    text = json.dumps({"picamcal": record}).replace('"@nested@"', "[" * deep + "]" * deep)
    path = tmp_path / "description.dng"
    tags = [*MINIMAL_TAGS, (270, 2, 0, text, True)]
    tifffile.imwrite(path, _mosaic(), photometric=32803, extratags=tags, metadata=None)
    raw = outcome(read_dng, path, capfd)
    assert isinstance(raw, RawImage)  # the record is informative: never a reason to refuse the image
    meta = raw.metadata
    assert raw.sensor is None or isinstance(raw.sensor, str)
    for key in ("exposure_time_s", "analogue_gain", "colour_temperature"):
        assert key not in meta or (isinstance(meta[key], (int, float)) and 0 < meta[key] < math.inf), meta[key]
    if "colour_gains" in meta:
        assert len(meta["colour_gains"]) == 2 and all(0 < g < math.inf for g in meta["colour_gains"])
    if "iso" in meta:
        assert isinstance(meta["iso"], int) and meta["iso"] > 0
    assert not deep or "nested" not in meta  # deeper than picamcal's own records nest: left out


# --- DNG: what each malformed tag gives ------------------------------------------------------------------------


def _rational_at(data: bytes, code: int, index: int, numerator: int, denominator: int) -> bytes:
    """``data`` with the ``index``-th (S)RATIONAL of tag ``code`` (stored out of line) replaced."""
    at = struct.unpack_from("<I", data, dng_entries(data)[code] + 8)[0] + 8 * index
    out = bytearray(data)
    struct.pack_into("<ii" if numerator < 0 else "<II", out, at, numerator, denominator)
    return bytes(out)


def _entry(data: bytes, code: int) -> int:
    return dng_entries(data)[code]


#: (case: how to damage picamcal's DNG, the error fragment) -- tags that decide the pixels or their levels.
DNG_ERRORS = {
    "SamplesPerPixel with 2 values": (lambda d: rewrite(d, _entry(d, 277), count=2), "SamplesPerPixel has 2 values"),
    "SamplesPerPixel of type LONG": (lambda d: rewrite(d, _entry(d, 277), kind=4), "SamplesPerPixel is of type LONG"),
    "BitsPerSample 40": (lambda d: rewrite(d, _entry(d, 258), value=40), "BitsPerSample is 40"),
    "ImageWidth 2**31": (lambda d: rewrite(d, _entry(d, 256), value=2**31), "over the limit"),
    "ImageWidth 0": (lambda d: rewrite(d, _entry(d, 256), value=0), "declares an image of 0x48"),
    "Photometric RGB": (lambda d: rewrite(d, _entry(d, 262), value=2), "not a Bayer mosaic"),
    "strip past the end": (lambda d: d[:-10], "truncated file: strip 1 of 1 of the raw image ends at byte"),
    "strip too short": (lambda d: rewrite(d, _entry(d, 279), value=100), "uncompressed strip 1 holds 100 bytes"),
    "CFA pattern nonsense": (lambda d: rewrite(d, _entry(d, 33422), value=0x03030303), "CFAPattern [3, 3, 3, 3]"),
    "CFA of three greens": (lambda d: rewrite(d, _entry(d, 33422), value=0x01010102), "is not a Bayer pattern"),
    "CFA repeat 3x3": (lambda d: rewrite(d, _entry(d, 33421), value=0x00030003), "picamcal reads 2x2 Bayer"),
    "BlackLevel 0/0": (lambda d: _rational_at(d, 50714, 1, 0, 0), "BlackLevel has a zero denominator"),
    "WhiteLevel 0": (lambda d: rewrite(d, _entry(d, 50717), value=0), "WhiteLevel 0 is not between"),
    "WhiteLevel below black": (lambda d: rewrite(d, _entry(d, 50717), value=50), "WhiteLevel 50 is not between"),
    "no DNGVersion": (lambda d: _renamed(d, 50706), "no DNGVersion tag"),
    "IFD past the end": (lambda d: d[:4] + struct.pack("<I", len(d) + 8) + d[8:], "IFD 0 (bytes"),
    "not TIFF": (lambda d: b"II+\x00" + d[4:], "no TIFF header"),
}


def _renamed(data: bytes, code: int) -> bytes:
    """``data`` with tag ``code`` renumbered to a private tag no reader knows (65000)."""
    out = bytearray(data)
    struct.pack_into("<H", out, _entry(data, code), 65000)
    return bytes(out)


@pytest.mark.parametrize("case", DNG_ERRORS)
def test_a_malformed_pixel_tag_is_a_one_line_error_naming_the_file_and_tag(tmp_path, capfd, dngs, case):
    damage, fragment = DNG_ERRORS[case]
    path = tmp_path / "bad.dng"
    path.write_bytes(damage(dngs["uncompressed"]))
    error = outcome(read_dng, path, capfd)
    assert isinstance(error, RawFormatError) and fragment in error.problem, error


#: Informative metadata: left out with one PicamcalWarning naming the tag; the image still reads.
DNG_WARNINGS = {
    "AsShotNeutral 1/0": (lambda d: _rational_at(d, 50728, 0, 1, 0), "as_shot_neutral", "AsShotNeutral has a zero"),
    "AsShotNeutral 0": (lambda d: _rational_at(d, 50728, 2, 0, 1), "as_shot_neutral", "AsShotNeutral must be posit"),
    # picamcal's JSON record keeps its own exposure_time_s: only the warning tells.
    "ExposureTime of 2 values": (lambda d: rewrite(d, _entry(d, 33434), count=2), None, "ExposureTime has 2 values"),
    "ColorMatrix1 of 8 values": (lambda d: rewrite(d, _entry(d, 50721), count=8), "color_matrix1", "ColorMatrix1 has"),
    "ForwardMatrix1 as SHORT": (lambda d: rewrite(d, _entry(d, 50964), kind=3), "forward_matrix1", "type SHORT"),
    "Illuminant of 2 values": (lambda d: rewrite(d, _entry(d, 50778), count=2), "calibration_illuminant1", "Illum"),
    "ISO 0": (lambda d: rewrite(d, _entry(d, 34855), value=0), "iso", "ISOSpeedRatings must be positive"),
    "Model past the end": (lambda d: rewrite(d, _entry(d, 272), value=2**31), "model", "DNG tag Model"),
    "EXIF IFD past the end": (lambda d: rewrite(d, _entry(d, 34665), value=2**31), None, "the EXIF IFD (bytes"),
}


@pytest.mark.parametrize("case", DNG_WARNINGS)
def test_malformed_informative_metadata_is_left_out_with_one_warning(tmp_path, dngs, case):
    damage, key, fragment = DNG_WARNINGS[case]
    path = tmp_path / "odd.dng"
    path.write_bytes(damage(dngs["uncompressed"]))
    with pytest.warns(PicamcalWarning) as caught:
        raw = read_dng(path)
    assert len(caught) == 1 and fragment in str(caught[0].message) and str(path) in str(caught[0].message)
    assert key is None or key not in raw.metadata
    np.testing.assert_array_equal(raw.bayer, _mosaic())


def test_libraw_giving_up_is_told_with_the_malformed_metadata_picamcal_found(tmp_path, capfd, dngs):
    # LibRaw gives up on a compressed DNG whose EXIF IFD lies past the end with nothing but "Input/output error":
    # the error adds what picamcal found.
    path = tmp_path / "bad.dng"
    tifffile.imwrite(
        path,
        iter([imagecodecs.ljpeg_encode(_mosaic(), bitspersample=10)]),
        shape=(HEIGHT, WIDTH),
        dtype=np.uint16,
        photometric=32803,
        compression=7,
        extratags=[*MINIMAL_TAGS, (34664, 4, 1, 2**31, True)],  # tifffile writes no ExifIFD tag: renamed below
        metadata=None,
    )
    data = bytearray(path.read_bytes())
    struct.pack_into("<H", data, _entry(bytes(data), 34664), 34665)
    path.write_bytes(bytes(data))
    error = outcome(read_dng, path, capfd)
    assert isinstance(error, RawFormatError), error
    assert "LibRaw cannot read it" in error.problem and "malformed: corrupt TIFF/DNG structure" in error.problem


@pytest.mark.parametrize(
    ("text", "warned"),
    [
        ("OLYMPUS DIGITAL CAMERA", False),  # another writer's description: not picamcal's, passed over quietly
        ('{"other": 1}', False),
        ('{"picamcal": [1, 2]}', True),
        ('{"picamcal": {"exposure_time_s": "fast", "iso": -3, "scene": "white"}}', True),
        ('{"picamcal": {"x": ' + "[" * 10000 + "]" * 10000 + "}}", True),  # a RecursionError in json, caught
        ('{"picamcal": {"x": ' + "[" * 100 + "]" * 100 + "}}", True),  # parses, but deeper than a record nests
        ('{"picamcal": {"colour_gains": [1e999, 1]}}', True),
        ('{"picamcal": {"sensor_size": [10' + "0" * 400 + ", 2]}}", True),  # an integer beyond any float
    ],
)
def test_image_description_json(tmp_path, text, warned):
    path = tmp_path / "d.dng"
    tags = [*MINIMAL_TAGS, (270, 2, 0, text, True)]
    tifffile.imwrite(path, _mosaic(), photometric=32803, extratags=tags, metadata=None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        raw = read_dng(path)
    assert [issubclass(w.category, PicamcalWarning) for w in caught] == ([True] if warned else [])
    assert not {"exposure_time_s", "iso", "colour_gains", "sensor_size", "x"} & raw.metadata.keys()
    if "scene" in text:
        assert raw.metadata["scene"] == "white"  # a good value beside bad ones is kept


def test_the_writer_records_no_number_json_lacks(tmp_path):
    # An unknown black level is NaN in metadata; JSON has no NaN (and the reader refuses it): null is written.
    meta = {"declared_black_level": [math.nan] * 4, "lux": np.float32("inf"), "scene": "white"}
    path = write_dng(tmp_path / "nan.dng", RawImage(_mosaic(), "BGGR", 64, 1023, 10, "imx219", meta))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = read_dng(path).metadata
    assert back["declared_black_level"] == [None] * 4 and back["scene"] == "white" and "lux" not in back


def test_expected_shape_mismatch_is_refused_and_a_match_reads(tmp_path, dngs):
    path = tmp_path / "frame.dng"
    path.write_bytes(dngs["uncompressed"])
    with pytest.raises(CalibrationFileError, match="size 64x48, calibration is for 320x240"):
        read_dng(path, expected_shape=(240, 320))
    assert read_dng(path, expected_shape=(HEIGHT, WIDTH)).bayer.shape == (HEIGHT, WIDTH)


def test_a_raw_image_in_a_subifd_is_the_one_checked_and_read(tmp_path, capfd):
    # rpicam-apps' layout: IFD 0 a thumbnail (NewSubFileType 1) with the DNG tags, the mosaic in a SubIFD.
    path = tmp_path / "rpicam.dng"
    camera = [(50706, 1, 4, bytes((1, 4, 0, 0)), True), (50708, 2, 0, "imx219", True)]
    mosaic = [tag for tag in MINIMAL_TAGS if tag[0] in (33421, 33422, 50714, 50717)]
    with tifffile.TiffWriter(path) as tif:
        tif.write(np.zeros((12, 16, 3), np.uint8), subifds=1, subfiletype=1, extratags=camera, metadata=None)
        tif.write(_mosaic(), photometric=32803, subfiletype=0, extratags=mosaic, metadata=None)
    raw = outcome(read_dng, path, capfd)
    np.testing.assert_array_equal(raw.bayer, _mosaic())
    assert (raw.sensor, raw.pattern, raw.black_level[0], raw.white_level) == ("imx219", "BGGR", 64.0, 1023)
    data = path.read_bytes()
    subifd = struct.unpack_from("<I", data, dng_entries(data)[330] + 8)[0]
    path.write_bytes(rewrite(data, ifd_entries(data, subifd)[256], value=2**31))  # the mosaic's width, not IFD 0's
    error = outcome(read_dng, path, capfd)
    assert isinstance(error, RawFormatError) and "declares an image of 2147483648x48 pixels" in error.problem


def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.dng"
    os.mkfifo(fifo)
    for read in (read_dng, read_brcm):
        with pytest.raises(RawFormatError, match="FIFO"):
            read(fifo)


# --- LibRaw's own messages --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def corrupt_ljpeg(tmp_path_factory, dngs) -> Path:
    """The lossless-JPEG DNG with its compressed data damaged: LibRaw prints "data corrupted at 352" on fd 2."""
    data = bytearray(dngs["ljpeg"])
    with tifffile.TiffFile(io.BytesIO(bytes(data))) as tif:
        start, length = tif.pages.first.dataoffsets[0], tif.pages.first.databytecounts[0]
    data[start + length // 8 : start + length // 8 + 16] = bytes(range(0, 256, 16))
    path = tmp_path_factory.mktemp("corrupt") / "corrupt.dng"
    path.write_bytes(bytes(data))
    return path


@pytest.mark.slow
def test_libraw_output_is_folded_into_the_one_error_line(corrupt_ljpeg):
    result = run("inspect", str(corrupt_ljpeg))
    assert_bad_input(result, str(corrupt_ljpeg), "LibRaw cannot read it", "LibRaw said: data corrupted at ")
    assert result.stderr.count("data corrupted") == 1  # LibRaw's own line is not printed beside it


@pytest.mark.slow
def test_libraw_output_stays_with_its_own_read_when_threads_read_at_once(tmp_path, capfd, corrupt_ljpeg, dngs):
    # Two threads, one reading a good DNG and one the corrupt one, many times: the descriptor swap is locked, so
    # every error carries LibRaw's message, no good read gets a warning, and fd 2 is restored every time.
    good = tmp_path / "good.dng"
    good.write_bytes(dngs["uncompressed"])
    errors: list[str] = []
    warned: list[str] = []

    def read_many(path: Path) -> None:
        for _ in range(40):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    read_dng(path)
                except RawFormatError as exc:
                    errors.append(exc.problem)
            warned.extend(str(w.message) for w in caught)

    threads = [threading.Thread(target=read_many, args=(p,)) for p in (good, corrupt_ljpeg)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(errors) == 40 and all("LibRaw said: data corrupted at" in e for e in errors), errors[:2]
    assert warned == [] and capfd.readouterr().err == ""
    print("after", file=sys.stderr)  # the real stderr is back
    assert capfd.readouterr().err == "after\n"


# --- BRCM: property tests --------------------------------------------------------------------------------------

BRCM_FIELDS = struct.Struct("<32s4H6I2H2B")
BRCM_FIELDS_AT = 0xB0
#: (index in the unpacked fields, largest value) of width, height, padding_right, padding_down, transform,
#: format, bayer_order and bayer_format.
BRCM_NUMBERS = [(1, 0xFFFF), (2, 0xFFFF), (3, 0xFFFF), (4, 0xFFFF), (11, 0xFFFF), (12, 0xFFFF), (13, 255), (14, 255)]


def _block_start(data: bytes) -> int:
    return len(data) - 445440  # the IMX219 640x480 block


@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_brcm_byte_changes_and_truncation_give_only_picamcal_errors(tmp_path, capfd, brcm, data):
    start = _block_start(brcm)
    where = st.one_of(
        st.integers(0, start - 1),  # the JPEG and its EXIF
        st.integers(start, start + BRCM_FIELDS_AT + BRCM_FIELDS.size),  # the raw header
        st.integers(0, len(brcm) - 1),
    )
    mutated = bytearray(brcm)
    for offset, value in data.draw(st.lists(st.tuples(where, st.integers(0, 255)), max_size=12)):
        mutated[offset] = value
    cut = data.draw(st.one_of(st.just(len(mutated)), st.integers(0, len(mutated))))
    path = tmp_path / "mutated.jpg"
    path.write_bytes(bytes(mutated[:cut]))
    outcome(read_brcm, path, capfd)


@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_brcm_header_field_rewrites_give_only_picamcal_errors(tmp_path, capfd, brcm, data):
    at = _block_start(brcm) + BRCM_FIELDS_AT
    fields = list(BRCM_FIELDS.unpack_from(brcm, at))
    for index, top in data.draw(st.lists(st.sampled_from(BRCM_NUMBERS), min_size=1, max_size=4)):
        fields[index] = data.draw(st.one_of(st.sampled_from([0, 1, 2, 3, 4, 5, 33, top]), st.integers(0, top)))
    if data.draw(st.booleans()):
        fields[0] = data.draw(st.binary(max_size=32))
    mutated = bytearray(brcm)
    BRCM_FIELDS.pack_into(mutated, at, *fields)
    path = tmp_path / "header.jpg"
    path.write_bytes(bytes(mutated))
    result = outcome(read_brcm, path, capfd)
    if isinstance(result, RawImage):  # only a header consistent with its block reads, and then exactly
        assert result.bayer.shape == (480, 640) and result.pattern in ("RGGB", "GBRG", "BGGR", "GRBG")


@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_brcm_exif_tag_rewrites_give_only_picamcal_errors(tmp_path, capfd, brcm, data):
    base = brcm.index(b"Exif\x00\x00") + 6
    order = "<" if brcm[base : base + 2] == b"II" else ">"
    entries = ifd_entries(brcm, struct.unpack_from(order + "I", brcm, base + 4)[0], order, base)
    entries.update(ifd_entries(brcm, struct.unpack_from(order + "I", brcm, entries[0x8769] + 8)[0], order, base))
    mutated = bytearray(brcm)
    for _ in range(data.draw(st.integers(1, 3))):
        at = data.draw(st.sampled_from(sorted(entries.values())))
        offset, code = data.draw(st.sampled_from([(2, "H"), (4, "I"), (8, "I")]))
        top = 0xFFFF if code == "H" else 2**32 - 1
        struct.pack_into(order + code, mutated, at + offset, data.draw(st.integers(0, top)))
    path = tmp_path / "exif.jpg"
    path.write_bytes(bytes(mutated))
    result = outcome(read_brcm, path, capfd)
    assert isinstance(result, RawImage)  # the EXIF is informative: the raw block still reads
    meta = result.metadata
    assert "exposure_time_s" not in meta or 0 < meta["exposure_time_s"] < math.inf
    assert "iso" not in meta or (isinstance(meta["iso"], int) and meta["iso"] > 0)


# --- BRCM: what each malformed field gives ----------------------------------------------------------------------


def _brcm_field(data: bytes, index: int, value: int) -> bytes:
    at = _block_start(data) + BRCM_FIELDS_AT
    fields = list(BRCM_FIELDS.unpack_from(data, at))
    fields[index] = value
    out = bytearray(data)
    BRCM_FIELDS.pack_into(out, at, *fields)
    return bytes(out)


@pytest.mark.parametrize(
    ("index", "value", "fragment"),
    [
        (12, 0, "the raw header's format is 0, not 33 (Bayer)"),
        (14, 9, "unknown bayer_format code 9"),
        (14, 4, "the raw header says 12-bit samples"),
        (13, 4, "unknown Bayer order code 4"),
        (1, 65535, "the raw header says 65535x480"),
        (3, 400, "inconsistent raw layout: padding_right 400"),
    ],
)
def test_a_malformed_brcm_header_field_is_a_one_line_error(tmp_path, capfd, brcm, index, value, fragment):
    path = tmp_path / "bad.jpg"
    path.write_bytes(_brcm_field(brcm, index, value))
    error = outcome(read_brcm, path, capfd)
    assert isinstance(error, RawFormatError) and fragment in error.problem, error


def test_brcm_expected_shape_is_checked_before_the_rows_are_read(tmp_path, brcm):
    path = tmp_path / "frame.jpg"
    path.write_bytes(brcm)
    with pytest.raises(CalibrationFileError, match="size 640x480, calibration is for 320x240"):
        read_brcm(path, expected_shape=(240, 320))
    assert read_brcm(path, expected_shape=(480, 640)).bayer.shape == (480, 640)


def test_brcm_malformed_exif_values_are_left_out_with_one_warning(tmp_path, brcm):
    # The MakerNote's gains of 0 and an ExposureTime of two values: informative, so warned and left out.
    from PIL import Image, TiffImagePlugin

    exif = Image.Exif()
    exif[272] = "RP_imx219"
    sub = exif.get_ifd(0x8769)
    sub[33434] = (TiffImagePlugin.IFDRational(1, 100), TiffImagePlugin.IFDRational(1, 50))
    sub[37500] = b"exp=10000 ag=512 gain_r=0 gain_b=1.5"
    head = io.BytesIO()
    Image.new("RGB", (32, 24)).save(head, "JPEG", exif=exif)
    path = tmp_path / "odd.jpg"
    path.write_bytes(head.getvalue() + brcm[_block_start(brcm) :])
    with pytest.warns(PicamcalWarning) as caught:
        raw = read_brcm(path)
    message = str(caught[0].message)
    assert len(caught) == 1 and "ExposureTime" in message and "gain_r=0" in message
    assert raw.metadata["analogue_gain"] == 2.0 and not {"exposure_time_s", "colour_gains"} & raw.metadata.keys()


# --- memory: forged sizes are refused before anything of that size is allocated -----------------------------------

CLI = (sys.executable, "-c", "from picamcal.cli import main; main()")


def _forged_dng(small: bytes, path: Path, width: int, height: int, *, sparse: bool) -> Path:
    """picamcal's small DNG declaring ``width`` x ``height``, its strip sized to match; sparse: the file as long
    as the strip says (holes, no disk used), so that LibRaw would decode it in full."""
    data = small
    for code, value in ((256, width), (257, height), (278, height), (279, width * height * 2)):
        data = rewrite(data, _entry(data, code), value=value)
    start = _strip_start(data)
    with open(path, "wb") as f:
        f.write(data[:start])
        if sparse:
            f.truncate(start + width * height * 2)
    return path


@pytest.fixture(scope="module")
def frames(tmp_path_factory, dngs, brcm) -> dict[str, Path]:
    """Small and full-size (3280x2464) legitimate DNG and BRCM files, and a 320x240 calibration."""
    folder = tmp_path_factory.mktemp("frames")
    full = RawImage(_mosaic(2464, 3280, seed=1), "BGGR", (64,) * 4, 1023, 10, "imx219")
    (folder / "small.dng").write_bytes(dngs["uncompressed"])
    (folder / "small.jpg").write_bytes(brcm)
    refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    calibrate(**refs).save(folder / "cal.npz")
    return {
        "small.dng": folder / "small.dng",
        "full.dng": write_dng(folder / "full.dng", full),
        "small.jpg": folder / "small.jpg",
        "full.jpg": write_brcm(folder / "full.jpg", full),
        "cal": folder / "cal.npz",
    }


def _correct(frames: dict[str, Path], source: Path, out: Path) -> tuple[int, str, int]:
    # No worker pool: the file is read in the process measured.
    return run_measured(*CLI, "correct", str(frames["cal"]), str(source), "--out", str(out), "--workers", "0")


@pytest.fixture(scope="module")
def budget(frames, tmp_path_factory) -> dict[str, float]:
    """What one legitimate 3280x2464 frame costs, and what each command costs refusing a small file.

    The frame: ``inspect`` of the full-size DNG beyond ``inspect`` of the 64x48 one (measured: about 18 MB, its
    16 MB mosaic read from the strips; 35 MB when LibRaw decoded it, LibRaw's buffer and picamcal's copy). A
    refusal may cost at most a quarter of that beyond the command's own refusal of a small file (``correct``
    refuses the small files too: they are not the calibration's size).
    """
    out = tmp_path_factory.mktemp("refused")
    code, _, small = run_measured(*CLI, "inspect", str(frames["small.dng"]))
    assert code == 0
    code, _, full = run_measured(*CLI, "inspect", str(frames["full.dng"]))
    assert code == 0 and full - small > 12 << 20, (small, full)  # the frame's cost is real, or this proves nothing
    refused = {name: _correct(frames, frames[name], out / name) for name in ("small.dng", "small.jpg")}
    assert all(code != 0 for code, _, _ in refused.values())
    return {
        "inspect": small,
        "correct dng": refused["small.dng"][2],
        "correct brcm": refused["small.jpg"][2],
        "frame": full - small,
    }


@pytest.mark.slow
def test_forged_dng_sizes_are_refused_in_far_less_memory_than_one_frame(tmp_path, frames, budget):
    # Before these checks, the sparse 16000x16000 file cost 1.5 GB.
    small = frames["small.dng"].read_bytes()
    sparse = _forged_dng(small, tmp_path / "sparse.dng", 16000, 16000, sparse=True)
    declared = _forged_dng(small, tmp_path / "declared.dng", 34000, 34000, sparse=False)
    for forged, size in ((sparse, "16000x16000"), (declared, "34000x34000")):
        code, stderr, peak = run_measured(*CLI, "inspect", str(forged))
        assert_bad_input(subprocess.CompletedProcess(CLI, code, "", stderr), str(forged), f"{size} pixels", "limit")
        assert peak - budget["inspect"] < budget["frame"] / 4, (forged.name, peak, budget)
    for forged, fragment in (
        (sparse, "declares an image of 16000x16000 pixels"),
        # legitimate, but larger than any mode of the calibration's sensor area: refused from its header
        (frames["full.dng"], "size 3280x2464, larger than the calibration's 320x240 sensor area"),
    ):
        # Exit 1 (a batch with a bad file) or 2: how a one-file batch ends is the batch's; here, what it costs.
        code, stderr, peak = _correct(frames, forged, tmp_path / forged.stem)
        assert code in (1, 2) and fragment in stderr and "Traceback" not in stderr, stderr
        assert peak - budget["correct dng"] < budget["frame"] / 4, (forged.name, peak, budget)


@pytest.mark.slow
def test_a_mismatched_dng_is_refused_before_it_is_decoded(frames, budget):
    # The library alone: read_dng with the calibration's shape refuses a legitimate 3280x2464 frame of another
    # size for what reading the 64x48 file costs, not what decoding the frame costs.
    script = "import sys; from picamcal.raw.dng import read_dng; read_dng(sys.argv[1], expected_shape={})"
    code, _, small = run_measured(sys.executable, "-c", script.format("None"), str(frames["small.dng"]))
    assert code == 0
    code, stderr, refused = run_measured(sys.executable, "-c", script.format((1232, 1640)), str(frames["full.dng"]))
    assert "CalibrationFileError" in stderr and "size 3280x2464, calibration is for 1640x1232" in stderr
    assert refused - small < budget["frame"] / 4, (small, refused, budget)


@pytest.mark.slow
def test_forged_brcm_files_are_refused_in_far_less_memory_than_one_frame(tmp_path, frames, budget):
    # A header declaring 65535x65535 in a valid block, and a sparse 1 GiB "JPEG" whose only BRCM is 32 MB from its
    # end (the diagnosis scans the last 64 MB: in 1 MB chunks now; through a memory map before, 30 MB more).
    data = frames["small.jpg"].read_bytes()
    header = tmp_path / "header.jpg"
    header.write_bytes(_brcm_field(_brcm_field(data, 1, 65535), 2, 65535))
    sparse = tmp_path / "sparse.jpg"
    with open(sparse, "wb") as f:
        f.write(data[: _block_start(data)])
        f.seek((1 << 30) - (32 << 20))
        f.write(b"BRCM")
        f.truncate(1 << 30)
    for forged, fragment in (
        (header, "the raw header says 65535x65535"),
        (sparse, "matches no known sensor mode"),
        (frames["full.jpg"], "size 3280x2464, larger than the calibration's 320x240 sensor area"),
    ):
        code, stderr, peak = _correct(frames, forged, tmp_path / forged.stem)
        assert code in (1, 2) and fragment in stderr and "Traceback" not in stderr, stderr
        assert peak - budget["correct brcm"] < budget["frame"] / 4, (forged.name, peak, budget)
