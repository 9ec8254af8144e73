"""Raw formats: DNG written by picamcal read back bit-exactly by LibRaw; the npz container; bad files."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import rawpy

from picamcal import RawFormatError, read_raw
from picamcal.raw import PATTERNS, RAW_SUFFIXES, RawImage, write_dng, write_npz


def _random_raw(pattern: str, bits: int = 10) -> RawImage:
    rng = np.random.default_rng(1)
    bayer = rng.integers(0, 2**bits, size=(48, 64), dtype=np.uint16)
    meta = {"exposure_time_s": 0.02, "analogue_gain": 2.0}
    return RawImage(bayer, pattern, (64.0, 65.0, 66.0, 67.0), 2**bits - 1, bits, "imx219", meta)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_dng_round_trip_is_bit_exact_through_libraw(tmp_path, pattern):
    raw = _random_raw(pattern)
    path = write_dng(tmp_path / "x.dng", raw)
    with rawpy.imread(str(path)) as rp:  # LibRaw directly, independent of our reader
        np.testing.assert_array_equal(rp.raw_image_visible, raw.bayer)
        desc = rp.color_desc.decode()
        assert "".join(desc[i] for i in rp.raw_pattern.ravel()) == pattern
    back = read_raw(path)
    np.testing.assert_array_equal(back.bayer, raw.bayer)
    assert back.pattern == pattern
    assert back.black_level == raw.black_level  # per site, in the file's site order
    assert (back.white_level, back.bit_depth, back.sensor) == (1023, 10, "imx219")
    assert back.metadata["format"] == "dng"
    assert back.metadata["exposure_time_s"] == pytest.approx(0.02)
    assert back.metadata["iso"] == 200


def test_dng_12_bit(tmp_path):
    raw = _random_raw("RGGB", bits=12)
    back = read_raw(write_dng(tmp_path / "x.dng", raw))
    np.testing.assert_array_equal(back.bayer, raw.bayer)
    assert (back.white_level, back.bit_depth) == (4095, 12)


def test_npz_round_trip(tmp_path):
    raw = _random_raw("GRBG")
    back = read_raw(write_npz(tmp_path / "x.npz", raw))
    np.testing.assert_array_equal(back.bayer, raw.bayer)
    assert (back.pattern, back.black_level, back.white_level) == ("GRBG", raw.black_level, 1023)
    assert back.metadata["format"] == "npz" and back.metadata["analogue_gain"] == 2.0


def test_black_subtracted_uses_each_site_level():
    raw = RawImage(np.full((4, 4), 100, np.uint16), "RGGB", (10, 20, 30, 40), 1023, 10)
    assert raw.black_subtracted()[:2, :2].tolist() == [[90.0, 80.0], [70.0, 60.0]]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "empty file"),
        (b"\x89PNG\r\n\x1a\n" + b"\0" * 32, "a PNG image, not a raw image"),
        (b"hello world, not an image", "not a raw image format"),
        (b"II*\x00" + b"\0" * 64, "corrupt TIFF/DNG structure"),
        (b"PK\x03\x04garbage", "corrupt picamcal raw file"),
    ],
)
def test_bad_files_raise_one_clear_error_naming_the_file(tmp_path, content, message):
    path = tmp_path / "bad.dng"
    path.write_bytes(content)
    with pytest.raises(RawFormatError, match=message) as info:
        read_raw(path)
    assert str(info.value).startswith(str(path))
    assert "\n" not in str(info.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(RawFormatError, match="no such file"):
        read_raw(tmp_path / "nope.dng")
    with pytest.raises(RawFormatError, match="is a directory"):
        read_raw(tmp_path)


def test_npz_without_bayer_is_refused(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, something=np.zeros(3))
    with pytest.raises(RawFormatError, match="not a picamcal raw image"):
        read_raw(path)


def test_raw_image_validates_its_fields():
    with pytest.raises(RawFormatError, match="unknown Bayer pattern"):
        RawImage(np.zeros((4, 4), np.uint16), "RGBG", (0,) * 4, 1023, 10)
    with pytest.raises(RawFormatError, match="even width and height"):
        RawImage(np.zeros((3, 4), np.uint16), "RGGB", (0,) * 4, 1023, 10)
    with pytest.raises(RawFormatError, match="uint16"):
        RawImage(np.zeros((4, 4), np.float32), "RGGB", (0,) * 4, 1023, 10)


def test_dng_active_area_gives_the_visible_mosaic_and_its_pattern(tmp_path):
    # A DNG whose ActiveArea starts one pixel in: the pattern of the visible area is not the sensor's.
    import tifffile

    rng = np.random.default_rng(2)
    bayer = rng.integers(0, 1024, size=(64, 80), dtype=np.uint16)
    tags = [
        (33421, 3, 2, (2, 2), True),
        (33422, 1, 4, bytes((0, 1, 1, 2)), True),  # RGGB
        (50706, 1, 4, bytes((1, 4, 0, 0)), True),
        (50708, 2, 0, "imx219", True),
        (50713, 3, 2, (2, 2), True),
        (50714, 3, 4, (60, 61, 62, 63), True),
        (50717, 3, 1, 1023, True),
        (50829, 3, 4, (1, 1, 63, 79), True),  # ActiveArea top, left, bottom, right
    ]
    path = tmp_path / "active.dng"
    tifffile.imwrite(path, bayer, photometric=32803, extratags=tags, metadata=None)
    with rawpy.imread(str(path)) as rp:
        visible = rp.raw_image_visible.copy()
        colours = rp.raw_colors_visible[:2, :2]
        desc = rp.color_desc.decode()
    raw = read_raw(path, verify=False)
    h, w = visible.shape[0] // 2 * 2, visible.shape[1] // 2 * 2
    np.testing.assert_array_equal(raw.bayer, visible[:h, :w])  # LibRaw's visible area, cropped to whole 2x2 blocks
    assert raw.pattern == "".join(desc[c] for c in colours.ravel())
    assert raw.pattern != "RGGB" and raw.bayer.shape[0] % 2 == 0 and raw.sensor == "imx219"


def test_a_file_that_is_no_format_may_be_a_headless_dump(tmp_path):
    frame = 4128 * 2464  # one IMX219 full frame of packed RAW10 at libcamera's 32-byte row alignment (Pi 4)
    (tmp_path / "video").write_bytes(bytes(3 * frame))
    with pytest.raises(RawFormatError, match=r"fits IMX219 3280x2464 10-bit packed frames.*--raw-format S<order>10"):
        read_raw(tmp_path / "video")
    (tmp_path / "odd.raw").write_bytes(b"\x01" * 1001)
    with pytest.raises(RawFormatError, match=r"a headless dump \(rpicam-raw\)\? give --raw-format NAME and --size"):
        read_raw(tmp_path / "odd.raw")
    (tmp_path / "odd.txt").write_bytes(b"\x01" * 1001)
    with pytest.raises(RawFormatError) as info:
        read_raw(tmp_path / "odd.txt")
    assert "headless" not in str(info.value)  # no hint without a reason for one


def test_headless_options_without_a_raw_format_are_refused(tmp_path):
    path = write_npz(tmp_path / "x.npz", _random_raw("RGGB"))
    with pytest.raises(RawFormatError, match="describes a headless dump: give its raw format too"):
        read_raw(path, size=(64, 48))


def test_sensor_names_the_sensor_of_a_file_that_does_not(tmp_path):
    raw = RawImage(_random_raw("RGGB").bayer, "RGGB", float("nan"), 1023, 10)  # no sensor, no black level
    path = write_npz(tmp_path / "anon.npz", raw)
    known = read_raw(path, sensor="IMX519")  # imx519.json: 4096 on the 16-bit scale, 64 at 10 bits
    assert (known.sensor, known.black_level, known.metadata["sensor_known"]) == ("imx519", (64.0,) * 4, True)
    unknown = read_raw(path, sensor="imx298")
    assert (unknown.sensor, unknown.metadata["sensor_known"]) == ("imx298", False)
    assert all(np.isnan(unknown.black_level))
    named = read_raw(write_npz(tmp_path / "named.npz", _random_raw("RGGB")), sensor="imx477")
    assert named.sensor == "imx219" and named.black_level == (64.0, 65.0, 66.0, 67.0)  # the file's own wins


def test_each_format_recognises_only_its_own_files_and_the_docs_example_runs(tmp_path, monkeypatch, capsys):
    # docs/formats.md, "Where each format lives": each module's signature test is true for its own file only.
    text = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    section = text[text.index("## Where each format lives") :].split("\n## ", 1)[0]
    (block,) = re.findall(r"```python\n(.*?)```", section, re.DOTALL)
    monkeypatch.chdir(tmp_path)
    exec(compile(block, "docs/formats.md", "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    assert printed[:3] == ["frame.dng True False False", "frame.jpg False True False", "frame.npz False False True"]
    assert printed[3] == str(RAW_SUFFIXES)
    for name in ("frame.dng", "frame.jpg", "frame.npz"):
        assert read_raw(tmp_path / name).metadata["format"] == {"dng": "dng", "jpg": "brcm", "npz": "npz"}[name[6:]]
