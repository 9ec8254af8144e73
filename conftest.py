"""Doctests: every docstring example in ``src/picamcal`` runs (``python3 -m pytest`` collects them).

Each example runs in its own empty temporary folder (so it may write ``cal.npz`` and the like) with ``np`` and
``picamcal`` already imported. Examples build what they need on the simulator's small cameras, for instance::

    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)

The whole session (the tests under ``tests/`` too, and the processes they start) keeps its compiled C kernel
(:mod:`picamcal.ckernel`) in a temporary folder of its own, so that no test writes into the user's home: one
compile per session. It is set here, in the root, so that a run of the doctests alone has it as well.

The whole suite runs on ``python3 -m pytest -n auto`` (pytest-xdist, a test module to a worker): ``auto`` is one
worker more than the cores, and the longest modules start first (``LONGEST_FIRST``). Its workers and the processes
they start use one BLAS thread each (``BLAS_THREADS``): the suite already keeps every core busy, and OpenBLAS's
threads, which spin while they wait for work, then cost many times their work (a matrix product of the tuning export
took 20 times as long with two threads as with one on the busy 2-core machine).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

#: Set before numpy is first imported (here, in the process that starts the workers), so that the workers and every
#: process the tests start inherit it; a variable the caller set is kept.
BLAS_THREADS = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
for _name, _value in BLAS_THREADS.items():
    os.environ.setdefault(_name, _value)

import numpy as np  # noqa: E402 (after BLAS_THREADS)
import pytest  # noqa: E402
from _pytest.doctest import DoctestItem  # noqa: E402

import picamcal  # noqa: E402

#: Examples that run a whole workflow and cannot be fast: marked ``slow``, so the fast loop (``-m "not slow"``,
#: CONTRIBUTING.md) leaves them out; the full run still runs them. Every other example takes well under a second.
SLOW_EXAMPLES = {
    "picamcal.demo.run_demo",
    "picamcal.report.html.write_report",
    "picamcal.live.unmixer.LiveUnmixer.for_camera",
}


#: The test modules that take longest, longest first, with their seconds on one worker of a 2-core machine
#: (``python3 -m pytest -n auto --durations=0``, summed by module): they start first, so that the run does not end
#: with one worker alone on a long module while the others have finished. Refresh it when a module grows.
LONGEST_FIRST = (
    "test_docs_site.py",  # 264 s
    "test_table_import.py",  # 172 s
    "test_sensor_modes_matrix.py",  # 156 s
    "test_bad_input_corpus.py",  # 145 s
    "test_processed_modes.py",  # 139 s
    "test_docs.py",  # 126 s
    "test_virtualcam_pi_path.py",  # 118 s
    "test_verify_modes.py",  # 103 s
    "test_kill.py",  # 91 s
    "test_imports.py",  # 82 s
    "test_export.py",  # 78 s
    "test_virtualcam_picamera2.py",  # 69 s
    "test_output.py",  # 53 s
    "test_kernels.py",  # 51 s
    "test_live_modes.py",  # 48 s
    "test_report.py",  # 48 s
    "test_napari_widgets.py",  # 44 s
)


def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config, "workerinput") and os.environ.get("PICAMCAL_CACHE_DIR"):
        return  # an xdist worker: the folder of the run that started it, one compile for the whole run
    folder = tempfile.mkdtemp(prefix="picamcal-test-cache-")
    os.environ["PICAMCAL_CACHE_DIR"] = folder
    config.add_cleanup(lambda: shutil.rmtree(folder, ignore_errors=True))


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: two workers more than the cores (at most 4), as the suite's tests often wait (the virtual
    camera's frame clock, the processes they start) and a core left idle then would lengthen the run (on 2 cores,
    4 workers took the suite 858 s where 3 had taken 1260 to 1317 s); or ``$PYTEST_XDIST_AUTO_NUM_WORKERS``, as
    pytest-xdist's own default takes it."""
    if given := os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return int(given)
    return min(len(os.sched_getaffinity(0)) + 2, 4)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if isinstance(item, DoctestItem) and item.name in SLOW_EXAMPLES:
            item.add_marker(pytest.mark.slow)
    rank = {name: number for number, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(Path(str(item.path)).name, len(rank)))  # stable: the rest keep their order


@pytest.fixture(autouse=True)
def _doctest_folder(request: pytest.FixtureRequest, doctest_namespace: dict, tmp_path, monkeypatch) -> None:
    if isinstance(request.node, DoctestItem):
        monkeypatch.chdir(tmp_path)
        doctest_namespace.update(np=np, picamcal=picamcal)
