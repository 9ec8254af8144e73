"""Hardening of the buffer readers (picamera2 .npy + sidecar, picamcal raw .npz, headless dumps, read_raw).

Whatever the bytes, these readers raise only picamcal's own errors, and a size declared in a header is checked
before anything of that size is allocated: fuzz tests mutate real files written by picamcal's own writers, and
memory tests measure the peak resident memory of the command line refusing forged sizes.
"""

from __future__ import annotations

import copy
import io
import json
import math
import random
import re
import sys
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import run_measured
from picamcal.errors import CalibrationFileError, PicamcalError, PicamcalWarning, RawFormatError
from picamcal.raw import RawImage, read_raw, to_picamera2, write_dng, write_npz, write_picamera2_npy
from picamcal.raw.model import require_black_level
from picamcal.raw.packing import pack
from picamcal.raw.picamera2 import RAW_FORMATS

WIDTH, HEIGHT = 64, 48


def _raw(bits: int = 10, black: float | tuple = (64.0, 65.0, 66.0, 67.0), sensor: str | None = "imx219") -> RawImage:
    bayer = np.random.default_rng(1).integers(0, 2**bits, (HEIGHT, WIDTH), dtype=np.uint16)
    return RawImage(bayer, "BGGR", black, 2**bits - 1, bits, sensor, {"exposure_time_s": 0.01, "analogue_gain": 2.0})


