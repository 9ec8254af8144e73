"""``picamcal verify``: the white through the camera's own pipeline in every sensor mode, through the real picamera2
on the virtual camera (Pi 4 and Pi 5), and the measurement's pieces on their own.

With the stock tuning the virtual optics are far from flat in every mode (the stock IMX219 tables are made for
another lens: they over-correct these optics' corners by 30 % to 180 %); with a tuning exported from a calibration
acquired in the full-resolution mode every mode is flat and neutral (measured: corners within 0.4 % (Pi 5) and 1.3 %
(Pi 4) of the centre, the centre's R/G and B/G within 0.1 %).
"""

from __future__ import annotations

import copy
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from picamcal.acquire.verify import (
    CORNERS,
    ModeCheck,
    Verification,
    measurement_tuning,
    mode_colour_gains,
    shading_figures,
)
from picamcal.bayer import bin_sites, sites_to_channels
from picamcal.export.tuning import load_tuning, neutral_tuning, stock_tuning_path
from picamcal.simulate import make_camera, render
from test_acquire_modes import cli_error
from test_virtualcam_picamera2 import under_virtual_camera

ROOT = Path(__file__).resolve().parents[1]
needs_picamera2 = pytest.mark.skipif(
    importlib.util.find_spec("picamera2") is None,
    reason="picamera2 is not installed (pip install 'picamcal[virtual-camera]')",
)
SIZE = "640x480"
#: The IMX219's modes as the virtual camera reduced to 640x480 lists them (the driver's four sizes, 10 and 8 bits).
SMALL_MODES = ["124x94:10", "320x240:10", "374x210:10", "640x480:10", "124x94:8", "320x240:8", "374x210:8", "640x480:8"]
#: The real IMX219's modes (imx219.c), as picamera2 lists them.
FULL_MODES = [
    "640x480:10",
    "1640x1232:10",
    "1920x1080:10",
    "3280x2464:10",
    "640x480:8",
    "1640x1232:8",
    "1920x1080:8",
    "3280x2464:8",
]


def verify(folder: Path, platform: str, *args: str, size: str | None = SIZE) -> subprocess.CompletedProcess:
    """``picamcal verify --illuminator virtual ARGS`` on the virtual IMX219."""
    options = [f"--platform={platform}", "--sensor=imx219", *([f"--size={size}"] if size else [])]
    command = [sys.executable, "-m", "picamcal", "verify", "--camera", "picamera2", "--illuminator", "virtual", *args]
    return under_virtual_camera(command, *options, cwd=folder)


def picamcal(folder: Path, *args: str) -> None:
    done = subprocess.run([sys.executable, "-m", "picamcal", *args], capture_output=True, text=True, cwd=folder)
    assert done.returncode == 0, done.stderr


# --- the pieces ---------------------------------------------------------------------------------------------------


def test_the_measurement_tuning_makes_tone_curve_and_colour_matrix_identity_and_keeps_the_lens_shading():
    stock = load_tuning(stock_tuning_path("imx219", "pisp"))
    before = copy.deepcopy(stock)
    measured = measurement_tuning(stock)
    assert stock == before  # never modified
    sections = {name: params for algorithm in measured["algorithms"] for name, params in algorithm.items()}
    original = {name: params for algorithm in stock["algorithms"] for name, params in algorithm.items()}
    assert sections["rpi.contrast"]["gamma_curve"] == [0, 0, 65535, 65535]
    assert sections["rpi.contrast"]["ce_enable"] == 0
    assert sections["rpi.ccm"]["ccms"] == [{"ct": 5000, "ccm": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]}]
    assert sections["rpi.alsc"] == original["rpi.alsc"]
    changed = {name for name in original if sections[name] != original[name]}
    assert changed == {"rpi.contrast", "rpi.ccm"}


