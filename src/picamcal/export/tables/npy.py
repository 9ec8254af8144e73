"""Legacy tables saved as ``.npy`` (what ``picamcal export-lst`` writes, and ``numpy.save`` of any such table).

The header is read and checked before the data: a shape or dtype that is not a table is refused without
allocating what it declares.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ...limits import require_regular_file
from .model import MAX_CELLS, TableFileError, check_legacy_gains

NPY_MAGIC = b"\x93NUMPY"


def read_npy_table(path: str | os.PathLike[str]) -> np.ndarray:
    """The legacy table (uint8, (4, rows, cols)) in an ``.npy`` file.

    Raises
    ------
    TableFileError
        Not an ``.npy`` file, a header numpy cannot read, a dtype other than whole numbers, a shape other than
        (4, rows, columns), zeros; one line naming the file.

    Examples
    --------
    >>> np.save("lst.npy", np.full((4, 39, 52), 40, np.uint8))
    >>> read_npy_table("lst.npy").shape
    (4, 39, 52)
    """
    path = Path(path)
    size = require_regular_file(path, TableFileError)
    with open(path, "rb") as f:
        return read_npy_stream(f, size, path)


def read_npy_stream(f: BinaryIO, size: int, path: str | os.PathLike[str]) -> np.ndarray:
    """The legacy table in an open ``.npy`` stream of ``size`` bytes, checked as :func:`read_npy_table` says; errors
    name ``path``.

    Examples
    --------
    >>> import io
    >>> buffer = io.BytesIO()
    >>> np.save(buffer, np.full((4, 4, 6), 32, np.uint8))
    >>> read_npy_stream(io.BytesIO(buffer.getvalue()), len(buffer.getvalue()), "lst.npy").shape
    (4, 4, 6)
    """
    if f.read(len(NPY_MAGIC)) != NPY_MAGIC:
        raise TableFileError("not an .npy file (expected a legacy lens shading table saved by numpy)", path)
    f.seek(0)
    try:
        version = np.lib.format.read_magic(f)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran, dtype = read_header(f, max_header_size=10_000)
    except Exception as exc:  # numpy's header parser raises many types: one line, whatever it is
        raise TableFileError(f"its .npy header is not readable ({type(exc).__name__})", path) from None
    if dtype.hasobject:
        raise TableFileError("holds Python objects, expected uint8 u3.5 gains (32 = 1.0)", path)
    cells = shape[1:] if len(shape) == 3 else ()
    if len(shape) != 3 or shape[0] != 4 or not all(2 <= n <= MAX_CELLS for n in cells):
        raise TableFileError(
            f"a table of shape {tuple(shape)} is not a legacy lens shading table: expected (4, rows, columns) "
            "of u3.5 gains (planes R, Gr, Gb, B; (4, 39, 52) for an IMX219)",
            path,
        )
    count = int(np.prod(shape))
    data = f.read(count * dtype.itemsize)
    if f.tell() > size or len(data) < count * dtype.itemsize:
        raise TableFileError(f"is cut short: its header declares {tuple(shape)} {dtype}", path)
    table = np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")
    return check_legacy_gains(table, path)
