"""The screen illuminator against a real X server (Xvfb), its prompting fallback, and acquisitions through it.

The window is read back from the X server itself (Pillow's ImageGrab over XCB), so "the screen shows the colour" is
what the display holds, not what the code meant to draw. Xvfb is a Debian package (``.ci/run`` installs it); the tests
that need it skip, saying so, only where it is missing.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import ImageGrab

import napari_support
from picamcal import load_calibration
from picamcal.acquire.acquisition import acquire, open_rig
from picamcal.acquire.base import IlluminatorError
from picamcal.acquire.cameras import SimCamera
from picamcal.acquire.illuminators import REFERENCE_LIGHTS, open_illuminator
from picamcal.acquire.screen import ScreenPrompt, ScreenWindow, open_screen
from picamcal.manifest import load_manifest
from picamcal.references import read_manifest
from picamcal.target import SCREEN_COLOURS
from test_cli import run

SCREEN = (320, 240)
SIZE = (320, 240)
FIVE = ("white", "red", "green", "blue", "black")
ARGS = ("--camera", "sim", "--illuminator", "screen", "--size", "320x240", "--settle", "0")


def start_xvfb(depth: int = 24) -> tuple[subprocess.Popen, str]:
    """Xvfb with its root window white (-wr), and its display's name."""
    return napari_support.start_xvfb((*SCREEN, depth), "-wr")


@pytest.fixture(scope="module")
def xvfb():
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian package xvfb, see .ci/run)")
    server, display = start_xvfb()
    yield display
    server.terminate()
    server.wait(timeout=30)


def unused_display() -> str:
    """A display name no X server answers on: no socket and no lock file."""
    number = next(n for n in range(200, 400) if not Path(f"/tmp/.X11-unix/X{n}").exists())
    assert not Path(f"/tmp/.X{number}-lock").exists()
    return f":{number}"


def screen_colours(display: str) -> np.ndarray:
    """The distinct colours of every pixel of the display's screen, as the X server holds them."""
    pixels = np.asarray(ImageGrab.grab(xdisplay=display).convert("RGB"))
    assert pixels.shape == (SCREEN[1], SCREEN[0], 3)  # the whole screen, not a window
    return np.unique(pixels.reshape(-1, 3), axis=0)


# --- the window on a real X server -------------------------------------------------------------------------------


def test_the_window_fills_the_whole_screen_with_exactly_each_colour(xvfb):
    assert screen_colours(xvfb).tolist() == [[255, 255, 255]]  # the server's white root window
    screen = ScreenWindow(xvfb)
    try:
        assert screen_colours(xvfb).tolist() == [[0, 0, 0]]  # open: black over the whole screen
        # The references, an LED mixture and colours one code value apart: a 24-bit display holds them exactly.
        for rgb in [*SCREEN_COLOURS.values(), (0, 255, 255), (1, 2, 3), (254, 255, 0), (255, 0, 0)]:
            screen.set_rgb(*rgb)
            assert screen_colours(xvfb).tolist() == [list(rgb)], rgb
        assert screen.describe() == {
            "kind": "screen",
            "shows": "window",
            "display": xvfb,
            "size": list(SCREEN),
            "depth": 24,
        }
    finally:
        screen.close()
    assert screen_colours(xvfb).tolist() == [[255, 255, 255]]  # closed: the root window again


def test_a_bad_colour_is_refused_and_the_screen_keeps_its_colour(xvfb):
    screen = ScreenWindow(xvfb)
    try:
        screen.set_rgb(0, 0, 255)
        with pytest.raises(IlluminatorError, match=r"three whole numbers 0-255, got \(256, 0, 0\)"):
            screen.set_rgb(256, 0, 0)
        assert screen_colours(xvfb).tolist() == [[0, 0, 255]]
    finally:
        screen.close()


@pytest.mark.slow
def test_a_display_of_fewer_bits_warns_that_it_rounds_the_colours(xvfb):
    server, display = start_xvfb(depth=16)
    # In a process of its own: Tk keeps its connection to a display after the window closes, and a server that then
    # goes away ends the process that holds it.
    script = (
        "import warnings; from picamcal.acquire.screen import ScreenWindow\n"
        f"with warnings.catch_warnings(record=True) as caught:\n"
        f"    warnings.simplefilter('always'); screen = ScreenWindow({display!r})\n"
        "screen.set_rgb(255, 0, 0); screen.close(); print(screen.describe()['depth'], *caught, sep='\\n')"
    )
    try:
        result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    finally:
        server.terminate()
        server.wait(timeout=30)
    assert result.returncode == 0, result.stderr
    depth, warning = result.stdout.splitlines()[:2]
    assert depth == "16" and f"the display {display} has 16 bits a pixel: it rounds the colours" in warning


def test_open_screen_uses_the_display_named_or_in_the_environment(xvfb, monkeypatch):
    monkeypatch.setenv("DISPLAY", xvfb)
    for screen in (open_screen(), open_illuminator("screen"), open_illuminator(f"screen:{xvfb}")):
        try:
            assert isinstance(screen, ScreenWindow) and screen.display == xvfb
        finally:
            screen.close()
    screen = open_illuminator(f"screen:{xvfb[1:]}")  # a bare number is that display
    screen.close()
    assert screen.display == xvfb


def test_the_screen_is_set_to_the_colours_of_the_screen_images():
    # The acquisition sets each reference's REFERENCE_LIGHTS value; a screen must then show what the matching
    # screen_ROLE.png holds, each primary at full drive.
    assert REFERENCE_LIGHTS == SCREEN_COLOURS


