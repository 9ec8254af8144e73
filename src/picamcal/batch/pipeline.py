"""Read, correct and write at once: a worker's three stages overlapped in threads, with bounded memory.

Each file a worker does goes through three stages: reading (the file's bytes, and LibRaw's decoding for the DNGs
that need it), correcting (the numba kernel) and writing (tifffile's and imagecodecs' compression, zlib in
Pillow, the file's bytes). Each of them spends most of its time in code that releases the GIL, so
:func:`overlapped` runs them at once on consecutive files, each in its own thread: while file i is corrected,
file i+1 is read and file i-1 written. A batch then takes about as long as its slowest stage, not as the sum of
the three.

Memory stays bounded whatever the number of files: the reader runs at most :data:`READ_AHEAD` file ahead of the
corrector, and the corrector takes one of :data:`OUTPUT_SLOTS` output slots before it takes a file, which the
writer gives back when the file is written. So a worker holds at most ``OUTPUT_SLOTS`` corrected images and
``READ_AHEAD + 1`` decoded inputs. A slot keeps its array, so that the kernel writes each image into memory it
has touched already (``out=``), which is faster than fresh memory; and the slots outlive the run: a worker
process keeps them (:class:`SlotPool`) for its next task. Fresh memory is dear on a virtual machine: here an
8 MP frame's 48 MB of uint16 codes cost 6 ms to touch the first time, up to 100 ms once the process has grown
into memory it never used, and the correction itself 26 ms.

The stages are plain functions of one job; a failure of one stage for one file is that file's outcome, and the
others go on, except when ``fatal`` says the failure concerns every file (a full disk): then nothing more is
read, corrected or written. A run can be cancelled from outside (``cancel``: the batch was interrupted): then no
new file is read, corrected or written, the write under way is finished if it ends within ``grace`` seconds,
and otherwise left to its thread (the caller discards its temporary).
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

#: How many decoded inputs wait for the corrector (besides the one being read).
READ_AHEAD = 1
#: How many corrected images a worker holds at once: one being written, one being corrected.
OUTPUT_SLOTS = 2

_J = TypeVar("_J")
_END = object()  # sent down a queue after the last item
_POLL_S = 0.1  # how often a blocked stage looks whether the pipeline was stopped
#: Seconds a cancelled run waits for the write under way before it leaves it to its thread.
CANCEL_GRACE_S = 0.8


@dataclass
class Slot:
    """One corrected image's room: the array the corrector may write into again (None until it made one)."""

    array: Any = None


class SlotPool:
    """Sets of :data:`OUTPUT_SLOTS` slots kept between the runs of one process, each run taking a set of its own
    (runs may go on at once in threads, as in a dask worker) and giving it back when it ends; at most
    ``keep`` idle sets are kept.

    Examples
    --------
    >>> pool = SlotPool()
    >>> with pool.taken() as slots:
    ...     slots[0].array = "an image"
    >>> with pool.taken() as again:
    ...     again[0].array
    'an image'
    """

    def __init__(self, keep: int = 2) -> None:
        self.keep = keep
        self._idle: list[list[Slot]] = []
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def taken(self) -> Iterator[list[Slot]]:
        with self._lock:
            slots = self._idle.pop() if self._idle else [Slot() for _ in range(OUTPUT_SLOTS)]
        try:
            yield slots
        finally:
            with self._lock:
                if len(self._idle) < self.keep:
                    self._idle.append(slots)


@dataclass(frozen=True)
class Finished(Generic[_J]):
    """A job that went through the stages (``error`` None) or failed in one (``error``), and the warnings it gave."""

    job: _J
    error: Exception | None
    warnings: tuple[warnings.WarningMessage, ...] = ()


