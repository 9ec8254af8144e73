"""picamcal acquire on the simulated rig, then picamcal calibrate on its folder, through real subprocesses."""

from __future__ import annotations

import json

import numpy as np
import pytest

from picamcal import calibrate, load_calibration
from picamcal.manifest import load_manifest
from picamcal.simulate import make_camera, simulate_references
from test_cli import assert_bad_input, run


@pytest.mark.slow
def test_acquire_then_calibrate_equals_calibrating_the_simulator_directly(tmp_path):
    out = tmp_path / "run"
    result = run(
        "acquire",
        "--camera",
        "sim",
        "--illuminator",
        "sim",
        "--size",
        "320x240",
        "--seed",
        "4",
        "--out",
        str(out),
        "--extra",
        "target",
    )
    assert result.returncode == 0, result.stderr
    manifest = load_manifest(out)
    assert [e["role"] for e in manifest["entries"]] == ["white", "red", "green", "blue", "black", "target"]
    assert run("calibrate", str(out), "--out", str(tmp_path / "cal.npz")).returncode == 0
    acquired = load_calibration(tmp_path / "cal.npz")
    # The simulated frames at the exposure the auto-exposure settled on, calibrated directly.
    settings, camera = manifest["settings"], manifest["camera"]
    fraction = camera["brightness"] * settings["exposure_time_us"] / 10000 * settings["analogue_gain"]
    direct = calibrate(**simulate_references(make_camera("imx219", size=(320, 240), exposure=fraction), seed=4))
    direct_arrays, acquired_arrays = direct.to_arrays(), acquired.to_arrays()
    assert acquired_arrays.keys() == direct_arrays.keys()
    for name, array in direct_arrays.items():
        np.testing.assert_array_equal(acquired_arrays[name], array, err_msg=name)
    assert json.loads((out / "white.json").read_text())


def test_acquire_refuses_without_a_camera(tmp_path):
    assert_bad_input(
        run("acquire", "--camera", "picamera2", "--illuminator", "manual", "--out", str(tmp_path / "r")),
        "picamera2 is not installed",
    )
    assert not (tmp_path / "r").exists()
