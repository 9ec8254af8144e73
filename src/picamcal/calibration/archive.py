"""Reading a calibration's ``.npz`` archive without trusting it: sizes, headers and the record before any data.

numpy's own reader parses ``.npy`` headers with errors of many types and allocates whatever a header says; here
every member's compression, declared size, dtype and shape are checked against the record before a byte of its
data is read, and every problem is one :class:`~picamcal.errors.CalibrationFileError` naming the file.
"""

from __future__ import annotations

import ast
import math
import os
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from .._json import parse_json
from ..errors import CalibrationFileError
from ..limits import require_regular_file
from .schema import (
    ARRAYS,
    BOOL_ARRAYS,
    GLOBAL_ARRAYS,
    KIND_NAMES,
    READABLE_VERSIONS,
    SCHEMA,
    check_record,
    dtype_name,
    expected_shapes,
)

#: A record is a few kB; this leaves room for thousands of averaged frames.
_MAX_RECORD_CHARS = 1 << 20
#: picamcal writes calibrations uncompressed, and measured fields barely compress; a compressed member may
#: inflate at most this much (a zip bomb inflates a thousandfold), or to :data:`_INFLATION_FLOOR` bytes.
_MAX_INFLATION = 32
_INFLATION_FLOOR = 1 << 20
_NPY_MAGIC = b"\x93NUMPY"
#: numpy's own limit on a ``.npy`` header (``max_header_size``).
_MAX_NPY_HEADER = 10_000


#: First bytes of the files people give by mistake where a calibration belongs -> what they are.
_IMAGE_SIGNATURES = {
    b"II*\x00": "an image",  # TIFF, little-endian (a DNG is a raw image: see _not_a_calibration)
    b"MM\x00*": "an image",  # TIFF, big-endian
    b"\x93NUMPY": "a raw image",  # a .npy array (picamera2's raw dumps)
    b"\xff\xd8": "an image",  # JPEG (with or without the legacy firmware's raw block)
    b"\x89PNG\r\n\x1a\n": "an image",
}
_ZIP = b"PK\x03\x04"


class ImageNotCalibrationError(CalibrationFileError):
    """An image given where a calibration belongs; ``kind`` says which (``"a raw image"``, ``"an image"``), so that
    a command whose fix is another (``export-tuning``: make a calibration first) can say so."""

    kind = "an image"


def _not_a_calibration(path: Path) -> None:
    """Raise the one-line error for a file that is plainly not a calibration, from its first bytes."""
    from ..raw.npz import is_raw_npz

    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as exc:
        raise CalibrationFileError(f"cannot read the calibration file ({exc.strerror or exc})", path) from None
    what = next((kind for magic, kind in _IMAGE_SIGNATURES.items() if head.startswith(magic)), None)
    if what is not None and head[:2] in (b"II", b"MM") and path.suffix.lower() == ".dng":
        what = "a raw image"
    elif what is None and head.startswith(_ZIP) and is_raw_npz(path):
        what = "a raw image"
    elif what is None and not head.startswith(_ZIP) and path.suffix.lower() == ".raw":
        what = "a raw image"  # a headless dump has no signature, only its name
    if what is not None:
        error = ImageNotCalibrationError(
            f"this is {what}, not a calibration (the calibration comes first: picamcal correct CALIBRATION IMAGE...)",
            path,
        )
        error.kind = what
        raise error
    if not head.startswith(_ZIP):
        raise CalibrationFileError("not a picamcal calibration file (not an .npz archive)", path)


