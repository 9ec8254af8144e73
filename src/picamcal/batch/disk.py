"""The output place: made, cleared of a killed run's temporaries, and probed for room before any work."""

from __future__ import annotations

import errno
import os
from pathlib import Path

from .._atomic import make_temporary, remove_stale_temporaries
from ..errors import OutputError
from .claims import remove_stale_claims

#: errno values that mean the output place itself is unusable: every further file would fail the same way.
PLACE_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM}


def prepare_folder(out_dir: Path, frame_bytes: int) -> list[Path]:
    """Create the output folder, remove the temporaries and claims killed runs left, and check it takes one output.

    Returns
    -------
    list of Path
        The folders this call created (``out_dir`` and any missing parents, outermost first), for
        :func:`remove_empty_folders` when the batch writes nothing.

    Raises
    ------
    OutputError
        The folder cannot be made (a file is in the way, no permission), or has no room for ``frame_bytes``.

    Examples
    --------
    >>> prepare_folder(Path("scans/corrected"), 230_400)
    [PosixPath('scans'), PosixPath('scans/corrected')]
    >>> sorted(Path("scans/corrected").iterdir())  # the probe is removed again
    []
    """
    missing = missing_folders(out_dir)
    created: list[Path] = []
    try:
        try:
            for folder in missing:
                try:
                    folder.mkdir()
                    created.append(folder)
                except FileExistsError:  # another run made it meanwhile: not ours to remove
                    if not folder.is_dir():
                        raise
            out_dir.mkdir(exist_ok=True)
        except FileExistsError:
            raise OutputError("exists and is not a folder", out_dir) from None
        except OSError as exc:
            raise OutputError(f"cannot create the output folder: {exc.strerror or exc}", out_dir) from exc
        remove_stale_temporaries(out_dir)
        remove_stale_claims(out_dir)
        probe(out_dir, frame_bytes)
    except BaseException:  # refused, or interrupted: leave no folder this call made
        remove_empty_folders(created)
        raise
    return created


def missing_folders(path: Path) -> list[Path]:
    """``path`` and its parents that do not exist (yet), outermost first: what making ``path`` would create.

    Examples
    --------
    >>> missing_folders(Path("new/stack.zarr"))
    [PosixPath('new'), PosixPath('new/stack.zarr')]
    """
    return [folder for folder in (path, *path.parents) if not os.path.lexists(folder)][::-1]


def remove_empty_folders(created: list[Path]) -> None:
    """Remove the folders a batch created (outermost first, as :func:`prepare_folder` returns them) that are
    still empty, innermost first: a batch that wrote nothing leaves no empty output folder behind. A folder that
    holds anything (another run's outputs among them) is kept.

    Examples
    --------
    >>> made = prepare_folder(Path("out/a"), 1000)
    >>> remove_empty_folders(made)
    >>> Path("out").exists()
    False
    """
    for folder in reversed(created):
        try:
            folder.rmdir()
        except FileNotFoundError:  # gone already
            continue
        except OSError:  # not empty: keep it, and its parents with it
            return


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


__all__ = ["PLACE_ERRORS", "missing_folders", "prepare_folder", "probe", "remove_empty_folders"]
