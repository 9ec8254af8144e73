"""A frame's rows in blocks, one per core, each in a thread: for kernels compiled with ``nogil`` (numba), which then
run in parallel, as the virtual camera's per-frame work must to keep up with a sensor's frame rate.

Examples
--------
>>> out = np.zeros(1000)
>>> def fill(start, stop):
...     out[start:stop] = np.arange(start, stop)
>>> in_row_blocks(fill, 1000)
>>> bool(np.array_equal(out, np.arange(1000)))
True
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .kernels import available_cores

#: Fewer rows than this a block are not worth a thread.
MIN_BLOCK_ROWS = 64


@functools.cache
def _pool() -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max(1, available_cores() - 1), thread_name_prefix="picamcal-rows")


def in_row_blocks(run: Callable[[int, int], None], rows: int) -> None:
    """Call ``run(start, stop)`` on consecutive blocks of ``rows`` rows that cover them, one block per core.

    The first block runs in the calling thread, the others in a shared pool; it returns when all are done and
    raises a failed block's exception. Where there is one core, or too few rows, it is ``run(0, rows)``.
    """
    blocks = max(1, min(available_cores(), rows // MIN_BLOCK_ROWS))
    if blocks == 1:
        run(0, rows)
        return
    first, *others = itertools.pairwise(np.linspace(0, rows, blocks + 1).round().astype(int).tolist())
    futures = []
    try:
        for start, stop in others:
            try:
                futures.append(_pool().submit(run, start, stop))
            except RuntimeError:  # the interpreter is exiting, and concurrent.futures takes no new work: run it here
                run(start, stop)
        run(*first)
    finally:
        for future in futures:
            future.result()