def _npy_bytes(array: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.save(out, array)
    return out.getvalue()


def _npy_header(descr: object, fortran: object, shape: object, version: int = 1, length: int | None = None) -> bytes:
    """A .npy header as numpy writes it (a dict literal padded to 64 bytes), with any values and length field."""
    text = f"{{'descr': {descr!r}, 'fortran_order': {fortran!r}, 'shape': {shape!r}, }}"
    prefix = 10 if version == 1 else 12
    text += " " * (-(prefix + len(text) + 1) % 64) + "\n"
    size = len(text) if length is None else length
    field = size.to_bytes(2 if version == 1 else 4, "little")
    return b"\x93NUMPY" + bytes((version, 0)) + field + text.encode("latin1")


# --- mutations of real files ---------------------------------------------------------------------------------

_DESCRS = ["|u1", "<u2", ">u2", "<u4", "<i2", "|i1", "<f4", "<f8", "<c8", "|b1", "|O", "<U3", "|V4", "<M8[s]"]
_DESCRS += ["garbage", 5, [("a", "<u2")], [("a", "<u2"), ("b", "|u1")], ("<u2", (2,)), ("|u1", 10**12), [5], []]
_JSON_VALUES: list = [None, True, False, 0, -1, 1, 2, 3, 7, 10, 16, 64, 1023, 4096, 65535, 65536, 2**31, 2**64]
_JSON_VALUES += [10**400, -(10**30), 0.5, -0.0, 1e308, -1e-300, math.nan, math.inf, -math.inf, "", "x", "64"]
_JSON_VALUES += ["SBGGR10_CSI2P", "sbggr10_csi2p", "R10_CSI2P", "BGGR_PISP_COMP1", "YUV420", "BGGR", "imx219"]
_JSON_VALUES += ["ov9281", "picamcal-raw", "picamcal-picamera2", [], [1], [64, 48], [64.0, 48.0], [64, 48, 1]]
_JSON_VALUES += [[-64, 48], [10**9, 10**9], [4096] * 4, [4096] * 3, [math.nan] * 4, ["a"] * 4, [[1]], {}, {"a": 1}]
_JSON_VALUES += [{"bit_depth": 10}, {"format": "SBGGR10"}, [None] * 4, [1e400] * 4]
_DEEP = "\x00deep\x00"  # replaced by 10000 nested lists in the JSON text (json.dumps cannot write them)


def _random_shape(rng: random.Random) -> object:
    return rng.choice(
        [
            (),
            (rng.randint(0, 100),),
            (rng.randint(0, 100), rng.randint(0, 200)),
            (HEIGHT, rng.randint(0, 200), rng.randint(0, 3)),
            (rng.choice([-1, 0, 2, 10**6, 10**12, 2**62]), rng.choice([-5, 0, 96, 10**6, 10**12, 2**62])),
            (34000, 34000),
            (10**12,),
            [HEIGHT, 96],
            (HEIGHT, 96.0),
            "(48, 96)",
            None,
        ]
    )


def _mutate_npy(blob: bytes, rng: random.Random) -> bytes:
    """A .npy file's bytes with flipped bytes, cut short, or a rewritten (or cut) header over the same data."""
    header_end = 10 + int.from_bytes(blob[8:10], "little") if len(blob) >= 10 else 0
    data = blob[header_end:]
    kind = rng.randrange(6)
    if kind == 0:
        out = bytearray(blob)
        for _ in range(rng.randint(1, 8)):
            position = rng.randrange(min(len(out), 128)) if rng.random() < 0.7 else rng.randrange(len(out))
            out[position] = rng.randrange(256)
        return bytes(out)
    if kind == 1:
        return blob[: rng.randrange(len(blob))]
    if kind == 2:  # the header's text cut mid-way, its length field kept: numpy's tokenizer sees an open bracket
        text = blob[10:header_end]
        cut = rng.randrange(1, len(text))
        return blob[:10] + text[:cut] + b" " * (len(text) - cut - 1) + b"\n" + data
    descr = rng.choice(_DESCRS)
    fortran = rng.choice([False, True, False, 1, "no"])
    version = rng.choice([1, 1, 2])
    length = None if rng.random() < 0.9 else rng.randrange(0, 300)
    header = _npy_header(descr, fortran, _random_shape(rng), version, length)
    if kind == 5:
        data = data[: rng.randrange(len(data) + 1)] if data else data
    return header + data


def _json_paths(value: object, prefix: tuple = ()) -> list[tuple]:
    paths = [prefix]
    if isinstance(value, dict):
        for key, item in value.items():
            paths += _json_paths(item, (*prefix, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            paths += _json_paths(item, (*prefix, index))
    return paths


def _mutate_record(record: object, rng: random.Random) -> str:
    """A JSON record with one value replaced by another JSON value (or deleted, or an extra key), as text."""
    record = json.loads(json.dumps(record))
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        paths = _json_paths(record)
        path = rng.choice(paths)
        replacement = _DEEP if rng.random() < 0.03 else copy.deepcopy(rng.choice(_JSON_VALUES))
        if not path:
            record = replacement
            continue
        holder = record
        for key in path[:-1]:
            holder = holder[key]
        if isinstance(holder, dict) and rng.random() < 0.15:
            del holder[path[-1]]
        elif isinstance(holder, dict) and rng.random() < 0.1:
            holder[f"extra{rng.randrange(10)}"] = replacement
        else:
            holder[path[-1]] = replacement
    text = json.dumps(record)
    return text.replace(json.dumps(_DEEP), "[" * 10000 + "]" * 10000)


def _mutate_text(text: bytes, rng: random.Random) -> bytes:
    if rng.random() < 0.5:
        return text[: rng.randrange(len(text))]
    out = bytearray(text)
    for _ in range(rng.randint(1, 4)):
        out[rng.randrange(len(out))] = rng.randrange(256)
    return bytes(out)


def _zip(members: dict[str, bytes], rng: random.Random) -> bytes:
    out = io.BytesIO()
    compression = rng.choice([zipfile.ZIP_DEFLATED, zipfile.ZIP_DEFLATED, zipfile.ZIP_STORED])
    with zipfile.ZipFile(out, "w", compression) as archive:
        for name, content in members.items():
            archive.writestr(name, content)
    return out.getvalue()


def _mutate_npz(blob: bytes, rng: random.Random) -> bytes:
    """A raw .npz with its zip bytes flipped or cut, or its members rewritten, removed, renamed or replaced."""
    kind = rng.randrange(6)
    if kind == 0:
        out = bytearray(blob)
        for _ in range(rng.randint(1, 8)):
            out[rng.randrange(len(out))] = rng.randrange(256)
        return bytes(out)
    if kind == 1:
        return blob[: rng.randrange(len(blob))]
    with zipfile.ZipFile(io.BytesIO(blob)) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    if kind == 2:
        members["bayer.npy"] = _mutate_npy(members["bayer.npy"], rng)
    elif kind == 3:
        record = json.loads(str(np.load(io.BytesIO(members["metadata.npy"]))))
        members["metadata.npy"] = _npy_bytes(np.array(_mutate_record(record, rng)))
    elif kind == 4:
        replacement = rng.choice(
            [
                np.zeros((HEIGHT, WIDTH), np.float32),
                np.zeros((HEIGHT, WIDTH), np.int16) - 1,
                np.zeros((HEIGHT, WIDTH, 3), np.uint16),
                np.zeros(WIDTH, np.uint16),
                np.zeros((HEIGHT + 1, WIDTH), np.uint16),
                np.zeros((HEIGHT, WIDTH), np.uint8),
                np.zeros((HEIGHT, WIDTH), np.complex64),
                np.zeros((HEIGHT, WIDTH), [("a", "<u2")]),
                np.asfortranarray(np.arange(HEIGHT * WIDTH, dtype=np.uint16).reshape(HEIGHT, WIDTH)),
                np.array(5),
                np.array("text"),
            ]
        )
        members[rng.choice(["bayer.npy", "metadata.npy"])] = _npy_bytes(replacement)
    else:
        name = rng.choice(list(members))
        content = members.pop(name)
        if rng.random() < 0.5:
            members[rng.choice(["other.npy", "bayer", "unmixing.npy", name.upper()])] = content
    return _zip(members, rng)


_FORMAT_NAMES = [*RAW_FORMATS, "R10_CSI2P", "MONO_PISP_COMP1", "YUV420", "SBGGR10P", "", " sbggr10_csi2p "]


def _headless_options(rng: random.Random) -> dict:
    """Random read_raw options for a headless dump: mostly plausible, sometimes absurd."""

    def number(plausible: list) -> object:
        return rng.choice(plausible) if rng.random() < 0.7 else rng.choice([-1, 0, 1, 2**31, 10**12, 10**30, 2.5])

    size = rng.choice(
        [
            (WIDTH, HEIGHT),
            (number([2, 4, 32, 64, 320]), number([2, 6, 48, 240])),
            (60000, 60000),
            (WIDTH, HEIGHT, 1),
            (WIDTH,),
            (float(WIDTH), float(HEIGHT)),
            (True, 2),
            "64x48",
            None,
        ]
    )
    return {
        "raw_format": rng.choice(_FORMAT_NAMES) if rng.random() < 0.95 else rng.choice([5, None, b"SBGGR10"]),
        "size": size,
        "stride": rng.choice([None, None, number([80, 96, 128, 0]), 96.0, True]),
        "frame": rng.choice([None, 0, number([0, 1, 2]), -1, 1.0, False]),
        "sensor": rng.choice([None, "imx219", "imx298", "ov9281", "", 5]),
        "black_level": rng.choice([None, 64, [64] * 4, math.nan, -1, [64, 64], "64", math.inf, 10**400]),
    }


def _read(path: Path, **options) -> RawImage | None:
    """read_raw, quietly; None for a PicamcalError (anything else propagates and fails the test)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PicamcalWarning)
            return read_raw(path, **options)
    except PicamcalError as exc:  # naming the file, or its sidecar (the same name, .json)
        assert "\n" not in str(exc) and str(exc).startswith(str(path.with_suffix(""))), str(exc)
        return None


def _valid(raw: RawImage) -> None:
    assert raw.bayer.dtype == np.uint16 and raw.bayer.ndim == 2
    assert raw.height % 2 == 0 and raw.width % 2 == 0
    assert 1 <= raw.bit_depth <= 16 and 0 < raw.white_level <= 65535


@pytest.fixture(scope="module")
def originals(tmp_path_factory) -> dict[str, bytes]:
    """Files written by picamcal's own writers: picamera2 dumps (packed and unpacked), a raw npz, a headless dump."""
    folder = tmp_path_factory.mktemp("originals")
    files = {}
    for packed in (True, False):
        array, config, metadata = to_picamera2(_raw(), packed=packed)
        metadata.update(ExposureTime=10000, ColourGains=[1.5, 2.0], SensorTimestamp=123)
        path = write_picamera2_npy(folder / f"p{packed}.npy", array, config, metadata, sensor="imx219")
        files[f"npy{packed}"] = path.read_bytes()
        files[f"json{packed}"] = path.with_suffix(".json").read_bytes()
    files["npz"] = write_npz(folder / "a.npz", _raw()).read_bytes()
    files["dump"] = pack(_raw().bayer, 10, 96).tobytes() * 2
    return files


_FUZZ = settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.mark.slow
@_FUZZ
@given(rng=st.randoms(use_true_random=False), packed=st.booleans(), which=st.sampled_from(["npy", "json", "both"]))
def test_fuzz_mutated_picamera2_dumps_raise_only_picamcal_errors(tmp_path, originals, rng, packed, which):
    npy, sidecar = originals[f"npy{packed}"], originals[f"json{packed}"]
    if which in ("npy", "both"):
        npy = _mutate_npy(npy, rng)
    if which in ("json", "both"):
        record = json.loads(sidecar)
        sidecar = _mutate_record(record, rng).encode() if rng.random() < 0.8 else _mutate_text(sidecar, rng)
    path = tmp_path / "fuzz.npy"
    path.write_bytes(npy)
    path.with_suffix(".json").write_bytes(sidecar)
    if (raw := _read(path)) is not None:
        _valid(raw)


@_FUZZ
@given(rng=st.randoms(use_true_random=False))
def test_fuzz_mutated_raw_npz_files_raise_only_picamcal_errors(tmp_path, originals, rng):
    path = tmp_path / "fuzz.npz"
    path.write_bytes(_mutate_npz(originals["npz"], rng))
    if (raw := _read(path)) is not None:
        _valid(raw)


@_FUZZ
@given(rng=st.randoms(use_true_random=False), content=st.one_of(st.binary(max_size=2000), st.just(b"")))
def test_fuzz_headless_options_on_any_bytes_raise_only_picamcal_errors(tmp_path, originals, rng, content):
    path = tmp_path / "fuzz.raw"
    path.write_bytes(content if rng.random() < 0.5 else originals["dump"])
    options = _headless_options(rng)
    if (raw := _read(path, **options)) is not None:
        _valid(raw)
        assert raw.bayer.shape == (options["size"][1], options["size"][0])


@_FUZZ
@given(rng=st.randoms(use_true_random=False))
def test_fuzz_overrides_raise_only_picamcal_errors(tmp_path, originals, rng):
    path = tmp_path / "x.npz"
    path.write_bytes(originals["npz"])
    options = {
        "pattern": rng.choice([None, "RGGB", "rggb", "XYZW", "", 5, ["RGGB"]]),
        "black_level": rng.choice([None, 0, 64, [60, 61, 62, 63], math.nan, -1, 2000, [64, 64], "64", [None] * 4]),
        "sensor": rng.choice([None, "imx477", "ov9281", "", 5, b"imx219"]),
        "verify": rng.choice([True, False]),
    }
    if (raw := _read(path, **options)) is not None:
        _valid(raw)
        require_black_level(raw)


# --- each reader checks the declared size first -------------------------------------------------------------


@pytest.fixture()
def files(tmp_path, originals) -> dict[str, Path]:
    paths = {"npy": tmp_path / "p.npy", "npz": tmp_path / "a.npz", "dump": tmp_path / "d.raw"}
    paths["dng"] = write_dng(tmp_path / "w.dng", _raw())
    paths["npy"].write_bytes(originals["npyTrue"])
    paths["npy"].with_suffix(".json").write_bytes(originals["jsonTrue"])
    paths["npz"].write_bytes(originals["npz"])
    paths["dump"].write_bytes(originals["dump"])
    return paths


HEADLESS = {"raw_format": "SBGGR10_CSI2P", "size": (WIDTH, HEIGHT)}


@pytest.mark.parametrize("kind", ["npy", "npz", "dump", "dng"])
def test_expected_shape_is_checked_by_every_reader(files, kind):
    options = HEADLESS if kind == "dump" else {}
    raw = read_raw(files[kind], expected_shape=(HEIGHT, WIDTH), **options)
    np.testing.assert_array_equal(raw.bayer, _raw().bayer)  # bit-exact through every writer
    with pytest.raises(CalibrationFileError) as info:
        read_raw(files[kind], expected_shape=(240, 320), **options)
    assert str(info.value) == (
        f"{files[kind]}: image does not match the calibration: size {WIDTH}x{HEIGHT}, calibration is for 320x240"
    )


@pytest.mark.parametrize("kind", ["npy", "npz", "dump"])
def test_the_pixel_limit_is_stated_and_can_be_raised(files, kind, monkeypatch):
    options = HEADLESS if kind == "dump" else {}
    monkeypatch.setenv("PICAMCAL_MAX_PIXELS", str(WIDTH * HEIGHT - 1))
    with pytest.raises(RawFormatError) as info:
        read_raw(files[kind], **options)
    assert "declares an image of 64x48 pixels" in _one_line(info, files[kind])
    assert "(set PICAMCAL_MAX_PIXELS to read larger images)" in str(info.value)
    monkeypatch.setenv("PICAMCAL_MAX_PIXELS", str(WIDTH * HEIGHT))
    assert read_raw(files[kind], **options).bayer.shape == (HEIGHT, WIDTH)


def _one_line(excinfo, path: Path) -> str:
    message = str(excinfo.value)
    assert message.startswith(f"{path}: ") and "\n" not in message, message
    return message


# --- picamera2 .npy and its sidecar --------------------------------------------------------------------------


def _header_and_data(blob: bytes) -> tuple[bytes, bytes]:
    end = 10 + int.from_bytes(blob[8:10], "little")
    return blob[:end], blob[end:]


@pytest.mark.parametrize(
    ("header", "message"),
    [
        (_npy_header("|O", False, (HEIGHT, 96)), "object array of shape"),
        (_npy_header("<c8", False, (HEIGHT, 96)), "complex64 array of shape"),
        (_npy_header("<f4", False, (HEIGHT, 96)), "float32 array of shape"),
        (_npy_header([("a", "|u1")], False, (HEIGHT, 96)), "array of shape (48, 96), not a raw buffer"),
        (_npy_header("|u1", False, (HEIGHT, 96, 1)), "uint8 array of shape (48, 96, 1), not a raw buffer"),
        (_npy_header("|u1", False, (0, 2**62)), "uint8 array of shape (0, 4611686018427387904)"),
        (_npy_header("|u1", False, (HEIGHT, 2**40)), "truncated .npy"),
        (_npy_header("|u1", "yes", (HEIGHT, 96)), "corrupt .npy file (ValueError: fortran_order is not a valid bool"),
        (_npy_header("nonsense", False, (HEIGHT, 96)), "corrupt .npy file (ValueError: descr is not a valid dtype"),
        (_npy_header("|u1", False, (HEIGHT, 96), version=3), "unsupported .npy version 3.0"),
    ],
)
def test_npy_headers_that_are_no_raw_buffer_are_refused(files, header, message):
    _, data = _header_and_data(files["npy"].read_bytes())
    files["npy"].write_bytes(header + data)
    with pytest.raises(RawFormatError) as info:
        read_raw(files["npy"])
    assert message in _one_line(info, files["npy"])


def test_an_npy_header_cut_mid_way_is_one_line_not_a_tokenizer_error(files):
    header, data = _header_and_data(files["npy"].read_bytes())
    cut = header.index(b"'shape': (") + 12  # inside the shape's parentheses: numpy's tokenizer raises TokenError
    files["npy"].write_bytes(header[:cut] + b" " * (len(header) - cut - 1) + b"\n" + data)
    with pytest.raises(RawFormatError) as info:
        read_raw(files["npy"])
    assert "corrupt .npy file (TokenError: " in _one_line(info, files["npy"])


def test_a_fortran_ordered_or_flat_buffer_reads_the_same(files):
    _, data = _header_and_data(files["npy"].read_bytes())
    shape = (HEIGHT, 96)  # to_picamera2's packed rows: 80 bytes of RAW10 padded to 96
    rows = np.frombuffer(data, np.uint8).reshape(shape)
    fortran = _npy_header("|u1", True, shape) + rows.T.tobytes()  # column-major bytes, as numpy writes order F
    flat = _npy_header("|u1", False, (HEIGHT * 96,)) + data
    for blob in (fortran, flat):
        files["npy"].write_bytes(blob)
        np.testing.assert_array_equal(read_raw(files["npy"]).bayer, _raw().bayer)


def _sidecar(files, change) -> Path:
    record = json.loads(files["npy"].with_suffix(".json").read_text())
    change(record)
    files["npy"].with_suffix(".json").write_text(json.dumps(record).replace('"DEEP"', "[" * 10000 + "]" * 10000))
    return files["npy"].with_suffix(".json")


@pytest.mark.parametrize(
    ("change", "message", "names_sidecar"),
    [
        (lambda r: r["config"]["raw"].update(size=["64", 48]), "the raw width must be an integer", False),
        (lambda r: r["config"]["raw"].update(size=[64, 48, 1]), "'size' must be (width, height)", False),
        (lambda r: r["config"]["raw"].update(size=[64, 10**400]), "the raw height must be an integer from 2", False),
        (lambda r: r["config"]["raw"].update(stride="96"), "the stride must be an integer", False),
        (lambda r: r["config"]["raw"].update(stride=10**6), "stride of 1000000 bytes is longer than a camera", False),
        (lambda r: r["config"]["raw"].update(format="SBGGR10_CSI3P"), "unknown raw format 'SBGGR10_CSI3P'", False),
        (lambda r: r["config"]["raw"].update(format=10), "the raw format must be a string", False),
        (lambda r: r["metadata"].update(SensorBlackLevels=[4096] * 3), "SensorBlackLevels must be 4 numbers", False),
        (lambda r: r["metadata"].update(SensorBlackLevels=[math.nan] * 4), "not a finite number", False),
        (lambda r: r["metadata"].update(SensorBlackLevels=[-1] * 4), "outside the 16-bit range", False),
        (lambda r: r["metadata"].update(SensorBlackLevels=[10**400] * 4), "not a finite number", False),
        (lambda r: r["metadata"].update(SensorBlackLevels=[65535] * 4), "is not below the white level 1023", False),
        (lambda r: r["metadata"].update(ExposureTime="1/60"), "metadata ExposureTime must be numeric", False),
        (lambda r: r.update(sensor=5), "'sensor' must be a name or null", True),
        (lambda r: r.update(metadata="DEEP"), "corrupt sidecar of p.npy (RecursionError", True),
    ],
)
def test_sidecar_values_of_the_wrong_kind_are_one_line(files, change, message, names_sidecar):
    sidecar = _sidecar(files, change)
    with pytest.raises(RawFormatError) as info:
        read_raw(files["npy"])
    assert message in _one_line(info, sidecar if names_sidecar else files["npy"])


def test_a_sidecar_that_is_a_fifo_is_refused_without_blocking(files):
    import os

    sidecar = files["npy"].with_suffix(".json")
    sidecar.unlink()
    os.mkfifo(sidecar)
    with pytest.raises(RawFormatError) as info:
        read_raw(files["npy"])
    assert "is a FIFO (named pipe), not a regular file" in _one_line(info, sidecar)


def test_a_buffer_larger_than_its_frame_is_refused_unread(files):
    # The sidecar says 64x48 RAW10 (rows of 80 bytes; at most 2 * 80 + 256 per row); the header declares 48 rows
    # of 10^6 bytes and the file holds them (sparse): refused from the header, before 48 MB are read.
    path = files["npy"]
    with open(path, "wb") as f:
        f.write(_npy_header("|u1", False, (HEIGHT, 10**6)))
        f.truncate(f.tell() + HEIGHT * 10**6)
    with pytest.raises(RawFormatError) as info:
        read_raw(path)
    assert "a buffer of 48000000 bytes is larger than a 64x48 SBGGR10_CSI2P frame can be (at most 19968 bytes)" in (
        _one_line(info, path)
    )


# --- picamcal raw .npz ----------------------------------------------------------------------------------------


def _rewrite_npz(path: Path, **members: bytes | None) -> None:
    with zipfile.ZipFile(path) as archive:
        contents = {name: archive.read(name) for name in archive.namelist()}
    for name, content in members.items():
        contents.pop(f"{name}.npy")
        if content is not None:
            contents[f"{name}.npy"] = content
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, content in contents.items():
            archive.writestr(name, content)


def _record_of(path: Path) -> dict:
    with np.load(path) as data:
        return json.loads(str(data["metadata"]))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda r: r.pop("white_level"), "corrupt picamcal raw record: no 'white_level'"),
        (lambda r: r.update(white_level="1023"), "white_level must be a whole number from 1 to 1023, not '1023'"),
        (lambda r: r.update(white_level=1e400), "white_level must be a whole number from 1 to 1023, not inf"),
        (lambda r: r.update(white_level=4095), "white_level must be a whole number from 1 to 1023, not 4095"),
        (lambda r: r.update(bit_depth=None), "bit_depth must be a whole number from 1 to 16, not None"),
        (lambda r: r.update(black_level=[64, 64, 64]), "black_level 64 64 64: a black level is 1 or 4 finite numbers"),
        (lambda r: r.update(black_level=[64, 64, 64, math.inf]), "black_level 64 64 64 inf: a black level is"),
        (lambda r: r.update(black_level=[64, 64, 64, math.nan]), "is part unknown (NaN): give all four or none"),
        (lambda r: r.update(black_level=2000), "black_level 2000 2000 2000 2000 is not below the white level 1023"),
        (lambda r: r.update(black_level={"r": 64}), "a black level is 1 or 4 finite numbers >= 0"),
        (lambda r: r.update(pattern=["BGGR"]), "unknown Bayer pattern ['BGGR']"),
        (lambda r: r.update(sensor=219), "sensor must be a name or None, not 219"),
        (lambda r: r.update(metadata=[1, 2]), "'metadata' must be an object"),
        (lambda r: r.update(version=True), "unsupported picamcal raw version 'True'"),
    ],
)
def test_raw_npz_records_with_wrong_values_are_one_line(files, change, message):
    record = _record_of(files["npz"])
    change(record)
    _rewrite_npz(files["npz"], metadata=_npy_bytes(np.array(json.dumps(record))))
    with pytest.raises(RawFormatError) as info:
        read_raw(files["npz"])
    assert message in _one_line(info, files["npz"])