def overlapped(
    jobs: Sequence[_J],
    read: Callable[[_J], Any],
    correct: Callable[[Any, Slot], Any],
    write: Callable[[_J, Any], None],
    *,
    fatal: Callable[[Exception], bool] = lambda exc: False,
    slots: Sequence[Slot] | None = None,
    cancel: Callable[[], bool] | None = None,
    grace: float = CANCEL_GRACE_S,
) -> Iterator[Finished[_J]]:
    """Run ``write(job, correct(read(job), slot))`` for every job, the three stages at once on consecutive jobs.

    ``read`` runs in a thread of its own, ``correct`` in the caller's thread, ``write`` in a thread of its own.
    Each job finishes once, in the order the stages finish them (a job that fails in reading finishes before
    the jobs ahead of it are written). A job's warnings (those its stages give, in whichever thread) are recorded
    with it; other threads' warnings are left to the usual handling. After a failure for which ``fatal`` is
    true, nothing more is read, corrected or written, and the jobs not done are not reported. Closing the
    iterator early (or an exception in the caller) stops the stages likewise; a write under way is finished.
    Once ``cancel()`` is true, likewise, but a write under way is waited for ``grace`` seconds only: after that
    the run ends and leaves the write to its thread (its job is not reported, and the slots drop their arrays,
    which that write may still be reading).

    Parameters
    ----------
    jobs : sequence
        What each stage is called with (``read`` and ``write``).
    read : callable
        ``read(job)``: the decoded input.
    correct : callable
        ``correct(decoded, slot)``: what ``write`` takes; it may keep an array in ``slot.array`` and use it again
        for a later job (the slot is not used by any other job until this one is written).
    write : callable
        ``write(job, corrected)``.
    fatal : callable, optional
        Whether a failure (of any stage) is one every further job would meet.
    slots : sequence of Slot, optional
        The output slots, with the arrays of an earlier run (:class:`SlotPool`); by default
        :data:`OUTPUT_SLOTS` new ones.
    cancel : callable, optional
        Whether the run is cancelled from outside (an interrupted batch); asked every :data:`_POLL_S` seconds.
    grace : float
        Seconds a cancelled run waits for the write under way.

    Yields
    ------
    Finished

    Examples
    --------
    >>> done = overlapped([1, 2, 3], read=lambda n: n * 10, correct=lambda x, slot: x + 1, write=lambda n, y: None)
    >>> sorted((f.job, f.error) for f in done)
    [(1, None), (2, None), (3, None)]
    """
    run = _Run(jobs, fatal, cancel)
    own_slots = list(slots) if slots is not None else [Slot() for _ in range(OUTPUT_SLOTS)]
    free: queue.Queue[Slot] = queue.Queue()
    for slot in own_slots:
        free.put(slot)
    inputs: queue.Queue[Any] = queue.Queue(maxsize=READ_AHEAD)
    outputs: queue.Queue[Any] = queue.Queue()  # never longer than OUTPUT_SLOTS: each item holds a slot
    threads = [
        threading.Thread(target=run.reader, args=(read, inputs), name="picamcal-read", daemon=True),
        threading.Thread(target=run.writer, args=(write, outputs, free), name="picamcal-write", daemon=True),
    ]
    previous = warnings.showwarning
    with warnings.catch_warnings():
        warnings.simplefilter("always")  # a warning each file gives is recorded for each
        warnings.showwarning = run.warning_handler(previous)
        try:
            for thread in threads:
                thread.start()
            while (slot := run.get(free)) is not None and (item := run.get(inputs)) is not _END and item is not None:
                position, decoded = item
                if isinstance(decoded, Exception):
                    free.put(slot)
                    yield run.finish(position, decoded)
                    continue
                run.current.position = position
                try:
                    corrected = correct(decoded, slot)
                except Exception as exc:
                    free.put(slot)
                    yield run.finish(position, exc)
                    continue
                finally:
                    run.current.position = None
                    del decoded
                run.put(outputs, (position, corrected, slot))
                del corrected
                yield from run.drain()
            run.put(outputs, _END)
            yield from run.written(grace)
        finally:
            run.stop.set()
            deadline = run.deadline(grace) if run.cancelled() else None
            for thread in threads:
                thread.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
            if any(thread.is_alive() for thread in threads):  # a write left to its thread: it holds a slot's array
                for slot in own_slots:
                    slot.array = None


