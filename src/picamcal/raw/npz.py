"""picamcal's own lossless raw container: a ``.npz`` holding the mosaic and a JSON record.

Arrays: ``bayer`` (uint16, H x W) and ``metadata`` (a 0-d unicode array holding JSON with
``format`` ``"picamcal-raw"``, ``version``, ``pattern``, ``black_level``, ``white_level``,
``bit_depth``, ``sensor`` and the image ``metadata``). Read with ``allow_pickle=False``.
"""

from __future__ import annotations

import contextlib
import json
import os
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from .._atomic import atomic_path
from .._json import MAX_JSON_BYTES
from ..errors import RawFormatError, exception_detail
from ..limits import check_size, require_regular_file
from ..records import json_default
from .model import RawImage
from .npy import read_array_data, read_npy_header

FORMAT_NAME = "picamcal-raw"
VERSION = 1


def is_npz(head: bytes) -> bool:
    """True if the first bytes of a file are a zip archive's (an ``.npz`` is one); :func:`read_npz` checks the rest.

    Examples
    --------
    >>> is_npz(b"PK\\x03\\x04"), is_npz(b"\\x93NUMPY")
    (True, False)
    """
    return head.startswith(b"PK")


def write_npz(path: str | os.PathLike[str], raw: RawImage, overwrite: bool = True) -> Path:
    """Save a RawImage losslessly as a picamcal raw ``.npz`` (compressed, written atomically).

    Examples
    --------
    >>> write_npz("frame.npz", RawImage(np.full((4, 6), 300, np.uint16), "RGGB", 256, 4095, 12, "imx477"))
    PosixPath('frame.npz')
    """
    path = Path(path)
    record = {
        "format": FORMAT_NAME,
        "version": VERSION,
        "pattern": raw.pattern,
        "black_level": list(raw.black_level),
        "white_level": int(raw.white_level),
        "bit_depth": int(raw.bit_depth),
        "sensor": raw.sensor,
        "metadata": {k: v for k, v in raw.metadata.items() if k not in ("path", "format")},
    }
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, bayer=raw.bayer, metadata=np.array(json.dumps(record, default=json_default)))
    return path


def is_raw_npz(path: str | os.PathLike[str]) -> bool:
    """True if an ``.npz`` file is a picamcal raw image (not, say, a calibration), from its member names only.

    Examples
    --------
    >>> _ = write_npz("frame.npz", RawImage(np.full((4, 6), 300, np.uint16), "RGGB", 256, 4095, 12, "imx477"))
    >>> np.savez("cal.npz", unmixing=np.eye(3))
    >>> is_raw_npz("frame.npz"), is_raw_npz("cal.npz"), is_raw_npz("missing.npz")
    (True, False, False)
    """
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except _ZIP_ERRORS:
        return False
    return {"bayer.npy", "metadata.npy"} <= names and "unmixing.npy" not in names


def read_npz(path: str | os.PathLike[str], *, expected_shape: tuple[int, int] | None = None) -> RawImage:
    """Read a picamcal raw ``.npz`` written by :func:`write_npz`.

    Nothing is inflated before it is checked: the JSON record first (at most 16 MB), then the mosaic's ``.npy``
    header inside the zip, whose size goes through :func:`picamcal.limits.check_size` (and ``expected_shape``)
    and must account for every byte the zip says the member holds.

    Parameters
    ----------
    path : path-like
        The ``.npz`` file.
    expected_shape : (height, width), optional
        The Bayer size the caller needs (a calibration's): another size raises ``CalibrationFileError`` before the
        mosaic is inflated.

    Raises
    ------
    RawFormatError
        One line naming the file: not a zip, not a picamcal raw image, a corrupt member or record (the member and
        the field named), a declared size over the pixel limit.
    CalibrationFileError
        The mosaic's size is not ``expected_shape``.

    Examples
    --------
    >>> _ = write_npz("frame.npz", RawImage(np.full((4, 6), 300, np.uint16), "RGGB", 256, 4095, 12, "imx477"))
    >>> raw = read_npz("frame.npz")
    >>> raw.bayer.shape, raw.pattern, raw.black_level[0], raw.sensor, raw.metadata["format"]
    ((4, 6), 'RGGB', 256.0, 'imx477', 'npz')
    >>> read_npz("frame.npz", expected_shape=(240, 320))
    Traceback (most recent call last):
    ...
    picamcal.errors.CalibrationFileError: frame.npz: image does not match the calibration: size 6x4, ...
    """
    path = Path(path)
    require_regular_file(path)
    with _reading(path, "not a zip archive"):
        archive = zipfile.ZipFile(path)
    with archive:
        names = set(archive.namelist())
        if "bayer.npy" not in names or "metadata.npy" not in names:
            kind = "a calibration? " if "unmixing.npy" in names else ""
            raise RawFormatError(f"an .npz file but not a picamcal raw image ({kind}no 'bayer' array)", path)
        record = _record(archive, path)
        bayer = _mosaic(archive, path, expected_shape)
    meta = dict(record.get("metadata") or {})
    meta.update(format="npz", path=str(path))
    try:
        return RawImage(
            bayer,
            record["pattern"],
            record["black_level"],
            record["white_level"],
            record["bit_depth"],
            record.get("sensor"),
            meta,
        )
    except RawFormatError as exc:
        raise RawFormatError(f"corrupt picamcal raw record: {exc.problem}", path) from None


