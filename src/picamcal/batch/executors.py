"""Where the tasks run: in this process, in a local process pool, or on a dask.distributed cluster.

The three runners have one interface (``outcomes``, ``close``) and run the same pipeline of stages
(:func:`picamcal.batch.worker.outcomes`), so the outputs are the same bytes whichever runs them. A pool or a
cluster gets the files in tasks of a few (:func:`chunks`), so that each worker overlaps reading, correcting
and writing over consecutive files; in this process the files go through one pipeline. A pool's workers end
with the process that started them, however it ends (:func:`exit_with_parent`).

An interrupted batch (:class:`~picamcal.batch.stopping.Interrupt`) stops each runner the same way: no task is
submitted and no file started, and the files in flight are finished or dropped, so that the count the batch
reports is exactly the outputs it wrote. A pool's tasks have :data:`~picamcal.batch.stopping.GRACE_S` to finish;
then its workers are killed (their writes end with them, their temporaries are stale, for the batch to remove). A
task on a cluster cannot be stopped from outside (cancelled, it runs on in its worker, which outlives the batch),
so the batch waits for the tasks in flight, each of which only ends the write it has under way, and gets their
outcomes; only a task still running :data:`~picamcal.batch.stopping.CLUSTER_WAIT_S` seconds after the signal is
cancelled, and a warning says that what it finishes is not in the count.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import os
import signal
import socket
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Generator, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.context import BaseContext
from typing import Any

from .._atomic import _process_alive
from ..ckernel import c_available
from ..errors import PicamcalError, PicamcalWarning
from ..kernels import available_cores, numba_available, set_kernel_threads
from .stopping import CLUSTER_WAIT_S, GRACE_S, Interrupt
from .worker import (
    Job,
    Outcome,
    Settings,
    check_worker,
    outcomes,
    process_jobs,
    set_stop,
    stop_on_signal,
    tasks_running,
)

#: The most files in one task: the pipeline's start and end (reading the first file, writing the last, not
#: overlapped) are paid once per task, and the outcomes come back once per task.
MAX_CHUNK = 8
#: How often a runner waiting for its tasks looks whether the batch was interrupted.
_POLL_S = 0.1
#: The longest a closing pool waits for its workers to end (killed, they end at once; a process stuck in the
#: kernel may not, and its temporaries are then left for the next run to remove).
_WORKERS_END_S = 10.0


def _pool_context() -> BaseContext:
    """forkserver where there is one: workers start clean (fork would copy this process's threads and locks,
    unsafe with numba, zarr's event loop or a GUI), and fast (forked from a server that preloaded picamcal)."""
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        # What every worker imports (the raw reader, the kernel), once in the server rather than in each worker; not
        # colour-demosaicing (a second to import), which only the reference engine needs. The C kernel is compiled
        # here if it is not yet (once, rather than by every worker at once), and numba preloaded only for workers
        # that have no C kernel to use.
        preload = ["picamcal.batch", "picamcal.raw", "rawpy", "picamcal.ckernel"]
        if not c_available() and numba_available():
            preload.append("numba")
        context.set_forkserver_preload(preload)
        return context
    return multiprocessing.get_context("spawn")


class InProcess:
    """``workers=0``: the files go through one pipeline in this process (:func:`picamcal.batch.worker.outcomes`)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings

    def outcomes(
        self, jobs: Sequence[Job], stop: Callable[[], bool], interrupt: Interrupt
    ) -> Generator[Outcome, None, None]:
        """Each job's outcome as it finishes (the pipeline stops by itself when the output place fails, and on an
        interrupt: a write it leaves to its thread after the grace has a temporary the batch removes)."""
        yield from outcomes(self.settings, jobs, cancel=interrupt.is_set)

    def close(self) -> None:
        pass


def chunks(jobs: Sequence[Job], workers: int) -> list[list[Job]]:
    """The jobs in tasks of consecutive files: about two per worker, so that the last ones are shared out, and at
    most :data:`MAX_CHUNK` files, so that the outcomes come back as the batch goes.

    Examples
    --------
    >>> [len(chunk) for chunk in chunks([Job(i, f"{i}.dng", None) for i in range(10)], workers=2)]
    [3, 3, 3, 1]
    """
    size = max(1, min(MAX_CHUNK, math.ceil(len(jobs) / (2 * workers))))
    return [list(jobs[start : start + size]) for start in range(0, len(jobs), size)]


def _chunked(
    runner: Pool | Dask, jobs: Sequence[Job], stop: Callable[[], bool], interrupt: Interrupt
) -> Generator[Outcome, None, None]:
    """Run the tasks of ``jobs`` (:func:`chunks`), submitting as others finish so that at most ``runner.window``
    are in flight, and none once ``stop()`` is true or the batch is interrupted; each job's outcome as its task
    finishes. Interrupted, the tasks in flight are told to start no other file (``runner.interrupt``) and
    waited for ``runner.grace`` seconds after the signal; then those left are dropped (``runner.abandon``) and
    their files not reported (the batch counts the outputs they put in place)."""
    queue = iter(chunks(jobs, runner.workers))
    in_flight: dict[Any, list[Job]] = {}
    while True:
        while (
            not stop()
            and not interrupt.is_set()
            and len(in_flight) < runner.window
            and (chunk := next(queue, None)) is not None
        ):
            in_flight[runner.submit(chunk)] = chunk
        if not in_flight:
            return
        if interrupt.is_set():
            runner.interrupt()
            if interrupt.expired(runner.grace):
                runner.abandon(list(in_flight))
                return
        for future in runner.finished(list(in_flight), _POLL_S):
            yield from _outcomes_of(future, in_flight.pop(future))


def _outcomes_of(future: Any, chunk: list[Job]) -> list[Outcome]:
    """The task's outcomes; the files of a task that died with its worker (or was lost by the cluster) fail."""
    try:
        return future.result()
    except BrokenProcessPool:
        reason = "its worker process died (out of memory, or killed)"
    except Exception as exc:
        reason = f"the task was lost ({type(exc).__name__}: {exc})"
    return [Outcome(job.index, reason, lost=True) for job in chunk]


