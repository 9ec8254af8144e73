"""The plain DNGs read from their strips (picamcal.raw.dng.plain) give LibRaw's result bit for bit, and every
other DNG is still LibRaw's to decode."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import tifffile

from picamcal.calibrate import calibrate
from picamcal.errors import CalibrationFileError, RawFormatError
from picamcal.raw import RawImage, read_raw, write_dng
from picamcal.raw.dng import read_dng
from picamcal.raw.dng.libraw import decode
from picamcal.raw.dng.plain import is_plain
from picamcal.raw.dng.reader import raw_layout
from picamcal.raw.dng.tiff import TiffFile
from picamcal.simulate import make_camera, simulate_references
from test_hardening_dng_brcm import dng_entries, rewrite  # IFD 0's entries; one entry's fields rewritten

HEIGHT, WIDTH = 48, 64
#: Tags of a DNG's mosaic: CFA 2x2 BGGR, DNG version, BlackLevelRepeatDim 2x2, per-site BlackLevel, WhiteLevel.
MOSAIC_TAGS = [
    (33421, 3, 2, (2, 2), True),
    (33422, 1, 4, bytes((2, 1, 1, 0)), True),
    (50713, 3, 2, (2, 2), True),
    (50714, 3, 4, (60, 61, 62, 63), True),
    (50717, 4, 1, 1023, True),
]
CAMERA_TAGS = [(50706, 1, 4, bytes((1, 4, 0, 0)), True), (50708, 2, 0, "imx219", True)]


def mosaic(height: int = HEIGHT, width: int = WIDTH, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 1024, (height, width), dtype=np.uint16)


def plain(path: Path) -> bool:
    """Whether read_dng reads ``path`` from its strips (rather than by LibRaw)."""
    with open(path, "rb") as f:
        tiff = TiffFile(f, os.fstat(f.fileno()).st_size, path)
        ifd, layout = raw_layout(tiff, tiff.ifd(tiff.first_ifd, "IFD 0"))
        return is_plain(tiff, ifd, layout)


def assert_libraws(path: Path) -> RawImage:
    """read_dng's mosaic, pattern and levels are what LibRaw decodes from ``path``."""
    raw = read_dng(path)
    found = decode(path, None, [])
    np.testing.assert_array_equal(raw.bayer, found.bayer)
    assert raw.bayer.dtype == np.uint16 and raw.bayer.flags.c_contiguous
    assert (raw.pattern, raw.black_level, raw.white_level) == (found.pattern, found.black, found.white)
    return raw


def write_tiff_dng(path: Path, data: np.ndarray, tags: list, *, subifd: bool = False, **kwargs) -> Path:
    """A DNG written by tifffile: the mosaic in IFD 0, or (rpicam-apps' layout) in a SubIFD after a thumbnail."""
    with tifffile.TiffWriter(path, byteorder=kwargs.pop("byteorder", "<")) as tif:
        if subifd:
            tif.write(np.zeros((12, 16, 3), np.uint8), subifds=1, subfiletype=1, extratags=CAMERA_TAGS, metadata=None)
            tif.write(data, photometric=32803, subfiletype=0, extratags=tags, metadata=None, **kwargs)
        else:
            tif.write(data, photometric=32803, extratags=CAMERA_TAGS + tags, metadata=None, **kwargs)
    return path


@pytest.mark.parametrize("pattern", ["RGGB", "GRBG", "GBRG", "BGGR"])
def test_picamcals_own_dngs_are_plain_and_read_as_libraw_does(tmp_path, pattern):
    raw = RawImage(mosaic(), pattern, (64, 65, 66, 67), 1023, 10, "imx219", {"exposure_time_s": 0.01})
    path = write_dng(tmp_path / "own.dng", raw)
    assert plain(path)
    again = assert_libraws(path)
    np.testing.assert_array_equal(again.bayer, raw.bayer)
    assert (again.pattern, again.black_level, again.sensor) == (pattern, (64.0, 65.0, 66.0, 67.0), "imx219")


def test_a_simulated_frame_with_gain_map_opcodes_reads_as_libraw_does(tmp_path):
    refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    path = write_dng(tmp_path / "white.dng", refs["white"], gain_map=calibrate(**refs))
    assert plain(path)
    np.testing.assert_array_equal(assert_libraws(path).bayer, refs["white"].bayer)


def rational_blacks(values: tuple[float, ...]) -> tuple:
    return (50714, 5, len(values), tuple(v for b in values for v in (round(b * 2), 2)), True)


#: Layouts picamcal reads from the strips: (tags, tifffile keywords, SubIFD layout).
PLAIN = {
    # rpicam-apps: thumbnail in IFD 0, the mosaic in a SubIFD in many strips, BlackLevel as RATIONAL.
    "rpicam-apps": ([*MOSAIC_TAGS[:3], rational_blacks((60, 61, 62, 63)), MOSAIC_TAGS[4]], {"rowsperstrip": 5}, True),
    "big-endian": (MOSAIC_TAGS, {"byteorder": ">", "rowsperstrip": 7}, False),
    "no BlackLevel, repeat 2x2": ([*MOSAIC_TAGS[:3], MOSAIC_TAGS[4]], {}, False),  # found by the byte-change fuzz
    "one black level": ([*MOSAIC_TAGS[:2], (50714, 3, 1, 64, True), MOSAIC_TAGS[4]], {}, False),
    "CFAPlaneColor 2 1 0": ([*MOSAIC_TAGS, (50710, 1, 3, bytes((2, 1, 0)), True)], {}, False),
    "DefaultCrop": ([*MOSAIC_TAGS, (50719, 3, 2, (4, 6), True), (50720, 3, 2, (40, 30), True)], {}, False),
}


