"""picamcal acquire on the simulated rig, then picamcal calibrate on its folder, through real subprocesses."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from picamcal import calibrate, load_calibration
from picamcal.cli import main
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
    result = run("acquire", "--camera", "picamera2", "--illuminator", "manual", "--out", str(tmp_path / "r"))
    assert_bad_input(result, "picamera2")
    # picamera2 from PyPI (the test extra) imports libcamera, which only a Raspberry Pi (or the virtual camera) has
    assert "no module named 'libcamera'" in result.stderr or "picamera2 is not installed" in result.stderr
    assert not (tmp_path / "r").exists()


def cli_mistake(args: list[str], monkeypatch, capfd) -> list[str]:
    """Run the command line in this process (quick: each mistake is refused before any work); its stderr lines."""
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # main's global settings are put back
    with pytest.raises(SystemExit) as exit:
        main(args)
    assert exit.value.code == 2
    return capfd.readouterr().err.splitlines()


@pytest.mark.parametrize(
    ("colours", "problem"),
    [
        (["cyan"], "'cyan' is not NAME=R,G,B (e.g. cyan=0,255,255)"),
        (["cyan=0,255"], "'cyan=0,255' is not NAME=R,G,B (e.g. cyan=0,255,255)"),
        (["cyan=0,255,300"], "'cyan=0,255,300': R, G and B must be whole numbers from 0 to 255"),
        (["cyan=0,-1,255"], "'cyan=0,-1,255': R, G and B must be whole numbers from 0 to 255"),
        (["cyan!=0,255,255"], "'cyan!=0,255,255': the name must be 1 to 40 letters, digits or '-' (it names the file)"),
        (["green=0,255,0"], "'green=0,255,0': green is a reference already (white, red, green, blue, black); name the "
         "extra colour otherwise"),
        (["cyan=0,255,255", "Cyan=0,255,255"], "'Cyan=0,255,255': the colour Cyan is given twice"),
    ],
)  # fmt: skip
def test_acquire_refuses_a_bad_colour_in_one_line_naming_the_option(tmp_path, monkeypatch, capfd, colours, problem):
    out = tmp_path / "r"
    args = ["acquire", "--camera", "sim", "--illuminator", "sim", "--out", str(out)]
    for colour in colours:
        args += ["--colour", colour]
    assert cli_mistake(args, monkeypatch, capfd) == [
        f"picamcal: error: Invalid value for --colour: {problem} (see picamcal acquire --help)"
    ]
    assert not out.exists()