def test_raw_npz_unknown_black_level_round_trips_as_nan(tmp_path):
    raw = read_raw(write_npz(tmp_path / "x.npz", _raw(black=math.nan, sensor=None)))
    assert all(math.isnan(b) for b in raw.black_level)
    with pytest.raises(RawFormatError, match="no black level"):
        require_black_level(raw)


@pytest.mark.parametrize(
    ("members", "message"),
    [
        ({"bayer": None}, "not a picamcal raw image (no 'bayer' array)"),
        ({"metadata": None}, "not a picamcal raw image (no 'bayer' array)"),
        ({"bayer": _npy_bytes(np.zeros((HEIGHT, WIDTH), np.float32))}, "bayer.npy is a float32 array"),
        ({"bayer": _npy_bytes(np.zeros((HEIGHT, WIDTH), "<i2"))}, "bayer.npy is a int16 array"),
        ({"bayer": _npy_bytes(np.zeros((2, HEIGHT, WIDTH), np.uint16))}, "not a 2-D uint16 mosaic"),
        ({"bayer": _npy_bytes(np.zeros((HEIGHT, WIDTH), [("a", "<u2")]))}, "not a 2-D uint16 mosaic"),
        ({"bayer": _npy_bytes(np.zeros((HEIGHT + 1, WIDTH), np.uint16))}, "needs even width and height, got 64x49"),
        ({"metadata": _npy_bytes(np.array([1, 2]))}, "metadata.npy is a int64 array of shape (2,), not a JSON text"),
        ({"metadata": _npy_bytes(np.array("[" * 10000 + "]" * 10000))}, "corrupt picamcal raw record (RecursionError"),
        ({"bayer": _npy_header("<u2", False, (10**6, 10**6))}, "declares an image of 1000000x1000000 pixels"),
        ({"bayer": _npy_header("<u2", False, (HEIGHT, WIDTH)) + bytes(100)}, "member bayer.npy holds 228 bytes"),
        ({"bayer": _npy_header("<u2", False, (HEIGHT, WIDTH))[:40]}, "corrupt member bayer.npy (ValueError: EOF"),
    ],
)
def test_raw_npz_members_that_are_missing_or_wrong_are_one_line(files, members, message):
    _rewrite_npz(files["npz"], **members)
    with pytest.raises(RawFormatError) as info:
        read_raw(files["npz"])
    assert message in _one_line(info, files["npz"])