def read_archive(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The record (without ``schema`` and ``schema_version``) and the read-only arrays of a calibration file.

    Checked in the order :func:`picamcal.calibration.load_calibration` describes; the values are checked when
    the :class:`~picamcal.calibration.Calibration` is made from them.
    """
    path = Path(path)
    if not os.path.lexists(path):
        raise CalibrationFileError("no such calibration file", path)
    require_regular_file(path, CalibrationFileError)
    _not_a_calibration(path)
    try:
        with zipfile.ZipFile(path) as archive:
            members = _members(archive, path)
            if "metadata" not in members:
                raise CalibrationFileError("not a picamcal calibration file (an .npz without its record)", path)
            record = _read_record(archive, members.pop("metadata"), path)
            kind, nby, nbx = check_record(record, path, CalibrationFileError)
            expected = expected_shapes(kind, nby, nbx)
            extra = sorted(set(members) & (set(ARRAYS) | set(GLOBAL_ARRAYS)) - set(expected))
            if extra:
                raise CalibrationFileError(
                    f"a {kind} calibration holds {', '.join(map(repr, extra))}: inconsistent", path
                )
            arrays = {}
            for name, shape in expected.items():
                if name not in members:
                    raise CalibrationFileError(f"calibration lacks the array {name!r}", path)
                dtypes = "b" if name in BOOL_ARRAYS else "f"
                arrays[name] = _read_member(archive, members[name], name, dtypes, shape, path)
                arrays[name].setflags(write=False)  # fresh memory of its own: the calibration need not copy it
    except (OSError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, NotImplementedError) as exc:
        raise CalibrationFileError(f"not a readable picamcal calibration ({type(exc).__name__}: {exc})", path) from None
    return record, arrays


def _members(archive: zipfile.ZipFile, path: Path) -> dict[str, zipfile.ZipInfo]:
    """The archive's ``.npy`` members by array name, each checked for encryption and a zip bomb's inflation."""
    members: dict[str, zipfile.ZipInfo] = {}
    for info in archive.infolist():
        name = info.filename.removesuffix(".npy")
        if name in members:
            raise CalibrationFileError(f"the archive holds {info.filename!r} twice: corrupt", path)
        if info.flag_bits & 0x1:
            raise CalibrationFileError(f"its {info.filename!r} is encrypted: not a picamcal calibration", path)
        if info.compress_type != zipfile.ZIP_STORED and info.file_size > max(
            _INFLATION_FLOOR, _MAX_INFLATION * info.compress_size
        ):
            raise CalibrationFileError(
                f"the archive's {info.filename!r} would inflate from {info.compress_size / 1e6:.1f} MB to "
                f"{info.file_size / 1e6:.0f} MB: refused as a zip bomb (picamcal writes calibrations uncompressed)",
                path,
            )
        members[name] = info
    return members


def _read_record(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path) -> dict[str, Any]:
    """The JSON record of the ``metadata`` member, checked for its schema and version."""
    text = str(_read_member(archive, info, "metadata", "U", (), path)[()])
    try:
        record = parse_json(text, CalibrationFileError, "JSON", path)
    except CalibrationFileError as exc:
        raise CalibrationFileError(f"not a picamcal calibration file (its record is {exc.problem})", path) from None
    if not isinstance(record, dict) or record.get("schema") != SCHEMA:
        raise CalibrationFileError("not a picamcal calibration file", path)
    version = record.get("schema_version")
    if type(version) is not int or version not in READABLE_VERSIONS:
        shown = repr(version) if isinstance(version, (int, float, type(None))) else type(version).__name__
        raise CalibrationFileError(
            f"calibration schema version {shown} is not supported (this picamcal reads versions "
            f"{', '.join(map(str, READABLE_VERSIONS))}; a newer picamcal wrote it: update picamcal)",
            path,
        )
    del record["schema"], record["schema_version"]
    return record


def _read_member(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, name: str, kinds: str, shape: tuple[int, ...], path: Path
) -> np.ndarray:
    """One ``.npy`` member: its header checked against the dtype kinds and shape expected, then its data read.

    The header and the member's declared size must agree with ``shape`` before a byte of data is read, so a
    forged header or size costs nothing.
    """
    with archive.open(info) as stream:
        dtype, fortran, declared, offset = _npy_header(stream, name, path)
        if dtype.kind not in kinds or (dtype.kind == "f" and dtype.itemsize > 8):
            if dtype.hasobject:
                raise CalibrationFileError("not a picamcal calibration file (it holds Python objects)", path)
            raise CalibrationFileError(
                f"calibration array {name!r} has {dtype_name(dtype)}, expected {KIND_NAMES[kinds]}", path
            )
        if name == "metadata" and dtype.itemsize > 4 * _MAX_RECORD_CHARS:
            raise CalibrationFileError(f"the calibration record is over {_MAX_RECORD_CHARS} characters: corrupt", path)
        if declared != shape:
            raise CalibrationFileError(f"calibration array {name!r} has shape {declared}, expected {shape}", path)
        nbytes = dtype.itemsize * math.prod(shape)
        if info.file_size != offset + nbytes:
            raise CalibrationFileError(
                f"calibration array {name!r} declares {info.file_size} bytes, its header {offset + nbytes}: corrupt",
                path,
            )
        data = stream.read(nbytes)
    if len(data) != nbytes:
        raise CalibrationFileError(f"calibration array {name!r} is cut short", path)
    array = np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")
    return array.astype(dtype.newbyteorder("="), order="C")


def _npy_header(stream: Any, name: str, path: Path) -> tuple[np.dtype, bool, tuple[int, ...], int]:
    """(dtype, fortran order, shape, data offset) of a ``.npy`` stream, parsed without numpy's header reader.

    numpy's own raises errors of many types (tokenize.TokenError for a header cut mid-way) and allocates whatever
    the shape says; here every problem is a CalibrationFileError and nothing is allocated.
    """

    def corrupt(problem: str) -> CalibrationFileError:
        return CalibrationFileError(f"calibration array {name!r} {problem}: corrupt", path)

    prefix = stream.read(8)
    if len(prefix) < 8 or not prefix.startswith(_NPY_MAGIC):
        raise corrupt("is not a .npy array")
    size_bytes = {1: 2, 2: 4, 3: 4}.get(prefix[6])
    if size_bytes is None:
        raise corrupt(f"is a .npy array of unknown version {prefix[6]}")
    length = int.from_bytes(stream.read(size_bytes), "little")
    if length > _MAX_NPY_HEADER:
        raise corrupt(f"has a header of {length} bytes")
    raw = stream.read(length)
    if len(raw) != length:
        raise corrupt("has a header cut short")
    try:
        header = ast.literal_eval(raw.decode("utf-8" if prefix[6] == 3 else "latin-1"))
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError, UnicodeDecodeError):
        raise corrupt("has an unreadable header") from None
    if not isinstance(header, dict) or set(header) != {"descr", "shape", "fortran_order"}:
        raise corrupt("has a malformed header")
    shape, fortran, descr = header["shape"], header["fortran_order"], header["descr"]
    if not isinstance(shape, tuple) or not all(type(n) is int and n >= 0 for n in shape) or type(fortran) is not bool:
        raise corrupt("has a malformed header")
    if not isinstance(descr, str):
        raise CalibrationFileError(f"calibration array {name!r} is a structured array, not a field", path)
    try:
        dtype = np.dtype(descr)
    except (TypeError, ValueError):
        raise corrupt(f"has an unknown dtype {descr[:40]!r}") from None
    return dtype, fortran, shape, 8 + size_bytes + length
