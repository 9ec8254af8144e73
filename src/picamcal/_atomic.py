"""Write files so that a reader never sees a half-written one: a temporary name, then a rename.

Every temporary picamcal makes beside an output (a file being written, a report folder being built, a batch's
probe, a zarr stack's in-use marker) is named ``.<stem>.picamcal-<host>-<pid>-<random>.tmp<suffix>``: hidden,
recognisable, owned by process ``<pid>`` on the machine whose name hashes to ``<host>``, and never longer than a
file name may be (the stem is shortened). A run killed with ``kill -9`` cannot remove its temporaries; the next
run writing in the same folder does (:func:`remove_stale_temporaries`): only names of this pattern, made on this
machine, whose process has ended. Another machine's temporaries (a shared folder) and a live run's are kept.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import os
import re
import shutil
import socket
import stat
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from .errors import OutputError

#: The longest file name (bytes) of Linux, macOS and Windows file systems.
_NAME_MAX = 255
#: A picamcal temporary's name; ``host`` is :func:`_host_tag`, ``suffix`` the output's (none for a folder).
_TEMPORARY = re.compile(
    r"^\.(?P<stem>.*)\.picamcal-(?P<host>[0-9a-f]{8})-(?P<pid>[1-9][0-9]{0,9})-[0-9a-f]{8}\.tmp(?P<suffix>\.[^.]*)?$",
    re.DOTALL,  # a name may hold any character but "/"
)
#: Folders whose stale temporaries this process has removed already (atomic_path looks once per folder).
_CLEANED: set[Path] = set()
#: The temporaries of atomic_path in this process that are being written (for discard_own_temporaries).
_WRITING: set[Path] = set()
_WRITING_LOCK = threading.Lock()


@functools.cache
def _host_tag() -> str:
    """Eight hex digits naming this machine: a process id means something only on the machine that issued it."""
    return hashlib.sha256(socket.gethostname().encode("utf-8", "surrogateescape")).hexdigest()[:8]


def temporary_name(target: str | os.PathLike[str], suffix: str | None = None) -> Path:
    """A new temporary name beside ``target``, owned by this process (see the module docstring); not created.

    ``suffix`` defaults to ``target``'s, so that writers choosing a format by suffix still work. The stem is
    shortened so that the name fits in 255 bytes, whatever the length of ``target``'s name.

    Examples
    --------
    >>> temporary_name("out/cal.npz").name
    '.cal.picamcal-...tmp.npz'
    """
    target = Path(target)
    suffix, stem = _suffix_and_stem(target, suffix)
    tail = f".picamcal-{_host_tag()}-{os.getpid()}-{os.urandom(4).hex()}.tmp{suffix}"
    room = _NAME_MAX - 1 - len(os.fsencode(tail))
    stem = stem[: max(room, 0)]
    while len(os.fsencode(stem)) > room:  # cut whole characters: some file systems take only valid UTF-8
        stem = stem[:-1]
    return target.parent / f".{stem}{tail}"


def _suffix_and_stem(target: Path, suffix: str | None) -> tuple[str, str]:
    """The temporary's suffix (``target``'s by default) and the part of ``target``'s name before it."""
    suffix = target.suffix if suffix is None else suffix
    return suffix, target.name.removesuffix(target.suffix) if suffix == target.suffix else target.name


def make_temporary(target: str | os.PathLike[str], *, folder: bool = False, suffix: str | None = None) -> Path:
    """Create a new temporary file (or ``folder``) beside ``target`` with the permissions of an ordinary new one.

    The folders ``target`` lies in are created first where they are missing (:func:`make_parents`).

    Raises
    ------
    OutputError
        The folder cannot be created or written (read-only, full, a file in its place).

    Examples
    --------
    >>> build = make_temporary("report", folder=True)
    >>> build.is_dir(), build.name.startswith(".report.picamcal-")
    (True, True)
    """
    make_parents(target)
    for _ in range(100):  # a clash of 32 random bits with this process's own names: try another
        path = temporary_name(target, suffix)
        try:
            if folder:
                os.mkdir(path, 0o777)  # the umask applies: an ordinary folder, not mkdtemp's private 0700
            else:
                os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            continue
        except OSError as exc:
            raise OutputError(f"cannot write here: {exc.strerror or exc}", Path(target)) from exc
        return path
    raise OutputError("cannot make a temporary name here", Path(target))


def make_parents(target: str | os.PathLike[str]) -> None:
    """Create the folders ``target`` lies in that are missing (``--out newdir/cal.npz``); never removes anything.

    Raises
    ------
    OutputError
        A folder cannot be created: a file of its name is in the way, or its parent cannot be written.

    Examples
    --------
    >>> make_parents("runs/2024-05/cal.npz")
    >>> Path("runs/2024-05").is_dir(), Path("runs/2024-05/cal.npz").exists()
    (True, False)
    """
    parent = Path(target).parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        what = "a file is in the way" if isinstance(exc, (FileExistsError, NotADirectoryError)) else exc.strerror
        raise OutputError(f"cannot create its folder {parent}: {what or exc}", Path(target)) from exc