def test_a_damaged_deflate_stream_is_one_line(files):
    blob = bytearray(files["npz"].read_bytes())
    start = blob.index(b"bayer.npy") + len("bayer.npy") + 200  # inside the mosaic's compressed bytes
    blob[start : start + 16] = bytes(16)
    files["npz"].write_bytes(bytes(blob))
    with pytest.raises(RawFormatError) as info:
        read_raw(files["npz"])
    assert "corrupt picamcal raw file (bayer.npy: " in _one_line(info, files["npz"])


# --- headless dumps -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"size": (2**40, 2)}, "declares an image of 1099511627776x2 pixels"),
        ({"size": (60000, 60000)}, "declares an image of 60000x60000 pixels (3600 MP), over the limit"),
        ({"size": (WIDTH, HEIGHT, 1)}, "the frame size must be (width, height)"),
        ({"size": "64x48"}, "the frame size must be (width, height)"),
        ({"size": (64.5, 48)}, "the frame size must be two whole numbers"),
        ({"size": (True, 2)}, "the frame size must be two whole numbers"),
        ({"stride": 2**40}, "a stride of 1099511627776 bytes is longer than any camera pads 64 pixels"),
        ({"stride": 96.0}, "a stride of 96.0 bytes is too short"),
        ({"frame": 2**70}, "frame 1180591620717411303424 is past the end: the file holds 2 frame(s)"),
        ({"frame": 1.0}, "the frame must be a whole number from 0, not 1.0"),
        ({"raw_format": 10}, "a raw format is a name such as 'SBGGR10_CSI2P', not 10"),
        ({"sensor": 219}, "the sensor is a name such as 'imx219', not 219"),
        ({"black_level": math.nan}, "--black-level nan: a black level is 1 or 4 finite numbers >= 0"),
        ({"black_level": [64, -1, 64, 64]}, "--black-level 64 -1 64 64: a black level is 1 or 4 finite numbers"),
    ],
)
def test_headless_options_that_overflow_or_do_not_fit_are_one_line(files, options, message):
    with pytest.raises(RawFormatError) as info:
        read_raw(files["dump"], **{**HEADLESS, **options})
    assert message in _one_line(info, files["dump"])


