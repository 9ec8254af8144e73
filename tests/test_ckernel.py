"""The fused correction kernel in C (picamcal.ckernel): numpy's result to the bit, and its cache of one compile.

Tolerance 0 for both outputs. The C does numpy's float32 operations in the same order with every operation
rounded on its own (-ffp-contract=off, no fast-math): +, -, * and / are correctly rounded in IEEE float32
wherever they run, so the float32 image is numpy's bit for bit, and the uint16 codes (a power-of-two scale,
exact, then the same rounding) too.

The cache tests start fresh processes (a process loads the kernel once), with a compiler that is a small shell
script: it records that it ran, then runs the real compiler, or fails on purpose.
"""

from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from conftest import simulated_calibration
from picamcal import calibrate, correct
from picamcal.ckernel import c_available, cache_dir, compiler, correct_c
from picamcal.correct import UINT16_WHITE, correction_fields
from picamcal.errors import KernelBuildError
from picamcal.kernels import CorrectionFields, correct_numpy, numba_available, set_kernel_threads
from picamcal.raw import PATTERNS
from picamcal.simulate import make_camera, simulate_references, simulate_target

SRC = Path(__file__).resolve().parents[1] / "src"
ckernel = importlib.import_module("picamcal.ckernel")
correct_module = importlib.import_module("picamcal.correct")  # the package's `correct` is the function
REAL_CC = shutil.which(compiler()[0])
needs_cc = pytest.mark.skipif(REAL_CC is None, reason=f"no C compiler ({compiler()[0]})")


@pytest.fixture(scope="module")
def compiled():
    if not c_available():
        pytest.skip(f"the C kernel cannot be built here: {ckernel._library()}")


@pytest.fixture
def threads():
    """Set the kernels' threads in a test; back to every available core afterwards."""
    yield set_kernel_threads
    set_kernel_threads(None)


@pytest.fixture(scope="module", params=PATTERNS)
def scene(request):
    """A 202 x 162 frame in each Bayer order (half a row is 101 pixels: vector loops end in a remainder), its
    calibration (bins of 10) and its ``centre`` fields, with the white and the matrices."""
    camera = make_camera("imx219", pattern=request.param, size=(202, 162))
    cal = calibrate(**simulate_references(camera, seed=1), bin_size=10)
    target, _ = simulate_target(camera, seed=2)
    black = np.asarray(target.black_level, dtype=np.float32)
    fields = correction_fields(cal, "centre", target.height, target.width)._replace(black=black)
    return cal, target, fields


def _top_rows(fields: CorrectionFields, height: int) -> CorrectionFields:
    """The fields of the frame's first ``height`` rows (a crop: its bottom edge is mirrored there)."""

    def rows(taps):
        return taps._replace(first=taps.first[:height], weights=taps.weights[:, :height])

    return fields._replace(white_rows=rows(fields.white_rows), matrix_rows=rows(fields.matrix_rows))


@pytest.mark.usefixtures("compiled")
@pytest.mark.parametrize("height", [162, 128, 6, 4], ids=lambda h: f"h{h}")  # 64-row blocks: 2.5, 2, a part of one
@pytest.mark.parametrize("white", [True, False], ids=["white", "site_gains"])
@pytest.mark.parametrize("unmix", [True, False], ids=["matrices", "no-matrices"])
def test_c_kernel_is_numpy_to_the_bit(scene, threads, height, white, unmix):
    _, target, fields = scene
    fields = _top_rows(fields, height)
    fields = fields._replace(white=fields.white if white else None, matrices=fields.matrices if unmix else None)
    bayer = target.bayer[:height]
    expected = correct_numpy(bayer, fields)
    expected_codes = correct_numpy(bayer, fields, code_scale=UINT16_WHITE)
    assert np.isfinite(expected).all() and expected.max() > 0.5  # a real image, not zeros on both sides
    for n in (1, 3):
        threads(n)
        np.testing.assert_array_equal(correct_c(bayer, fields), expected)
        np.testing.assert_array_equal(correct_c(bayer, fields, code_scale=UINT16_WHITE), expected_codes)
        out = np.full(expected.shape, np.nan, np.float32)
        assert correct_c(bayer, fields, out) is out
        np.testing.assert_array_equal(out, expected)
        codes = np.zeros(expected.shape, np.uint16)
        assert correct_c(bayer, fields, codes, code_scale=UINT16_WHITE) is codes
        np.testing.assert_array_equal(codes, expected_codes)