def test_a_tuning_without_tone_curve_or_colour_matrix_gets_them_after_the_lens_shading():
    bare = {
        "version": 2.0,
        "target": "bcm2835",
        "algorithms": [{"rpi.black_level": {}}, {"rpi.alsc": {}}, {"rpi.agc": {}}],
    }
    names = [next(iter(a)) for a in measurement_tuning(bare)["algorithms"]]
    assert names == ["rpi.black_level", "rpi.alsc", "rpi.contrast", "rpi.ccm", "rpi.agc"]


def test_shading_figures_are_each_corner_over_the_centre_per_channel():
    image = np.full((60, 80, 3), 100.0)
    image[:6, :8] = [50, 100, 150]  # the top left corner's box: 10 % of each side
    image[-6:, -8:, 1] = 102
    image[24:36, 32:48] *= [1.0, 2.0, 0.5]  # the centre's box: 20 % of each side
    corners, centre = shading_figures(image)
    assert CORNERS[0] == "top left" and CORNERS[3] == "bottom right"
    np.testing.assert_allclose(corners[0], [0.5, 0.5, 3.0])
    np.testing.assert_allclose(corners[3], [1.0, 0.51, 2.0])
    np.testing.assert_allclose(centre, [0.5, 0.25])


def check(corners: list[list[float]], centre: tuple[float, float]) -> ModeCheck:
    return ModeCheck("640x480:10", (0, 0, 640, 480), None, (640, 480), np.array(corners), centre, (1.5, 1.2), "x", 1, 1)


def test_a_mode_is_flat_and_neutral_within_the_tolerances_and_names_its_worst_corner():
    flat = [[1.0] * 3, [1.0] * 3, [1.0] * 3, [1.0] * 3]
    bent = [[1.0] * 3, [1.0, 0.97, 1.0], [1.0] * 3, [1.015, 1.0, 1.0]]
    assert check(bent, (1.0, 1.0)).worst.tolist() == [1.015, 0.97, 1.0]
    assert check(bent, (1.0, 1.0)).worst_corner == "top right"
    result = Verification("imx219", "pisp", "t.json", 0.02, 0.03, [check(flat, (1.029, 0.975)), check(bent, (1, 1))])
    assert [result.passes(c) for c in result.modes] == [True, False]  # 3 % is not within 2 %
    assert not result.passed
    assert result.to_record()["modes"][1]["flatness"] == pytest.approx(0.03)
    assert not Verification("imx219", "pisp", "t.json", 0.02, 0.03, [check(flat, (1.031, 1.0))]).passed


def test_the_colour_gains_are_the_modes_then_the_calibrations_then_the_auto_white_balance():
    record = {"colour_gains": [1.5, 1.2], "colour_gains_by_mode": {"1920x1080:10": [1.8, 1.0]}}
    assert mode_colour_gains({"picamcal": record}, "1920x1080:10") == ((1.8, 1.0), "colour_gains_by_mode")
    assert mode_colour_gains({"picamcal": record}, "1920x1080:8") == ((1.5, 1.2), "colour_gains")
    assert mode_colour_gains({}, "1920x1080:10") == (None, "auto white balance")
    for broken in ({"colour_gains": [1.5]}, {"colour_gains": [0, 1]}, {"colour_gains": "1.5,1.2"}, []):
        assert mode_colour_gains({"picamcal": broken}, "1920x1080:10") == (None, "auto white balance")


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        (["--camera", "sim"], "'sim': verify checks a Raspberry Pi camera's own pipeline: picamera2 or picamera2:N"),
        (["--camera", "picamera2:x"], "camera number 'x' is not a whole number"),
        (["--tolerance", "0"], "'0': each tolerance is a percentage above 0 and below 100"),
        (["--tolerance", "2,100"], "'2,100': each tolerance is a percentage above 0 and below 100"),
        (["--tolerance", "2,3,4"], "'2,3,4' is not FLAT or FLAT,NEUTRAL in % (2 or 2,3)"),
        (["--tolerance", "flat"], "'flat' is not FLAT or FLAT,NEUTRAL in % (2 or 2,3)"),
        (["--tolerance", "nan"], "'nan': each tolerance is a percentage above 0 and below 100"),
    ],
)
def test_a_bad_option_is_one_line(args, problem, monkeypatch, capfd):
    assert problem in cli_error(["verify", *args], monkeypatch, capfd)


