"""Reading the first bytes of a file and `.npy` arrays, with the one-line errors every reader gives.

The ``.npy`` readers here never allocate from a header's word: a header is read and checked first (against the
file's size, by the caller against what a frame can be), then exactly that many bytes are read. No pickles.
"""

from __future__ import annotations

import math
import os
import tokenize
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from ..errors import RawFormatError, exception_detail
from ..limits import require_regular_file

#: What numpy's ``.npy`` header readers raise on a damaged header: ``ast.literal_eval`` and numpy's own checks
#: (ValueError, SyntaxError, TypeError for an unhashable key, RecursionError for deep nesting), the tokenizer of
#: its Python 2 fallback (``tokenize.TokenError``, for a header cut inside a bracket), ``EOFError`` for a short file.
_NPY_HEADER_ERRORS = (ValueError, TypeError, SyntaxError, RecursionError, OverflowError, EOFError, tokenize.TokenError)
_MAX_NPY_HEADER = 10_000  # numpy's own default limit on a header's length


def file_head(path: Path, size: int = 8) -> bytes:
    """The first ``size`` bytes of a file, for recognising its format.

    Raises
    ------
    RawFormatError
        No such file, a directory or another thing that is not a regular file (a FIFO would block), unreadable,
        or empty.
    """
    require_regular_file(path)
    try:
        with open(path, "rb") as f:
            head = f.read(size)
    except FileNotFoundError:
        raise RawFormatError("no such file", path) from None
    except IsADirectoryError:
        raise RawFormatError("is a directory, not an image file", path) from None
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from exc
    if not head:
        raise RawFormatError("empty file (0 bytes)", path)
    return head


def is_npy(head: bytes) -> bool:
    """True if the first bytes of a file are a NumPy ``.npy`` header.

    Examples
    --------
    >>> is_npy(b"\\x93NUMPY\\x01\\x00"), is_npy(b"II*\\x00")
    (True, False)
    """
    return head[:6] == np.lib.format.MAGIC_PREFIX


def read_npy_header(
    f: IO[bytes], source: str | os.PathLike[str], what: str = ".npy file"
) -> tuple[tuple, bool, np.dtype]:
    """The shape, Fortran order and dtype a ``.npy`` header declares, read from ``f`` without reading the data.

    ``f`` is left at the first byte of the data. Nothing is allocated from the header's values: the caller checks
    the shape before reading.

    Raises
    ------
    RawFormatError
        Not a ``.npy`` header, a version numpy does not write, or a header that does not parse (one line naming
        ``source`` and ``what``).

    Examples
    --------
    >>> import io
    >>> buffer = io.BytesIO()
    >>> np.save(buffer, np.zeros((2, 4), np.uint8))
    >>> _ = buffer.seek(0)
    >>> read_npy_header(buffer, "x.npy")
    ((2, 4), False, dtype('uint8'))
    """
    try:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f, max_header_size=_MAX_NPY_HEADER)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f, max_header_size=_MAX_NPY_HEADER)
        else:
            numbers = f"{version[0]}.{version[1]}"
            raise RawFormatError(f"unsupported .npy version {numbers} in {what} (numpy writes 1.0 and 2.0)", source)
    except _NPY_HEADER_ERRORS as exc:
        raise RawFormatError(f"corrupt {what} ({exception_detail(exc)})", source) from None
    return shape, fortran, dtype


def read_array_data(f: IO[bytes], dtype: np.dtype, count: int, source: str | os.PathLike[str], what: str) -> np.ndarray:
    """``count`` items of ``dtype`` from ``f`` (a file or a zip member), read into one array of that size only.

    Read in pieces, so that a stream that ends early or a forged size costs no more than the array the caller has
    already sized.

    Raises
    ------
    RawFormatError
        The stream ends before ``count`` items (``what`` names the data in the message).

    Examples
    --------
    >>> import io
    >>> read_array_data(io.BytesIO(bytes(range(6))), np.dtype("<u2"), 3, "x.npy", "data").tolist()
    [256, 770, 1284]
    """
    out = np.empty(count, dtype=dtype)
    view = out.view(np.uint8)
    done = 0
    while done < view.size:
        piece = f.read(min(view.size - done, 1 << 22))
        if not piece:
            raise RawFormatError(f"truncated {what}: {done} of {view.size} bytes of data", source)
        view[done : done + len(piece)] = np.frombuffer(piece, dtype=np.uint8)
        done += len(piece)
    return out


@dataclass(frozen=True)
class NpyHeader:
    """What a ``.npy`` file declares, and how many bytes of data the file holds; none of them read yet."""

    shape: tuple[int, ...]
    fortran: bool
    dtype: np.dtype
    offset: int  # where the data starts
    available: int  # bytes from there to the end of the file

    @property
    def nbytes(self) -> int:
        """Bytes of data the header declares."""
        return math.prod(self.shape) * self.dtype.itemsize

    def require_data(self, path: Path) -> None:
        """Raise unless the file holds all the data its header declares."""
        if self.available < self.nbytes:
            raise RawFormatError(f"truncated .npy: {self.available} of {self.nbytes} bytes of data", path)


def read_npy_file_header(path: Path) -> NpyHeader:
    """The header of the ``.npy`` file ``path``; the caller checks it, and :meth:`NpyHeader.require_data`.

    Raises
    ------
    RawFormatError
        Not a regular file, unreadable, or not a ``.npy`` file.

    Examples
    --------
    >>> np.save("buffer.npy", np.zeros((2, 32), np.uint8))
    >>> read_npy_file_header(Path("buffer.npy"))
    NpyHeader(shape=(2, 32), fortran=False, dtype=dtype('uint8'), offset=128, available=64)
    """
    require_regular_file(path)
    try:
        with open(path, "rb") as f:
            shape, fortran, dtype = read_npy_header(f, path)
            offset = f.tell()
            available = os.fstat(f.fileno()).st_size - offset
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from None
    return NpyHeader(shape, fortran, dtype, offset, available)


def load_npy(path: Path, header: NpyHeader) -> np.ndarray:
    """The array a checked header declares (:func:`read_npy_file_header`), read into one array of that size.

    Examples
    --------
    >>> np.save("buffer.npy", np.arange(6, dtype=np.uint16).reshape(2, 3))
    >>> load_npy(Path("buffer.npy"), read_npy_file_header(Path("buffer.npy"))).tolist()
    [[0, 1, 2], [3, 4, 5]]
    """
    try:
        with open(path, "rb") as f:
            f.seek(header.offset)
            data = read_array_data(f, header.dtype, math.prod(header.shape), path, ".npy")
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from None
    return data.reshape(header.shape, order="F" if header.fortran else "C")
