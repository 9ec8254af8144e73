"""What ``inspect`` says, and what every reader says of a black level taken from a default.

- a folder with no images (empty, or notes alone) is one error line and exit status 2, naming the folder;
- a file that is no image (a ``MANIFEST.md``) beside images is listed as "not an image", which is no failure;
- a white clipped beyond what ``calibrate`` takes (``picamcal.calibrate.MAX_CLIPPED_FRACTION``) is flagged;
- an unknown black level (a headless dump) is shown as unknown, with the reason and the fix;
- a DNG without a BlackLevel tag (the DNG default, 0) whose darkest pixels sit well above 0 gets a warning with
  the level they sit at and the option that gives it.

Commands run in this process through ``picamcal.cli.main``, on files the real writers wrote (picamcal's DNG writer,
tifffile for a DNG without the tag, the raw bytes of a headless dump).
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from pathlib import Path

import numpy as np
import pytest
import tifffile

from picamcal import PicamcalWarning, read_raw, write_dng
from picamcal.calibrate import MAX_CLIPPED_FRACTION
from picamcal.cli import main
from picamcal.raw import RawImage
from picamcal.simulate import make_camera, simulate_references

#: DNG tags of a camera picamcal does not know, and of a 2 x 2 RGGB mosaic with a 10-bit white level, no BlackLevel.
UNKNOWN_CAMERA = [(50706, 1, 4, bytes((1, 4, 0, 0)), True), (50708, 2, 0, "Some Camera", True)]
MOSAIC_WITHOUT_BLACK = [
    (33421, 3, 2, (2, 2), True),
    (33422, 1, 4, bytes((0, 1, 1, 2)), True),
    (50717, 4, 1, 1023, True),
]


@pytest.fixture
def cli(monkeypatch, capfd):
    """Run ``picamcal ARGS`` in this process: (exit status, the non-empty lines of stderr, stdout)."""

    def run(*args: object) -> tuple[int, list[str], str]:
        monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # main's global settings are put back
        monkeypatch.setenv("COLUMNS", "250")  # the table's rows on one line each
        with pytest.raises(SystemExit) as exit:
            main([str(arg) for arg in args])
        captured = capfd.readouterr()
        return exit.value.code, [line for line in captured.err.splitlines() if line.strip()], captured.out

    return run


@pytest.fixture(scope="module")
def white() -> RawImage:
    return simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]


def dng_without_black_level(path: Path, darkest: int, seed: int = 0) -> Path:
    """A DNG of an unknown camera with no BlackLevel tag: a white 500 DN above ``darkest`` in a dark margin of 8
    pixels, whose pixels sit at ``darkest`` to ``darkest`` + 9 DN."""
    rng = np.random.default_rng(seed)
    data = (darkest + rng.integers(0, 10, (120, 162))).astype(np.uint16)
    data[8:-8, 8:-8] += 500
    with tifffile.TiffWriter(path) as tif:
        tif.write(data, photometric=32803, extratags=UNKNOWN_CAMERA + MOSAIC_WITHOUT_BLACK, metadata=None)
    return path


def clipped(raw: RawImage, fraction: float) -> RawImage:
    """``raw`` with its brightest ``fraction`` of pixels at the white level."""
    bayer = raw.bayer.copy()
    brightest = np.argsort(bayer, axis=None)[bayer.size - round(fraction * bayer.size) :]
    bayer.flat[brightest] = raw.white_level
    return dataclasses.replace(raw, bayer=bayer)


# Folders ---------------------------------------------------------------------------------------------------------


def test_an_empty_folder_is_one_error_line_naming_it(cli, tmp_path):
    code, err, out = cli("inspect", tmp_path)
    assert (code, err, out) == (2, [f"picamcal: error: {tmp_path}: no images in this folder: it is empty"], "")


def test_a_folder_of_notes_alone_is_one_error_line_naming_them(cli, tmp_path):
    (tmp_path / "MANIFEST.md").write_text("# whites of 3 May\n")
    (tmp_path / "notes.txt").write_text("focus at 3 mm\n")
    code, err, out = cli("inspect", tmp_path)
    assert (code, out) == (2, "")
    assert err == [f"picamcal: error: {tmp_path}: no images in this folder: only 2 other files: MANIFEST.md, notes.txt"]


def test_a_manifest_beside_the_images_is_not_an_image_and_no_failure(cli, tmp_path, white):
    write_dng(tmp_path / "white.dng", white)
    (tmp_path / "MANIFEST.md").write_text("# whites of 3 May\n")
    code, err, out = cli("inspect", tmp_path, "--json")
    assert (code, err) == (0, [])
    records = {Path(r["path"]).name: r for r in json.loads(out)}
    assert (records["MANIFEST.md"]["format"], records["MANIFEST.md"]["readable"]) == ("not an image", True)
    assert records["white.dng"]["format"] == "dng" and records["white.dng"]["notes"] == []
    code, _, table = cli("inspect", tmp_path)
    assert code == 0 and "MANIFEST.md │ not an image" in table and "cannot read" not in table
    # An image's suffix on a file no reader takes is still an image gone wrong: exit 1, the listing complete.
    (tmp_path / "broken.dng").write_text("not a DNG at all\n")
    code, err, table = cli("inspect", tmp_path)
    assert (code, err) == (1, []) and "broken.dng: cannot read:" in table and "MANIFEST.md │ not an image" in table


def test_entries_named_as_images_that_are_no_files_are_passed_over_with_one_warning(cli, tmp_path, white):
    """A dangling link or a FIFO named .dng is not read (a FIFO would wait for ever), and not skipped silently."""
    write_dng(tmp_path / "white.dng", white)
    (tmp_path / "gone.dng").symlink_to(tmp_path / "deleted.dng")
    os.mkfifo(tmp_path / "pipe.DNG")
    (tmp_path / "notes").mkdir()  # a folder without an image's suffix is nothing to say
    code, err, out = cli("inspect", tmp_path, "--json")
    assert code == 0 and [Path(r["path"]).name for r in json.loads(out)] == ["white.dng"]
    assert len(err) == 1, err
    assert f"{tmp_path}: passed over 2 entries that are not regular files" in err[0]
    assert "gone.dng (a symbolic link to nothing)" in err[0] and "pipe.DNG (a FIFO)" in err[0]


def test_a_file_that_is_not_an_image_given_alone_is_one_error_line(cli, tmp_path):
    (tmp_path / "MANIFEST.md").write_text("# whites of 3 May\n")
    code, err, out = cli("inspect", tmp_path / "MANIFEST.md")
    assert (code, out) == (2, "")
    reason = "not a raw image format picamcal reads (DNG, JPEG+raw, picamera2 .npy or picamcal .npz)"
    assert err == [f"picamcal: error: {tmp_path / 'MANIFEST.md'}: {reason}"]


# Clipping --------------------------------------------------------------------------------------------------------


def test_a_white_clipped_beyond_what_calibrate_takes_is_flagged(cli, tmp_path, white):
    over = write_dng(tmp_path / "over.dng", clipped(white, 0.76))
    under = write_dng(tmp_path / "under.dng", clipped(white, 0.5 * MAX_CLIPPED_FRACTION))
    code, err, out = cli("inspect", over, under, "--json")
    assert (code, err) == (0, [])
    records = {Path(r["path"]).name: r for r in json.loads(out)}
    # The fractions are the files' own: 76 % exactly, and half the limit to one pixel in 76 800.
    assert records["over.dng"]["clipped_fraction"] == pytest.approx(0.76, abs=1 / white.bayer.size)
    assert records["under.dng"]["clipped_fraction"] == pytest.approx(0.5 * MAX_CLIPPED_FRACTION, abs=1.5e-5)
    assert records["over.dng"]["notes"] == [
        "76 % of its pixels are at the white level (1023): as a white reference calibrate refuses it (it takes up to "
        "0.01 %); reduce the exposure"
    ]
    assert records["under.dng"]["notes"] == []
    # The limit is calibrate's own: it refuses the one inspect flags and takes the other.
    code, err, _ = cli("calibrate", "--white", over, "--out", tmp_path / "over.npz")
    assert code == 2 and "white reference is saturated" in err[-1]
    code, err, _ = cli("calibrate", "--white", under, "--out", tmp_path / "under.npz")
    assert code == 0, err


# Black levels ----------------------------------------------------------------------------------------------------


def test_a_headless_dump_s_unknown_black_level_is_explained(cli, tmp_path, white):
    dump = tmp_path / "frame.raw"
    (white.bayer.astype("<u2") << 6).tofile(dump)  # SBGGR16: 16-bit samples, the 10 bits at the top
    options = ("--raw-format", "SBGGR16", "--size", "320x240")
    code, err, table = cli("inspect", dump, *options)
    assert (code, err) == (0, [])
    row = next(line for line in table.splitlines() if "frame.raw" in line and "│" in line)
    assert "unknown" in row and "nan" not in table
    assert "frame.raw: black level unknown: headless dumps carry none; give --black-level N or --sensor NAME" in table
    code, _, out = cli("inspect", dump, *options, "--json")
    record = json.loads(out)[0]
    assert record["black_level"] == [None] * 4 and record["notes"][0].startswith("black level unknown")
    # With the sensor named, the registry gives the level (the IMX219's, 64 DN at its 10 bits) and all is said.
    code, _, out = cli("inspect", dump, *options, "--sensor", "imx219", "--json")
    record = json.loads(out)[0]
    assert (code, record["bit_depth"], record["black_level"], record["notes"]) == (0, 10, [64.0] * 4, [])


def test_a_dng_without_black_level_whose_darkest_pixels_sit_at_70_is_said(tmp_path):
    path = dng_without_black_level(tmp_path / "other.dng", 70)
    with pytest.warns(PicamcalWarning) as caught:
        raw = read_raw(path)
    assert raw.black_level == (0.0,) * 4 and raw.metadata["black_level_source"] == "DNG default"
    assert [str(w.message) for w in caught] == [
        f"{path}: black level 0 is the DNG default (the file has no BlackLevel tag), but no pixel is darker than 70 "
        "DN: if the sensor's black level is 70 DN (a dark frame shows it; on a lit frame it is lower), pass "
        "--black-level 70"
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("error", PicamcalWarning)  # the level given, nothing to say
        assert read_raw(path, black_level=70).black_level == (70.0,) * 4
        # A sensor whose black is 0 clips its darkest pixels at 0 (here 0 to 9 DN): nothing to say either.
        assert read_raw(dng_without_black_level(tmp_path / "zero.dng", 0)).black_level == (0.0,) * 4
        # Nor of a level 0 the file records: the tag is the file's word (1 % of 1023 is the margin below 70).
        tagged = RawImage(read_raw(path, black_level=0).bayer, "RGGB", 0, 1023, 10, None, {"model": "Some Camera"})
        assert read_raw(write_dng(tmp_path / "tagged.dng", tagged)).metadata["black_level_source"] == "file"


def test_inspect_and_calibrate_say_so(cli, tmp_path):
    path = dng_without_black_level(tmp_path / "other.dng", 70)
    code, err, table = cli("inspect", path)
    assert code == 0 and "other.dng: black level 0 is the DNG default" in table and "--black-level 70" in table
    code, err, _ = cli("calibrate", "--white", path, "--out", tmp_path / "cal.npz")
    said = [line for line in err if "black level 0 is the DNG default" in line]
    assert code == 0 and len(said) == 1 and said[0].startswith("picamcal: warning: ") and "--black-level 70" in said[0]
    code, err, _ = cli("calibrate", "--white", path, "--black-level", "70", "--out", tmp_path / "given.npz")
    assert code == 0 and not any("DNG default" in line for line in err), err