# What reading a damaged zip raises: zipfile's own errors, zlib's for a damaged deflate stream, NotImplementedError
# for a compression method it lacks, RuntimeError for an encrypted member, and OSError/EOFError/ValueError for
# short or inconsistent files.
_ZIP_ERRORS = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    zlib.error,
    NotImplementedError,
    RuntimeError,
    OSError,
    EOFError,
    ValueError,
)


@contextlib.contextmanager
def _reading(path: Path, what: str) -> Iterator[None]:
    """Turn what zipfile and zlib raise on damaged bytes into one line naming the file and ``what`` was read."""
    try:
        yield
    except _ZIP_ERRORS as exc:
        raise RawFormatError(f"corrupt picamcal raw file ({what}: {exception_detail(exc)})", path) from None


def _member(
    archive: zipfile.ZipFile, name: str, path: Path, max_bytes: int | None = None
) -> tuple[zipfile.ZipInfo, IO[bytes]]:
    """Member ``name``'s entry in the zip's directory and a stream of its bytes, nothing inflated yet."""
    info = archive.getinfo(name)
    if max_bytes is not None and info.file_size > max_bytes:
        raise RawFormatError(f"member {name} declares {info.file_size} bytes, more than {max_bytes}", path)
    with _reading(path, name):
        member = archive.open(info)
    return info, member


def _record(archive: zipfile.ZipFile, path: Path) -> dict[str, Any]:
    """The JSON record of ``metadata.npy`` (a 0-d unicode array), checked field by field."""
    info, member = _member(archive, "metadata.npy", path, MAX_JSON_BYTES)
    with member, _reading(path, "metadata.npy"):
        shape, _, dtype = read_npy_header(member, path, "member metadata.npy")
        if dtype.kind != "U" or shape != ():
            raise RawFormatError(f"metadata.npy is a {dtype} array of shape {shape}, not a JSON text", path)
        if member.tell() + dtype.itemsize != info.file_size:
            raise RawFormatError(f"member metadata.npy holds {info.file_size} bytes, not a {dtype} text", path)
        text = str(read_array_data(member, dtype, 1, path, "metadata.npy")[0])
    try:
        record = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise RawFormatError(f"corrupt picamcal raw record ({type(exc).__name__}: {str(exc)[:80]})", path) from None
    if not isinstance(record, dict) or record.get("format") != FORMAT_NAME:
        raise RawFormatError("an .npz file but not a picamcal raw image", path)
    if record.get("version") != VERSION or isinstance(record.get("version"), bool):
        raise RawFormatError(f"unsupported picamcal raw version {str(record.get('version'))[:20]!r}", path)
    for key in ("pattern", "black_level", "white_level", "bit_depth"):
        if key not in record:
            raise RawFormatError(f"corrupt picamcal raw record: no {key!r}", path)
    if not isinstance(record.get("metadata") or {}, dict):
        raise RawFormatError("corrupt picamcal raw record: 'metadata' must be an object", path)
    return record


def _mosaic(archive: zipfile.ZipFile, path: Path, expected_shape: tuple[int, int] | None) -> np.ndarray:
    """``bayer.npy``: its header's size checked (limit, calibration, the zip's byte count), then inflated."""
    info, member = _member(archive, "bayer.npy", path)
    with member, _reading(path, "bayer.npy"):
        shape, fortran, dtype = read_npy_header(member, path, "member bayer.npy")
        if dtype.kind != "u" or dtype.itemsize > 2 or len(shape) != 2:
            raise RawFormatError(f"bayer.npy is a {dtype} array of shape {shape}, not a 2-D uint16 mosaic", path)
        height, width = shape
        check_size(path, width, height, expected_shape)
        need = member.tell() + height * width * dtype.itemsize
        if info.file_size != need:
            raise RawFormatError(
                f"member bayer.npy holds {info.file_size} bytes, but its header declares a {width}x{height} {dtype} "
                f"array of {need}",
                path,
            )
        data = read_array_data(member, dtype, height * width, path, "bayer.npy")
        if member.read(1):  # also where zipfile checks the member's CRC
            raise RawFormatError("member bayer.npy holds more bytes than its header declares", path)
    bayer = data.reshape(shape, order="F" if fortran else "C")
    return np.ascontiguousarray(bayer.astype(np.uint16, copy=False))
