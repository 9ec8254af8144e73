"""picamcal inspect on files and folders: every file listed, exit 1 if one is unreadable."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from test_cli import run


@pytest.fixture(scope="module")
def acquired(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("inspect") / "run"
    result = run("acquire", "--camera", "sim", "--illuminator", "sim", "--out", str(out), "--size", "320x240")
    assert result.returncode == 0, result.stderr
    return out


@pytest.mark.slow
def test_a_folder_lists_every_file_and_says_what_the_others_are(acquired):
    result = run("inspect", str(acquired), "--json")
    assert result.returncode == 0, result.stderr
    records = {Path(r["path"]).name: r for r in json.loads(result.stdout)}
    files = sorted(p.name for p in acquired.iterdir() if not p.name.startswith("."))
    assert sorted(records) == files  # every file, sidecars included
    dngs = [r for name, r in records.items() if name.endswith(".dng")]
    assert len(dngs) == 5 and all(r["raw"] and r["width"] == 320 for r in dngs)
    assert records["manifest.json"]["format"] == "acquisition manifest (picamcal acquire)"
    assert all(r["readable"] for r in records.values())


@pytest.mark.slow
def test_a_bad_file_does_not_stop_the_listing_and_exits_1(acquired, tmp_path):
    (tmp_path / "a_corrupt.dng").write_bytes(b"II*\x00" + bytes(200))
    (tmp_path / "notes.txt").write_text("focus at 3 mm\n")
    for name in ("white.dng", "white.json"):
        (tmp_path / name).write_bytes((acquired / name).read_bytes())
    result = run("inspect", str(tmp_path), str(tmp_path / "missing.dng"))
    assert result.returncode == 1, result.stderr
    table = result.stdout
    # The corrupt file comes first by name; the listing goes on to the good one after it.
    for name in ("a_corrupt.dng", "notes.txt", "white.dng", "white.json", "missing.dng"):
        assert name in table
    assert "a_corrupt.dng: cannot read: corrupt TIFF/DNG structure" in table.replace("\n", " ")
    assert "missing.dng: cannot read: no such file" in table
    assert "JSON sidecar of an acquired frame" in table
    assert result.stderr == ""


@pytest.mark.slow
def test_a_calibration_is_named_as_such(tmp_path):
    sim = tmp_path / "sim"
    assert run("simulate", "--out", str(sim), "--size", "320x240").returncode == 0
    assert run("calibrate", str(sim), "--out", str(tmp_path / "cal.npz")).returncode == 0
    result = run("inspect", str(tmp_path / "cal.npz"), "--json")
    assert result.returncode == 0
    assert json.loads(result.stdout)[0]["format"] == "picamcal calibration (imx219 320x240)"
    # What the calibration says of itself: a flat field from a white, and the light its references were taken under.
    white = ["calibrate", "--white", str(sim / "white.dng"), "--light", "screen", "--out", str(tmp_path / "flat.npz")]
    assert run(*white).returncode == 0
    result = run("inspect", str(tmp_path / "flat.npz"), "--json")
    assert json.loads(result.stdout)[0]["format"] == (
        "picamcal calibration (imx219 320x240, a flat field from a white, light: screen)"
    )