# --- through picamera2 on the virtual camera ----------------------------------------------------------------------


def table_rows(stdout: str) -> dict[str, list[str]]:
    """The table's rows by mode (its first cell)."""
    rows = {}
    for line in stdout.splitlines():
        cells = [cell.strip() for cell in line.strip("│ ").split("│")]
        if len(cells) > 5 and cells[0] and ":" in cells[0]:
            rows[cells[0]] = cells
    return rows


@needs_picamera2
@pytest.mark.slow
def test_the_stock_tuning_fails_in_every_mode_on_a_pi_5(tmp_path):
    result = verify(tmp_path, "pisp", "--json")
    assert result.returncode == 1, result.stderr
    record = json.loads(result.stdout)
    assert record["tuning"].startswith("stock: ") and record["tuning"].endswith("pisp/imx219.json")
    assert record["tolerance"] == {"flatness": 0.02, "neutrality": 0.03} and record["passed"] is False
    modes = {m["mode"]: m for m in record["modes"]}
    assert list(modes) == SMALL_MODES
    for name, mode in modes.items():
        assert mode["gains_source"] == "auto white balance" and not mode["passed"], name
        # The stock tables lift these optics' corners in every channel: measured 1.06 to 1.31 in the smallest
        # cropped mode, 1.29 to 2.8 in the full-field ones; the red far outside 2 % whatever the noise.
        assert min(min(corner) for corner in mode["corners"].values()) > 1.02, (name, mode["corners"])
        assert mode["worst"][0] > 1.15, (name, mode["worst"])
    assert modes["640x480:10"]["worst"][0] > 2.4 and modes["320x240:10"]["worst"][0] > 2.4
    assert modes["640x480:10"]["crop"] == [0, 0, 640, 480] and modes["374x210:10"]["crop"] == [132, 134, 374, 210]
    assert modes["374x210:10"]["scaler_crop"] == [132, 134, 374, 210]  # the whole mode is measured


@needs_picamera2
@pytest.mark.slow
def test_the_stock_tuning_fails_on_a_pi_4_and_the_table_lists_every_mode(tmp_path):
    result = verify(tmp_path, "vc4")
    assert result.returncode == 1, result.stderr
    rows = table_rows(result.stdout)
    assert list(rows) == SMALL_MODES
    for name, cells in rows.items():
        assert cells[-1].startswith("not flat"), (name, cells)
        # The R, G and B corners over the centre: measured 1.17, 1.05 and 1.03 in the smallest cropped mode, 2.5,
        # 1.28 and 1.22 in the full-field ones.
        red, green, blue = (float(cells[i]) for i in (2, 3, 4))
        assert red > 1.15 and green > 1.02 and blue > 1.01, (name, cells)
        if name.split(":")[0] in ("320x240", "640x480"):
            assert red > 2.3 and green > 1.2 and blue > 1.15, (name, cells)
    assert "vc4/imx219.json" in result.stdout
    assert (
        "Tolerance: flat when every corner is within 2 % of the centre in each channel; neutral when the centre's "
        "R/G and B/G are within 3 % of 1." in result.stdout
    )
    assert f"8 of 8 modes fail: {', '.join(SMALL_MODES)}" in result.stdout