def remove_stale_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Remove the temporaries in ``folder`` that runs killed on this machine left; return what was removed.

    Only names of picamcal's pattern (module docstring) whose process has ended; never a live process's
    temporary, another machine's, or anything else. A folder that cannot be read is left alone.

    Examples
    --------
    >>> Path("corrected").mkdir()
    >>> stale = Path("corrected") / f".f07.picamcal-{_host_tag()}-999999999-9b0c77d2.tmp.tiff"  # no such process
    >>> stale.touch()
    >>> remove_stale_temporaries("corrected") == [stale], stale.exists()
    (True, False)
    """
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        if not _is_stale(entry.name):
            continue
        path = Path(entry.path)
        try:
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(path)
            else:
                path.unlink()
        except FileNotFoundError:  # another run removed it first
            pass
        except OSError:  # not ours to remove after all (permissions): leave it
            continue
        removed.append(path)
    return removed


def has_live_temporary(target: str | os.PathLike[str], suffix: str | None = None) -> bool:
    """Whether a temporary for ``target`` (:func:`temporary_name` with this ``suffix``) is beside it and not stale:
    a live process's, or another machine's.

    A shortened stem matches every name it is the start of: in doubt, the answer is yes.

    Examples
    --------
    >>> has_live_temporary("run1.zarr", ".writing")
    False
    >>> marker = make_temporary("run1.zarr", suffix=".writing")
    >>> has_live_temporary("run1.zarr", ".writing")
    True
    """
    target = Path(target)
    suffix, stem = _suffix_and_stem(target, suffix)
    try:
        names = [entry.name for entry in os.scandir(target.parent)]
    except OSError:
        return False
    for name in names:
        match = _TEMPORARY.match(name)
        if match and (match["suffix"] or "") == suffix and stem.startswith(match["stem"]) and not _is_stale(name):
            return True
    return False


def _is_stale(name: str) -> bool:
    match = _TEMPORARY.match(name)
    return match is not None and match["host"] == _host_tag() and not _process_alive(int(match["pid"]))


def _process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine; when in doubt, yes (then its temporaries are kept)."""
    if pid == os.getpid() or os.name != "posix":  # elsewhere os.kill(pid, 0) would end the process
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # another user's process (EPERM), or no such number
        return True
    try:  # a zombie has ended already: only its exit status waits for its parent
        with open(f"/proc/{pid}/stat", "rb") as stat:
            return stat.read().rpartition(b")")[2].split()[0] != b"Z"
    except (OSError, IndexError):
        return True


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``, on failure remove it.

    The temporary (:func:`temporary_name`) keeps ``path``'s suffix so that writers choosing a format by suffix
    still work. The first time this process writes in a folder, the temporaries that killed runs left there
    are removed (:func:`remove_stale_temporaries`).

    Examples
    --------
    >>> with atomic_path("notes.txt") as tmp:
    ...     _ = tmp.write_text("complete or absent")
    >>> Path("notes.txt").read_text()
    'complete or absent'
    """
    target = Path(path)
    if not overwrite and target.exists():
        raise OutputError("exists already (use --overwrite to replace it)", target)
    folder = target.parent.absolute()
    if folder not in _CLEANED:
        remove_stale_temporaries(folder)
        _CLEANED.add(folder)
    tmp = make_temporary(target)
    with _WRITING_LOCK:
        _WRITING.add(tmp.absolute())
    try:
        yield tmp
        os.replace(tmp, target)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write: {exc.strerror or exc}", target) from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        with _WRITING_LOCK:
            _WRITING.discard(tmp.absolute())


def discard_own_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Remove the temporaries this process's :func:`atomic_path` is writing in ``folder``; return them.

    For a write abandoned in a thread that goes on (an interrupted batch that could not wait for it): the write
    then fails to rename its temporary, so nothing half-written ever takes the output's name.

    Examples
    --------
    >>> with atomic_path("notes.txt") as tmp:  # the rename then finds no temporary
    ...     removed = discard_own_temporaries(".")
    Traceback (most recent call last):
    ...
    picamcal.errors.OutputError: notes.txt: cannot write: No such file or directory
    >>> removed == [tmp.absolute()], Path("notes.txt").exists()
    (True, False)
    """
    folder = Path(folder).absolute()
    with _WRITING_LOCK:
        mine = [path for path in _WRITING if path.parent == folder]
    for path in mine:
        path.unlink(missing_ok=True)
    return mine


