"""The command line through real subprocesses: the happy path and every kind of bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from picamcal import Mode, load_calibration, read_raw
from picamcal.raw import write_dng

SIM_SIZE = "320x240"


def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", "from picamcal.cli import main; main()", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=300,
    )


def assert_bad_input(result: subprocess.CompletedProcess, *fragments: str) -> None:
    assert result.returncode == 2, result.stdout + result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr  # one line, no traceback
    assert lines[0].startswith("picamcal: error: ")
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "run"
    result = run("simulate", "--sensor", "imx219", "--out", str(out), "--size", SIM_SIZE, "--seed", "3")
    assert result.returncode == 0, result.stderr
    return out


@pytest.fixture(scope="module")
def cal_path(sim, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cal") / "cal.npz"
    result = run("calibrate", str(sim), "--out", str(out))
    assert result.returncode == 0, result.stderr
    return out


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_simulate_writes_a_run(sim):
    names = {p.name for p in sim.iterdir()}
    assert {"white.dng", "red.dng", "green.dng", "blue.dng", "black.dng", "target.dng", "layout.json"} <= names
    raw = read_raw(sim / "white.dng")
    assert (raw.width, raw.height, raw.pattern, raw.sensor) == (320, 240, "BGGR", "imx219")


@pytest.mark.slow
def test_calibrate_from_a_folder_equals_calibrate_from_named_files(sim, cal_path, tmp_path):
    named = tmp_path / "named.npz"
    result = run(
        "calibrate",
        *[f"--{r}={sim / f'{r}.dng'}" for r in ("white", "red", "green", "blue", "black")],
        "--out",
        str(named),
    )
    assert result.returncode == 0, result.stderr
    a, b = load_calibration(cal_path), load_calibration(named)
    np.testing.assert_array_equal(a.unmixing, b.unmixing)
    assert [i["sha256"] for i in a.inputs] == [i["sha256"] for i in b.inputs]


@pytest.mark.slow
def test_calibrate_finds_paper_style_names(sim, tmp_path):
    folder = tmp_path / "paper"
    folder.mkdir()
    for role, rgb in {
        "white": (255, 255, 255),
        "red": (255, 0, 0),
        "green": (0, 255, 0),
        "blue": (0, 0, 255),
        "black": (0, 0, 0),
    }.items():
        shutil.copy(sim / f"{role}.dng", folder / "capture_r{}_g{}_b{}.dng".format(*rgb))
    result = run("calibrate", str(folder), "--out", str(tmp_path / "cal.npz"))
    assert result.returncode == 0, result.stderr
    assert {i["role"] for i in load_calibration(tmp_path / "cal.npz").inputs} == {
        "white",
        "red",
        "green",
        "blue",
        "black",
    }


@pytest.mark.slow
def test_correct_writes_float_tiffs_and_never_overwrites(sim, cal_path, tmp_path):
    out = tmp_path / "out"
    before = snapshot(sim)
    result = run("correct", str(cal_path), str(sim / "target.dng"), str(sim / "white.dng"), "--out", str(out))
    assert result.returncode == 0, result.stderr
    white = tifffile.imread(out / "white.tiff")
    assert white.dtype == np.float32 and white.shape == (240, 320, 3)
    assert abs(float(np.median(white)) - 1.0) < 0.01  # the calibration's white maps to 1.0
    # Run again: the existing output is kept and skipped (an interrupted batch resumes the same way).
    before_again = (out / "white.tiff").stat().st_mtime_ns
    again = run("correct", str(cal_path), str(sim / "white.dng"), "--out", str(out))
    assert again.returncode == 0 and "skipped 1" in again.stderr + again.stdout
    assert (out / "white.tiff").stat().st_mtime_ns == before_again
    result = run(
        "correct", str(cal_path), str(sim / "white.dng"), "--out", str(out), "--overwrite", "--binned", "--mode", "flat"
    )
    assert result.returncode == 0 and tifffile.imread(out / "white.tiff").shape == (15, 20, 3)
    assert snapshot(sim) == before  # inputs are never modified


@pytest.mark.slow
def test_demo_runs_and_writes_its_outputs_the_tuning_files_and_the_legacy_table(tmp_path):
    out = tmp_path / "demo"
    data = Path(__file__).parent / "data"
    bases = (
        "--tuning-base",
        str(data / "tuning_vc4_imx219.json"),
        "--tuning-base",
        str(data / "tuning_pisp_imx219.json"),
    )
    result = run("demo", "--out", str(out), "--size", "640x480", *bases)
    assert result.returncode == 0, result.stderr
    assert "centre" in result.stdout and "ΔE2000" in result.stdout
    figures = json.loads((out / "figures.json").read_text())
    assert figures["modes"]["centre"]["max_delta_e"] < 1.0 < figures["modes"]["flat"]["max_delta_e"]
    for mode in ("uncorrected", "flat", "centre", "pure"):
        assert (out / f"target_{mode}.png").stat().st_size > 1000
    assert figures["mode_meaning"] == {mode.value: mode.description for mode in Mode}  # one definition
    assert load_calibration(out / "calibration.npz").sensor == "imx219"
    assert set(figures["exports"]) == {"lens_shading_legacy.npy", "tuning_bcm2835.json", "tuning_pisp.json"}
    for name, record in figures["exports"].items():
        assert (out / name).exists()
        assert record["white_flatness_percent"] < 3.0  # an independent noisy white, through each export
    assert "tuning_pisp.json" in result.stdout
    assert_bad_input(run("demo", "--out", str(out), "--size", "480x360"), "not empty")


# ---------------------------------------------------------------------------------------------- bad input
@pytest.mark.slow
def test_missing_and_non_raw_inputs(sim, tmp_path):
    png = tmp_path / "picture.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    out = tmp_path / "cal.npz"
    refs = [f"--{r}={sim / f'{r}.dng'}" for r in ("red", "green", "blue")]
    assert_bad_input(
        run("calibrate", f"--white={tmp_path / 'nope.dng'}", *refs, "--out", str(out)), "nope.dng", "no such file"
    )
    assert_bad_input(run("calibrate", f"--white={png}", *refs, "--out", str(out)), "picture.png", "a PNG image")
    empty = tmp_path / "empty.dng"
    empty.write_bytes(b"")
    assert_bad_input(run("calibrate", f"--white={empty}", *refs, "--out", str(out)), "empty.dng", "empty file")
    assert not out.exists()


@pytest.mark.slow
def test_references_that_do_not_match(sim, tmp_path):
    other = tmp_path / "other"
    result = run("simulate", "--out", str(other), "--size", "256x192", "--seed", "1")
    assert result.returncode == 0
    out = tmp_path / "cal.npz"
    args = [f"--{r}={sim / f'{r}.dng'}" for r in ("white", "green", "blue")]
    assert_bad_input(
        run("calibrate", *args, f"--red={other / 'red.dng'}", "--out", str(out)), "red.dng", "size 256x192 differs"
    )
    raw = read_raw(sim / "red.dng")
    raw.pattern = "RGGB"
    write_dng(tmp_path / "red_rggb.dng", raw)
    assert_bad_input(
        run("calibrate", *args, f"--red={tmp_path / 'red_rggb.dng'}", "--out", str(out)),
        "red_rggb.dng",
        "Bayer pattern RGGB differs",
    )
    assert not out.exists()


@pytest.mark.slow
def test_saturated_dark_and_swapped_references(sim, tmp_path):
    white = read_raw(sim / "white.dng")
    bright = tmp_path / "bright.dng"
    white.bayer = np.minimum(white.bayer.astype(np.int32) * 4, white.white_level).astype(np.uint16)
    write_dng(bright, white)
    out = tmp_path / "cal.npz"
    colours = [f"--{r}={sim / f'{r}.dng'}" for r in ("red", "green", "blue")]
    assert_bad_input(run("calibrate", f"--white={bright}", *colours, "--out", str(out)), "bright.dng", "saturated")
    dark = read_raw(sim / "white.dng")
    dark.bayer = (64 + (dark.bayer.astype(np.int32) - 64) // 50).clip(0).astype(np.uint16)
    write_dng(tmp_path / "dark.dng", dark)
    assert_bad_input(
        run("calibrate", f"--white={tmp_path / 'dark.dng'}", *colours, "--out", str(out)), "dark.dng", "too dark"
    )
    assert_bad_input(
        run("calibrate", f"--white={sim / 'white.dng'}", *colours, f"--black={sim / 'white.dng'}", "--out", str(out)),
        "white.dng",
        "not darker than the white",
    )
    assert not out.exists()


@pytest.mark.slow
def test_calibration_that_does_not_fit_the_image(cal_path, tmp_path):
    other = tmp_path / "other"
    assert run("simulate", "--out", str(other), "--sensor", "imx477", "--size", SIM_SIZE).returncode == 0
    out = tmp_path / "out"
    result = run("correct", str(cal_path), str(other / "target.dng"), "--out", str(out))
    # One file that does not fit is an error like any other: one line, exit status 2, no output folder.
    assert_bad_input(result, f"{other / 'target.dng'}: ", "sensor imx477, calibration is for imx219")
    assert not out.exists()
    # In a batch each is reported and the others go on: exit status 1, the failures before the summary, and no
    # output folder left empty.
    result = run("correct", str(cal_path), str(other / "target.dng"), str(other / "white.dng"), "--out", str(out))
    assert result.returncode == 1, result.stderr
    lines = result.stderr.splitlines()
    assert [line.split(": ")[1] for line in lines[:2]] == ["failed", "failed"] and len(lines) == 3, result.stderr
    assert lines[0].startswith(f"picamcal: failed: {other / 'target.dng'}: ") and "sensor imx477" in lines[0]
    assert lines[2].startswith("wrote 0 image(s)") and lines[2].endswith("failed 2")
    assert not out.exists()


@pytest.mark.slow
def test_corrupt_calibration(sim, tmp_path):
    bad = tmp_path / "cal.npz"
    bad.write_bytes(b"PK\x03\x04 this is not a zip")
    assert_bad_input(
        run("correct", str(bad), str(sim / "target.dng"), "--out", str(tmp_path / "o")),
        "cal.npz",
        "not a readable picamcal calibration",
    )
    assert_bad_input(
        run("correct", str(tmp_path / "none.npz"), str(sim / "target.dng"), "--out", str(tmp_path / "o")),
        "none.npz",
        "no such calibration file",
    )


@pytest.mark.slow
def test_refuses_to_overwrite_calibration_or_an_input(sim, cal_path, tmp_path):
    assert_bad_input(run("calibrate", str(sim), "--out", str(cal_path)), "exists already")
    result = run("calibrate", str(sim), "--out", str(sim / "white.dng"), "--overwrite")
    assert_bad_input(result, "white.dng", "is an input of this command")


def test_folder_without_references(tmp_path):
    assert_bad_input(run("calibrate", str(tmp_path), "--out", str(tmp_path / "c.npz")), "no white, red, green, blue")
