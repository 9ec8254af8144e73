"""``picamcal acquire --sensor-mode``: acquiring in a chosen sensor mode, through the real picamera2 on the virtual
camera, and the mode's crop and ScalerCrop in the acquisition's records and the calibration's geometry."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from picamcal import load_calibration
from picamcal.acquire.base import CameraError
from picamcal.acquire.pi_camera import choose_mode, is_cropped, mode_geometry, mode_name
from picamcal.cli import main
from test_virtualcam_picamera2 import under_virtual_camera

needs_picamera2 = pytest.mark.skipif(
    importlib.util.find_spec("picamera2") is None,
    reason="picamera2 is not installed (pip install 'picamcal[virtual-camera]')",
)
SIZE = "640x480"
#: The HQ camera's modes as picamera2 describes them on a Pi (imx477.c: size, bit depth, crop on the 4056x3040 array).
HQ_MODES = [
    {"size": (1332, 990), "bit_depth": 10, "unpacked": "SRGGB10", "crop_limits": (696, 528, 2664, 1980)},
    {"size": (2028, 1080), "bit_depth": 12, "unpacked": "SRGGB12", "crop_limits": (0, 440, 4056, 2160)},
    {"size": (2028, 1520), "bit_depth": 12, "unpacked": "SRGGB12", "crop_limits": (0, 0, 4056, 3040)},
    {"size": (4056, 3040), "bit_depth": 12, "unpacked": "SRGGB12", "crop_limits": (0, 0, 4056, 3040)},
]


def test_the_named_mode_is_chosen_and_the_full_resolution_one_by_default():
    assert mode_name(choose_mode(HQ_MODES, None)) == "4056x3040:12"
    assert mode_name(choose_mode(HQ_MODES, "2028x1080")) == "2028x1080:12"
    assert mode_name(choose_mode(HQ_MODES, "1332x990:10")) == "1332x990:10"
    with pytest.raises(CameraError) as refused:
        choose_mode(HQ_MODES, "1332x990:12", "imx477")
    assert str(refused.value) == (
        "--sensor-mode 1332x990:12: the imx477 has no such mode (picamera2 reports 1332x990:10, 2028x1080:12, "
        "2028x1520:12, 4056x3040:12)"
    )


def test_a_mode_is_cropped_when_it_reads_part_of_the_sensor():
    geometries = {mode_name(m): mode_geometry(m, (4056, 3040)) for m in HQ_MODES}
    assert {name: is_cropped(g) for name, g in geometries.items()} == {
        "1332x990:10": True,
        "2028x1080:12": True,
        "2028x1520:12": False,
        "4056x3040:12": False,
    }
    assert [g.binning for g in geometries.values()] == [2, 2, 2, 1]
    # A reduced virtual sensor's binned mode leaves the array's last two columns (1014 is no multiple of 4).
    small = {"size": (506, 380), "bit_depth": 12, "crop_limits": (0, 0, 1012, 760)}
    assert not is_cropped(mode_geometry(small, (1014, 760)))


def cli_error(args: list[str], monkeypatch, capfd) -> str:
    """The one error line of a command refused before any work, run in this process."""
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)
    with pytest.raises(SystemExit) as exit:
        main(args)
    assert exit.value.code == 2
    lines = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize(
    ("mode", "problem"),
    [
        (
            "1920x1080",
            "--sensor-mode chooses a mode of a Raspberry Pi camera (--camera picamera2); the simulated "
            "camera takes --size",
        ),
        ("1920x", "--sensor-mode '1920x': give the mode's size as WIDTHxHEIGHT, optionally :BITS (1920x1080:10)"),
    ],
)
def test_a_sensor_mode_for_the_simulated_camera_or_a_malformed_one_is_one_line(
    tmp_path, mode, problem, monkeypatch, capfd
):
    out = tmp_path / "run"
    args = ["acquire", "--camera", "sim", "--illuminator", "sim", "--sensor-mode", mode, "--out", str(out)]
    assert problem in cli_error(args, monkeypatch, capfd)
    assert not out.exists()


def acquire(folder: Path, platform: str, *args: str) -> subprocess.CompletedProcess:
    """``picamcal acquire --camera picamera2 --illuminator virtual ARGS`` on the virtual IMX219 reduced to 640x480."""
    command = [sys.executable, "-m", "picamcal", "acquire", "--camera", "picamera2", "--illuminator", "virtual"]
    return under_virtual_camera(
        [*command, "--settle", "0", *args], f"--platform={platform}", "--sensor=imx219", f"--size={SIZE}", cwd=folder
    )


def calibrate(folder: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "picamcal", "calibrate", "run", "-o", "cal.npz"],
        capture_output=True,
        text=True,
        cwd=folder,
    )
    assert done.returncode == 0, done.stderr


@pytest.fixture(scope="module")
def cropped_run(tmp_path_factory):
    """A run acquired on a Pi 5 in the IMX219's 1920x1080 mode, which the 640x480 virtual sensor makes 374x210 at
    (132, 134): the real mode's crop (680, 692, 1920, 1080) scaled by 640/3280 and 480/2464."""
    folder = tmp_path_factory.mktemp("cropped")
    result = acquire(folder, "pisp", "--sensor-mode", "374x210:10", "-o", "run")
    assert result.returncode == 0, result.stderr
    return folder, result


