"""Where the tasks run: in this process, in a local process pool, or on a dask.distributed cluster.

The three runners have one interface (``window``, ``submit``, ``finished``, ``close``) and run the same task,
:func:`picamcal.batch.worker.process`, so the outputs are the same bytes whichever runs them. A pool's workers
end with the process that started them, however it ends (:func:`exit_with_parent`).
"""

from __future__ import annotations

import multiprocessing
import os
import socket
import threading
from collections.abc import Iterable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.context import BaseContext
from typing import Any

from ..errors import PicamcalError
from .worker import Job, Outcome, Settings, check_worker, process


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity), else the machine's.

    Examples
    --------
    >>> available_cores() >= 1
    True
    """
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def _pool_context() -> BaseContext:
    """forkserver where there is one: workers start clean (fork would copy this process's threads and locks,
    unsafe with numba, zarr's event loop or a GUI), and fast (forked from a server that preloaded picamcal)."""
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        # The demosaicing library's import (it brings colour-science) is most of a worker's start-up.
        context.set_forkserver_preload(["picamcal.batch", "colour_demosaicing"])
        return context
    return multiprocessing.get_context("spawn")


class InProcess:
    """``workers=0``: each job runs here, at once, when it is submitted."""

    window = 1

    def __init__(self, settings: Settings) -> None:
        self.settings = settings

    def submit(self, job: Job) -> Future[Outcome]:
        future: Future[Outcome] = Future()
        future.set_result(process(self.settings, job))
        return future

    def finished(self, futures: list[Any]) -> Iterable[Any]:
        return futures

    def close(self) -> None:
        pass


class Pool:
    """A local process pool; replaced when a worker dies (out of memory, killed), and the files it held fail."""

    def __init__(self, settings: Settings, size: int) -> None:
        self.settings = settings
        self.size = size
        self.window = 2 * size
        self.context = _pool_context()
        self.executor = self._executor()

    def _executor(self) -> ProcessPoolExecutor:
        threads = max(1, available_cores() // self.size)
        return ProcessPoolExecutor(self.size, mp_context=self.context, initializer=_init_worker, initargs=(threads,))

    def submit(self, job: Job) -> Future[Outcome]:
        try:
            return self.executor.submit(process, self.settings, job)
        except BrokenProcessPool:
            self.executor.shutdown(wait=False, cancel_futures=True)
            self.executor = self._executor()
            return self.executor.submit(process, self.settings, job)

    def finished(self, futures: list[Any]) -> Iterable[Any]:
        return wait(futures, return_when=FIRST_COMPLETED).done

    def close(self) -> None:
        self.executor.shutdown(wait=True, cancel_futures=True)


def _init_worker(threads: int) -> None:
    """End with the process that started the pool, and share the cores among the workers.

    numba's parallel kernels would otherwise use a thread per core in every worker. numba's own runtime
    setting, not NUMBA_NUM_THREADS: numba re-reads its environment when it compiles and refuses a value
    that differs from the threads it has started.
    """
    exit_with_parent()
    try:
        import numba
    except ImportError:  # no numba (32-bit Raspberry Pi OS): the numpy path runs in one thread anyway
        return
    # numba.config sets its attributes at import from the environment, so they are not in its stubs.
    most = int(getattr(numba.config, "NUMBA_NUM_THREADS"))  # noqa: B009
    numba.set_num_threads(min(threads, most))


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
        from distributed import as_completed

        self.settings = settings
        self.client = client
        self.window = 2 * max(1, sum(client.nthreads().values()))
        self.completed = as_completed(loop=client.loop)

    def submit(self, job: Job) -> Any:
        future = self.client.submit(process, self.settings, job, pure=False)
        self.completed.add(future)
        return future

    def finished(self, futures: list[Any]) -> Iterable[Any]:
        return self.completed.next_batch(block=True)

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

__all__ = ["Dask", "InProcess", "Pool", "Runner", "available_cores", "connect", "exit_with_parent"]