@needs_picamera2
@pytest.mark.slow
def test_with_a_unity_table_verify_measures_the_optics_own_fall_off(tmp_path):
    # Lens shading alone is measured: with unity tables the processed white's corners over its centre are the raw
    # white's, the simulated optics' (0.90 red, 0.57 green and blue). A tone curve or a colour matrix left in place
    # would change them (the stock curve lifts 0.57 to about 0.75; the stock matrix mixes red into green).
    tuning = tmp_path / "unity.json"
    tuning.write_text(json.dumps(neutral_tuning(load_tuning(stock_tuning_path("imx219", "pisp")))))
    result = verify(tmp_path, "pisp", "--tuning", str(tuning), "--json")
    assert result.returncode == 1, result.stderr
    measured = {m["mode"]: m for m in json.loads(result.stdout)["modes"]}["640x480:10"]
    raw = render(make_camera("imx219", size=(640, 480)), np.ones(3), noise=False)
    expected = shading_figures(sites_to_channels(bin_sites(raw.black_subtracted(), 2), raw.pattern))[0].mean(axis=0)
    corners = np.mean(list(measured["corners"].values()), axis=0)
    print("corners over centre: measured", corners, "optics", expected)
    # The frame's noise and 8-bit output over 32 x 24 pixel boxes: a few tenths of a %; 1.5 % leaves room.
    np.testing.assert_allclose(corners, expected, rtol=0.015)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Tuning files for both Pis exported from a calibration acquired through picamera2 in the IMX219's
    full-resolution mode (the virtual camera at the sensor's full 3280x2464, so that its modes are the real ones
    the export records colour gains for)."""
    folder = tmp_path_factory.mktemp("exported")
    command = ["acquire", "--camera", "picamera2", "--illuminator", "virtual", "-o", "run", "--settle", "0"]
    acquired = under_virtual_camera(
        [sys.executable, "-m", "picamcal", *command],
        "--platform=pisp",
        "--sensor=imx219",
        cwd=folder,
    )
    assert acquired.returncode == 0, acquired.stderr
    picamcal(folder, "calibrate", "run", "-o", "cal.npz")
    for target in ("pisp", "vc4"):
        picamcal(folder, "export-tuning", "cal.npz", "--target", target, "--out", "tuning")
    return folder


@needs_picamera2
@pytest.mark.slow
@pytest.mark.parametrize("platform", ["pisp", "vc4"])
def test_an_exported_tuning_makes_every_mode_flat_and_neutral(exported, platform):
    result = verify(exported, platform, "--tuning", f"tuning/imx219_{platform}.json", "--json", size=None)
    assert result.returncode == 0, result.stdout + result.stderr
    record = json.loads(result.stdout)
    assert record["passed"] is True and record["tuning"] == f"tuning/imx219_{platform}.json"
    modes = {m["mode"]: m for m in record["modes"]}
    assert list(modes) == FULL_MODES
    for name, mode in modes.items():
        print(platform, name, mode["worst"], mode["centre"])
        assert mode["gains_source"] == "colour_gains_by_mode", name
        # Measured: corners within 0.4 % (pisp) and 1.3 % (vc4, whose 16 x 12 grid is coarser), centre within 0.1 %.
        assert mode["flatness"] < 0.016 and mode["neutrality"] < 0.005, (name, mode)
    assert modes["1920x1080:10"]["crop"] == [680, 692, 1920, 1080]


@needs_picamera2
@pytest.mark.slow
@pytest.mark.parametrize(
    ("platform", "tuning", "problem"),
    [
        ("pisp", "missing.json", "missing.json: no such tuning file"),
        (
            "vc4",
            str(ROOT / "src/picamcal/data/libcamera-tuning/pisp/imx219.json"),
            "imx219.json is for a Raspberry Pi 5 (target pisp), but this is a Raspberry Pi 4 or earlier (vc4, target "
            "bcm2835): export the tuning again with --target vc4",
        ),
        (
            "pisp",
            str(ROOT / "src/picamcal/data/libcamera-tuning/pisp/imx477.json"),
            "imx477.json is a tuning file for the imx477, but camera 0 is the imx219: give the imx219's",
        ),
    ],
    ids=["missing", "other-pi", "other-sensor"],
)
def test_a_bad_tuning_is_one_line(tmp_path, platform, tuning, problem):
    result = verify(tmp_path, platform, "--tuning", tuning)
    assert result.returncode == 2, result.stdout + result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("picamcal: error: ") and problem in lines[0], lines
    assert result.stdout == ""
