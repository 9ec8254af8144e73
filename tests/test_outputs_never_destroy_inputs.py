"""Outputs never destroy inputs: no output is, holds or lies inside an input, and --overwrite replaces only
what picamcal wrote itself (issue: data lost with --overwrite)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from test_cli import assert_bad_input, run, snapshot

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def setup(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("guard")
    assert run("simulate", "--out", str(root / "captures"), "--size", "320x240", "--no-noise").returncode == 0
    assert run("calibrate", str(root / "captures"), "--out", str(root / "cal.npz")).returncode == 0
    shutil.copy(DATA / "tuning_vc4_imx219.json", root / "tuning.json")
    return root


def unchanged(root: Path, command: tuple[str, ...], *fragments: str) -> None:
    """The command is refused with one line, and nothing under ``root`` changes, byte for byte."""
    before = snapshot(root)
    assert_bad_input(run(*command), *fragments)
    assert snapshot(root) == before


@pytest.mark.slow
def test_the_reported_data_losses_are_refused(setup):
    cal, captures, tuning = setup / "cal.npz", setup / "captures", setup / "tuning.json"
    target, white = captures / "target.dng", captures / "white.dng"
    unchanged(setup, ("report", str(cal), "--out", str(cal), "--overwrite"), "cal.npz", "is an input")
    unchanged(
        setup,
        ("report", str(cal), "--test", str(target), "--out", str(captures), "--overwrite"),
        "holds the input",
    )
    unchanged(setup, ("export-lst", str(cal), "--out", str(cal), "--overwrite"), "is an input")
    unchanged(setup, ("apply-tuning", str(tuning), str(white), "--out", str(tuning), "--overwrite"), "is an input")


@pytest.mark.parametrize(
    "command",
    [
        ("calibrate", "{captures}", "--out", "{captures}/cal.npz", "--overwrite"),
        ("calibrate", "--white", "{captures}/white.dng", "--out", "{captures}/white.dng", "--overwrite"),
        ("correct", "{cal}", "{captures}", "--out", "{captures}", "--overwrite"),
        ("correct", "{cal}", "{captures}/target.dng", "--out", "{captures}/target.dng/x"),
        ("correct", "{cal}", "{captures}", "--out", "{root}"),  # captures/corrected, new, is allowed: beside them
        ("correct", "{cal}", "{captures}/target.dng", "--zarr", "{cal}", "--overwrite"),
        ("export-tuning", "{cal}", "--base", "{tuning}", "--out", "{tuning}", "--overwrite"),
        ("export-tuning", "{cal}", "--out", "{root}", "--overwrite"),
        ("analyse", "{captures}/target.dng", "--calibration", "{cal}", "--out", "{captures}"),
        ("report", "{cal}", "--out", "{root}", "--overwrite"),
    ],
    ids=lambda c: " ".join(c[:1] + c[-2:]),
)
@pytest.mark.slow
def test_no_output_is_holds_or_lies_inside_an_input(setup, command):
    names = {"root": setup, "captures": setup / "captures", "cal": setup / "cal.npz", "tuning": setup / "tuning.json"}
    unchanged(setup, tuple(part.format(**names) for part in command), "choose another")


@pytest.mark.slow
def test_overwrite_replaces_only_what_picamcal_wrote(setup, tmp_path):
    cal = str(setup / "cal.npz")
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "lab-book.txt").write_text("day 1\n")
    foreign = tmp_path / "other.npz"
    foreign.write_bytes(b"PK\x05\x06" + bytes(18))  # an empty zip: not a calibration
    (tmp_path / "table.npy").write_text("not a table")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "target.tiff").write_bytes((DATA / "tuning_vc4_imx219.json").read_bytes())
    white = setup / "captures" / "white.dng"
    unchanged(tmp_path, ("report", cal, "--out", str(notes), "--overwrite"), "not a picamcal report")
    unchanged(tmp_path, ("calibrate", "--white", str(white), "--out", str(foreign), "--overwrite"), "calibration")
    unchanged(tmp_path, ("export-lst", cal, "--out", str(tmp_path / "table.npy"), "--overwrite"), "legacy")
    target = str(setup / "captures" / "target.dng")
    unchanged(tmp_path, ("correct", cal, target, "--out", str(tmp_path / "out"), "--overwrite"), "picamcal wrote")


@pytest.mark.slow
def test_a_report_is_replaced_and_readable_by_others(setup, tmp_path):
    cal = str(setup / "cal.npz")
    report = tmp_path / "report"
    assert run("report", cal, "--out", str(report)).returncode == 0
    assert (report / ".picamcal-report").is_file()
    umask = os.umask(0)
    os.umask(umask)
    assert report.stat().st_mode & 0o777 == 0o777 & ~umask  # not mkdtemp's private 0700
    first = json.loads((report / "report.json").read_text())
    result = run("report", cal, "--out", str(report), "--overwrite")
    assert result.returncode == 0, result.stderr
    assert json.loads((report / "report.json").read_text())["checks"] == first["checks"]
    assert [p.name for p in tmp_path.iterdir()] == ["report"]  # no temporary or old folder left
