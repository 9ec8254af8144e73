"""The HTML report, `picamcal target`, `analyse` and `report`, with the page opened in a real browser."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from picamcal import calibrate, write_dng
from picamcal.report import write_report
from picamcal.simulate import make_camera, simulate_references, simulate_target
from test_cli import assert_bad_input, run

BROWSER = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def open_in_browser(page: Path) -> str:
    """The DOM of a page after a real headless browser has loaded it (and run its scripts)."""
    with tempfile.TemporaryDirectory() as profile:
        result = subprocess.run(
            [
                BROWSER,
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                f"--user-data-dir={profile}",
                "--allow-file-access-from-files",
                "--virtual-time-budget=10000",
                "--dump-dom",
                page.resolve().as_uri(),
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert result.returncode == 0, result.stderr[-2000:]
    return result.stdout


@pytest.fixture(scope="module")
def run_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("run")
    camera = make_camera("imx219", size=(640, 480))
    refs = simulate_references(camera, seed=2, dust=3)
    target, layout = simulate_target(camera, seed=3)
    for name, raw in {**refs, "target": target}.items():
        write_dng(folder / f"{name}.dng", raw)
    cal = calibrate(**refs)
    cal.save(folder / "cal.npz")
    (folder / "layout.json").write_text(json.dumps(layout))
    return folder, cal


@pytest.mark.slow
def test_report_renders_with_every_figure_in_a_real_browser(run_files, tmp_path):
    if BROWSER is None:
        pytest.skip("no browser: Debian's chromium is installed by .ci/run (apt-get install chromium)")
    folder, cal = run_files
    index = write_report(cal, tmp_path / "report", test_images=[folder / "target.dng"])
    html = index.read_text()
    images = html.count("<img ")
    assert images >= 6 + 9  # six diagnostic figures, and image, wheels and polar plot for three modes
    dom = open_in_browser(index)
    assert f'data-images="{images}/{images}"' in dom  # every figure loaded and decoded in the browser
    assert "Verdicts" in dom and "dust" in dom and "warn" in dom  # the simulated dust is found and flagged
    record = json.loads((tmp_path / "report" / "report.json").read_text())
    centre = record["test_images"][0]["analysis"]["centre"]["summary"]["max_delta_e"]
    flat = record["test_images"][0]["analysis"]["flat"]["summary"]["max_delta_e"]
    assert centre < 2.0 < flat  # noisy frames: the correction still brings the corners to the centre's colours
    # Each test image gets a verdict with its thresholds stated and what the workflows of its kind reach.
    verdict = record["test_images"][0]["verdict"]
    assert verdict["mode"] == "centre" and verdict["verdict"] in ("pass", "warn", "fail")
    assert verdict["max_delta_e"] == pytest.approx(centre)
    assert "Verdict:" in dom and "pass at mean &lt;= 1" in html and "jig-monitor" in dom


def test_a_missing_figure_is_seen_by_the_browser(tmp_path):
    if BROWSER is None:
        pytest.skip("no browser: Debian's chromium is installed by .ci/run (apt-get install chromium)")
    # The check the report test relies on must be able to fail.
    Image.new("RGB", (8, 8)).save(tmp_path / "a.png")
    page = tmp_path / "index.html"
    from picamcal.report.html import _LOAD_CHECK

    page.write_text(f"<html><body><img src='a.png'><img src='gone.png'><script>{_LOAD_CHECK}</script></body></html>")
    assert 'data-images="1/2"' in open_in_browser(page)


@pytest.mark.slow
def test_report_is_all_or_nothing(run_files, tmp_path, monkeypatch):
    _, cal = run_files
    out = tmp_path / "report"
    from picamcal.analysis import figures

    def broken(*args, **kwargs):
        raise RuntimeError("disk trouble")

    monkeypatch.setattr(figures, "dust_map", broken)
    with pytest.raises(RuntimeError):
        write_report(cal, out)
    assert not out.exists() and list(tmp_path.iterdir()) == []  # no half-written report, no temporary folder


@pytest.mark.slow
def test_report_cli_refuses_a_folder_that_is_not_empty(run_files, tmp_path):
    folder, _ = run_files
    out = tmp_path / "report"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert_bad_input(run("report", str(folder / "cal.npz"), "--out", str(out)), "not empty")
    assert (out / "notes.txt").read_text() == "mine"
    # --overwrite replaces only a report picamcal wrote, never a folder of someone's own files.
    assert_bad_input(run("report", str(folder / "cal.npz"), "--out", str(out), "--overwrite"), "not a picamcal report")
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


@pytest.mark.slow
def test_target_command_writes_png_pdf_and_layout(tmp_path):
    assert run("target", "--out", str(tmp_path / "t.png"), "--size", "800x600").returncode == 0
    assert Image.open(tmp_path / "t.png").size == (800, 600)
    layout = json.loads((tmp_path / "t.json").read_text())
    assert len(layout["wheels"]) == 9 and layout["fiducials"]
    assert run("target", "--out", str(tmp_path / "print.pdf")).returncode == 0
    assert (tmp_path / "print.pdf").read_bytes().startswith(b"%PDF") and (tmp_path / "print.json").exists()
    assert_bad_input(run("target", "--out", str(tmp_path / "t.png")), "exists already")


@pytest.mark.slow
def test_analyse_command(run_files, tmp_path):
    folder, _ = run_files
    out = tmp_path / "analysis"
    result = run("analyse", str(folder / "target.dng"), "--calibration", str(folder / "cal.npz"), "--out", str(out))
    assert result.returncode == 0, result.stderr
    record = json.loads((out / "target_analysis.json").read_text())
    # The simulated target is the one picamcal target prints: nine wheels.
    names = {"centre", "top", "bottom", "left", "right", "top-left", "top-right", "bottom-left", "bottom-right"}
    assert {w["name"] for w in record["layout"]["wheels"]} == names
    assert record["analysis"]["centre"]["summary"]["max_delta_e"] < 2.0
    assert (out / "target_centre_polar.png").stat().st_size > 0
    # An image with no wheels, and a layout that does not match the image: one line, status 2.
    Image.fromarray(np.full((480, 640, 3), 200, np.uint8)).save(tmp_path / "blank.png")
    assert_bad_input(
        run("analyse", str(tmp_path / "blank.png"), "--out", str(out)), "blank.png", "no colour wheels found"
    )
    # The simulated target is the printed one at 4:3: a 16:9 layout of it puts the wheels elsewhere.
    assert run("target", "--out", str(tmp_path / "t.png"), "--size", "640x360").returncode == 0
    assert_bad_input(
        run("analyse", str(folder / "target.dng"), "--layout", str(tmp_path / "t.json"), "--out", str(tmp_path / "o2")),
        "target.dng",
        "does not match the image",
    )


@pytest.mark.slow
def test_the_report_shows_the_expected_accuracy_of_the_light_the_calibration_records(tmp_path):
    import dataclasses
    import html as html_text
    import re

    cal = calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    pages = {}
    for light in ("screen", None):
        index = write_report(dataclasses.replace(cal, light=light), tmp_path / f"report-{light}")
        page = html_text.unescape(re.sub(r"<[^>]+>", " ", index.read_text()))
        pages[light] = " ".join(page.split())
    # The screen's workflows (monitor colours at normal incidence 0.18 mean, docs/accuracy.md), none of the jig's.
    screen = pages["screen"]
    assert "Expected accuracy Light: screen (a monitor's full-screen colours), as the calibration records it." in screen
    assert "screen screen monitor none 0.18 0.69 0.12" in screen and "jig-monitor" not in screen
    # Not recorded: said so, and every light's workflows shown, the jig's (1.14 mean) and the screen's.
    unknown = pages[None]
    assert "Expected accuracy Unknown light: expected accuracy of each workflow" in unknown
    assert "jig-monitor jig monitor none 1.14 2.82 0.12" in unknown and "screen screen monitor none 0.18" in unknown


def test_report_module_has_no_side_effects_on_import():
    # matplotlib's backend stays untouched: the figures use Agg canvases of their own.
    code = "import picamcal.report, picamcal.analysis.figures, matplotlib; print(matplotlib.get_backend())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip()