@pytest.mark.parametrize("case", PLAIN)
def test_plain_layouts_of_other_writers_read_as_libraw_does(tmp_path, case):
    tags, keywords, subifd = PLAIN[case]
    path = write_tiff_dng(tmp_path / "plain.dng", mosaic(), tags, subifd=subifd, **keywords)
    assert plain(path)
    np.testing.assert_array_equal(assert_libraws(path).bayer, mosaic())


def test_an_odd_sized_plain_mosaic_is_cropped_to_even_as_libraw_does(tmp_path):
    path = write_tiff_dng(tmp_path / "odd.dng", mosaic(HEIGHT + 1, WIDTH + 1), MOSAIC_TAGS, rowsperstrip=5)
    assert plain(path)
    raw = assert_libraws(path)
    np.testing.assert_array_equal(raw.bayer, mosaic(HEIGHT + 1, WIDTH + 1)[:HEIGHT, :WIDTH])


#: Layouts left to LibRaw, each with what sends it there.
LIBRAW = {
    "fractional BlackLevel": ([*MOSAIC_TAGS[:3], rational_blacks((60.5, 61, 62, 63)), MOSAIC_TAGS[4]], {}),
    "ActiveArea": ([*MOSAIC_TAGS, (50829, 3, 4, (2, 4, 46, 60), True)], {}),
    "LinearizationTable": ([*MOSAIC_TAGS, (50712, 3, 1024, tuple(range(1024)), True)], {}),
    "BlackLevelDeltaV": ([*MOSAIC_TAGS, (50716, 3, HEIGHT, (1,) * HEIGHT, True)], {}),
    "no WhiteLevel": (MOSAIC_TAGS[:4], {}),
    "BlackLevelRepeatDim 1x2": ([*MOSAIC_TAGS[:2], (50713, 3, 2, (1, 2), True), (50714, 3, 2, (60, 61), True)], {}),
    "tiles": (MOSAIC_TAGS, {"tile": (16, 16)}),
}


@pytest.mark.parametrize("case", LIBRAW)
def test_other_layouts_are_left_to_libraw(tmp_path, case):
    tags, keywords = LIBRAW[case]
    path = write_tiff_dng(tmp_path / "other.dng", mosaic(), tags, **keywords)
    assert not plain(path)
    assert_libraws(path)


def test_signed_samples_are_left_to_libraw(tmp_path):
    path = write_tiff_dng(tmp_path / "signed.dng", mosaic().astype(np.int16), MOSAIC_TAGS)  # SampleFormat 2
    assert not plain(path)
    np.testing.assert_array_equal(assert_libraws(path).bayer, mosaic())


def test_a_packed_12_bit_dng_is_left_to_libraw(tmp_path):
    # BitsPerSample 12: two samples in three bytes, big-endian bit order (TIFF's), as some cameras write.
    values = mosaic() * 4
    pairs = values.reshape(-1, 2).astype(np.uint32)
    packed = np.stack([pairs[:, 0] >> 4, ((pairs[:, 0] & 15) << 4) | (pairs[:, 1] >> 8), pairs[:, 1] & 255], 1)
    path = tmp_path / "packed.dng"
    tags = [*MOSAIC_TAGS[:4], (50717, 4, 1, 4095, True)]
    tifffile.imwrite(
        path,
        packed.astype(np.uint8).reshape(HEIGHT, WIDTH * 3 // 2),
        photometric=32803,
        extratags=CAMERA_TAGS + tags,
        metadata=None,
    )
    data = path.read_bytes()  # tifffile wrote bytes: declare them 12-bit samples of the mosaic's size
    data = rewrite(data, dng_entries(data)[256], value=WIDTH)
    path.write_bytes(rewrite(data, dng_entries(data)[258], value=12))
    assert not plain(path)
    np.testing.assert_array_equal(assert_libraws(path).bayer, values)


def test_the_expected_shape_is_checked_before_the_strips_are_read(tmp_path):
    path = write_dng(tmp_path / "own.dng", RawImage(mosaic(), "BGGR", 64, 1023, 10, "imx219"))
    with pytest.raises(CalibrationFileError, match="size 64x48, calibration is for 320x240"):
        read_raw(path, expected_shape=(240, 320))


def test_a_file_that_shrinks_while_it_is_read_is_a_truncated_file(tmp_path, monkeypatch):
    # The strips are checked against the size the file had when it was opened; it loses its end before they are read.
    path = write_tiff_dng(tmp_path / "plain.dng", mosaic(), MOSAIC_TAGS, rowsperstrip=8)
    size = path.stat().st_size
    with tifffile.TiffFile(path) as tif:
        strips = tif.pages.first.dataoffsets
    os.truncate(path, strips[2] + 10)
    real_fstat = os.fstat
    monkeypatch.setattr(os, "fstat", lambda fd: os.stat_result((*real_fstat(fd)[:6], size, *real_fstat(fd)[7:])))
    with pytest.raises(RawFormatError, match="truncated file: strip 3 of the raw image ends early"):
        read_dng(path)
