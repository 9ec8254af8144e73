"""Doctests: every docstring example in ``src/picamcal`` runs (``python3 -m pytest`` collects them).

Each example runs in its own empty temporary folder (so it may write ``cal.npz`` and the like) with ``np`` and
``picamcal`` already imported. Examples build what they need on the simulator's small cameras, for instance::

    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)

The whole session (the tests under ``tests/`` too, and the processes they start) keeps its compiled C kernel
(:mod:`picamcal.ckernel`) in a temporary folder of its own, so that no test writes into the user's home: one
compile per session. It is set here, in the root, so that a run of the doctests alone has it as well.
"""

from __future__ import annotations

import os
import shutil
import tempfile

import numpy as np
import pytest
from _pytest.doctest import DoctestItem

import picamcal

#: Examples that run a whole workflow and cannot be fast: marked ``slow``, so the fast loop (``-m "not slow"``,
#: CONTRIBUTING.md) leaves them out; the full run still runs them. Every other example takes well under a second.
SLOW_EXAMPLES = {
    "picamcal.demo.run_demo",
    "picamcal.report.html.write_report",
    "picamcal.live.unmixer.LiveUnmixer.for_camera",
}


def pytest_configure(config: pytest.Config) -> None:
    folder = tempfile.mkdtemp(prefix="picamcal-test-cache-")
    os.environ["PICAMCAL_CACHE_DIR"] = folder
    config.add_cleanup(lambda: shutil.rmtree(folder, ignore_errors=True))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if isinstance(item, DoctestItem) and item.name in SLOW_EXAMPLES:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(autouse=True)
def _doctest_folder(request: pytest.FixtureRequest, doctest_namespace: dict, tmp_path, monkeypatch) -> None:
    if isinstance(request.node, DoctestItem):
        monkeypatch.chdir(tmp_path)
        doctest_namespace.update(np=np, picamcal=picamcal)
