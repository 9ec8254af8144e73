"""Errors that point at the fix: one line, whatever went wrong and however the output is read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from test_cli import assert_bad_input, run


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("errors")
    assert run("simulate", "--out", str(folder / "sim"), "--size", "320x240", "--no-noise").returncode == 0
    assert run("calibrate", str(folder / "sim"), "--out", str(folder / "cal.npz")).returncode == 0
    return folder / "sim", folder / "cal.npz"


@pytest.mark.slow
def test_a_jpeg_given_as_raw_is_pointed_to_processed(sim_run, tmp_path):
    sim, cal = sim_run
    Image.fromarray(np.full((240, 320, 3), 128, np.uint8)).save(tmp_path / "photo.jpg")
    Image.fromarray(np.full((240, 320, 3), 128, np.uint8)).save(tmp_path / "photo.png")
    for name in ("photo.jpg", "photo.png"):
        result = run("correct", str(cal), str(tmp_path / name), "--out", str(tmp_path / "out"), "--workers", "0")
        assert_bad_input(result, name, "--processed")  # one file that cannot be corrected: one line, exit 2
    refs = [f"--{role}={sim / f'{role}.dng'}" for role in ("red", "green", "blue")]
    assert_bad_input(
        run("calibrate", f"--white={tmp_path / 'photo.jpg'}", *refs, "--out", str(tmp_path / "c.npz")),
        "photo.jpg",
        "--processed",
    )
    assert not (tmp_path / "c.npz").exists()


@pytest.mark.slow
def test_a_raw_image_given_as_processed_is_told_so(sim_run, tmp_path):
    sim, cal = sim_run
    result = run("correct", str(cal), str(sim / "target.dng"), "--processed", "--out", str(tmp_path / "o"))
    assert_bad_input(result, "target.dng: a DNG raw image, not a processed one: leave out --processed")


@pytest.mark.slow
def test_choices_are_case_insensitive_and_near_misses_get_did_you_mean(sim_run, tmp_path):
    sim, cal = sim_run
    result = run("correct", str(cal), str(sim / "target.dng"), "--out", str(tmp_path / "o"), "--mode", "Centre")
    assert result.returncode == 0, result.stderr
    assert_bad_input(
        run("correct", str(cal), str(sim / "target.dng"), "--out", str(tmp_path / "p"), "--mode", "center"),
        "--mode",
        "did you mean centre?",
    )
    processed = tmp_path / "o" / "target.tiff"
    result = run(
        "correct", str(cal), str(processed), "--processed", "--input-encoding", "Linear", "--out", str(tmp_path / "q")
    )
    assert result.returncode == 0, result.stderr
    assert_bad_input(
        run("correct", str(cal), str(processed), "--processed", "--input-encoding", "srbg", "--out", str(tmp_path)),
        "did you mean srgb?",
    )
    assert_bad_input(run("simulate", "--out", str(tmp_path / "s"), "--format", "DGN"), "did you mean dng?")
    assert not (tmp_path / "p").exists() and not (tmp_path / "s").exists()


@pytest.mark.slow
def test_usage_errors_are_one_line_too(sim_run):
    _, cal = sim_run
    assert_bad_input(run("correct", str(cal)), "Missing argument", "picamcal correct --help")
    assert_bad_input(run("no-such-command"), "No such command")
    assert_bad_input(run("correct", str(cal), "x.dng", "--out", "o", "--no-such-option"), "--no-such-option")


def test_a_long_error_is_never_wrapped(tmp_path):
    deep = tmp_path.joinpath(*(["a_rather_long_folder_name"] * 12))
    deep.mkdir(parents=True)
    result = run("correct", str(deep / "calibration.npz"), str(deep / "x.dng"), "--out", str(deep / "out"))
    assert_bad_input(result, str(deep / "calibration.npz"), "no such calibration file")
    assert len(result.stderr.strip()) > 200  # long enough that a terminal-width wrap would have split it


def test_a_monochrome_sensor_is_not_simulated(tmp_path):
    assert_bad_input(run("simulate", "--out", str(tmp_path / "s"), "--sensor", "ov9281"), "ov9281", "monochrome")
    assert not (tmp_path / "s").exists()