class _Run(Generic[_J]):
    """What the stages of one :func:`overlapped` run share: the jobs, the stop signal, the finished jobs and
    the warnings each job gave."""

    def __init__(
        self, jobs: Sequence[_J], fatal: Callable[[Exception], bool], cancel: Callable[[], bool] | None = None
    ) -> None:
        self.jobs = jobs
        self.fatal = fatal
        self.cancelled = cancel or (lambda: False)
        self.cancelled_at: float | None = None
        self.stop = threading.Event()
        self.finished: queue.Queue[Any] = queue.Queue()  # Finished values, then _END
        self.current = threading.local()  # the position of the job this thread works on
        self.caught: dict[int, list[warnings.WarningMessage]] = {}
        self.lock = threading.Lock()

    def warning_handler(self, previous: Callable[..., None]) -> Callable[..., None]:
        def handler(message: Warning | str, category: type[Warning], filename: str, lineno: int, *args: Any) -> None:
            position = getattr(self.current, "position", None)
            if position is None:  # not one of this run's stages: as before
                previous(message, category, filename, lineno, *args)
                return
            with self.lock:
                self.caught.setdefault(position, []).append(
                    warnings.WarningMessage(message, category, filename, lineno)
                )

        return handler

    def finish(self, position: int, error: Exception | None) -> Finished[_J]:
        if error is not None and self.fatal(error):
            self.stop.set()
        with self.lock:
            caught = tuple(self.caught.pop(position, ()))
        return Finished(self.jobs[position], error, caught)

    def stopped(self) -> bool:
        """Whether the stages should start nothing more: stopped (a fatal failure, the end) or cancelled."""
        if self.stop.is_set():
            return True
        if self.cancelled():
            self.deadline(0.0)  # the grace counts from the first stage that saw the cancel
            return True
        return False

    def deadline(self, grace: float) -> float:
        """When a cancelled run stops waiting for its stages: ``grace`` seconds after it was first asked."""
        if self.cancelled_at is None:
            self.cancelled_at = time.monotonic()
        return self.cancelled_at + grace

    def written(self, grace: float) -> Iterator[Finished[_J]]:
        """The jobs the writer finishes, until it sends _END (which it does however it ends); once the run is
        cancelled, until its :meth:`deadline`."""
        while True:
            try:
                finished = self.finished.get(timeout=_POLL_S)
            except queue.Empty:
                if self.cancelled() and time.monotonic() > self.deadline(grace):
                    return
                continue
            if finished is _END:
                return
            yield finished

    def drain(self) -> Iterator[Finished[_J]]:
        """The jobs the writer finished so far (its _END, the last thing it sends, is left for the end)."""
        while True:
            try:
                finished = self.finished.get_nowait()
            except queue.Empty:
                return
            if finished is _END:
                self.finished.put(_END)
                return
            yield finished

    def get(self, source: queue.Queue[Any]) -> Any:
        """The next item, or None once the run is stopped or cancelled."""
        while not self.stopped():
            try:
                return source.get(timeout=_POLL_S)
            except queue.Empty:
                continue
        return None

    def put(self, target: queue.Queue[Any], item: Any) -> bool:
        """Hand ``item`` on; False (dropped) once the run is stopped or cancelled."""
        while not self.stopped():
            try:
                target.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def reader(self, read: Callable[[_J], Any], inputs: queue.Queue[Any]) -> None:
        for position, job in enumerate(self.jobs):
            if self.stopped():
                return
            self.current.position = position
            try:
                decoded = read(job)
            except Exception as exc:
                decoded = exc
            self.current.position = None
            if not self.put(inputs, (position, decoded)):
                return
            del decoded
        self.put(inputs, _END)

    def writer(self, write: Callable[[_J, Any], None], outputs: queue.Queue[Any], slots: queue.Queue[Slot]) -> None:
        try:
            while (item := self.get(outputs)) is not None and item is not _END:
                position, corrected, slot = item
                del item
                if self.stopped():
                    return
                self.current.position = position
                try:
                    write(self.jobs[position], corrected)
                    error = None
                except Exception as exc:
                    error = exc
                finally:
                    self.current.position = None
                    del corrected
                slots.put(slot)
                self.finished.put(self.finish(position, error))
        finally:
            self.finished.put(_END)


__all__ = ["CANCEL_GRACE_S", "OUTPUT_SLOTS", "READ_AHEAD", "Finished", "Slot", "SlotPool", "overlapped"]
