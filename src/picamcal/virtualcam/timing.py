"""Where the virtual camera's CPU time goes: each stage's CPU time, frame by frame, switched on by the environment
variable ``PICAMCAL_VIRTUAL_CAMERA_TIMING=1`` (``benchmarks/bench_virtualcam.py`` turns it on; off, it costs nothing
but a test of one global).

A stage's time is CPU time (``time.thread_time``) of the threads that do its work: the calling thread's, less what the
stages nested in it took there, and, for work split into row blocks (:func:`picamcal._rows.in_row_blocks`), each
block's in the thread that ran it. So the stages add up to the virtual camera's share of the process's CPU time, and
the rest is the application's (picamera2, the script).

Examples
--------
>>> timings = Timings()
>>> with timings.stage("frame"):
...     with timings.stage("readout"):
...         _ = sum(range(10_000))
>>> sorted(timings.counts.items()), all(s >= 0 for s in timings.seconds.values())
([('frame', 1), ('readout', 1)], True)
"""

from __future__ import annotations

import os
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext

from .._rows import in_row_blocks

#: The environment variable that switches the timings on (any value but empty or ``0``).
VARIABLE = "PICAMCAL_VIRTUAL_CAMERA_TIMING"


class Timings:
    """CPU seconds and calls per stage, added up from any thread.

    Attributes
    ----------
    seconds : dict
        CPU seconds of each stage (its own: the stages nested in it are counted apart).
    counts : collections.Counter
        Calls of each :meth:`stage` (row blocks count none: time them within a stage of the same name).
    """

    def __init__(self) -> None:
        self.seconds: defaultdict[str, float] = defaultdict(float)
        self.counts: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._local = threading.local()

    def _add(self, name: str, seconds: float, calls: int) -> None:
        with self._lock:
            self.seconds[name] += seconds
            self.counts[name] += calls

    def _nested(self) -> float:
        """CPU seconds the stages that ended in this thread took (what encloses them leaves out)."""
        return float(getattr(self._local, "nested", 0.0))

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the enclosed work in this thread as ``name``, less the stages nested in it (the module's example)."""
        start, nested = time.thread_time(), self._nested()
        try:
            yield
        finally:
            spent = time.thread_time() - start
            self._add(name, spent - (self._nested() - nested), 1)
            self._local.nested = nested + spent

    def row_blocks(self, name: str, run: Callable[[int, int], None], rows: int) -> None:
        """:func:`~picamcal._rows.in_row_blocks`, each block's CPU time counted as ``name`` (in the thread that ran it,
        and left out of the stages around it there).

        Examples
        --------
        >>> timings = Timings()
        >>> with timings.stage("render"):
        ...     timings.row_blocks("render", lambda start, stop: None, 1000)
        >>> timings.counts["render"], sorted(timings.snapshot())
        (1, ['render'])
        """

        def timed(start: int, stop: int) -> None:
            begin, nested = time.thread_time(), self._nested()
            try:
                run(start, stop)
            finally:
                spent = time.thread_time() - begin
                self._add(name, spent - (self._nested() - nested), 0)
                self._local.nested = nested + spent

        in_row_blocks(timed, rows)

    def snapshot(self) -> dict[str, tuple[float, int]]:
        """Each stage's (CPU seconds, calls) so far."""
        with self._lock:
            return {name: (self.seconds[name], self.counts[name]) for name in self.seconds}

    def reset(self) -> None:
        """Start counting again from zero."""
        with self._lock:
            self.seconds.clear()
            self.counts.clear()


#: The timings of this process, or None when they are off (:data:`VARIABLE`).
TIMINGS: Timings | None = Timings() if os.environ.get(VARIABLE, "") not in ("", "0") else None


def stage(name: str) -> AbstractContextManager[None]:
    """:meth:`Timings.stage` of :data:`TIMINGS`, or nothing when the timings are off.

    Examples
    --------
    >>> with stage("statistics"):  # timed only where PICAMCAL_VIRTUAL_CAMERA_TIMING is set
    ...     total = sum(range(100))
    >>> total
    4950
    """
    return nullcontext() if TIMINGS is None else TIMINGS.stage(name)


def row_blocks(name: str, run: Callable[[int, int], None], rows: int) -> None:
    """:meth:`Timings.row_blocks` of :data:`TIMINGS`, or :func:`~picamcal._rows.in_row_blocks` when they are off.

    Examples
    --------
    >>> out = np.zeros(300)
    >>> def fill(start, stop):
    ...     out[start:stop] = 1.0
    >>> row_blocks("readout", fill, 300)
    >>> float(out.sum())
    300.0
    """
    if TIMINGS is None:
        in_row_blocks(run, rows)
    else:
        TIMINGS.row_blocks(name, run, rows)
