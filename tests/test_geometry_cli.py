"""One full-sensor calibration corrects raw frames of every IMX219 mode from the command line: a headless rpicam-raw
dump of the 1920x1080 mode, DNGs of the binned modes as rpicam-still writes them (no crop recorded: the registry's
mode of their size), a frame of a mode picamcal does not know (--sensor-crop); and refuses what it cannot cover."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile

import picamcal
from picamcal.raw import RawImage
from picamcal.raw.packing import pack
from picamcal.simulate import make_camera, render
from test_cli import assert_bad_input, run
from test_geometry import corners_over_centre, mode_frame

pytestmark = pytest.mark.slow

#: IMX219 modes (imx219.c): crop on the 3280 x 2464 array and binning.
MODES = {
    "1920x1080": ((680, 692, 1920, 1080), 1),
    "1640x1232": ((0, 0, 3280, 2464), 2),
    "640x480": ((1000, 752, 1280, 960), 2),
}


def as_rpicam_still(raw: RawImage) -> RawImage:
    """The frame as rpicam-still's DNG holds it: its sensor named, its place on the sensor not recorded."""
    kept = {k: v for k, v in raw.metadata.items() if k not in ("sensor_size", "sensor_crop", "sensor_flips",
                                                                 "geometry_source", "simulated", "scene")}  # fmt: skip
    return RawImage(raw.bayer, raw.pattern, raw.black_level, raw.white_level, raw.bit_depth, "imx219", kept)


@pytest.fixture(scope="module")
def full(tmp_path_factory):
    """A full-resolution IMX219 white and dark frame (tilted optics: vignetting off-centre), their flat calibration."""
    folder = tmp_path_factory.mktemp("full")
    camera = make_camera("imx219", tilt=(0.2, -0.1))
    white, black = render(camera, "white", noise=False), render(camera, "black", noise=False)
    picamcal.write_dng(folder / "white.dng", as_rpicam_still(white))
    picamcal.write_dng(folder / "black.dng", as_rpicam_still(black))
    result = run("calibrate", "--white", str(folder / "white.dng"), "--black", str(folder / "black.dng"),
                 "--bin-size", "32", "-o", str(folder / "cal.npz"))  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "3280x2464: the whole 3280x2464 sensor, 10 bits (registry)" in result.stdout + result.stderr
    return {"folder": folder, "white": white, "cal": folder / "cal.npz"}


def _frame(full, name: str) -> RawImage:
    crop, binning = MODES[name]
    return as_rpicam_still(mode_frame(full["white"], crop, binning, size=(3280, 2464)))


def _corrected(path: Path) -> np.ndarray:
    return tifffile.imread(path)


@pytest.mark.parametrize("name", ["1640x1232", "640x480"])
def test_dngs_of_binned_modes_are_corrected_at_their_own_mode(full, tmp_path, name):
    dng = picamcal.write_dng(tmp_path / f"{name}.dng", _frame(full, name))
    inspected = run("inspect", str(dng))
    assert inspected.returncode == 0 and "registry" not in inspected.stdout  # the table's short form
    result = run("correct", str(full["cal"]), str(dng), "--mode", "flat", "--out", str(tmp_path / "out"))
    assert result.returncode == 0, result.stderr
    ratio = corners_over_centre(_corrected(tmp_path / "out" / f"{name}.tiff"))
    assert np.abs(ratio - 1).max() < 0.02, (name, ratio.round(4).tolist())  # the goal: within 2 %


def test_a_headless_dump_of_the_1920x1080_mode_is_corrected(full, tmp_path):
    frame = _frame(full, "1920x1080")
    assert frame.pattern == "BGGR"
    dump = tmp_path / "crop.raw"
    dump.write_bytes(pack(frame.bayer, 10, 2400).tobytes())  # rpicam-raw's SBGGR10_CSI2P, rows padded to 32 bytes
    headless = ("--raw-format", "SBGGR10_CSI2P", "--size", "1920x1080", "--sensor", "imx219")
    result = run("correct", str(full["cal"]), str(dump), *headless, "--mode", "flat", "--out", str(tmp_path / "o"))
    assert result.returncode == 0, result.stderr
    ratio = corners_over_centre(_corrected(tmp_path / "o" / "crop.tiff"))
    assert np.abs(ratio - 1).max() < 0.02, ratio.round(4).tolist()
    uncorrected = run("correct", str(full["cal"]), str(dump), *headless, "--mode", "uncorrected", "--out",
                      str(tmp_path / "u"))  # fmt: skip
    assert uncorrected.returncode == 0
    assert np.abs(corners_over_centre(_corrected(tmp_path / "u" / "crop.tiff")) - 1).max() > 0.1  # it was not flat


def test_a_mode_picamcal_does_not_know_takes_sensor_crop(full, tmp_path):
    crop = (400, 300, 1000, 700)
    dng = picamcal.write_dng(tmp_path / "odd.dng", as_rpicam_still(mode_frame(full["white"], crop, size=(3280, 2464))))
    out = tmp_path / "o"
    refused = run("correct", str(full["cal"]), str(dng), "--out", str(out))
    assert_bad_input(refused, "odd.dng", "--sensor-crop X,Y,WIDTH,HEIGHT")
    assert not out.exists()
    result = run("correct", str(full["cal"]), str(dng), "--sensor-crop", "400,300,1000,700", "--mode", "flat",
                 "--out", str(out))  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert np.abs(corners_over_centre(_corrected(out / "odd.tiff")) - 1).max() < 0.02


def test_a_cropped_calibration_refuses_what_it_does_not_cover(full, tmp_path):
    white = picamcal.write_dng(tmp_path / "white.dng", _frame(full, "1920x1080"))
    cal = tmp_path / "crop.npz"
    result = run("calibrate", "--white", str(white), "--black-level", "64", "--bin-size", "32", "-o", str(cal))
    assert result.returncode == 0, result.stderr
    assert "1920x1080: the 1920x1080 area at (680, 692) of the 3280x2464 sensor" in result.stdout + result.stderr
    binned = picamcal.write_dng(tmp_path / "binned.dng", _frame(full, "1640x1232"))
    out = tmp_path / "o"
    refused = run("correct", str(cal), str(binned), "--out", str(out))
    assert_bad_input(refused, "binned.dng", "larger than the calibration's 1920x1080 sensor area", "covers every mode")
    offset = picamcal.write_dng(tmp_path / "offset.dng", as_rpicam_still(mode_frame(full["white"], (0, 0, 1000, 700),
                                                                                   size=(3280, 2464))))  # fmt: skip
    refused = run("correct", str(cal), str(offset), "--sensor-crop", "0,0,1000,700", "--out", str(out))
    assert_bad_input(refused, "offset.dng", "outside the calibration's 1920x1080 at (680, 692)")
    assert not out.exists()
    for option, value, message in (
        ("--sensor-crop", "3000,0,1920,1080", "--sensor-crop 3000,0,1920,1080 lies outside the 3280x2464 sensor"),
        ("--sensor-crop", "0,0,1000", "give X,Y,WIDTH,HEIGHT"),
        ("--sensor-mode", "1332x990", "the imx219 has no such mode (it has 640x480:8"),
        ("--sensor-mode", "640x480", "the frame is 1640x1232, the mode 640x480"),
    ):
        result = run("correct", str(full["cal"]), str(binned), option, value, "--out", str(out))
        assert result.returncode == 2 and message in result.stderr, (option, value, result.stderr)
        assert len(result.stderr.strip().splitlines()) == 1 and not out.exists()
