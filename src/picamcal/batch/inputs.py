"""A batch's inputs: files, folders and glob patterns turned into one list of files."""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

from ..errors import PicamcalError
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


def expand_inputs(items: Iterable[str | os.PathLike[str]], suffixes: Sequence[str] = RAW_SUFFIXES) -> list[Path]:
    """Turn files, folders and glob patterns into a list of files, in order, without duplicates.

    A file is taken as it is. A folder gives its files whose suffix is one of ``suffixes`` (any case;
    not its sub-folders, not hidden files, not ``.npz`` files that are not raw images), sorted by name. A
    glob pattern (``*``, ``?``, ``[``; ``**`` crosses folders) gives its matches sorted, folders among them
    expanded as folders: useful when the shell cannot expand it (too many files, or quoted). A file reached
    twice is kept the first time.

    Parameters
    ----------
    items : iterable of path-like
        Files, folders or glob patterns.
    suffixes : sequence of str
        Suffixes taken from folders: :data:`picamcal.raw.RAW_SUFFIXES`, ``HEADLESS_SUFFIXES`` or
        ``PROCESSED_SUFFIXES``.

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
    """
    wanted = tuple(s.lower() for s in suffixes)
    found: list[Path] = []
    seen: set[Path] = set()
    for item in items:
        path = Path(item)
        if path.is_dir():
            files = _folder_files(path, wanted)
        elif is_pattern(item) and not path.exists():
            files = []
            for match in sorted(glob.glob(str(item), recursive=True)):
                files.extend(_folder_files(Path(match), wanted) if Path(match).is_dir() else [Path(match)])
            if not files:
                raise PicamcalError("no files match this pattern", item)
        else:  # a file, or what is named as one: one that is missing or unreadable fails on its own in the batch
            files = [path]
        for file in files:
            key = Path(os.path.realpath(file))
            if key not in seen:
                seen.add(key)
                found.append(file)
    return found


def _folder_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    # A folder's .npz files that are not raw images (the calibration itself, say) are passed over.
    files = sorted(
        p
        for p in folder.iterdir()
        if p.suffix.lower() in suffixes
        and not p.name.startswith(".")
        and p.is_file()
        and (p.suffix.lower() != ".npz" or is_raw_npz(p))
    )
    if not files:
        raise PicamcalError(f"no {', '.join(suffixes)} files in this folder", folder)
    return files


__all__ = ["expand_inputs", "is_pattern"]