# --- overrides and the RawImage itself -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("black_level", "message"),
    [
        (math.nan, "--black-level nan: a black level is 1 or 4 finite numbers >= 0 (DN)"),
        ([64, 64, math.inf, 64], "--black-level 64 64 inf 64: a black level is 1 or 4 finite numbers"),
        (-2, "--black-level -2: a black level is 1 or 4 finite numbers >= 0"),
        ([64, 64], "--black-level 64 64: a black level is 1 or 4 finite numbers"),
        ("64", "--black-level '64': a black level"),
        (1023, "--black-level 1023 is not below the white level 1023"),
    ],
)
def test_a_black_level_override_that_is_not_a_level_is_refused(files, black_level, message):
    with pytest.raises(RawFormatError) as info:
        read_raw(files["npz"], black_level=black_level)
    assert message in _one_line(info, files["npz"])


def test_cli_black_level_nan_is_one_line_naming_the_option(files):
    from test_cli import assert_bad_input, run

    assert_bad_input(run("inspect", str(files["npz"]), "--black-level", "nan"), "--black-level", "nan")


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"bayer": np.zeros((4, 4), np.float64)}, "must be uint16, got float64"),
        ({"bayer": np.zeros((4, 4), np.int32)}, "must be uint16, got int32"),
        ({"bayer": np.zeros((4, 4, 3), np.uint16)}, "must be a 2-D array"),
        ({"bayer": np.zeros(16, np.uint16)}, "must be a 2-D array"),
        ({"bayer": np.zeros((4, 6), np.uint16)[:, :5]}, "even width and height, got 5x4"),
        ({"bayer": [[1, 2], [3]]}, "must be a 2-D uint16 array"),
        ({"pattern": None}, "unknown Bayer pattern None"),
        ({"black_level": (64, 64, math.nan, 64)}, "part unknown (NaN)"),
        ({"black_level": -math.inf}, "a black level is 1 or 4 finite numbers >= 0"),
        ({"black_level": 1023}, "is not below the white level 1023"),
        ({"white_level": 1023.0}, "white_level must be a whole number from 1 to 1023, not 1023"),
        ({"white_level": 0}, "white_level must be a whole number from 1 to 1023, not 0"),
        ({"bit_depth": 17}, "bit_depth must be a whole number from 1 to 16, not 17"),
        ({"bit_depth": True}, "bit_depth must be a whole number from 1 to 16, not True"),
        ({"sensor": 219}, "sensor must be a name or None"),
        ({"metadata": [("path", "x")]}, "metadata must be a dict, not list"),
    ],
)
def test_raw_image_refuses_fields_no_camera_makes(fields, message):
    base = {"bayer": np.zeros((4, 4), np.uint16), "pattern": "RGGB", "black_level": 64, "white_level": 1023}
    with pytest.raises(RawFormatError) as info:
        RawImage(**{**base, "bit_depth": 10, **fields})
    assert message in str(info.value)


