"""The sensor-mode matrix of docs/sensor-modes.md, through the real picamera2 on the virtual camera: for the IMX219
and the IMX477, a calibration acquired in each sensor mode, its tuning exported and loaded, the white's main stream
measured in every mode on a Pi 5 and a Pi 4 (``docs/images/sensor_modes.py``, which also makes the figure)."""

from __future__ import annotations

import importlib.util
import runpy
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        importlib.util.find_spec("picamera2") is None,
        reason="picamera2 is not installed (pip install 'picamcal[virtual-camera]')",
    ),
]


@pytest.fixture(scope="module")
def matrix(tmp_path_factory):
    script = runpy.run_path(str(ROOT / "docs" / "images" / "sensor_modes.py"))
    return script, script["run_matrix"](work=tmp_path_factory.mktemp("matrix"))


def test_every_mode_inside_a_calibrations_crop_is_flat_within_2_percent(matrix):
    script, result = matrix
    assert set(result["sensors"]) == {"imx219", "imx477"}
    for sensor, platforms in result["sensors"].items():
        assert set(platforms) == {"pisp", "vc4"}
        for rows in platforms.values():
            # a calibration from every mode, each checked in every mode of the sensor
            assert set(rows) == set(script["calibration_modes"](sensor, tuple(result["size"])))
            assert all(len(row["modes"]) == len(next(iter(rows.values()))["modes"]) for row in rows.values())
    assert script["covered_failures"](result) == []  # the goal: every covered corner within 2 %


def test_full_and_binned_calibrations_cover_every_mode_and_cropped_ones_only_their_crop(matrix):
    _, result = matrix
    for sensor, platforms in result["sensors"].items():
        for platform, rows in platforms.items():
            for calibrated, row in rows.items():
                covered = {mode for mode, check in row["modes"].items() if check["covered"]}
                whole = row["crop"][:2] == [0, 0] and row["crop"][2:] == result["size"]
                if whole:
                    assert covered == set(row["modes"]), (sensor, platform, calibrated)
                else:
                    assert calibrated in covered and covered != set(row["modes"]), (sensor, platform, calibrated)
                    # outside its crop the table is extrapolated, and it shows (the test can fail)
                    worst = max(check["flatness"] for check in row["modes"].values() if not check["covered"])
                    assert worst > 0.02, (sensor, platform, calibrated, worst)
                # neutral in every mode it covers, with the colour gains the file records for each
                assert all(row["modes"][m]["neutrality"] < 0.03 for m in covered), (sensor, platform, calibrated)


def test_the_figure_is_drawn(matrix, tmp_path):
    script, result = matrix
    path = script["plot_matrix"](result, tmp_path / "sensor-modes.png")
    assert path.stat().st_size > 10_000
