"""What the napari tests share: a virtual X display for napari's Qt viewer, one per test process (and the
screen illuminator's tests their Xvfb).

napari draws its canvas with OpenGL (vispy), which Qt's offscreen platform does not give; an X server with Mesa does.
The suite runs as ``python3 -m pytest`` with no wrapper, so the first napari test of a process starts Xvfb itself and
opens the process's QApplication on it (``DISPLAY``, ``QT_QPA_PLATFORM=xcb``), before anything else can make one.
The QApplication lives as long as the process, and so must its display: Xvfb runs with ``-terminate``, so it ends
when its last client (the QApplication) disconnects as the process exits, and never outlives the tests.
The environment is put back once the QApplication exists, so that the tests after these see no display.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

#: The virtual screen: large enough for napari's main window and its docks.
SCREEN = (1600, 1200, 24)
#: The display this process's QApplication is on, once started.
_started: dict[str, str] = {}


def start_xvfb(screen: tuple[int, int, int] = SCREEN, *options: str) -> tuple[subprocess.Popen, str]:
    """Xvfb on a display number it finds free itself (-displayfd), with more ``options`` (``-terminate``: ending with
    its last client; ``-wr``: a white root window); the server and the display's name (``:N``). Also the screen
    illuminator's tests' (tests/test_screen.py)."""
    read, write = os.pipe()
    width, height, depth = screen
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write), "-screen", "0", f"{width}x{height}x{depth}", "-nolisten", "tcp", *options],
        pass_fds=(write,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # not in the test's process group: a test's signal does not reach it
    )
    os.close(write)
    with os.fdopen(read) as announced:
        number = announced.readline().strip()  # written once the server accepts connections
    if not number:
        server.kill()
        pytest.fail(f"Xvfb did not start (exit status {server.wait()})")
    return server, f":{number}"


def qt_application_on_virtual_display() -> str:
    """This process's QApplication, made on a virtual display started for it (once; later calls find it); the
    display's name. Skips when Xvfb is not installed."""
    from qtpy.QtWidgets import QApplication

    if "display" in _started or QApplication.instance() is not None:
        return _started.get("display", os.environ.get("DISPLAY", ""))
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian package xvfb, see .ci/run)")
    _, display = start_xvfb(SCREEN, "-terminate")
    saved = {name: os.environ.get(name) for name in ("DISPLAY", "QT_QPA_PLATFORM")}
    os.environ.update(DISPLAY=display, QT_QPA_PLATFORM="xcb")
    try:
        from napari.qt import get_qapp

        get_qapp()  # napari's: with the attributes its OpenGL canvas needs, set before the application exists
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    _started["display"] = display
    return display
