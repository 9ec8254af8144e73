"""picamcal calibrate's messages and the light it records, and the workflow in ``picamcal --help``, through
:func:`picamcal.cli.main` in this process (each mistake is refused before any work, and the calibrations are small)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from conftest import one_error
from picamcal import calibrate, load_calibration, write_dng
from picamcal.acquire.acquisition import acquire, open_rig
from picamcal.cli import app
from picamcal.raw import read_raw, to_picamera2
from picamcal.simulate import make_camera, render, simulate_references

SIZE = (160, 120)


@pytest.fixture(scope="module")
def refs(tmp_path_factory) -> Path:
    """A folder of simulated IMX219 references (white, red, green, blue, black) as DNG files."""
    folder = tmp_path_factory.mktemp("refs")
    for role, raw in simulate_references(make_camera("imx219", size=SIZE), seed=1).items():
        write_dng(folder / f"{role}.dng", raw)
    return folder


# ------------------------------------------------------------------------------------------ messages
def test_a_processed_image_is_refused_with_what_calibrate_needs(cli, refs, tmp_path):
    Image.fromarray(np.full((120, 160, 3), 200, np.uint8)).save(tmp_path / "photo.jpg")
    Image.fromarray(np.full((120, 160, 3), 200, np.uint8)).save(tmp_path / "photo.png")
    out = tmp_path / "cal.npz"
    for photo, what in (("photo.jpg", "a JPEG image with no raw (BRCM) block"), ("photo.png", "a PNG image")):
        line = one_error(*cli("calibrate", "--white", tmp_path / photo, "--out", out)[:2])
        # calibrate has no --processed: the line says what it needs, and where processed images do go.
        assert line.startswith(f"{tmp_path / photo}: {what}, not a raw image (DNG, JPEG+raw from raspistill --raw")
        assert "a calibration cannot be made from processed images; correct takes them with --processed" in line
    assert not out.exists()
    # correct, which has --processed, meets the same line, and it names the option it needs.
    calibrate(**{role: refs / f"{role}.dng" for role in ("white", "red", "green", "blue")}).save(tmp_path / "c.npz")
    status, lines, _ = cli(
        "correct", tmp_path / "c.npz", tmp_path / "photo.jpg", "--out", tmp_path / "o", "--workers", 0
    )
    assert status != 0 and any("photo.jpg" in line and "correct takes them with --processed" in line for line in lines)


def test_a_calibration_given_as_the_folder_of_references_is_named_as_one(cli, refs, tmp_path):
    calibrate(read_raw(refs / "white.dng")).save(tmp_path / "flat.npz")
    out = tmp_path / "cal.npz"
    line = one_error(*cli("calibrate", tmp_path / "flat.npz", "--white", refs / "white.dng", "--out", out)[:2])
    assert line.startswith(f"{tmp_path / 'flat.npz'} is a picamcal calibration, not a folder of reference images")
    line = one_error(*cli("calibrate", refs / "white.dng", "--out", out)[:2])
    assert line.startswith(f"{refs / 'white.dng'}: a file, not a folder of reference images: give its folder")
    line = one_error(*cli("calibrate", tmp_path / "missing", "--out", out)[:2])
    assert line == f"{tmp_path / 'missing'}: no such folder of reference images"
    assert not out.exists()


def test_a_raw_format_without_its_bayer_order_lists_the_four_and_picks_none(cli, tmp_path):
    white = simulate_references(make_camera("imx219", size=SIZE), seed=1)["white"]
    assert white.pattern == "BGGR"  # a dump of a BGGR sensor: picking RGGB would swap red and blue
    (tmp_path / "white.raw").write_bytes(to_picamera2(white)[0].tobytes())
    args = ("calibrate", "--white", tmp_path / "white.raw", "--size", "160x120", "--sensor", "imx219")
    line = one_error(*cli(*args, "--raw-format", "RAW10_CSI2P", "--out", tmp_path / "cal.npz")[:2])
    assert line.endswith(
        "did you mean SBGGR10_CSI2P, SGBRG10_CSI2P, SGRBG10_CSI2P or SRGGB10_CSI2P: the Bayer order is part of the "
        "format (rpicam-raw prints it: 'format NAME')"
    )
    assert not (tmp_path / "cal.npz").exists()
    # The format with its order, as rpicam-raw printed it, calibrates.
    status, lines, _ = cli(*args, "--raw-format", "SBGGR10_CSI2P", "--out", tmp_path / "cal.npz")
    assert status == 0, lines
    assert load_calibration(tmp_path / "cal.npz").pattern == "BGGR"


def test_a_white_and_a_numbered_white_in_a_folder_are_averaged_and_said(cli, tmp_path):
    camera = make_camera("imx219", size=SIZE)
    frames = [render(camera, "white", rng=k) for k in (1, 2)]
    black = render(camera, "black", rng=0)
    folder = tmp_path / "refs"
    folder.mkdir()
    write_dng(folder / "white.dng", frames[0])
    write_dng(folder / "white2.dng", frames[1])
    write_dng(folder / "black.dng", black)
    status, lines, _ = cli("calibrate", folder, "--out", tmp_path / "flat.npz")
    assert status == 0, lines
    assert sum(line.startswith("white: 2 frames averaged: temporal noise ") for line in lines) == 1, lines
    cal = load_calibration(tmp_path / "flat.npz")
    white = cal.inputs[0]
    assert white["frame_count"] == 2 and [f["name"] for f in white["frames"]] == ["white.dng", "white2.dng"]
    # Both frames are in the flat field: it is the mean of the two, not either one alone (noise differs bin by bin).
    both, first = calibrate(frames, black=black), calibrate(frames[0], black=black)
    np.testing.assert_allclose(cal.site_white, both.site_white, rtol=1e-6)  # float32 fields: rounding only
    assert not np.allclose(cal.site_white, first.site_white, rtol=1e-6)


def test_frames_of_one_white_taken_at_other_settings_are_refused(cli, tmp_path):
    camera = make_camera("imx219", size=SIZE)
    first, second = (render(camera, "white", rng=k) for k in (1, 2))
    exposure = first.metadata["exposure_time_s"]
    folder = tmp_path / "refs"
    folder.mkdir()
    write_dng(folder / "white.dng", first)
    longer = dataclasses.replace(second, metadata={**second.metadata, "exposure_time_s": 2 * exposure})
    write_dng(folder / "white2.dng", longer)
    line = one_error(*cli("calibrate", folder, "--out", tmp_path / "flat.npz")[:2])
    assert line.startswith(
        f"{folder / 'white2.dng'}: exposure time (s) {2 * exposure:g} differs from the first white frame's "
        f"{exposure:g}: frames of one reference are averaged"
    )
    assert not (tmp_path / "flat.npz").exists()


# --------------------------------------------------------------------------------------------- light
@pytest.mark.parametrize(("illuminator", "light"), [("sim", "jig"), ("screen:prompt", "screen")])
def test_calibrating_an_acquisition_records_its_light(cli, tmp_path, illuminator, light):
    run = tmp_path / "run"
    with open_rig("sim", illuminator, size=SIZE, seed=2, prompt=lambda text: "") as rig:
        acquire(rig.camera, rig.illuminator, run, prompt=rig.prompt, settle_s=0)
    assert json.loads((run / "manifest.json").read_text())["illuminator"]["kind"] == illuminator.partition(":")[0]
    status, lines, _ = cli("calibrate", run, "--out", tmp_path / "cal.npz")
    assert status == 0, lines
    assert lines[0].startswith(f"wrote {tmp_path / 'cal.npz'}: ") and f", light {light} (" in lines[0]
    assert load_calibration(tmp_path / "cal.npz").light == light
    # Another light than the run's is refused, naming its manifest.
    other = "sheets"
    line = one_error(*cli("calibrate", run, "--light", other, "--out", tmp_path / "other.npz")[:2])
    assert line.startswith(
        f"{run / 'manifest.json'}: the acquisition's illuminator was {illuminator.partition(':')[0]}"
    )
    assert not (tmp_path / "other.npz").exists()


def test_the_light_option_is_recorded_checked_or_left_unknown(cli, refs, tmp_path):
    status, lines, _ = cli("calibrate", refs, "--light", "Screen", "--out", tmp_path / "screen.npz")
    assert status == 0, lines
    assert load_calibration(tmp_path / "screen.npz").light == "screen"
    status, lines, _ = cli("calibrate", refs, "--out", tmp_path / "unknown.npz")
    assert status == 0 and ", light " not in lines[0], lines
    assert load_calibration(tmp_path / "unknown.npz").light is None
    line = one_error(*cli("calibrate", refs, "--light", "scren", "--out", tmp_path / "typo.npz")[:2])
    assert "--light" in line and "'scren' is not one of jig, screen, sheets; did you mean screen?" in line
    assert not (tmp_path / "typo.npz").exists()


# ---------------------------------------------------------------------------------------------- help
def test_the_help_shows_the_workflow_above_the_commands(cli, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    status, _, out = cli("--help")
    assert status == 0
    lines = out.splitlines()
    start, commands = lines.index("Workflow, in this order:"), lines.index("Commands:")
    steps = lines[start + 1 : lines.index("", start)]
    assert start < commands
    names = [line.split()[1] for line in steps]
    assert names == ["inspect", "calibrate", "correct", "export-tuning", "report"]
    assert [line.split()[0] for line in steps] == ["1.", "2.", "3.", "4.", "5."]  # one line each, numbered
    assert set(names) <= {command.name for command in app.registered_commands}
    assert all(len(line) <= 80 for line in steps)
