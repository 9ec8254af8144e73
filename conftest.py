"""Doctests: every docstring example in ``src/picamcal`` runs (``python3 -m pytest`` collects them).

Each example runs in its own empty temporary folder (so it may write ``cal.npz`` and the like) with ``np`` and
``picamcal`` already imported. Examples build what they need on the simulator's small cameras, for instance::

    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
"""

from __future__ import annotations

import numpy as np
import pytest
from _pytest.doctest import DoctestItem

import picamcal


@pytest.fixture(autouse=True)
def _doctest_folder(request: pytest.FixtureRequest, doctest_namespace: dict, tmp_path, monkeypatch) -> None:
    if isinstance(request.node, DoctestItem):
        monkeypatch.chdir(tmp_path)
        doctest_namespace.update(np=np, picamcal=picamcal)
