"""What ``import picamcal`` and the command line import before they do any work (issue 14: instant commands).

Each check starts a fresh interpreter on this tree's ``src``, does one thing (an import, or one ``picamcal`` command
through :func:`picamcal.cli.main`) and lists ``sys.modules`` at the end. The heavy packages (numba 0.3 s,
colour-science 1 s with the matplotlib and scipy it imports, ...) must not be among them unless the command needs
them: importing picamcal, the command line, ``--help`` and ``--version`` need none, and a few common commands
need only what their work uses. What is checked is the list of modules, never a time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from conftest import simulated_calibration
from picamcal.cli import app

SRC = Path(__file__).resolve().parents[1] / "src"

#: Never imported to start the command line or to show its help (the guarded list of issue 14).
GUARDED = ("numba", "matplotlib", "colour", "scipy.ndimage", "dask", "zarr", "rawpy", "tifffile")
#: What a command that measures or plots nothing must not import.
PLOTTING_AND_KERNELS = ("numba", "matplotlib", "colour", "scipy.ndimage")

COMMANDS = [command.name for command in app.registered_commands]

_RUN = """
import json, sys
try:
    exec({action!r})
except SystemExit:
    pass
finally:
    with open({out!r}, "w") as f:
        json.dump(sorted(sys.modules), f)
"""


def modules_after(action: str, tmp_path: Path, cwd: Path | None = None) -> set[str]:
    """The modules a fresh interpreter holds after running the Python statements ``action``."""
    out = tmp_path / f"modules-{len(list(tmp_path.glob('modules-*')))}.json"
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    code = textwrap.dedent(_RUN).format(action=action, out=str(out))
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=cwd or tmp_path, env=env, capture_output=True, text=True, timeout=120
    )
    assert out.exists(), result.stderr
    return set(json.loads(out.read_text()))


def command_modules(args: list[str], tmp_path: Path, cwd: Path | None = None) -> set[str]:
    """The modules after ``picamcal ARGS`` (its exit status is not checked here)."""
    return modules_after(f"from picamcal.cli import main; main({args!r})", tmp_path, cwd)


def heavy(modules: set[str], names: tuple[str, ...] = GUARDED) -> list[str]:
    """Which of ``names`` (packages, or subpackages such as scipy.ndimage) were imported."""
    return [name for name in names if name in modules]


def test_the_guard_sees_an_import(tmp_path):
    # The check itself: a module imported by the action is listed, so an empty list means "not imported".
    assert heavy(modules_after("import numba, scipy.ndimage", tmp_path)) == ["numba", "scipy.ndimage"]


@pytest.mark.parametrize("module", ["picamcal", "picamcal.cli"])
def test_importing_picamcal_imports_no_heavy_package(tmp_path, module):
    modules = modules_after(f"import {module}", tmp_path)
    assert heavy(modules) == []
    assert "numpy" not in modules  # the names of picamcal are imported when first used (PEP 562)


def test_the_names_of_picamcal_work_when_imported_lazily(tmp_path):
    # picamcal.calibrate and picamcal.correct stay the functions after their modules are imported.
    action = """
import picamcal, picamcal.calibrate, picamcal.correct
from picamcal import Calibration, calibrate, read_raw
checks = {
    "calibrate": callable(picamcal.calibrate) and calibrate is picamcal.calibrate,
    "correct": callable(picamcal.correct),
    "Calibration": Calibration.__module__ == "picamcal.calibration",
    "read_raw": read_raw.__module__ == "picamcal.raw",
    "dir": set(picamcal.__all__) <= set(dir(picamcal)),
}
if not all(checks.values()):
    raise SystemExit(f"failed: {checks}")
open("ok", "w").close()
"""
    modules = modules_after(action, tmp_path)
    assert (tmp_path / "ok").exists()
    assert "picamcal.calibrate" in modules and "picamcal.correct" in modules


@pytest.mark.parametrize("args", [["--help"], ["--version"], *([name, "--help"] for name in COMMANDS)], ids=" ".join)
def test_help_and_version_import_no_heavy_package(tmp_path, args):
    modules = command_modules(args, tmp_path)
    assert heavy(modules) == []
    assert "numpy" not in modules and "pydantic" not in modules


def test_every_command_is_checked():
    # The list comes from the app, so a new command is checked too; this guards against an empty list.
    assert {"calibrate", "correct", "inspect", "export-lst", "report"} <= set(COMMANDS)


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A small simulated run (DNG files) and its calibration, made in this process."""
    folder = tmp_path_factory.mktemp("run")
    refs, cal = simulated_calibration(folder, (320, 240), seed=3)
    return folder, refs, cal


def test_inspecting_a_dng_imports_no_plotting_or_kernels(tmp_path, simulated):
    _, refs, _ = simulated
    modules = command_modules(["inspect", str(refs["white"])], tmp_path)
    assert "picamcal.raw.dng.plain" in modules  # it did read the file: a plain DNG, from its strips,
    assert "rawpy" not in modules  # so LibRaw is not even loaded
    assert heavy(modules, PLOTTING_AND_KERNELS) == []


