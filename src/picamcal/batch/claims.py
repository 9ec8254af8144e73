"""Claims: how batches writing into one folder at once share the work, each output written by one of them only.

Before a worker reads a file, it claims the file's output: it creates ``.<output name>.picamcal-claim`` beside it
with ``O_CREAT | O_EXCL`` (of two runs trying at once, exactly one succeeds), holding who claimed it (machine,
process id and that process's start, as JSON). The claim is removed by its holder once the output is written, or
failed, or dropped. A run that finds an output claimed by another leaves it to that run, and comes back to it once
the claim is gone (:func:`wait_for`): written by the other run, or to do after all.

A claim whose holder is gone is stale and is taken over: on this machine, when its process has ended (or its
number belongs to a process started later); on any machine (a folder shared over the network, a dask cluster's
workers), when it has not been touched for :data:`STALE_AFTER_S` seconds (a holder touches it as its file goes
from one stage to the next, and one file takes seconds); an empty or unreadable claim (its maker killed between
creating and writing it), after :data:`EMPTY_STALE_AFTER_S`. A stale claim is taken over by renaming it to a
name of this process's own: of several runs trying at once only one succeeds, and it then checks that what it
renamed is the stale claim it judged, not a new one made meanwhile (which it puts back).
"""

from __future__ import annotations

import functools
import json
import os
import time
from pathlib import Path
from typing import Any

from .._atomic import _host_tag, _process_alive, temporary_name

#: The suffix of a claim's name: ``.<output name>.picamcal-claim``.
CLAIM_SUFFIX = ".picamcal-claim"
#: Seconds after which another machine's claim untouched is taken for a killed run's.
STALE_AFTER_S = 600.0
#: Seconds after which an empty or unreadable claim is taken for that of a run killed while it made it.
EMPTY_STALE_AFTER_S = 30.0


def claim_path(target: str | os.PathLike[str]) -> Path:
    """Where the claim of the output ``target`` lies: beside it, hidden.

    Examples
    --------
    >>> claim_path("corrected/f00.tiff")
    PosixPath('corrected/.f00.tiff.picamcal-claim')
    """
    target = Path(target)
    return target.parent / f".{target.name}{CLAIM_SUFFIX}"


@functools.cache
def _start_of(pid: int) -> str | None:
    """When process ``pid`` started (clock ticks since boot, from /proc), or None where that cannot be known: with
    the pid, it names one process, a later process given the same number being another."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as stat:
            return stat.read().rpartition(b")")[2].split()[19].decode()
    except (OSError, IndexError):
        return None


def _holder(run: str) -> dict[str, Any]:
    """This process, working for the batch ``run``, as its claims name it."""
    pid = os.getpid()
    return {"host": _host_tag(), "pid": pid, "start": _start_of(pid), "run": run}


def take(target: str | os.PathLike[str], run: str) -> bool:
    """Claim the output ``target`` for the batch ``run`` (any string naming it, the same in all its workers) in
    this process: True if it is theirs now (also when it was already); False if another live run holds it.

    Raises
    ------
    OSError
        The claim cannot be created (a folder that cannot be written): the write would fail the same way.

    Examples
    --------
    >>> Path("out").mkdir()
    >>> take("out/f00.tiff", "run1"), take("out/f00.tiff", "run1"), take("out/f00.tiff", "run2")
    (True, True, False)
    >>> release("out/f00.tiff", "run1"); list(Path("out").iterdir())
    []
    """
    path = claim_path(target)
    mine = _holder(run)
    text = json.dumps(mine).encode()
    for _ in range(10):  # each pass either claims, finds it held, or removes a stale claim
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            holder = _read(path)
            if holder == mine:
                return True
            if not _is_stale(path, holder):
                return False
            _take_over(path, holder)
            continue
        try:
            os.write(fd, text)
        finally:
            os.close(fd)
        return True
    return False


def release(target: str | os.PathLike[str], run: str) -> None:
    """Remove the claim of ``target`` this process holds for ``run``, if it does (another's is left alone)."""
    path = claim_path(target)
    if _read(path) == _holder(run):
        path.unlink(missing_ok=True)


def touch(target: str | os.PathLike[str]) -> None:
    """Say that this process still works on ``target``: its claim's time is now (for other machines' runs)."""
    try:
        os.utime(claim_path(target))
    except OSError:
        pass


def is_claimed(target: str | os.PathLike[str]) -> bool:
    """Whether a live run holds the claim of ``target`` (a stale claim, or none, is not one).

    Examples
    --------
    >>> is_claimed("out/f00.tiff")
    False
    """
    path = claim_path(target)
    if not os.path.lexists(path):
        return False
    return not _is_stale(path, _read(path))


def remove_stale_claims(folder: str | os.PathLike[str]) -> list[Path]:
    """Remove the claims in ``folder`` whose holder is gone for certain (a run on this machine that was killed);
    return them. Another machine's claims are left to :func:`take`, which judges them by their age."""
    removed: list[Path] = []
    try:
        names = [entry.name for entry in os.scandir(folder)]
    except OSError:
        return removed
    for name in names:
        if not (name.startswith(".") and name.endswith(CLAIM_SUFFIX)):
            continue
        path = Path(folder) / name
        holder = _read(path)
        if holder is not None and holder.get("host") == _host_tag() and _is_stale(path, holder):
            if _take_over(path, holder):
                removed.append(path)
    return removed


def _read(path: Path) -> dict[str, Any] | None:
    """The claim's holder; None if it is empty, unreadable or gone."""
    try:
        holder = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return None
    return holder if isinstance(holder, dict) else None


def _is_stale(path: Path, holder: dict[str, Any] | None) -> bool:
    """Whether the claim at ``path`` held by ``holder`` is a killed run's (module docstring)."""
    try:
        age = time.time() - os.stat(path).st_mtime
    except OSError:  # gone: nothing to take over
        return False
    if holder is None:
        return age > EMPTY_STALE_AFTER_S
    if age > STALE_AFTER_S:  # untouched for that long: a killed run's, or one lost by a process that lives on
        return True
    if holder.get("host") != _host_tag():
        return False
    pid = holder.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return age > EMPTY_STALE_AFTER_S
    if not _process_alive(pid):
        return True
    start = holder.get("start")
    now = _start_of.__wrapped__(pid)  # not cached: the number may belong to another process by now
    return start is not None and now is not None and start != now


def _take_over(path: Path, holder: dict[str, Any] | None) -> bool:
    """Remove the stale claim at ``path``, judged stale as held by ``holder``, unless another run replaced it
    meanwhile (then it stays). True if this call removed it."""
    aside = temporary_name(path, suffix=".stale")
    try:
        os.rename(path, aside)  # of several runs at once, one moves it; the others find it gone
    except OSError:
        return False
    if _read(aside) == holder:
        aside.unlink(missing_ok=True)
        return True
    try:  # a new claim made between the judging and the renaming: put it back, unless yet another is there
        os.link(aside, path)
    except OSError:
        pass
    aside.unlink(missing_ok=True)
    return False


__all__ = [
    "CLAIM_SUFFIX",
    "EMPTY_STALE_AFTER_S",
    "STALE_AFTER_S",
    "claim_path",
    "is_claimed",
    "release",
    "remove_stale_claims",
    "take",
    "touch",
]
