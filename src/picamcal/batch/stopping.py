"""Stopping a batch on SIGINT (Ctrl-C) or SIGTERM (systemd, ``timeout``, ``kill``) without leaving anything half done.

While a batch works, :class:`Interrupt` catches the two signals: no new file is started, the files in flight
are finished if they end within :data:`GRACE_S` seconds and dropped otherwise (on a dask cluster, whose tasks
cannot be stopped from outside, each task's write under way is waited for, up to :data:`CLUSTER_WAIT_S`), the
temporaries are removed, and ``run_batch`` raises :class:`~picamcal.batch.run.BatchInterrupted`, which says how
many files were written (exactly the outputs the batch put in place) and that running the same batch again
resumes it. Before the work starts (checks, planning), nothing is being
written, and a signal stops the batch at once.
"""

from __future__ import annotations

import signal
import threading
import time
from types import FrameType, TracebackType
from typing import Any

#: Seconds the files in flight have to finish once a batch is interrupted; then they are dropped.
GRACE_S = 0.8
#: Seconds an interrupted batch on a dask cluster waits for its tasks in flight, each ending the write it has under
#: way (a write takes seconds); a task still running then is cancelled, and a warning says what it may still write.
CLUSTER_WAIT_S = 30.0
#: The signals that stop a batch: Ctrl-C, and the polite request to end of systemd, ``timeout`` and ``kill``.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupt:
    """The stop signals a running batch received; a context manager that catches them while it is entered.

    The handlers are installed only in the main thread (Python runs signal handlers there alone) and only over
    the default handlers: a program that ignores SIGINT, or handles SIGTERM itself, keeps its own. Until
    :meth:`working` is called a signal raises :class:`KeyboardInterrupt` at once, as Ctrl-C does; after it,
    the signal is only recorded (:attr:`signum`), for the batch to stop at its own pace.

    Examples
    --------
    >>> with Interrupt() as interrupt:  # SIGINT and SIGTERM are caught in here (tests/test_kill.py sends them)
    ...     interrupt.working()
    >>> interrupt.is_set(), interrupt.expired(), interrupt.signal_name
    (False, False, '')
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self.since: float | None = None
        self._working = False
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> Interrupt:
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                if signal.getsignal(signum) in (signal.default_int_handler, signal.SIG_DFL):
                    self._previous[signum] = signal.signal(signum, self._caught)
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, traceback: TracebackType | None
    ) -> None:
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)
        self._previous.clear()

    def _caught(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is None:
            self.signum, self.since = signum, time.monotonic()
        if not self._working:  # nothing is being written yet: stop at once
            raise KeyboardInterrupt

    def working(self) -> None:
        """From now on a signal is recorded, not raised: the batch stops its work itself."""
        self._working = True

    def is_set(self) -> bool:
        """Whether a stop signal came."""
        return self.signum is not None

    def expired(self, grace: float = GRACE_S) -> bool:
        """Whether the ``grace`` the files in flight had (:data:`GRACE_S`, or :data:`CLUSTER_WAIT_S` on a dask
        cluster) is over."""
        return self.since is not None and time.monotonic() - self.since > grace

    @property
    def signal_name(self) -> str:
        """The signal's name (``SIGINT``, ``SIGTERM``), or an empty string if none came."""
        return "" if self.signum is None else signal.Signals(self.signum).name


__all__ = ["CLUSTER_WAIT_S", "GRACE_S", "STOP_SIGNALS", "Interrupt"]
