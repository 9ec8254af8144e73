"""The reference images of a calibration run: their roles, and finding them in a folder by name or manifest."""

from __future__ import annotations

import os
import re
from pathlib import Path

from .errors import CalibrationInputError
from .manifest import MANIFEST_NAME, AcquisitionError, load_manifest
from .raw import HEADLESS_SUFFIXES, RAW_SUFFIXES

__all__ = ["COLOURS", "ROLES", "find_references", "read_manifest", "role_of"]

#: The roles of the reference images, in the order they are captured: the white, the three colours, the black
#: (LED off). The one list of them: calibration, acquisition, simulator and command line all use it.
ROLES = ("white", "red", "green", "blue", "black")
#: The colour references, each lit by one primary of the illuminator.
COLOURS = ("red", "green", "blue")
# What an acquisition must have captured before it can be calibrated.
_REQUIRED = ("white", *COLOURS)
# Every raw file a reference can be: headless dumps too, as calibrate takes their sensor and size as options.
_REFERENCE_SUFFIXES = frozenset((*RAW_SUFFIXES, *HEADLESS_SUFFIXES))
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


def read_manifest(folder: str | os.PathLike[str], *, extras: bool = False) -> dict[str, Path]:
    """The captured files of an acquisition (``picamcal acquire``), role -> path, for ``picamcal calibrate DIR``.

    Parameters
    ----------
    folder : path-like
        A folder written by :func:`picamcal.acquire.acquisition.acquire`, with its ``manifest.json``
        (:func:`picamcal.manifest.load_manifest`).
    extras : bool
        Also return the extra images (test targets); by default only the references (:data:`ROLES`).

    Returns
    -------
    dict of str to Path
        ``white``, ``red``, ``green``, ``blue`` and (when captured) ``black``, in capture order.

    Raises
    ------
    AcquisitionError
        No or a corrupt manifest, a required reference not captured yet, or a listed file missing.

    Examples
    --------
    A run of the simulated camera and light:

    >>> from picamcal.acquire.acquisition import acquire
    >>> from picamcal.acquire.cameras import SimCamera
    >>> camera = SimCamera("imx219", size=(64, 48))
    >>> _ = acquire(camera, camera.light, "run1", extras=["target"], prompt=print, settle_s=0)
    Put the target in front of the camera and press Enter
    >>> {role: path.name for role, path in read_manifest("run1").items()}
    {'white': 'white.dng', 'red': 'red.dng', 'green': 'green.dng', 'blue': 'blue.dng', 'black': 'black.dng'}
    >>> read_manifest("run1", extras=True)["target"].name
    'target.dng'
    """
    folder = Path(folder)
    record = load_manifest(folder)
    files = {e["role"]: folder / e["file"] for e in record["entries"] if extras or e["role"] in ROLES}
    missing = [role for role in _REQUIRED if role not in files]
    if missing:
        raise AcquisitionError(
            f"the acquisition is incomplete (no {', '.join(missing)} yet): run picamcal acquire again with the same "
            "--out to finish it",
            folder,
        )
    for path in files.values():
        if not path.is_file():
            raise AcquisitionError("listed in the manifest but missing", path)
    return files


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
        The folder holds a ``manifest.json`` that is not a usable one (:func:`read_manifest`).

    Examples
    --------
    Only the names are looked at (empty files will do here):

    >>> from pathlib import Path
    >>> for name in ("white.dng", "red.dng", "green.dng", "blue.dng", "notes.txt"):
    ...     _ = Path(name).write_bytes(b"")
    >>> {role: path.name for role, path in find_references(".").items()}
    {'blue': 'blue.dng', 'green': 'green.dng', 'red': 'red.dng', 'white': 'white.dng'}
    >>> _ = Path("white_2.dng").write_bytes(b"")
    >>> [path.name for path in find_references(".")["white"]]
    ['white.dng', 'white_2.dng']
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CalibrationInputError("no such folder of reference images", folder)
    if not in_situ and (folder / MANIFEST_NAME).is_file():
        return dict(read_manifest(folder))
    try:
        entries = sorted(folder.iterdir(), key=_natural)
    except OSError as exc:
        raise CalibrationInputError(f"cannot list the folder: {exc.strerror or exc}", folder) from None
    found: dict[str, list[Path]] = {}
    for path in entries:
        # is_file follows links and is False for a FIFO, a device or a symlink loop: those are left out
        role = role_of(path.name) if path.suffix.lower() in _REFERENCE_SUFFIXES and path.is_file() else None
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