@pytest.mark.usefixtures("compiled")
@pytest.mark.parametrize("block_rows", [1, 2, 7, 1000])
def test_blocks_of_any_height_give_the_same_image(scene, block_rows):
    _, target, fields = scene
    np.testing.assert_array_equal(
        correct_c(target.bayer, fields, block_rows=block_rows), correct_c(target.bayer, fields)
    )


@pytest.mark.usefixtures("compiled")
def test_fields_that_do_not_fit_are_refused_not_read_outside(scene):
    _, target, fields = scene
    with pytest.raises(ValueError, match=r"white_rows\.first has shape"):
        correct_c(target.bayer[:100], fields)  # the fields of 162 rows
    beyond = fields.matrix_cols._replace(first=fields.matrix_cols.first + 3)
    with pytest.raises(ValueError, match="reach outside"):
        correct_c(target.bayer, fields._replace(matrix_cols=beyond))
    with pytest.raises(ValueError, match="even height and width"):
        correct_c(target.bayer[:, :-1], fields)


@pytest.mark.usefixtures("compiled")
@pytest.mark.parametrize("mode", ["uncorrected", "flat", "centre", "pure"])
def test_engine_c_of_correct_is_numpys_to_the_bit(scene, mode):
    cal, target, _ = scene
    for dtype in (np.float32, np.uint16):
        expected = correct(target, cal, mode, engine="numpy", dtype=dtype)
        np.testing.assert_array_equal(correct(target, cal, mode, engine="c", dtype=dtype), expected)
        np.testing.assert_array_equal(correct(target, cal, mode, dtype=dtype), expected)  # auto is c here


# ---------------------------------------------------------------------------------------------
# The cache, in fresh processes

#: A child process: one correction with the C kernel (engine given as argv[1]), checked against numpy; prints
#: whether numba was imported.
_CHILD = """
import sys
import numpy as np
from picamcal import calibrate, correct
from picamcal.simulate import make_camera, simulate_references, simulate_target
camera = make_camera("imx219", size=(64, 48))
cal = calibrate(**simulate_references(camera, seed=1))
target, _ = simulate_target(camera, seed=2)
rgb = correct(target, cal, "centre", engine=sys.argv[1])
assert np.array_equal(rgb, correct(target, cal, "centre", engine="numpy")), "not numpy's image"
print("numba" in sys.modules)
"""


def _child(env: dict[str, str], engine: str = "c") -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", _CHILD, engine],
        env={**os.environ, "PYTHONPATH": str(SRC), **env},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(child: subprocess.Popen) -> str:
    stdout, stderr = child.communicate(timeout=300)
    assert child.returncode == 0, stderr
    return stdout.strip()


def _compiler_script(folder: Path, body: str) -> Path:
    """A "compiler": a shell script that appends a line to ``folder``/calls, then runs ``body``."""
    script = folder / "cc"
    script.write_text(f'#!/bin/sh\necho "$$" >> "{folder}/calls"\n{body}\n')
    script.chmod(0o755)
    return script


def _calls(folder: Path) -> int:
    calls = folder / "calls"
    return len(calls.read_text().splitlines()) if calls.exists() else 0


@needs_cc
def test_a_second_process_loads_the_kernel_without_compiling(tmp_path):
    cc = _compiler_script(tmp_path, f'exec "{REAL_CC}" "$@"')
    env = {"CC": str(cc), "PICAMCAL_CACHE_DIR": str(tmp_path / "cache")}
    _finish(_child(env))
    assert _calls(tmp_path) == 1
    _finish(_child(env))
    assert _calls(tmp_path) == 1  # loaded from the cache: the compiler did not run
    assert [p.suffix for p in (tmp_path / "cache").iterdir()] == [".so"]


@needs_cc
def test_two_processes_compiling_at_once_leave_one_library(tmp_path):
    # The compiler waits until both processes have started it (for 60 s at most), so the two compiles overlap.
    barrier = (
        f'i=0; while [ "$(wc -l < "{tmp_path}/calls")" -lt 2 ] && [ $i -lt 1200 ]; do sleep 0.05; i=$((i+1)); done'
    )
    cc = _compiler_script(tmp_path, f'{barrier}\nexec "{REAL_CC}" "$@"')
    env = {"CC": str(cc), "PICAMCAL_CACHE_DIR": str(tmp_path / "cache")}
    children = [_child(env), _child(env)]
    for child in children:
        _finish(child)
    assert _calls(tmp_path) == 2
    assert [p.suffix for p in (tmp_path / "cache").iterdir()] == [".so"]  # no temporary left


