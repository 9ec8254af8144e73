"""The output place: made, cleared of a killed run's temporaries, and probed for room before any work."""

from __future__ import annotations

import errno
import os
from pathlib import Path

from .._atomic import make_temporary, remove_stale_temporaries
from ..errors import OutputError

#: errno values that mean the output place itself is unusable: every further file would fail the same way.
PLACE_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM}


def prepare_folder(out_dir: Path, frame_bytes: int) -> None:
    """Create the output folder, remove the temporaries killed runs left, and check it takes one output.

    Raises
    ------
    OutputError
        The folder cannot be made (a file is in the way, no permission), or has no room for ``frame_bytes``.

    Examples
    --------
    >>> prepare_folder(Path("corrected"), 230_400)
    >>> sorted(Path("corrected").iterdir())  # the probe is removed again
    []
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError("exists and is not a folder", out_dir) from None
    except OSError as exc:
        raise OutputError(f"cannot create the output folder: {exc.strerror or exc}", out_dir) from exc
    remove_stale_temporaries(out_dir)
    probe(out_dir, frame_bytes)


def probe(folder: Path, nbytes: int) -> None:
    """Write (reserve) one output's worth of bytes in ``folder`` and remove it: read-only or full fails here.

    Raises
    ------
    OutputError
        The folder cannot be written, or has no room for ``nbytes`` (where the filesystem can say so at once).

    Examples
    --------
    >>> Path("out").mkdir()
    >>> probe(Path("out"), 1_000_000)
    >>> list(Path("out").iterdir())
    []
    """
    try:
        name = make_temporary(folder / "probe")
    except OutputError as exc:  # about the folder, not the probe's name
        raise OutputError(exc.problem, folder) from exc.__cause__
    fd = os.open(name, os.O_WRONLY)
    try:
        if hasattr(os, "posix_fallocate"):
            try:
                os.posix_fallocate(fd, 0, max(nbytes, 1))
            except OSError as exc:
                # Filesystems without fallocate say EOPNOTSUPP or EINVAL: then only the writes will tell.
                if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                    raise OutputError(
                        f"no room for one output ({nbytes / 1e6:.1f} MB): {exc.strerror or exc}", folder
                    ) from exc
    finally:
        os.close(fd)
        os.unlink(name)


__all__ = ["PLACE_ERRORS", "prepare_folder", "probe"]
