"""Write files so that a reader never sees a half-written one: a temporary name, then a rename."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from .errors import OutputError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``, on failure remove it.

    The temporary file keeps ``path``'s suffix so that writers choosing a format by suffix still work.
    """
    target = Path(path)
    if not overwrite and target.exists():
        raise OutputError("exists already (use --overwrite to replace it)", target)
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent)
    except OSError as exc:
        raise OutputError(f"cannot write here: {exc.strerror or exc}", target) from exc
    os.close(fd)
    tmp = Path(tmp_name)
    # mkstemp makes the file private (0600); give it the permissions an ordinary new file would get.
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield tmp
        os.replace(tmp, target)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write: {exc.strerror or exc}", target) from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def refuse_inputs_as_output(output: str | os.PathLike[str], inputs: Iterable[str | os.PathLike[str] | None]) -> None:
    """Raise OutputError if ``output`` is, contains or lies inside one of ``inputs`` (None entries are skipped).

    Writing there could replace or delete what the command reads (``--out`` given the calibration, or the
    folder of captures), so no command does it, ``--overwrite`` or not.

    Examples
    --------
    >>> refuse_inputs_as_output("report", ["cal.npz", "captures/target.dng"])
    >>> refuse_inputs_as_output("captures", ["captures/target.dng"])
    Traceback (most recent call last):
    ...
    picamcal.errors.OutputError: captures: holds the input captures/target.dng; choose another output
    """
    out = Path(output).absolute().resolve()
    for item in inputs:
        if item is None:
            continue
        source = Path(item).absolute().resolve()
        if out == source:
            raise OutputError("is an input of this command; choose another output", output)
        if source.is_relative_to(out):
            raise OutputError(f"holds the input {item}; choose another output", output)
        if out.is_relative_to(source):
            raise OutputError(f"lies inside the input {item}; choose another output", output)


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
