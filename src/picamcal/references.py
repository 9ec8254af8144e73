"""Finding the reference images of a calibration run in a folder, by their names."""

from __future__ import annotations

import re
from pathlib import Path

from .errors import CalibrationInputError

ROLES = ("white", "red", "green", "blue", "black")
COLOURS = ("red", "green", "blue")
#: Suffixes of reference files: DNG, legacy JPEG+raw, picamera2 .npy, picamcal .npz, headless dumps (rpicam-raw).
RAW_SUFFIXES = {".dng", ".jpg", ".jpeg", ".npy", ".npz", ".raw"}
_PAPER_STYLE = re.compile(r"r(\d+)_g(\d+)_b(\d+)", re.IGNORECASE)


def role_of(name: str) -> str | None:
    """The reference role a file name stands for, or None.

    Names hold the role as a word (``white.dng``, ``run3_red.dng``, ``white_2.dng``) or, as in the paper's
    code, the LED setting (``..._r255_g0_b0.dng`` is red, all equal and non-zero is white, all zero is black).

    Examples
    --------
    >>> role_of("capture_r0_g255_b0.dng"), role_of("White.DNG"), role_of("white_2.raw"), role_of("target.dng")
    ('green', 'white', 'white', None)
    """
    stem = Path(name).stem.lower()
    match = _PAPER_STYLE.search(stem)
    if match:
        r, g, b = (int(v) for v in match.groups())
        if r == g == b:
            return "black" if r == 0 else "white"
        lit = [role for role, v in zip(COLOURS, (r, g, b), strict=True) if v > 0]
        return lit[0] if len(lit) == 1 else None
    words = set(re.split(r"[^a-z0-9]+", stem))
    found = [role for role in ROLES if role in words]
    return found[0] if len(found) == 1 else None


def _natural(path: Path) -> list:
    """Sort key that orders ``white_2`` before ``white_10``."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name.lower())]


def find_references(folder: str | Path, *, in_situ: bool = False) -> dict[str, Path | list[Path]]:
    """Map each role to its file (or files) in a folder.

    The white is required and the black optional. Red, green and blue come all three (a full calibration) or
    not at all (a flat-field calibration from the white alone); with ``in_situ`` (the colours come from a
    jig calibration) they are not looked for. Several files of one role (``white_1.dng``, ``white_2.dng``,
    ...) are frames to average: that role maps to a list of them, in natural name order. A folder written
    by ``picamcal acquire`` is read through its ``manifest.json``, which names each file's role.

    Raises
    ------
    CalibrationInputError
        The folder is missing or cannot be listed, has no white, or has some but not all of red, green and blue.
    AcquisitionError
        The folder holds a ``manifest.json`` that is not a usable one (see
        :func:`picamcal.acquire.acquisition.load_manifest`).

    Examples
    --------
    >>> find_references("run1")  # doctest: +SKIP
    {'white': PosixPath('run1/white.dng'), 'red': PosixPath('run1/red.dng'), ...}
    >>> find_references("microscope")  # doctest: +SKIP
    {'white': [PosixPath('microscope/white_1.dng'), PosixPath('microscope/white_2.dng')]}
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CalibrationInputError("no such folder of reference images", folder)
    if not in_situ and (folder / "manifest.json").is_file():
        from .acquire.acquisition import read_manifest

        return dict(read_manifest(folder))
    try:
        entries = sorted(folder.iterdir(), key=_natural)
    except OSError as exc:
        raise CalibrationInputError(f"cannot list the folder: {exc.strerror or exc}", folder) from None
    found: dict[str, list[Path]] = {}
    for path in entries:
        # is_file follows links and is False for a FIFO, a device or a symlink loop: those are left out
        role = role_of(path.name) if path.suffix.lower() in RAW_SUFFIXES and path.is_file() else None
        if role and not (in_situ and role in COLOURS):
            found.setdefault(role, []).append(path)
    if "white" not in found:
        what = "white" if found else "white, red, green, blue or black"
        raise CalibrationInputError(
            f"no {what} reference found (a white alone is enough, for a flat field: files named e.g. white.dng, "
            "white_1.dng or *_r255_g255_b255.dng)",
            folder,
        )
    missing = [role for role in COLOURS if role not in found]
    if len(missing) in (1, 2):
        raise CalibrationInputError(
            f"no {', '.join(missing)} reference found: give red, green and blue references together, or none "
            "of them for a flat-field calibration (white only)",
            folder,
        )
    return {role: paths[0] if len(paths) == 1 else paths for role, paths in found.items()}
