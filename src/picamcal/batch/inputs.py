"""A batch's inputs: files, folders and glob patterns turned into one list of files."""

from __future__ import annotations

import glob
import os
import re
import warnings
from collections.abc import Iterable, Sequence
from pathlib import Path

from .._atomic import entry_kind, passed_over_message
from ..errors import PicamcalError, PicamcalWarning
from ..raw import RAW_SUFFIXES
from ..raw.npz import is_raw_npz

_GLOB_CHARS = re.compile(r"[*?[]")


def is_pattern(item: str | os.PathLike[str]) -> bool:
    """True if ``item`` holds a glob character (``*``, ``?``, ``[``).

    Examples
    --------
    >>> is_pattern("run1/*.dng"), is_pattern("run1")
    (True, False)
    """
    return bool(_GLOB_CHARS.search(str(item)))


def expand_inputs(
    items: Iterable[str | os.PathLike[str]],
    suffixes: Sequence[str] = RAW_SUFFIXES,
    *,
    skip: str | os.PathLike[str] | None = None,
) -> list[Path]:
    """Turn files, folders and glob patterns into a list of files, in order, without duplicates.

    A file is taken as it is. A folder gives its files whose suffix is one of ``suffixes`` (any case;
    not its sub-folders, not hidden files, not ``.npz`` files that are not raw images), sorted by name; an entry
    with such a suffix that is no regular file (a symbolic link to nothing, a FIFO, a device, a folder) is passed
    over, and one :class:`~picamcal.errors.PicamcalWarning` names every entry passed over. A glob pattern (``*``,
    ``?``, ``[``; ``**`` crosses folders) gives its matches sorted, folders among them expanded as folders (one
    with no such file gives none): useful when the shell cannot expand it (too many files, or quoted). A file
    reached twice is kept the first time. Nothing inside ``skip`` (a batch's own output place) is taken from a
    folder or a pattern.

    Parameters
    ----------
    items : iterable of path-like
        Files, folders or glob patterns.
    suffixes : sequence of str
        Suffixes taken from folders: :data:`picamcal.raw.RAW_SUFFIXES`, ``HEADLESS_SUFFIXES`` or
        ``PROCESSED_SUFFIXES``.
    skip : path-like, optional
        A folder whose files are never inputs: the output place, which may lie inside a folder of inputs.

    Returns
    -------
    list of Path

    Raises
    ------
    PicamcalError
        A pattern matches nothing, or a folder holds no such file. A named file that is missing is kept: it
        fails on its own when the batch reads it, and the other files are still done.

    Examples
    --------
    >>> from picamcal.simulate import simulate_run
    >>> refs = simulate_run("run1", "imx219", size=(320, 240), seed=1)
    >>> [p.name for p in expand_inputs(["run1/t*.dng", "run1", "missing.dng"])]
    ['target.dng', 'black.dng', 'blue.dng', 'green.dng', 'red.dng', 'white.dng', 'missing.dng']
    >>> Path("run1/gone.dng").symlink_to("nowhere.dng")
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     found = expand_inputs(["run1"])
    >>> len(found), str(caught[0].message)
    (6, 'run1: passed over 1 entry that is not a regular file: gone.dng (a symbolic link to nothing)')
    """
    wanted = tuple(s.lower() for s in suffixes)
    avoid = None if skip is None else Path(os.path.realpath(skip))
    found: list[Path] = []
    seen: set[Path] = set()
    passed_over: dict[Path, list[str]] = {}
    for item in items:
        path = Path(item)
        if path.is_dir():
            files = _folder_files(path, wanted, avoid, passed_over)
        elif is_pattern(item) and not path.exists():
            files = []
            for match in map(Path, sorted(glob.glob(str(item), recursive=True))):
                if _inside(match, avoid):
                    continue
                files.extend(
                    _folder_files(match, wanted, avoid, passed_over, required=False) if match.is_dir() else [match]
                )
            if not files:
                raise PicamcalError("no files match this pattern", item)
        else:  # a file, or what is named as one: one that is missing or unreadable fails on its own in the batch
            files = [path]
        for file in files:
            key = Path(os.path.realpath(file))
            if key not in seen:
                seen.add(key)
                found.append(file)
    if passed_over:
        warnings.warn(passed_over_message(passed_over), PicamcalWarning, stacklevel=2)
    return found


def _inside(path: Path, folder: Path | None) -> bool:
    return folder is not None and Path(os.path.realpath(path)).is_relative_to(folder)


def _folder_files(
    folder: Path,
    suffixes: tuple[str, ...],
    avoid: Path | None,
    passed_over: dict[Path, list[str]],
    *,
    required: bool = True,
) -> list[Path]:
    """The folder's files of ``suffixes`` (``required``: at least one); its entries of those suffixes that are no
    regular files are added to ``passed_over`` (a folder's .npz files that are not raw images, the calibration
    itself, are passed over without a word)."""
    files = []
    for entry in sorted(folder.iterdir()):
        if entry.suffix.lower() not in suffixes or entry.name.startswith("."):
            continue
        # The output place itself, or a link into it (a folder given that lies inside it is refused as an input).
        if (entry.is_symlink() or entry.is_dir()) and _inside(entry, avoid):
            continue
        if not entry.is_file():
            passed_over.setdefault(folder, []).append(f"{entry.name} ({entry_kind(entry)})")
        elif entry.suffix.lower() != ".npz" or is_raw_npz(entry):
            files.append(entry)
    if required and not files:
        raise PicamcalError(f"no {', '.join(suffixes)} files in this folder", folder)
    return files


__all__ = ["expand_inputs", "is_pattern"]
