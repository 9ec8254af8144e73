"""Shared fixtures: a small, exactly known linear sensor model that needs no simulator."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from picamcal.raw import RawImage, site_channels

SPECTRAL = np.array([[0.90, 0.10, 0.02], [0.08, 0.85, 0.12], [0.02, 0.12, 0.88]])


def linear_mixing(height: int, width: int, pattern: str) -> np.ndarray:
    """A smooth per-pixel mixing field (H, W, 3 primaries): vignetting plus crosstalk growing with radius."""
    y, x = np.mgrid[0:height, 0:width]
    r2 = ((x - (width - 1) / 2) ** 2 + (y - (height - 1) / 2) ** 2) / (width / 2) ** 2
    channel = np.empty((height, width), dtype=np.intp)
    for site, c in enumerate(site_channels(pattern)):
        channel[site // 2 :: 2, site % 2 :: 2] = c
    own = SPECTRAL[channel] * (1 - 0.3 * r2)[..., None]
    leak = 0.12 * r2[..., None] * (np.arange(3) != channel[..., None])
    return (1 - 0.45 * r2)[..., None] * (own + leak)


def render_linear(mixing: np.ndarray, amounts, scale: float = 700.0, black: int = 64, bits: int = 10) -> RawImage:
    """Render a noiseless raw of uniform primaries ``amounts`` through a mixing field; quantised."""
    signal = mixing @ np.asarray(amounts, dtype=float) * scale + black
    bayer = np.clip(np.round(signal), 0, 2**bits - 1).astype(np.uint16)
    return bayer


@pytest.fixture(params=["BGGR", "RGGB"])
def linear_refs(request) -> dict[str, RawImage]:
    """White, red, green, blue and black references of the linear model (256 x 192)."""
    pattern = request.param
    mixing = linear_mixing(192, 256, pattern)
    amounts = {"white": (1, 1, 1), "red": (1, 0, 0), "green": (0, 1, 0), "blue": (0, 0, 1), "black": (0, 0, 0)}
    return {
        name: RawImage(render_linear(mixing, a), pattern, (64,) * 4, 1023, 10, "imx219", {"path": f"<{name}>"})
        for name, a in amounts.items()
    }


def simulated_calibration(folder, size: tuple[int, int], seed: int):
    """A simulated IMX219 run in ``folder``/sim and its full calibration, saved as ``folder``/cal.npz: (paths, cal)."""
    from picamcal.calibrate import calibrate
    from picamcal.raw import read_raw
    from picamcal.simulate import simulate_run

    refs = simulate_run(folder / "sim", "imx219", size=size, seed=seed)
    calibrate(**{role: read_raw(refs[role]) for role in ("white", "red", "green", "blue", "black")}).save(
        folder / "cal.npz"
    )
    return refs, folder / "cal.npz"


@pytest.fixture
def no_c_kernel(monkeypatch, tmp_path):
    """This test runs as on a machine without a C compiler (``CC=/nonexistent/cc``, an empty kernel cache), so
    that the fallbacks of ``engine="auto"`` run; the session's compiled kernel comes back afterwards."""
    import importlib

    ckernel = importlib.import_module("picamcal.ckernel")
    monkeypatch.setenv("CC", "/nonexistent/cc")
    monkeypatch.setenv("PICAMCAL_CACHE_DIR", str(tmp_path / "kernel-cache"))
    ckernel._library.cache_clear()
    yield
    monkeypatch.undo()
    ckernel._library.cache_clear()


# Started from a small launcher: Linux starts a child's ru_maxrss at the peak of the process it was forked from
# (exec keeps the old memory's high-water mark), so a child forked from pytest itself would report at least
# pytest's own size. The launcher is a bare Python of about 10 MB that reports its own child's peak alone.
_LAUNCHER = """
import os, subprocess, sys
child = subprocess.Popen(sys.argv[2:], stdout=subprocess.DEVNULL)
_, status, usage = os.wait4(child.pid, 0)
with open(sys.argv[1], "w") as f:
    f.write(str(usage.ru_maxrss * 1024))
sys.exit(os.waitstatus_to_exitcode(status))
"""


def run_measured(*args: str, env: dict[str, str] | None = None, timeout: float = 300) -> tuple[int, str, int]:
    """Run a command to the end: its exit status, stderr and peak resident memory in bytes (the kernel's count).

    For memory tests; compare the peak with a legitimate input's measured in the same test.
    """
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        peak_file = Path(folder) / "peak"
        result = subprocess.run(
            [sys.executable, "-c", _LAUNCHER, str(peak_file), *args],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            timeout=timeout,
        )
        return result.returncode, result.stderr, int(peak_file.read_text())


@pytest.fixture
def cli(monkeypatch, capfd):
    """Run ``picamcal ARGS`` in this process: (exit status, the non-empty lines of stderr, stdout). A module with a
    ``cli`` of its own (a subprocess, other settings) uses that one."""
    from picamcal.cli import main

    def run(*args: object) -> tuple[int, list[str], str]:
        monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # main's global settings are put back
        with pytest.raises(SystemExit) as exit:
            main([str(arg) for arg in args])
        captured = capfd.readouterr()
        return exit.value.code, [line for line in captured.err.splitlines() if line.strip()], captured.out

    return run


def one_error(status: int, lines: list[str]) -> str:
    """The one error line of a refused command (exit status 2), without its prefix."""
    assert status == 2 and len(lines) == 1, lines
    assert lines[0].startswith("picamcal: error: "), lines
    return lines[0].removeprefix("picamcal: error: ")