def test_raw_image_keeps_an_unknown_black_level_and_normalises_numbers():
    raw = RawImage(np.zeros((2, 2), np.uint16), "RGGB", math.nan, np.int64(1023), np.uint8(10))
    assert all(math.isnan(b) for b in raw.black_level)
    assert (type(raw.white_level), type(raw.bit_depth)) == (int, int)
    fortran = RawImage(np.asfortranarray(np.arange(16, dtype=np.uint16).reshape(4, 4)), "RGGB", [1, 2, 3, 4], 15, 4)
    assert fortran.black_level == (1.0, 2.0, 3.0, 4.0) and fortran.bayer[1, 0] == 4


# --- memory: forged sizes are refused for less than a real frame costs ------------------------------------------
# Each test measures, in its own run, `picamcal inspect` refusing a file of junk (the baseline: the command's
# imports, and inspect's second try of the file as a processed image, but no pixels), `inspect` of one legitimate
# IMX219 full frame (3280x2464) in the format, and `inspect` of each forged file. A forged file must be refused
# (exit 2, one line naming the file) with a peak below the baseline plus a quarter of what the legitimate frame
# costs over it: decoding any forged size at all would cost at least a frame.

FULL = (3280, 2464)


def _cli(*args: str) -> tuple[int, str, int]:
    """Exit status, stderr and peak resident memory in bytes of ``picamcal ARGS``."""
    return run_measured(sys.executable, "-c", "from picamcal.cli import main; main()", *args)


