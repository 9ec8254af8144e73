"""The OpenFlexure Microscope's saved lens shading table: ``microscope_settings.npz`` holding ``lens_shading_table``.

The OpenFlexure server keeps the legacy firmware's table ((4, 39, 52) uint8 for the IMX219, 32 = 1.0) in an
``.npz`` beside its other settings; only that member is read (without pickles), its ``.npy`` header checked before
a byte of its data is inflated.
"""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path

import numpy as np

from ...limits import require_regular_file
from .model import TableFileError
from .npy import NPY_MAGIC, read_npy_stream

#: The member OpenFlexure saves the table under.
TABLE_KEY = "lens_shading_table"
#: A (4, 512, 512) table and its header: no real member is larger inflated.
_MAX_MEMBER_BYTES = 4 * 512 * 512 * 8 + 10_000
_ZIP_ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError, NotImplementedError)


def npz_keys(path: str | os.PathLike[str]) -> list[str] | None:
    """The array names of an ``.npz`` archive (its ``.npy`` members without the suffix), or None if it is not one.

    Examples
    --------
    >>> np.savez("settings.npz", lens_shading_table=np.full((4, 39, 52), 32, np.uint8), exposure=np.array(1))
    >>> npz_keys("settings.npz")
    ['exposure', 'lens_shading_table']
    """
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
    except _ZIP_ERRORS:
        return None
    return sorted(name.removesuffix(".npy") for name in names)


def is_openflexure_npz(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is an ``.npz`` holding a ``lens_shading_table`` array (OpenFlexure's ``microscope_settings``).

    Examples
    --------
    >>> np.savez("settings.npz", lens_shading_table=np.full((4, 39, 52), 32, np.uint8))
    >>> is_openflexure_npz("settings.npz"), is_openflexure_npz("missing.npz")
    (True, False)
    """
    return TABLE_KEY in (npz_keys(path) or [])


def read_openflexure_table(path: str | os.PathLike[str]) -> np.ndarray:
    """The legacy table (uint8, (4, rows, cols)) an OpenFlexure ``microscope_settings.npz`` holds.

    Raises
    ------
    TableFileError
        Not a zip archive, no ``lens_shading_table`` member (the message lists the keys it holds), a member that is
        compressed absurdly or is not a table (:func:`picamcal.export.tables.npy.read_npy_table`'s checks).

    Examples
    --------
    >>> np.savez("settings.npz", lens_shading_table=np.full((4, 39, 52), 40, np.uint8), shutter_speed=np.array(2))
    >>> read_openflexure_table("settings.npz").shape
    (4, 39, 52)
    """
    path = Path(path)
    require_regular_file(path, TableFileError)
    try:
        with zipfile.ZipFile(path) as archive:
            members = {name.removesuffix(".npy"): name for name in archive.namelist()}
            if TABLE_KEY not in members:
                shown = ", ".join(sorted(members)[:6]) + (" ..." if len(members) > 6 else "")
                raise TableFileError(
                    f"an .npz without {TABLE_KEY!r} (it holds {shown or 'nothing'}): expected a picamcal calibration "
                    f"or an OpenFlexure microscope_settings.npz with its {TABLE_KEY}",
                    path,
                )
            info = archive.getinfo(members[TABLE_KEY])
            if info.file_size > _MAX_MEMBER_BYTES:
                raise TableFileError(f"its {TABLE_KEY} declares {info.file_size} bytes: not a lens shading table", path)
            with archive.open(info) as member:
                content = member.read(_MAX_MEMBER_BYTES + 1)
    except _ZIP_ERRORS as exc:
        raise TableFileError(f"not a readable .npz archive ({type(exc).__name__})", path) from None
    if not content.startswith(NPY_MAGIC):
        raise TableFileError(f"its {TABLE_KEY} is not an .npy array", path)
    try:
        return read_npy_stream(io.BytesIO(content), len(content), path)
    except TableFileError as exc:
        raise TableFileError(f"its {TABLE_KEY}: {exc.problem}", path) from None