class Pool:
    """A local process pool; replaced when a worker dies (out of memory, killed), and the files it held fail."""

    def __init__(self, settings: Settings, size: int) -> None:
        self.settings = settings
        self.workers = size
        self.window = 2 * size
        self.grace = GRACE_S  # then the workers are killed, their writes with them
        self.context = _pool_context()
        self.stop = self.context.Event()  # the batch's interrupt, as the workers see it
        self.executor = self._executor()
        self.pids: set[int] = set()  # every worker this pool started, replaced executors' too

    def _executor(self) -> ProcessPoolExecutor:
        threads = max(1, available_cores() // self.workers)
        return ProcessPoolExecutor(
            self.workers, mp_context=self.context, initializer=_init_worker, initargs=(threads, self.stop)
        )

    def outcomes(
        self, jobs: Sequence[Job], stop: Callable[[], bool], interrupt: Interrupt
    ) -> Generator[Outcome, None, None]:
        """Each job's outcome as its task finishes; no task is started once ``stop()`` is true or the batch is
        interrupted."""
        return _chunked(self, jobs, stop, interrupt)

    def interrupt(self) -> None:
        """Tell the workers to start no other file."""
        self.stop.set()

    def abandon(self, futures: list[Any]) -> None:
        """Drop the tasks in flight: kill the workers, whose temporaries are then stale. The executor's own
        processes are private to it (ProcessPoolExecutor kills its workers itself only from Python 3.14)."""
        processes = list(getattr(self.executor, "_processes", {}).values())
        for process in processes:
            process.kill()
        for process in processes:  # ended before the batch looks for their temporaries, which are stale only then
            process.join(timeout=2)

    def submit(self, chunk: list[Job]) -> Future[list[Outcome]]:
        try:
            future = self.executor.submit(process_jobs, self.settings, chunk)
        except BrokenProcessPool:
            self.executor.shutdown(wait=False, cancel_futures=True)
            self.executor = self._executor()
            future = self.executor.submit(process_jobs, self.settings, chunk)
        self.pids.update(getattr(self.executor, "_processes", None) or {})  # started by submit
        return future

    def finished(self, futures: list[Any], timeout: float) -> Iterable[Any]:
        return wait(futures, timeout=timeout, return_when=FIRST_COMPLETED).done

    def close(self) -> None:
        """Shut the pool down and wait until its workers have ended: only then are their temporaries stale.

        ``join`` alone does not say so under forkserver: a SIGTERM to the whole process group ends the forkserver
        too, and a worker's join then returns at once, while the worker may still be ending (its files open)."""
        self.executor.shutdown(wait=True, cancel_futures=True)
        deadline = time.monotonic() + _WORKERS_END_S
        while any(map(_process_alive, self.pids)) and time.monotonic() < deadline:
            time.sleep(0.01)


def _init_worker(threads: int, stop: Any) -> None:
    """End with the process that started the pool, stop when it says so, and share the cores among the workers.

    Ctrl-C reaches every process of the terminal's process group, the workers too: they start no other file
    (:func:`~picamcal.batch.worker.stop_on_signal`, no KeyboardInterrupt), and the process that started them stops
    them on any signal (``stop``, an event it sets) and decides whether each finishes or drops its file in flight.
    A SIGTERM sent to the whole group (systemd, ``timeout``) ends the workers at once, as the process that started
    them would after its grace; their temporaries are then stale, and it removes them.
    The parallel kernels (C or numba) would otherwise use a thread per core in every worker.
    """
    exit_with_parent()
    signal.signal(signal.SIGINT, stop_on_signal)
    set_stop(stop)
    set_kernel_threads(threads)


def exit_with_parent() -> None:
    """End this worker as soon as the process that started it ends, however it ends (``kill -9`` included).

    Nothing else would end it: a worker waits for tasks on a pipe it holds both ends of, and the forkserver
    and resource tracker wait for their pipes' writers, the workers among them, so all would run on.
    prctl(PR_SET_PDEATHSIG) does not serve: under forkserver a worker's parent is the forkserver. What
    multiprocessing gives instead is the parent's sentinel, a pipe only the starting process writes to: it
    reads as ended when that process is gone. A thread waits on it (no polling) and ends the process. In a
    process multiprocessing did not start, nothing happens.

    Examples
    --------
    >>> exit_with_parent()  # this process was not started by multiprocessing: nothing to watch
    """
    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def wait_then_exit() -> None:
        parent.join()
        os._exit(1)

    threading.Thread(target=wait_then_exit, name="picamcal-exit-with-parent", daemon=True).start()


class Dask:
    """The same jobs on a dask.distributed cluster (the caller connects and closes the client)."""

    def __init__(self, settings: Settings, client: Any) -> None:
        from distributed import Event

        self.client = client
        self.workers = max(1, sum(client.nthreads().values()))
        self.window = 2 * self.workers
        self.grace = CLUSTER_WAIT_S  # a task cannot be stopped from outside: each ends the write under way
        self.stop = Event(f"picamcal-stop-{uuid.uuid4().hex}", client=client)  # the interrupt, as tasks see it
        self.told = False
        self.settings = dataclasses.replace(settings, stop_event=self.stop.name)

    def outcomes(
        self, jobs: Sequence[Job], stop: Callable[[], bool], interrupt: Interrupt
    ) -> Generator[Outcome, None, None]:
        """Each job's outcome as its task finishes; no task is started once ``stop()`` is true or the batch is
        interrupted."""
        return _chunked(self, jobs, stop, interrupt)

    def submit(self, chunk: list[Job]) -> Any:
        return self.client.submit(process_jobs, self.settings, chunk, pure=False)

    def interrupt(self) -> None:
        """Tell the tasks to start no other file."""
        if not self.told:
            self.told = True
            self.stop.set()

    def abandon(self, futures: list[Any]) -> None:
        """Drop the tasks still in flight :data:`~picamcal.batch.stopping.CLUSTER_WAIT_S` seconds after the signal.

        Those queued never start. One a worker is executing runs on (dask cannot stop a thread) until its write
        under way has ended, whole or not at all (:func:`~picamcal.batch.worker.process_jobs`); if the workers say
        that some still run (:func:`~picamcal.batch.worker.tasks_running`), a warning says that the outputs they
        finish are not in the batch's count.
        """
        self.client.cancel(futures)
        running = self.running()
        if running:
            warnings.warn(
                f"{running} task(s) on the dask cluster were still writing {CLUSTER_WAIT_S:g} s after the signal: "
                "the outputs they finish are not in this count (running the same command again skips them)",
                PicamcalWarning,
                stacklevel=2,
            )

    def running(self) -> int:
        """How many tasks of this batch the cluster's workers are running (a worker that cannot say counts as one;
        a worker gone has taken its tasks with it)."""
        try:
            answers = self.client.run(tasks_running, self.settings.run, on_error="return")
        except Exception:  # the scheduler cannot be asked: nothing is known
            return 1
        return sum(answer if isinstance(answer, int) else 1 for answer in answers.values())

    def finished(self, futures: list[Any], timeout: float) -> Iterable[Any]:
        """The futures done, waiting ``timeout`` seconds at most for one (a future's state is kept up to date by
        the client's own thread: looking is cheap)."""
        deadline = time.monotonic() + timeout
        while not (done := [future for future in futures if future.done()]) and time.monotonic() < deadline:
            time.sleep(0.005)
        return done

    def close(self) -> None:
        pass


def connect(address: str, settings: Settings, timeout: float) -> Any:
    """A client of the scheduler at ``address``, checked: reachable, with workers that can read the calibration.

    Raises
    ------
    PicamcalError
        No dask.distributed, the scheduler cannot be reached or has no worker within ``timeout`` seconds, or a
        worker cannot read the calibration (the workers need the same files at the same paths).
    """
    try:
        from distributed import Client
    except ImportError:
        raise PicamcalError("--scheduler needs the dask.distributed package") from None
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        protocol, location = parse_address(address)
        if protocol == "tcp":  # a refused connection is certain at once; the client would retry until its timeout
            socket.create_connection(parse_host_port(location), timeout=timeout).close()
        client = Client(address, timeout=timeout, set_as_default=False)
    except (OSError, ValueError, TypeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise PicamcalError(f"cannot reach the dask scheduler ({reason})", address) from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except (TimeoutError, OSError):
            raise PicamcalError(f"the dask cluster has no workers (waited {timeout:g} s)", address) from None
        for worker, problem in client.run(check_worker, settings).items():
            if problem is not None:
                raise PicamcalError(
                    f"dask worker {worker} cannot use the calibration ({problem}); the workers need the same "
                    "files at the same paths",
                    settings.calibration,
                )
    except BaseException:
        client.close()
        raise
    return client


Runner = InProcess | Pool | Dask

__all__ = [
    "MAX_CHUNK",
    "Dask",
    "InProcess",
    "Pool",
    "Runner",
    "available_cores",
    "chunks",
    "connect",
    "exit_with_parent",
]
