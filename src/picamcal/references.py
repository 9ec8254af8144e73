"""Finding the reference images of a calibration run in a folder, by their names."""

from __future__ import annotations

import re
from pathlib import Path

from .errors import CalibrationInputError

ROLES = ("white", "red", "green", "blue", "black")
RAW_SUFFIXES = {".dng", ".jpg", ".jpeg", ".npy", ".npz"}
_PAPER_STYLE = re.compile(r"r(\d+)_g(\d+)_b(\d+)", re.IGNORECASE)


def role_of(name: str) -> str | None:
    """The reference role a file name stands for, or None.

    Names hold the role as a word (``white.dng``, ``run3_red.dng``) or, as in the paper's code, the
    LED setting (``..._r255_g0_b0.dng`` is red, all equal and non-zero is white, all zero is black).

    Examples
    --------
    >>> role_of("capture_r0_g255_b0.dng"), role_of("White.DNG"), role_of("target.dng")
    ('green', 'white', None)
    """
    stem = Path(name).stem.lower()
    match = _PAPER_STYLE.search(stem)
    if match:
        r, g, b = (int(v) for v in match.groups())
        if r == g == b:
            return "black" if r == 0 else "white"
        lit = [role for role, v in zip(("red", "green", "blue"), (r, g, b), strict=True) if v > 0]
        return lit[0] if len(lit) == 1 else None
    words = set(re.split(r"[^a-z0-9]+", stem))
    found = [role for role in ROLES if role in words]
    return found[0] if len(found) == 1 else None


def find_references(folder: str | Path, *, need_colours: bool = True) -> dict[str, Path]:
    """Map each role to its file in a folder; white, red, green and blue are required, black optional.

    With ``need_colours=False`` (an in-situ calibration) only the white is required. A folder written by
    ``picamcal acquire`` is read through its ``manifest.json``, which names each file's role.

    Raises
    ------
    CalibrationInputError
        The folder is missing, a required role has no file, or a role has several.

    Examples
    --------
    >>> find_references("run1")  # doctest: +SKIP
    {'white': PosixPath('run1/white.dng'), ...}
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CalibrationInputError("no such folder of reference images", folder)
    if need_colours and (folder / "manifest.json").is_file():
        from .acquire.acquisition import read_manifest

        return read_manifest(folder)
    found: dict[str, list[Path]] = {}
    for path in sorted(folder.iterdir()):
        role = role_of(path.name) if path.suffix.lower() in RAW_SUFFIXES else None
        if role:
            found.setdefault(role, []).append(path)
    for role, paths in found.items():
        if len(paths) > 1:
            names = ", ".join(p.name for p in paths)
            raise CalibrationInputError(
                f"several files for the {role} reference ({names}); name them explicitly", folder
            )
    missing = [role for role in (ROLES[:4] if need_colours else ROLES[:1]) if role not in found]
    if missing:
        raise CalibrationInputError(
            f"no {', '.join(missing)} reference found (expected files named e.g. white.dng or *_r255_g0_b0.dng)", folder
        )
    return {role: paths[0] for role, paths in found.items()}