@needs_picamera2
@pytest.mark.slow
def test_a_cropped_mode_is_acquired_with_a_warning_and_its_crop_and_scaler_crop_recorded(cropped_run):
    folder, result = cropped_run
    warnings_given = [line for line in result.stderr.splitlines() if line.startswith("picamcal: warning:")]
    assert warnings_given == [
        "picamcal: warning: the imx219's 374x210:10 mode reads only the 374x210 area at (132, 134) of its 640x480 "
        "sensor: the calibration, and the lens shading table exported from it, will cover only that crop (acquire in "
        "the full-resolution or a binned mode to cover every mode)"
    ]
    camera = json.loads((folder / "run/manifest.json").read_text())["camera"]
    assert {k: camera[k] for k in ("size", "sensor_mode", "sensor_size", "crop", "scaler_crop")} == {
        "size": [374, 210],
        "sensor_mode": "374x210:10",
        "sensor_size": [640, 480],
        "crop": [132, 134, 374, 210],
        "scaler_crop": [132, 134, 374, 210],  # the processed stream shows the whole mode
    }
    frame = json.loads((folder / "run/white.json").read_text())["metadata"]
    assert frame["sensor_crop"] == [132, 134, 374, 210] and frame["scaler_crop"] == [132, 134, 374, 210]


@needs_picamera2
@pytest.mark.slow
def test_the_calibration_of_a_cropped_mode_records_the_modes_crop(cropped_run):
    folder, _ = cropped_run
    calibrate(folder)
    geometry = load_calibration(folder / "cal.npz").geometry
    assert geometry is not None
    assert (geometry.sensor_size, geometry.crop, geometry.binning, geometry.bit_depth, geometry.source) == (
        (640, 480),
        (132, 134, 374, 210),
        1,
        10,
        "camera",
    )


@needs_picamera2
@pytest.mark.slow
def test_a_run_is_not_resumed_in_another_mode(cropped_run):
    folder, _ = cropped_run
    result = acquire(folder, "pisp", "--sensor-mode", "374x210:8", "-o", "run")
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert (
        len(lines) == 1 and "it was started in another sensor mode (sensor_mode 374x210:10, now 374x210:8)" in lines[0]
    )


@needs_picamera2
@pytest.mark.slow
def test_a_binned_mode_covers_the_whole_sensor_without_a_warning(tmp_path):
    # The 1640x1232 mode (2 x 2 binned), 320x240 on the reduced sensor, on a Pi 4 (unpacked 10-bit raw).
    result = acquire(tmp_path, "vc4", "--sensor-mode", "320x240", "-o", "run")
    assert result.returncode == 0, result.stderr
    assert "warning" not in result.stderr
    camera = json.loads((tmp_path / "run/manifest.json").read_text())["camera"]
    assert (camera["sensor_mode"], camera["crop"], camera["raw_format"]) == ("320x240:10", [0, 0, 640, 480], "SBGGR10")
    calibrate(tmp_path)
    geometry = load_calibration(tmp_path / "cal.npz").geometry
    assert geometry is not None and (geometry.crop, geometry.binning) == ((0, 0, 640, 480), 2)


@needs_picamera2
@pytest.mark.slow
def test_a_mode_the_sensor_does_not_have_is_one_line_and_nothing_is_written(tmp_path):
    result = acquire(tmp_path, "pisp", "--sensor-mode", "1920x1080", "-o", "run")
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines == [
        "picamcal: error: --sensor-mode 1920x1080: the imx219 has no such mode (picamera2 reports 124x94:8, 124x94:10, "
        "320x240:8, 320x240:10, 374x210:8, 374x210:10, 640x480:8, 640x480:10)"
    ]
    assert not (tmp_path / "run").exists()