def test_measuring_the_wheels_imports_no_colour_science(tmp_path, simulated):
    # L*a*b* and CIEDE2000 are computed in numpy (analysis.metrics): colour-science's import takes seconds.
    _, refs, cal = simulated
    modules = command_modules(["analyse", str(refs["target"]), "--calibration", str(cal), "--out", "a"], tmp_path)
    assert (tmp_path / "a").is_dir() and "picamcal.analysis.metrics" in modules
    assert heavy(modules, ("colour",)) == []


def test_exporting_a_legacy_table_imports_no_plotting_or_kernels(tmp_path, simulated):
    _, _, cal = simulated
    modules = command_modules(["export-lst", str(cal), "--out", str(tmp_path / "table.npy")], tmp_path)
    assert (tmp_path / "table.npy").exists()
    assert heavy(modules, PLOTTING_AND_KERNELS) == []


def test_exporting_a_tuning_file_imports_no_plotting_or_kernels(tmp_path, simulated):
    _, _, cal = simulated
    modules = command_modules(["export-tuning", str(cal), "--out", str(tmp_path / "tuning")], tmp_path)
    assert len(list((tmp_path / "tuning").glob("*.json"))) == 2
    assert heavy(modules, PLOTTING_AND_KERNELS) == []


def test_correcting_to_tiff_imports_no_plotting(tmp_path, simulated):
    _, refs, cal = simulated
    args = ["correct", str(cal), str(refs["target"]), "--out", str(tmp_path / "out"), "--workers", "0"]
    modules = command_modules(args, tmp_path)
    assert (tmp_path / "out" / "target.tiff").exists()
    # scipy.interpolate (0.6 s here): the correction's splines are solved with numpy.
    assert heavy(modules, ("matplotlib", "colour", "dask", "zarr", "scipy.interpolate")) == []


def picamcal_modules() -> list[str]:
    """Every module of the package, by its dotted name."""
    package = SRC / "picamcal"
    names = []
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(SRC).with_suffix("").parts
        if parts[-1] == "__main__":
            continue
        names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


#: What the interpreters of the check below have imported before picamcal: third-party packages only, whose import
#: is not what it tests (they are forked from one process that imported them: tests/forked_python.py).
THIRD_PARTY = ("numpy", "scipy.ndimage", "scipy.interpolate", "matplotlib.pyplot", "colour", "numba", "PIL.Image",
               "rawpy", "tifffile", "typer", "rich.console", "yaml", "dask.distributed", "zarr")  # fmt: skip


@pytest.mark.slow
def test_every_module_imports_first_in_a_fresh_interpreter(tmp_path):
    # With the names of picamcal imported lazily, any module may be the first one imported; a cycle through a
    # package's __init__ (which tests/test_layers.py does not follow) would fail only in some orders. Each interpreter
    # holds no module of picamcal before its one import.
    from concurrent.futures import ThreadPoolExecutor

    from forked_python import forkers

    env = {**os.environ, "PYTHONPATH": str(SRC)}
    modules = picamcal_modules()
    assert len(modules) > 50 and "picamcal.raw.dng.reader" in modules

    def failure(started, module: str) -> str | None:
        forker = started.get()
        try:
            code = f"import sys\nassert not any(m.startswith('picamcal') for m in sys.modules)\nimport {module}"
            status, _, stderr = forker.run(code, [], cwd=tmp_path, env=env, streams=tmp_path / module, timeout=300)
        finally:
            started.put(forker)
        return f"{module}: {(stderr.strip().splitlines() or ['no answer'])[-1]}" if status != 0 else None

    with forkers(2, THIRD_PARTY, env) as started, ThreadPoolExecutor(max_workers=2) as pool:
        failures = [f for f in pool.map(lambda module: failure(started, module), modules) if f]
    assert failures == []


def test_drawing_the_target_imports_no_colour_science(tmp_path):
    modules = command_modules(["target", "--out", str(tmp_path / "t.png"), "--size", "640x360"], tmp_path)
    assert (tmp_path / "t.png").exists()
    assert heavy(modules, PLOTTING_AND_KERNELS) == []


def test_the_srgb_encoding_is_colour_sciences_code_for_code():
    # encode_srgb writes out the transfer function instead of importing colour-science for it: the same codes for
    # every value, both sides of the linear segment's end (0.0031308) and out of range included.
    import colour
    from colour.utilities import domain_range_scale

    from picamcal.analysis.metrics import encode_srgb

    linear = np.concatenate([np.linspace(-0.1, 1.2, 200_001), np.nextafter(0.0031308, [0.0, 1.0]), [np.nan]])
    with domain_range_scale("reference"):
        expected = colour.cctf_encoding(np.clip(np.nan_to_num(linear), 0.0, 1.0), function="sRGB")
    np.testing.assert_array_equal(encode_srgb(linear), np.rint(np.asarray(expected) * 255.0).astype(np.uint8))