def _full_frame() -> RawImage:
    # A smooth ramp: decoding it costs what any frame does, and it compresses (and so is written) quickly.
    bayer = np.add.outer(np.arange(FULL[1]) // 8, np.arange(FULL[0]) // 8).astype(np.uint16) + 64
    return RawImage(bayer, "BGGR", 64, 1023, 10, "imx219")


def _assert_refused_cheaply(legit: list[str], forged: list[tuple[list[str], str]]) -> None:
    junk = Path(legit[0]).with_name(f"junk{Path(legit[0]).suffix}")
    junk.write_bytes(np.random.default_rng(3).integers(0, 256, 1000, dtype=np.uint8).tobytes())
    status, err, baseline = _cli("inspect", str(junk), *legit[1:])
    assert status == 2, err
    status, err, legit_peak = _cli("inspect", *legit)
    assert status == 0, err
    allowed = baseline + (legit_peak - baseline) / 4
    for args, fragment in forged:
        status, err, peak = _cli("inspect", *args)
        lines = err.strip().splitlines()
        assert status == 2 and len(lines) == 1 and lines[0].startswith(f"picamcal: error: {args[0]}: "), err
        assert fragment in lines[0], lines[0]
        mib = f"{peak / 2**20:.0f} MiB; a real frame {legit_peak / 2**20:.0f}, baseline {baseline / 2**20:.0f}"
        assert peak < allowed, f"{args[0]}: {mib}"
        print(f"{Path(args[0]).name}: {mib}")


def _sparse(path: Path, head: bytes, size: int) -> Path:
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(size)
    return path


@pytest.mark.slow
def test_memory_forged_picamera2_npy_sizes(tmp_path):
    array, config, metadata = to_picamera2(_full_frame())
    legit = write_picamera2_npy(tmp_path / "legit.npy", array, config, metadata, sensor="imx219")
    forged = []
    # 34000 x 34000 RAW10 (rows of 42528 bytes) as the sidecar and header declare it, in a 1.4 GB sparse file.
    huge = _sparse(tmp_path / "huge.npy", _npy_header("|u1", False, (34000, 42528)), 34000 * 42528 + 128)
    config34 = {"raw": {"format": "SBGGR10_CSI2P", "size": [34000, 34000], "stride": 42528}, "sensor": {}}
    record = {"format": "picamcal-picamera2", "version": 1, "config": config34, "metadata": {}, "sensor": "imx219"}
    huge.with_suffix(".json").write_text(json.dumps(record))
    forged.append(([str(huge)], "declares an image of 34000x34000 pixels (1156 MP), over the limit"))
    # The same buffer under the legitimate frame's sidecar: larger than that frame can be.
    wide = _sparse(tmp_path / "wide.npy", _npy_header("|u1", False, (34000, 42528)), 34000 * 42528 + 128)
    wide.with_suffix(".json").write_bytes(legit.with_suffix(".json").read_bytes())
    forged.append(([str(wide)], "is larger than a 3280x2464 SBGGR10_CSI2P frame can be"))
    _assert_refused_cheaply([str(legit)], forged)


def _zip_member(path: Path, members: dict[str, bytes], stream: tuple[str, bytes, int] | None = None) -> Path:
    """A zip of small members and, optionally, one member of a header followed by ``count`` zero bytes."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        for name, content in members.items():
            archive.writestr(name, content)
        if stream is not None:
            name, head, count = stream
            with archive.open(name, "w", force_zip64=True) as member:
                member.write(head)
                zeros = bytes(1 << 24)
                for start in range(0, count, len(zeros)):
                    member.write(zeros[: min(len(zeros), count - start)])
    return path


@pytest.mark.slow
def test_memory_forged_raw_npz_sizes(tmp_path):
    legit = write_npz(tmp_path / "legit.npz", _full_frame())
    with zipfile.ZipFile(legit) as archive:
        metadata = archive.read("metadata.npy")
    forged = []
    # A bomb: 0.6 MB of deflate inflating to a 16000 x 20000 uint16 mosaic of 640 MB.
    bomb = tmp_path / "bomb.npz"
    _zip_member(bomb, {"metadata.npy": metadata}, ("bayer.npy", _npy_header("<u2", False, (16000, 20000)), 64 * 10**7))
    assert bomb.stat().st_size < 10**6
    forged.append(([str(bomb)], "declares an image of 20000x16000 pixels (320 MP), over the limit"))
    # A member whose header declares a 64x48 mosaic but which inflates to 64 MB: refused from the zip's directory.
    stuffed = tmp_path / "stuffed.npz"
    _zip_member(stuffed, {"metadata.npy": metadata}, ("bayer.npy", _npy_header("<u2", False, (HEIGHT, WIDTH)), 2**26))
    forged.append(([str(stuffed)], "member bayer.npy holds 67108992 bytes, but its header declares a 64x48"))
    # A header claiming 10^12 elements over 16 bytes of data.
    claims = tmp_path / "claims.npz"
    _zip_member(claims, {"metadata.npy": metadata, "bayer.npy": _npy_header("<u2", False, (10**6, 10**6)) + bytes(16)})
    forged.append(([str(claims)], "declares an image of 1000000x1000000 pixels"))
    _assert_refused_cheaply([str(legit)], forged)


@pytest.mark.slow
def test_memory_forged_headless_size(tmp_path):
    legit = tmp_path / "legit.raw"
    legit.write_bytes(pack(_full_frame().bayer, 10, 4128).tobytes())  # RAW10 rows of 4100 bytes padded to 4128
    options = ["--raw-format", "SRGGB10_CSI2P"]
    forged = [([str(legit), *options, "--size", "60000x60000"], "declares an image of 60000x60000 pixels (3600 MP)")]
    _assert_refused_cheaply([str(legit), *options, "--size", "3280x2464"], forged)


def test_the_docs_limits_example_runs(tmp_path, monkeypatch, capsys):
    text = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    section = text[text.index("## Limits") :].split("\n## ", 1)[0]
    (block,) = re.findall(r"```python\n(.*?)```", section, re.DOTALL)
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("PICAMCAL_MAX_PIXELS", raising=False)
    exec(compile(block, "docs/formats.md", "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    expected = [line.split("# ")[-1].removesuffix("(set ...)") for line in block.splitlines() if "print(error)" in line]
    assert len(printed) == len(expected) == 3
    for line, start in zip(printed, expected, strict=True):
        assert line.startswith(start), (line, start)