def refuse_inputs_as_output(
    output: str | os.PathLike[str],
    inputs: Iterable[str | os.PathLike[str] | None],
    *,
    own_folder: Callable[[Path], bool] | None = None,
) -> None:
    """Raise OutputError if ``output`` is, contains or lies inside one of ``inputs`` (None entries are skipped).

    Writing there could replace or delete what the command reads (``--out`` given the calibration, or the
    folder of captures), so no command does it, ``--overwrite`` or not. With ``own_folder``, an output folder
    inside an input *folder* is allowed when it does not exist yet or ``own_folder(output)`` says it is
    picamcal's own (:func:`is_own_folder`): a batch writing ``scans/corrected`` beside ``scans/*.dng``, whose
    scans of ``scans`` pass over its own output. It still never is, or holds, an input.

    Examples
    --------
    >>> refuse_inputs_as_output("report", ["cal.npz", "captures/target.dng"])
    >>> refuse_inputs_as_output("captures", ["captures/target.dng"])
    Traceback (most recent call last):
    ...
    picamcal.errors.OutputError: captures: holds the input captures/target.dng; choose another output
    >>> Path("captures").mkdir()
    >>> refuse_inputs_as_output("captures/corrected", ["captures"], own_folder=lambda p: False)  # new: allowed
    """
    out = Path(os.path.realpath(output))  # realpath, not resolve: a symlink loop is an input like any other
    for item in inputs:
        if item is None:
            continue
        source = Path(os.path.realpath(item))
        if out == source:
            raise OutputError("is an input of this command; choose another output", output)
        if source.is_relative_to(out):
            raise OutputError(f"holds the input {item}; choose another output", output)
        if out.is_relative_to(source):
            if own_folder is not None and source.is_dir() and (not os.path.lexists(out) or own_folder(out)):
                continue
            beside = " (an output folder inside it must be new or picamcal's own)" if own_folder is not None else ""
            raise OutputError(f"lies inside the input {item}{beside}; choose another output", output)


def is_own_folder(folder: str | os.PathLike[str], is_own: Callable[[Path], bool]) -> bool:
    """Whether ``folder`` is a folder that holds only what picamcal wrote: files ``is_own`` recognises and
    picamcal's temporaries, besides hidden entries (which no scan reads and no output replaces). An empty
    folder is one.

    Examples
    --------
    >>> Path("out").mkdir()
    >>> _ = Path("out/a.tiff").write_text("mine")
    >>> is_own_folder("out", lambda p: p.read_text() == "mine")
    True
    >>> _ = Path("out/notes.txt").write_text("yours")
    >>> is_own_folder("out", lambda p: p.read_text() == "mine")
    False
    """
    try:
        with os.scandir(folder) as entries:
            for entry in entries:
                if entry.name.startswith("."):
                    continue
                if not (entry.is_file(follow_symlinks=False) and _is_own(Path(entry.path), is_own)):
                    return False
    except OSError:  # not a folder, or one that cannot be read: not known to be ours
        return False
    return True


def refuse_foreign(path: str | os.PathLike[str], is_own: Callable[[Path], bool], what: str) -> None:
    """Raise OutputError if ``path`` exists and is not ``what`` picamcal wrote: ``--overwrite`` replaces only those.

    Examples
    --------
    >>> refuse_foreign("cal.npz", lambda p: p.suffix == ".npz", "a picamcal calibration")
    """
    target = Path(path)
    if (target.exists() or target.is_symlink()) and not _is_own(target, is_own):
        raise OutputError(
            f"exists and is not {what}: picamcal replaces only what it wrote itself; choose another output", target
        )


def _is_own(path: Path, is_own: Callable[[Path], bool]) -> bool:
    try:
        return path.is_file() and not path.is_symlink() and bool(is_own(path))
    except Exception:  # whatever the bytes: a file the check cannot read is not one of ours
        return False


def entry_kind(entry: Path) -> str:
    """What a folder's entry is, when it is no regular file: what a folder scan says it passed over.

    Examples
    --------
    >>> Path("gone.dng").symlink_to("nowhere.dng")
    >>> entry_kind(Path("gone.dng"))
    'a symbolic link to nothing'
    """
    try:
        mode = entry.lstat().st_mode
        if stat.S_ISLNK(mode):
            try:
                return f"a symbolic link to {_kind(entry.stat().st_mode)}"
            except FileNotFoundError:
                return "a symbolic link to nothing"
            except OSError as exc:  # a loop (ELOOP), or a target that cannot be looked at
                return "a symbolic link that loops" if exc.errno == errno.ELOOP else f"unreadable: {exc.strerror}"
    except OSError as exc:
        return f"unreadable: {exc.strerror}"
    return _kind(mode)


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    kinds = {stat.S_ISFIFO: "a FIFO", stat.S_ISCHR: "a character device", stat.S_ISBLK: "a block device"}
    kinds[stat.S_ISSOCK] = "a socket"
    return next((name for test, name in kinds.items() if test(mode)), "not a regular file")


def passed_over_message(passed_over: dict[Path, list[str]]) -> str:
    """One warning for every entry the folders' scans passed over, by folder."""
    parts = []
    for folder, entries in passed_over.items():
        what = "entry that is not a regular file" if len(entries) == 1 else "entries that are not regular files"
        parts.append(f"{folder}: passed over {len(entries)} {what}: {', '.join(entries)}")
    return "; ".join(parts)
