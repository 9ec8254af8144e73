"""The lens shading table read from a user's file, and the checks every legacy table passes.

:class:`ShadingTable` is what each reader of :mod:`picamcal.export.tables` returns: a legacy firmware table (uint8
planes R, Gr, Gb, B, u3.5) or a libcamera tuning file's ``rpi.alsc``, with where it came from and what the file says
of its sensor.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import CalibrationFileError
from ..legacy import UNITY

#: The most rows or columns of cells a legacy table may have: the largest sensor of the registry (the OV64A40,
#: 9248 x 6944) needs 109 x 145; anything far beyond is not a table.
MAX_CELLS = 512


class TableFileError(CalibrationFileError):
    """A file given as a lens shading calibration that is not one picamcal can use; one line naming the file."""


#: What each kind of file is called in messages and by ``picamcal inspect``.
FORMATS = {
    "npy": "legacy lens shading table (.npy, picamcal export-lst)",
    "openflexure": "OpenFlexure lens shading table (microscope_settings.npz)",
    "c-header": "legacy lens shading table (C header)",
    "tuning": "libcamera tuning file",
}


@dataclass(frozen=True, eq=False)
class ShadingTable:
    """A lens shading calibration a user already has, as read from its file.

    Attributes
    ----------
    kind : {"npy", "openflexure", "c-header", "tuning"}
        The file's kind (:data:`FORMATS` names each).
    path : Path
        The file.
    legacy : ndarray of uint8, shape (4, rows, cols), or None
        A legacy firmware table: planes R, Gr, Gb, B, gains in u3.5 (32 = 1.0) at cell centres 32 + 64 k.
    tuning : dict or None
        A libcamera tuning file (with an ``rpi.alsc`` section) for the other kind.
    sensor : str or None
        The sensor the file names (a tuning file's ``picamcal`` record or its name), else None.
    details : mapping
        What else the file says (a header's ``ref_transform``, a tuning's colour temperatures), for ``inspect``.
    rounding : {"nearest", "floor"}
        How the tool that wrote a legacy table rounded its gains (:data:`picamcal.export.legacy.ROUNDINGS`):
        ``nearest`` for picamcal's ``.npy``, ``floor`` for OpenFlexure's ``.npz`` and the C headers' tools.
    """

    kind: str
    path: Path
    legacy: np.ndarray | None = None
    tuning: dict[str, Any] | None = None
    sensor: str | None = None
    details: Mapping[str, Any] = field(default_factory=dict)
    rounding: str = "nearest"

    @property
    def format(self) -> str:
        """What the file is, in words."""
        return FORMATS[self.kind]


def check_legacy_gains(table: np.ndarray, path: str | os.PathLike[str]) -> np.ndarray:
    """``table`` as a legacy table (uint8, (4, rows, cols)), or TableFileError naming ``path`` and what was expected.

    Values must be whole numbers 1..255 (u3.5 gains, 32 = 1.0): a zero is a gain of 0, which no flat field has.

    Examples
    --------
    >>> check_legacy_gains(np.full((4, 39, 52), 32), "lst.npy").dtype
    dtype('uint8')
    >>> check_legacy_gains(np.zeros((4, 3, 3), np.uint8), "lst.npy")
    Traceback (most recent call last):
    ...
    picamcal.export.tables.model.TableFileError: lst.npy: the table holds 36 zeros (gain 0; 32 is 1.0): not a \
lens shading table
    """
    shape = tuple(int(n) for n in np.shape(table))
    if len(shape) != 3 or shape[0] != 4 or not all(2 <= n <= MAX_CELLS for n in shape[1:]):
        raise TableFileError(
            f"a table of shape {shape} is not a legacy lens shading table: expected (4, rows, columns) of u3.5 "
            f"gains (planes R, Gr, Gb, B; (4, 39, 52) for an IMX219)",
            path,
        )
    values = np.asarray(table)
    if values.dtype.kind not in "ui" or (values.dtype.kind == "i" and values.size and values.min() < 0):
        raise TableFileError(
            f"the table holds {values.dtype} values, expected whole numbers 1..255 (u3.5 gains, 32 = 1.0)", path
        )
    if values.size and values.max() > 255:
        raise TableFileError(f"the table holds {int(values.max())}, past 255: not u3.5 gains in a byte", path)
    zeros = int(np.count_nonzero(values == 0))
    if zeros:
        raise TableFileError(f"the table holds {zeros} zeros (gain 0; {UNITY} is 1.0): not a lens shading table", path)
    return values.astype(np.uint8)