@needs_cc
def test_a_cache_that_cannot_be_written_still_corrects(tmp_path):
    (tmp_path / "file").write_text("a file where the cache's parent folder would be")
    private = tmp_path / "tmp"
    private.mkdir()
    env = {"PICAMCAL_CACHE_DIR": str(tmp_path / "file" / "cache"), "TMPDIR": str(private)}
    assert _finish(_child(env)) == "False"  # the C kernel ran: no numba
    assert list(private.iterdir()) == []  # compiled in a private folder, removed once loaded


def test_without_a_compiler_auto_uses_numba_and_c_says_what_to_do(tmp_path):
    env = {"CC": "/nonexistent/cc", "PICAMCAL_CACHE_DIR": str(tmp_path / "cache")}
    assert _finish(_child(env, "auto")) == str(numba_available())  # numba's kernel when there is numba
    child = _child(env, "c")
    _, stderr = child.communicate(timeout=300)
    assert child.returncode != 0
    message = stderr.strip().splitlines()[-1]
    assert message.startswith("picamcal.errors.KernelBuildError: the C kernel cannot be compiled with /nonexistent/cc")
    assert "cannot run /nonexistent/cc" in message and "apt install gcc" in message and 'engine="numba"' in message


@pytest.fixture
def fresh_library(monkeypatch, tmp_path):
    """This process's kernel forgotten (as in a new process), with the cache in ``tmp_path``/cache; the session's
    kernel comes back afterwards."""
    monkeypatch.setenv("PICAMCAL_CACHE_DIR", str(tmp_path / "cache"))
    ckernel._library.cache_clear()
    yield
    monkeypatch.undo()
    ckernel._library.cache_clear()


@pytest.mark.usefixtures("fresh_library")
def test_a_failed_compile_is_remembered_until_the_compiler_changes(tmp_path, monkeypatch):
    cc = _compiler_script(tmp_path, 'echo "<stdin>:3:1: error: this compiler fails on purpose" >&2\nexit 1')
    monkeypatch.setenv("CC", str(cc))
    for _ in range(2):
        with pytest.raises(KernelBuildError, match="error: this compiler fails on purpose") as error:
            correct_c(np.zeros((4, 4), np.uint16), None)
        ckernel._library.cache_clear()  # a new process
    assert _calls(tmp_path) == 1  # the second process read the failure from the cache
    (marker,) = cache_dir().glob("*.failed")
    assert f"remembered in {marker}" in str(error.value)
    assert not c_available()
    ckernel._library.cache_clear()
    os.utime(cc, ns=(0, 0))  # another compiler installed there: tried again
    assert not c_available() and _calls(tmp_path) == 2


@pytest.mark.usefixtures("no_c_kernel")
def test_engine_c_without_a_compiler_raises_and_auto_falls_back():
    camera = make_camera("imx219", size=(64, 48))
    cal = calibrate(**simulate_references(camera, seed=1))
    target, _ = simulate_target(camera, seed=2)
    expected = correct(target, cal, "centre", engine="numpy", dtype=np.uint16)
    np.testing.assert_array_equal(correct(target, cal, "centre", dtype=np.uint16), expected)
    with pytest.raises(KernelBuildError, match="set CC to one"):
        correct(target, cal, "centre", engine="c")


# ---------------------------------------------------------------------------------------------
# The command line

_CLI = """
import json, sys
from picamcal.cli import main
try:
    main({args!r})
except SystemExit as exit_:
    assert exit_.code in (0, None), exit_.code
with open({out!r}, "w") as f:
    json.dump(sorted(sys.modules), f)
"""


@pytest.mark.usefixtures("compiled")
def test_correcting_one_file_from_the_command_line_uses_c_and_no_numba(tmp_path):
    import tifffile

    from picamcal.calibration import load_calibration
    from picamcal.raw import read_raw

    refs, cal_path = simulated_calibration(tmp_path, (320, 240), seed=3)
    args = ["correct", str(cal_path), str(refs["target"]), "--out", str(tmp_path / "out")]
    code = textwrap.dedent(_CLI).format(args=args, out=str(tmp_path / "modules.json"))
    result = subprocess.run(
        [sys.executable, "-c", code],
        env={**os.environ, "PYTHONPATH": str(SRC)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    modules = set(json.loads((tmp_path / "modules.json").read_text()))
    assert "picamcal.ckernel" in modules and "numba" not in modules
    expected = correct(read_raw(refs["target"]), load_calibration(cal_path), engine="numpy")
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "out" / "target.tiff"), expected)