# --- without a display: the prompts ------------------------------------------------------------------------------


def test_without_a_display_the_screen_asks_for_each_image_and_says_why(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    asked: list[str] = []
    screen = open_screen(colours={"Amber": (255, 191, 0)}, input_fn=asked.append)
    assert isinstance(screen, ScreenPrompt)
    assert screen.describe() == {"kind": "screen", "shows": "prompt", "why": "no display (DISPLAY is not set)"}
    for rgb in (*REFERENCE_LIGHTS.values(), (255, 191, 0), (255, 191, 0), (9, 9, 9)):
        screen.set_rgb(*rgb)
    assert asked == [
        "Show screen_white.png full-screen, then press Enter",
        "Show screen_red.png full-screen, then press Enter",
        "Show screen_green.png full-screen, then press Enter",
        "Show screen_blue.png full-screen, then press Enter",
        "Show screen_black.png full-screen, then press Enter",
        "Show screen_colour_amber.png full-screen, then press Enter",  # once: shown already the second time
        "Show a full-screen colour (9, 9, 9) (not one of picamcal's screen images), then press Enter",
    ]


def test_a_display_that_cannot_be_opened_falls_back_unless_it_was_named(monkeypatch):
    dead = unused_display()
    monkeypatch.setenv("DISPLAY", dead)
    screen = open_screen(input_fn=lambda prompt: "")
    assert isinstance(screen, ScreenPrompt)
    assert screen.describe()["why"].startswith(f"cannot open the display '{dead}'")
    with pytest.raises(IlluminatorError, match=f"cannot open the display '{dead}'"):
        open_illuminator(f"screen:{dead}")


def test_end_of_input_at_a_prompt_is_an_illuminator_error():
    def closed(prompt):
        raise EOFError

    with pytest.raises(IlluminatorError, match=r"no answer \(end of input\) when asked to show the screen"):
        ScreenPrompt(input_fn=closed).set_rgb(255, 0, 0)


# --- acquisitions through the screen -----------------------------------------------------------------------------


class _ScreenWatchingCamera(SimCamera):
    """The simulated camera, which also reads the X screen at each capture: what a real camera would see."""

    def __init__(self, display: str, **kwargs) -> None:
        super().__init__("imx219", size=SIZE, seed=5, **kwargs)
        self.display = display
        self.seen: list[tuple[tuple[int, int, int], list[list[int]]]] = []

    def capture(self):
        self.seen.append((self.light.rgb, screen_colours(self.display).tolist()))
        return super().capture()


def test_each_frame_is_captured_while_the_screen_shows_its_colour(xvfb, tmp_path):
    with open_rig("sim", f"screen:{xvfb}", size=SIZE, seed=5) as rig:
        camera = _ScreenWatchingCamera(xvfb, light=rig.camera.light)
        acquire(camera, rig.illuminator, tmp_path, colours={"cyan": (0, 255, 255)}, settle_s=0)
    # Every frame, auto-exposure's included, saw the whole screen in the light the simulated camera rendered.
    assert camera.seen and all(screen == [list(rgb)] for rgb, screen in camera.seen)
    captured = [rgb for rgb, _ in camera.seen][-6:]
    assert captured == [*REFERENCE_LIGHTS.values(), (0, 255, 255)]
    record = load_manifest(tmp_path)
    assert record["illuminator"] == {
        "kind": "screen",
        "shows": "window",
        "display": xvfb,
        "size": list(SCREEN),
        "depth": 24,
        "seen_by": "sim",
    }
    assert record["roles"] == [*FIVE, "colour_cyan"] and record["colours"] == {"colour_cyan": [0, 255, 255]}


@pytest.mark.slow
def test_acquire_with_the_screen_under_xvfb_then_calibrate(xvfb, tmp_path, monkeypatch):
    monkeypatch.setenv("DISPLAY", xvfb)
    out = tmp_path / "run"
    result = run(
        "acquire",
        *ARGS,
        "--colour",
        "cyan=0,255,255",
        "--out",
        str(out),
    )
    assert result.returncode == 0, result.stderr
    assert f"showing the colours full-screen on the display {xvfb}" in " ".join(result.stderr.split())
    record = load_manifest(out)
    assert record["complete"] and record["illuminator"]["shows"] == "window"
    assert [e["role"] for e in record["entries"]] == [*FIVE, "colour_cyan"]
    assert list(read_manifest(out)) == [*FIVE, "colour_cyan"]
    assert run("calibrate", str(out), "--out", str(tmp_path / "cal.npz")).returncode == 0
    cal = load_calibration(tmp_path / "cal.npz")
    assert (cal.width, cal.height) == SIZE


@pytest.mark.slow
def test_acquire_with_the_screen_and_no_display_prompts_on_the_terminal(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    out = tmp_path / "run"
    result = subprocess.run(
        [sys.executable, "-c", "from picamcal.cli import main; main()", "acquire", *ARGS, "--out", str(out)],
        input="\n" * 6,  # one Enter for each colour
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "(no display (DISPLAY is not set))" in " ".join(result.stderr.split())  # rich wraps at 80 columns
    shown = [line for line in result.stdout.split("then press Enter") if "Show " in line]
    assert [line.split("Show ")[-1] for line in shown] == [f"screen_{role}.png full-screen, " for role in FIVE]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["illuminator"]["shows"] == "prompt" and manifest["complete"]
