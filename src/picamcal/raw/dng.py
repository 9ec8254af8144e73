"""DNG raw files: checked and read through LibRaw (rawpy), written by a small TIFF writer of this module.

Only this module knows the DNG tag layout. The reader first reads the TIFF structure itself, only the bytes it
needs, and checks every tag it relies on (type, count and value, DNG specification 1.4) and the raw image's
declared size (:func:`picamcal.limits.check_size`) before anything is decoded; then it takes the mosaic, CFA
pattern, per-site black levels and white level from LibRaw, and the exposure, capture date and colour tags from
the TIFF tags. The writer makes an
uncompressed DNG 1.4 that LibRaw reads back bit-exactly: IFD 0 with the mosaic in one strip and the DNG colour
tags, and an EXIF IFD with the exposure time, ISO and capture date (docs/dng.md).

Colour (DNG specification 1.4, chapter 6 "Mapping Camera Color Space to CIE XYZ Space"): with the camera's
white-balance gains ``g = (g_R, 1, g_B)`` (picamera2's ``ColourGains``) and its colour correction matrix ``C``
(``ColourCorrectionMatrix``, libcamera's ``rpi.ccm``: white-balanced camera RGB to linear sRGB), the file carries

- ``AsShotNeutral = 1 / g``: the camera's raw response to the scene's white;
- ``ColorMatrix1 = (M_sRGB->XYZ C diag(g))^-1``: XYZ to camera RGB, so that the D65 white maps to the neutral;
- ``ForwardMatrix1 = B_D65->D50 M_sRGB->XYZ C``: white-balanced camera RGB to XYZ D50 (Bradford adaptation),
  so that camera white (1, 1, 1) maps to the D50 white;
- ``CalibrationIlluminant1 = 21`` (D65): the matrices are built through sRGB, whose white is D65.

Without a CCM ``C`` is the identity (camera RGB, once white-balanced, is shown as linear sRGB), and without gains
``g = 1`` (the white is not known: no balance).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import struct
import sys
import tempfile
import threading
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from fractions import Fraction
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .._atomic import atomic_path
from .._json import parse_json
from .._version import __version__
from ..errors import OutputError, PicamcalWarning, RawFormatError, short
from ..limits import check_size, require_regular_file
from ..records import json_default
from ..sensors import find_sensor_name
from .model import PATTERNS, RawImage, require_black_level

__all__ = ["is_dng", "read_dng", "write_dng"]

# TIFF 6.0 / TIFF-EP / EXIF 2.32 / DNG 1.4 tag codes.
_NEW_SUBFILE_TYPE, _IMAGE_WIDTH, _IMAGE_LENGTH, _BITS_PER_SAMPLE, _COMPRESSION = 254, 256, 257, 258, 259
_PHOTOMETRIC, _IMAGE_DESCRIPTION, _MAKE, _MODEL, _STRIP_OFFSETS = 262, 270, 271, 272, 273
_ORIENTATION, _SAMPLES_PER_PIXEL, _ROWS_PER_STRIP, _STRIP_BYTE_COUNTS = 274, 277, 278, 279
_PLANAR_CONFIGURATION, _SOFTWARE, _DATE_TIME = 284, 305, 306
_TILE_WIDTH, _TILE_LENGTH, _TILE_OFFSETS, _TILE_BYTE_COUNTS, _SUB_IFDS = 322, 323, 324, 325, 330
_CFA_REPEAT_DIM, _CFA_PATTERN, _EXIF_IFD = 33421, 33422, 34665
_EXPOSURE_TIME, _ISO, _EXIF_VERSION, _DATE_TIME_ORIGINAL = 33434, 34855, 36864, 36867
_OFFSET_TIME, _OFFSET_TIME_ORIGINAL = 36880, 36881
_DNG_VERSION, _DNG_BACKWARD, _UNIQUE_MODEL, _CFA_PLANE_COLOR, _CFA_LAYOUT = 50706, 50707, 50708, 50710, 50711
_BLACK_REPEAT_DIM, _BLACK_LEVEL, _WHITE_LEVEL = 50713, 50714, 50717
_COLOR_MATRIX1, _AS_SHOT_NEUTRAL, _ILLUMINANT1, _FORWARD_MATRIX1 = 50721, 50728, 50778, 50964

_TAG_NAMES = {
    _NEW_SUBFILE_TYPE: "NewSubFileType", _IMAGE_WIDTH: "ImageWidth", _IMAGE_LENGTH: "ImageLength",
    _BITS_PER_SAMPLE: "BitsPerSample", _COMPRESSION: "Compression", _PHOTOMETRIC: "PhotometricInterpretation",
    _IMAGE_DESCRIPTION: "ImageDescription", _MAKE: "Make", _MODEL: "Model", _STRIP_OFFSETS: "StripOffsets",
    _SAMPLES_PER_PIXEL: "SamplesPerPixel", _ROWS_PER_STRIP: "RowsPerStrip", _STRIP_BYTE_COUNTS: "StripByteCounts",
    _PLANAR_CONFIGURATION: "PlanarConfiguration", _TILE_WIDTH: "TileWidth", _TILE_LENGTH: "TileLength",
    _TILE_OFFSETS: "TileOffsets", _TILE_BYTE_COUNTS: "TileByteCounts", _SUB_IFDS: "SubIFDs",
    _CFA_REPEAT_DIM: "CFARepeatPatternDim", _CFA_PATTERN: "CFAPattern", _EXIF_IFD: "ExifIFD",
    _EXPOSURE_TIME: "ExposureTime", _ISO: "ISOSpeedRatings", _DATE_TIME_ORIGINAL: "DateTimeOriginal",
    _DNG_VERSION: "DNGVersion", _UNIQUE_MODEL: "UniqueCameraModel", _CFA_PLANE_COLOR: "CFAPlaneColor",
    _CFA_LAYOUT: "CFALayout", _BLACK_REPEAT_DIM: "BlackLevelRepeatDim", _BLACK_LEVEL: "BlackLevel",
    _WHITE_LEVEL: "WhiteLevel", _COLOR_MATRIX1: "ColorMatrix1", _AS_SHOT_NEUTRAL: "AsShotNeutral",
    _ILLUMINANT1: "CalibrationIlluminant1", _FORWARD_MATRIX1: "ForwardMatrix1",
}  # fmt: skip

# TIFF field types (TIFF 6.0 section 2, and IFD of TIFF technical note 1), the struct code of one value (a
# rational is two) and their names for messages.
_BYTE, _ASCII, _SHORT, _LONG, _RATIONAL, _SBYTE, _UNDEFINED = 1, 2, 3, 4, 5, 6, 7
_SSHORT, _SLONG, _SRATIONAL, _FLOAT, _DOUBLE, _IFD = 8, 9, 10, 11, 12, 13
_STRUCT = {
    _BYTE: "B", _ASCII: "B", _SHORT: "H", _LONG: "I", _RATIONAL: "II", _SBYTE: "b", _UNDEFINED: "B",
    _SSHORT: "h", _SLONG: "i", _SRATIONAL: "ii", _FLOAT: "f", _DOUBLE: "d", _IFD: "I",
}  # fmt: skip
_TYPE_SIZE = {kind: struct.calcsize("<" + code) for kind, code in _STRUCT.items()}
_TYPE_NAMES = {
    _BYTE: "BYTE", _ASCII: "ASCII", _SHORT: "SHORT", _LONG: "LONG", _RATIONAL: "RATIONAL", _SBYTE: "SBYTE",
    _UNDEFINED: "UNDEFINED", _SSHORT: "SSHORT", _SLONG: "SLONG", _SRATIONAL: "SRATIONAL", _FLOAT: "FLOAT",
    _DOUBLE: "DOUBLE", _IFD: "IFD",
}  # fmt: skip

_CFA_CODES = {"R": 0, "G": 1, "B": 2}
_METADATA_KEY = "picamcal"
_CFA_PHOTOMETRIC, _LINEAR_RAW = 32803, 34892
_D65 = 21  # EXIF LightSource / DNG CalibrationIlluminant code
_DATA_ALIGNMENT = 16  # the strip starts on a 16-byte boundary (TIFF needs 2; aligned data maps cheaply)

# Linear sRGB (D65 white) to CIE XYZ, IEC 61966-2-1 (to 7 digits, as Bruce Lindbloom tabulates it).
_SRGB_TO_XYZ = np.array(
    [[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]]
)
# The Bradford cone response matrix, for the D65 -> D50 chromatic adaptation of the ForwardMatrix.
_BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])
_D50_XY = (0.3457, 0.3585)  # the DNG specification's D50, white of its profile connection space

# Limits of what the reader believes a DNG declares: a real DNG's tags are far smaller, its raw image is in IFD 0
# or one of a few SubIFDs, its black level repeats over a few pixels (LibRaw holds 4096 values at most).
_MAX_TAG_BYTES = 4 << 20
_MAX_SUB_IFDS = 16
_MAX_BLACK_REPEAT = 4096
_MAX_SAID_BYTES = 64 << 10  # of LibRaw's stderr, enough for its first few messages
_C_STDERR_LOCK = threading.Lock()

# Metadata keys that the colour tags carry: the tags are the truth, the JSON copy would go stale.
_COLOUR_KEYS = ("as_shot_neutral", "color_matrix1", "forward_matrix1", "calibration_illuminant1")


def is_dng(head: bytes) -> bool:
    """True if the first bytes of a file are a TIFF header (DNG is a TIFF).

    Examples
    --------
    >>> is_dng(b"II*\\x00\\x08\\x00\\x00\\x00"), is_dng(b"\\x89PNG")
    (True, False)
    """
    return head[:4] in (b"II*\x00", b"MM\x00*")


# --- reading: the TIFF structure, every offset, type and count checked ------------------------------------------


@dataclass(frozen=True)
class _Field:
    """One IFD entry as found: tag code, field type, value count and the file offset of its values."""

    code: int
    type: int
    count: int
    at: int


class _TiffFile:
    """A TIFF file's IFDs and tag values, read on demand: only the bytes asked for, each range checked first.

    Nothing here trusts a count or an offset: a value that lies past the end of the file, a tag of another type
    or count than the DNG specification gives, a zero denominator or a non-finite number is a
    :class:`~picamcal.errors.RawFormatError` naming the tag.
    """

    def __init__(self, f: BinaryIO, size: int, path: Path) -> None:
        self.f, self.size, self.path = f, size, path
        head = self.read(0, 8, "the TIFF header")
        orders = {b"II*\x00": "<", b"MM\x00*": ">"}
        if head[:4] not in orders:
            raise RawFormatError("not a DNG: no TIFF header (II*/MM*; a BigTIFF is not a DNG)", path)
        self.order = orders[head[:4]]
        self.first_ifd = struct.unpack(self.order + "I", head[4:])[0]

    def read(self, offset: int, length: int, what: str) -> bytes:
        if offset + length > self.size:
            raise RawFormatError(
                f"corrupt TIFF/DNG structure: {what} (bytes {offset} to {offset + length}) lies beyond the end of "
                f"the file ({self.size} bytes): a truncated file?",
                self.path,
            )
        self.f.seek(offset)
        data = self.f.read(length)
        if len(data) != length:  # the file shrank while it was read
            raise RawFormatError(f"truncated file: {what} ends early", self.path)
        return data

    def ifd(self, offset: int, what: str) -> dict[int, _Field]:
        """The entries of the IFD at ``offset`` by tag code (TIFF forbids repeated tags: the first one counts)."""
        (count,) = struct.unpack(self.order + "H", self.read(offset, 2, what))
        if count == 0:
            raise RawFormatError(f"corrupt TIFF/DNG structure: {what} has no entries", self.path)
        table = self.read(offset + 2, 12 * count, what)
        fields: dict[int, _Field] = {}
        for start in range(0, 12 * count, 12):
            code, kind, values = struct.unpack_from(self.order + "HHI", table, start)
            at = offset + 2 + start + 8
            if _TYPE_SIZE.get(kind, 0) * values > 4:  # longer values lie elsewhere, at the offset given
                at = struct.unpack_from(self.order + "I", table, start + 8)[0]
            fields.setdefault(code, _Field(code, kind, values, at))
        return fields

    def tag(
        self,
        ifd: Mapping[int, _Field],
        code: int,
        types: Sequence[int],
        count: int | None = None,
        *,
        default: Any = None,
        positive: bool = False,
    ) -> Any:
        """The values of tag ``code``: a list of numbers (rationals divided out), or text for ASCII.

        ``types`` are the field types the specification allows, ``count`` the number of values it needs (None: at
        least one), ``positive`` requires every value above 0; ``default`` is returned when the tag is absent.
        """
        field = ifd.get(code)
        if field is None:
            return default
        name = _TAG_NAMES.get(code, f"#{code}")
        if field.type not in types:
            allowed = " or ".join(_TYPE_NAMES[t] for t in types)
            kind = _TYPE_NAMES.get(field.type, f"unknown type {field.type}")
            raise RawFormatError(f"DNG tag {name} is of type {kind}, not {allowed}", self.path)
        if field.count == 0 or (count is not None and field.count != count):
            raise RawFormatError(f"DNG tag {name} has {field.count} values, not {count or 'at least 1'}", self.path)
        nbytes = _TYPE_SIZE[field.type] * field.count
        if nbytes > _MAX_TAG_BYTES:
            raise RawFormatError(f"DNG tag {name} declares {field.count} values, more than a DNG tag holds", self.path)
        data = self.read(field.at, nbytes, f"the value of DNG tag {name}")
        if field.type == _ASCII:
            return _text(data)
        if field.type in (_BYTE, _UNDEFINED):
            values: list[Any] = list(data)
        else:
            code_of_one = _STRUCT[field.type]
            flat = struct.unpack(f"{self.order}{len(code_of_one) * field.count}{code_of_one[0]}", data)
            if field.type in (_RATIONAL, _SRATIONAL):
                if any(den == 0 for den in flat[1::2]):
                    raise RawFormatError(f"DNG tag {name} has a zero denominator: {_short(flat)}", self.path)
                values = [num / den for num, den in zip(flat[::2], flat[1::2], strict=True)]
            else:
                values = list(flat)
        if not all(math.isfinite(v) for v in values):
            raise RawFormatError(f"DNG tag {name} has a value that is not finite: {_short(values)}", self.path)
        if positive and not all(v > 0 for v in values):
            raise RawFormatError(f"DNG tag {name} must be positive, not {_short(values)}", self.path)
        return values

    def one(self, ifd: Mapping[int, _Field], code: int, types: Sequence[int], default: Any = None) -> Any:
        """The single value of tag ``code`` (a count other than 1 is an error), or ``default`` when absent."""
        values = self.tag(ifd, code, types, 1)
        return default if values is None else values[0]


def _text(data: bytes) -> str:
    """ASCII tag bytes as text: up to the first NUL, undecodable bytes replaced, no control characters."""
    text = data.split(b"\x00", 1)[0].decode("utf-8", "replace")
    return "".join(c if c.isprintable() else " " for c in text).strip()


def _short(values: Any) -> str:
    """A tag's value for a one-line message (a tuple of values shown as a list)."""
    return short(list(values) if isinstance(values, tuple) else values)


def _raw_ifd(tiff: _TiffFile, ifd0: Mapping[int, _Field]) -> Mapping[int, _Field]:
    """The IFD of the raw mosaic: IFD 0 or the first SubIFD whose NewSubFileType is 0 (DNG 1.4, chapter 3)."""
    if tiff.one(ifd0, _NEW_SUBFILE_TYPE, (_SHORT, _LONG), default=0) == 0:
        return ifd0
    offsets = tiff.tag(ifd0, _SUB_IFDS, (_LONG, _IFD), default=[])
    if len(offsets) > _MAX_SUB_IFDS:
        raise RawFormatError(f"DNG tag SubIFDs lists {len(offsets)} images, more than a DNG holds", tiff.path)
    for n, offset in enumerate(offsets):
        ifd = tiff.ifd(offset, f"SubIFD {n + 1}")
        if tiff.one(ifd, _NEW_SUBFILE_TYPE, (_SHORT, _LONG), default=0) == 0:
            return ifd
    raise RawFormatError("no raw image in it: no IFD has NewSubFileType 0 (the DNG's main image)", tiff.path)


def _check_raw_ifd(tiff: _TiffFile, ifd: Mapping[int, _Field]) -> None:
    """Check what the raw IFD declares before LibRaw decodes it: the size first, then the mosaic's tags and data.

    Every tag that decides the pixels, their colours or their levels must be as the DNG specification gives it;
    strips and tiles must lie inside the file and, uncompressed, hold the rows they declare.
    """
    path, integer = tiff.path, (_SHORT, _LONG)
    width, height = tiff.one(ifd, _IMAGE_WIDTH, integer), tiff.one(ifd, _IMAGE_LENGTH, integer)
    if width is None or height is None:
        raise RawFormatError("the raw image has no ImageWidth or ImageLength tag", path)
    check_size(path, width, height)
    if tiff.one(ifd, _SAMPLES_PER_PIXEL, (_SHORT,), default=1) != 1:
        raise RawFormatError("DNG tag SamplesPerPixel is not 1: not a colour filter array mosaic", path)
    photometric = tiff.one(ifd, _PHOTOMETRIC, (_SHORT,))
    if photometric != _CFA_PHOTOMETRIC:
        kind = (
            "LinearRaw, already demosaiced"
            if photometric == _LINEAR_RAW
            else f"PhotometricInterpretation {photometric}"
        )
        raise RawFormatError(f"not a Bayer mosaic ({kind}): picamcal reads colour filter array raw images", path)
    bits = tiff.one(ifd, _BITS_PER_SAMPLE, (_SHORT,), default=1)
    if not 1 <= bits <= 16:
        raise RawFormatError(f"DNG tag BitsPerSample is {bits}: LibRaw reads integer samples of 1 to 16 bits", path)
    compression = tiff.one(ifd, _COMPRESSION, (_SHORT,), default=1)
    if tiff.one(ifd, _PLANAR_CONFIGURATION, (_SHORT,), default=1) not in (1, 2):
        raise RawFormatError("DNG tag PlanarConfiguration is neither 1 nor 2", path)
    _check_cfa(tiff, ifd)
    repeat = tiff.tag(ifd, _BLACK_REPEAT_DIM, (_SHORT,), 2, default=[1, 1], positive=True)
    if repeat[0] * repeat[1] > _MAX_BLACK_REPEAT:
        raise RawFormatError(f"DNG tag BlackLevelRepeatDim is {repeat[0]}x{repeat[1]}, larger than LibRaw reads", path)
    black = tiff.tag(ifd, _BLACK_LEVEL, (_SHORT, _LONG, _RATIONAL), repeat[0] * repeat[1], default=[0])
    white = tiff.one(ifd, _WHITE_LEVEL, integer, default=(1 << bits) - 1)
    if not max(black) < white <= 0xFFFF:
        raise RawFormatError(f"DNG tag WhiteLevel {white} is not between the black level {max(black)} and 65535", path)
    _check_data(tiff, ifd, width, height, bits, compression)


def _check_cfa(tiff: _TiffFile, ifd: Mapping[int, _Field]) -> None:
    """A 2x2 Bayer pattern of red, green and blue on a rectangular grid (CFA tags of TIFF/EP and DNG)."""
    path = tiff.path
    dims = tiff.tag(ifd, _CFA_REPEAT_DIM, (_SHORT,), 2)
    codes = tiff.tag(ifd, _CFA_PATTERN, (_BYTE, _UNDEFINED))
    if dims is None or codes is None:
        raise RawFormatError("the raw image has no CFARepeatPatternDim or CFAPattern tag", path)
    if dims != [2, 2] or len(codes) != 4:
        raise RawFormatError(
            f"DNG tags CFARepeatPatternDim {dims} and CFAPattern {_short(codes)}: picamcal reads 2x2 Bayer patterns",
            path,
        )
    planes = tiff.tag(ifd, _CFA_PLANE_COLOR, (_BYTE,), 3, default=[0, 1, 2])
    if sorted(planes) != [0, 1, 2]:
        raise RawFormatError(f"DNG tag CFAPlaneColor {planes} is not red, green and blue", path)
    pattern = "".join("RGB"[planes[c]] if c < 3 else "?" for c in codes)
    if pattern not in PATTERNS:
        raise RawFormatError(f"DNG tag CFAPattern {codes} is not a Bayer pattern ({pattern})", path)
    if tiff.one(ifd, _CFA_LAYOUT, (_SHORT,), default=1) != 1:
        raise RawFormatError("DNG tag CFALayout is not 1: picamcal reads rectangular colour filter arrays", path)


def _check_data(tiff: _TiffFile, ifd: Mapping[int, _Field], width: int, height: int, bits: int, compression: int):
    """Strips or tiles inside the file; uncompressed, each as long as the rows it declares."""
    path, integer = tiff.path, (_SHORT, _LONG)
    row_bytes = -(-width * bits // 8)
    if _TILE_WIDTH in ifd or _TILE_OFFSETS in ifd:
        unit, codes = "tile", (_TILE_OFFSETS, _TILE_BYTE_COUNTS)
        tile_width, tile_length = tiff.one(ifd, _TILE_WIDTH, integer), tiff.one(ifd, _TILE_LENGTH, integer)
        if not (tile_width and tile_length):
            raise RawFormatError("DNG tags TileWidth and TileLength must be given and positive", path)
        count = -(-width // tile_width) * -(-height // tile_length)
    else:
        unit, codes = "strip", (_STRIP_OFFSETS, _STRIP_BYTE_COUNTS)
        rows = min(tiff.one(ifd, _ROWS_PER_STRIP, integer, default=height), height)
        if rows < 1:
            raise RawFormatError("DNG tag RowsPerStrip is 0", path)
        count = -(-height // rows)
    # Read (and so bounded by the largest tag) before anything is allocated per strip or tile.
    offsets, lengths = (tiff.tag(ifd, code, integer, count) for code in codes)
    if offsets is None or lengths is None:
        raise RawFormatError(f"the raw image has no {_TAG_NAMES[codes[0]]} or {_TAG_NAMES[codes[1]]} tag", path)
    lengths = np.asarray(lengths, dtype=np.int64)
    ends = np.asarray(offsets, dtype=np.int64) + lengths
    if ends.max() > tiff.size:
        k = int(np.argmax(ends > tiff.size))
        raise RawFormatError(
            f"truncated file: {unit} {k + 1} of {count} of the raw image ends at byte {ends[k]}, "
            f"but the file has {tiff.size} bytes",
            path,
        )
    if compression != 1:
        return
    if unit == "tile":
        needed = np.full(count, tile_length * -(-tile_width * bits // 8), dtype=np.int64)
    else:
        needed = np.minimum(rows, height - rows * np.arange(count, dtype=np.int64)) * row_bytes
    if np.any(lengths < needed):
        k = int(np.argmax(lengths < needed))
        raise RawFormatError(
            f"DNG tag {_TAG_NAMES[codes[1]]}: uncompressed {unit} {k + 1} holds {lengths[k]} bytes, "
            f"but its {bits}-bit samples need {needed[k]}",
            path,
        )


def _optional(problems: list[str], read: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``read(*args)``, or None with the reason noted in ``problems`` if the metadata it reads is malformed."""
    try:
        return read(*args, **kwargs)
    except RawFormatError as exc:
        problems.append(exc.problem)
        return None


def _tag_metadata(tiff: _TiffFile, ifd0: Mapping[int, _Field], problems: list[str]) -> dict[str, Any]:
    """Make, model, exposure, capture date, colour tags and picamcal's own record, from IFD 0 and the EXIF IFD.

    All of these are informative: a malformed one is left out and noted in ``problems`` (which become one
    warning), never an error.
    """
    meta: dict[str, Any] = {}
    for code, key in ((_MAKE, "make"), (_MODEL, "model"), (_UNIQUE_MODEL, "unique_camera_model")):
        text = _optional(problems, tiff.tag, ifd0, code, (_ASCII,))
        if text:
            meta[key] = text
    exif: Mapping[int, _Field] = {}
    exif_at = _optional(problems, tiff.one, ifd0, _EXIF_IFD, (_LONG, _IFD))
    if exif_at is not None:
        exif = _optional(problems, tiff.ifd, exif_at, "the EXIF IFD") or {}
    # Earlier picamcal DNGs (and some other writers) put the exposure tags in IFD 0: keep reading those.
    for key, code, types in (("exposure_time_s", _EXPOSURE_TIME, (_RATIONAL,)), ("iso", _ISO, (_SHORT, _LONG))):
        for ifd in (exif, ifd0):
            values = _optional(
                problems, tiff.tag, ifd, code, types, 1 if key == "exposure_time_s" else None, positive=True
            )
            if values is not None:
                meta[key] = values[0] if key == "exposure_time_s" else int(values[0])
                break
    stamp = _optional(problems, tiff.tag, exif, _DATE_TIME_ORIGINAL, (_ASCII,))
    if stamp:
        meta["timestamp"] = stamp
    colour = {
        "as_shot_neutral": _optional(problems, tiff.tag, ifd0, _AS_SHOT_NEUTRAL, (_SHORT, _RATIONAL), 3, positive=True),
        "color_matrix1": _optional(problems, tiff.tag, ifd0, _COLOR_MATRIX1, (_SRATIONAL,), 9),
        "forward_matrix1": _optional(problems, tiff.tag, ifd0, _FORWARD_MATRIX1, (_SRATIONAL,), 9),
        "calibration_illuminant1": _optional(problems, tiff.one, ifd0, _ILLUMINANT1, (_SHORT,)),
    }
    description = _optional(problems, tiff.tag, ifd0, _IMAGE_DESCRIPTION, (_ASCII,))
    meta.update(_recorded(description, problems))
    # The tags are the truth for colour: a JSON copy could only disagree.
    meta.update({key: values for key, values in colour.items() if values is not None})
    return meta


def _finite(value: Any) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond any float
        return False


def _positive(value: Any) -> bool:
    return _finite(value) and value > 0


def _numbers_of(length: int, each: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda value: isinstance(value, list) and len(value) == length and all(each(v) for v in value)


#: What picamcal's readers put under each metadata key that code downstream uses (key: (description, test)).
_RECORD_KEYS: dict[str, tuple[str, Callable[[Any], bool]]] = {
    "sensor": ("a sensor name", lambda v: isinstance(v, str)),
    **{key: ("text", lambda v: isinstance(v, str)) for key in ("make", "model", "timestamp")},
    **{
        key: ("a positive number", _positive)
        for key in ("exposure_time_s", "analogue_gain", "digital_gain", "colour_temperature")
    },
    "lux": ("a number of at least 0", lambda v: _finite(v) and v >= 0),
    "iso": ("a positive whole number", lambda v: _positive(v) and isinstance(v, int)),
    "sensor_timestamp_ns": ("a whole number", lambda v: _finite(v) and isinstance(v, int)),
    "colour_gains": ("2 positive numbers", _numbers_of(2, _positive)),
    "colour_correction_matrix": ("9 finite numbers", _numbers_of(9, _finite)),
    "sensor_size": ("2 positive whole numbers", _numbers_of(2, lambda v: _positive(v) and isinstance(v, int))),
}


def _recorded(text: str | None, problems: list[str]) -> dict[str, Any]:
    """The metadata picamcal recorded as JSON in ImageDescription, each value it relies on checked.

    Another writer's description (not a JSON object) is passed over; a malformed record, or a value of the wrong
    kind under a key picamcal uses, is left out and noted in ``problems``; null under such a key means unknown.
    """
    if not text or not text.startswith("{"):
        return {}
    try:
        record = parse_json(text, RawFormatError, "JSON")
    except RawFormatError as exc:
        problems.append(f"ImageDescription: {exc.problem}")
        return {}
    ours = record.get(_METADATA_KEY) if isinstance(record, dict) else None
    if ours is None:
        return {}
    if not isinstance(ours, dict):
        problems.append(f"ImageDescription's {_METADATA_KEY!r} record is not a JSON object")
        return {}
    kept = {}
    for key, value in ours.items():
        what, test = _RECORD_KEYS.get(key, ("", lambda v: True))
        if value is None and key in _RECORD_KEYS:
            continue  # not known (the writer records NaN so)
        if test(value):
            kept[key] = value
        else:
            problems.append(f"ImageDescription's {key} is {_short(value)}, not {what}")
    return kept


# --- reading: LibRaw ------------------------------------------------------------------------------------------


@contextlib.contextmanager
def _c_stderr(said: list[str]) -> Iterator[None]:
    """Capture what C code (LibRaw) writes to the process's stderr meanwhile; its lines land in ``said``.

    LibRaw prints its data errors ("data corrupted at 352", "Unexpected end of file") to file descriptor 2
    itself, which would add lines to picamcal's one-line error. The descriptor is pointed at a temporary file and
    restored however the block ends; a lock keeps two threads from swapping it under each other (what another
    thread writes to stderr meanwhile is caught too).
    """
    with _C_STDERR_LOCK, tempfile.TemporaryFile() as sink:
        with contextlib.suppress(AttributeError, OSError, ValueError):  # no sys.stderr, or a closed one
            sys.stderr.flush()
        try:
            saved = os.dup(2)
        except OSError:  # no descriptor 2 at all (a daemon): nothing to capture
            saved = None
        if saved is None:
            yield
            return
        try:
            os.dup2(sink.fileno(), 2)
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read(_MAX_SAID_BYTES).decode("utf-8", "replace")
            said.extend(line.strip() for line in text.splitlines() if line.strip())


def _libraw_said(said: list[str], path: Path) -> str:
    """LibRaw's own messages, once each and without the file name it puts in front, for a one-line message."""
    prefix = f"{path}: "
    lines = list(dict.fromkeys(line.removeprefix(prefix) for line in said))
    text = "; ".join(lines[:3]) + ("; ..." if len(lines) > 3 else "")
    return text if len(text) <= 200 else text[:197] + "..."


def _libraw_error(exc: BaseException) -> str:
    message = exc.args[0] if exc.args else ""
    message = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


def _check_libraw_sizes(path: Path, sizes: Any, expected_shape: Sequence[int] | None) -> tuple[int, int]:
    """Check the sizes LibRaw found before it allocates the mosaic; the visible area's even (height, width)."""
    check_size(path, int(sizes.raw_width), int(sizes.raw_height))
    height, width = int(sizes.height), int(sizes.width)
    if (
        height < 2
        or width < 2
        or sizes.top_margin + height > sizes.raw_height
        or sizes.left_margin + width > sizes.raw_width
    ):
        raise RawFormatError(
            f"corrupt file: LibRaw finds a visible area of {width}x{height} at ({sizes.left_margin}, "
            f"{sizes.top_margin}) in a {sizes.raw_width}x{sizes.raw_height} mosaic",
            path,
        )
    shape = (height // 2 * 2, width // 2 * 2)
    check_size(path, shape[1], shape[0], expected_shape)
    return shape


def _decode(
    path: Path, expected_shape: Sequence[int] | None, problems: list[str]
) -> tuple[np.ndarray, str, tuple, int, str]:
    """The visible mosaic (even-sized), its pattern, per-site black levels and white level, from LibRaw.

    Returns also what LibRaw printed while reading ("" if nothing), for a warning when it still succeeded. If
    LibRaw fails, the error says what it printed and the malformed metadata picamcal found (``problems``): LibRaw
    gives up on some of it (an EXIF IFD past the end of the file) with nothing more than "Input/output error".
    """
    import rawpy

    failures = (rawpy.LibRawError, rawpy.NotSupportedError, NotImplementedError, MemoryError, OSError)
    said: list[str] = []
    try:
        with _c_stderr(said), rawpy.RawPy() as rp:
            rp.open_file(os.fspath(path))
            height, width = _check_libraw_sizes(path, rp.sizes, expected_shape)
            rp.unpack()
            desc = rp.color_desc.decode("latin-1")
            cfa = rp.raw_colors_visible[:2, :2].ravel().tolist() if rp.raw_pattern is not None else []
            per_channel = [float(v) for v in rp.black_level_per_channel]
            if rp.num_colors != 3 or len(cfa) != 4 or max(cfa) >= min(len(desc), len(per_channel)):
                raise RawFormatError("not a Bayer raw image (LibRaw finds no 2x2 colour filter pattern)", path)
            white = int(rp.white_level)
            bayer = np.array(rp.raw_image_visible[:height, :width], dtype=np.uint16, copy=True)
    except failures as exc:
        told = f"; LibRaw said: {_libraw_said(said, path)}" if said else ""
        told += f"; malformed: {'; '.join(problems)}" if problems else ""
        raise RawFormatError(f"LibRaw cannot read it as a raw image ({_libraw_error(exc)}{told})", path) from exc
    pattern = "".join(desc[i] for i in cfa)
    if pattern not in PATTERNS:
        raise RawFormatError(f"unsupported colour filter pattern {pattern!r}", path)
    black = tuple(per_channel[i] for i in cfa)
    if not (all(math.isfinite(b) and b >= 0 for b in black) and max(black) < white <= 0xFFFF):
        raise RawFormatError(f"LibRaw finds black levels {list(black)} and white level {white}: no usable range", path)
    return bayer, pattern, black, white, _libraw_said(said, path) if said else ""


def read_dng(path: str | os.PathLike[str], *, expected_shape: Sequence[int] | None = None) -> RawImage:
    """Read a DNG file's Bayer mosaic and metadata, checking what it declares before decoding anything.

    First the file's TIFF structure is read and checked by picamcal itself, only the bytes it needs: the raw
    image's declared size against :func:`picamcal.limits.check_size`, its strips or tiles against the file's
    length, and every tag that decides the pixels or their levels (SamplesPerPixel, BitsPerSample,
    PhotometricInterpretation, CFARepeatPatternDim, CFAPattern, CFAPlaneColor, CFALayout, BlackLevelRepeatDim,
    BlackLevel, WhiteLevel, the strip or tile tags, SubIFDs, NewSubFileType) against the DNG specification's
    types, counts and values. Then LibRaw (rawpy) opens the file; the sizes it finds are checked again, and
    against ``expected_shape``, before it decodes the mosaic. What LibRaw prints on stderr is folded into the
    error (or into a warning, if the read still succeeds).

    Informative metadata (Make, Model, UniqueCameraModel, the EXIF IFD and its ExposureTime, ISOSpeedRatings and
    DateTimeOriginal, AsShotNeutral, ColorMatrix1, ForwardMatrix1, CalibrationIlluminant1, and picamcal's JSON
    record in ImageDescription) is checked the same way, but a malformed value is left out with one
    :class:`~picamcal.errors.PicamcalWarning` naming the tags, not an error.

    Parameters
    ----------
    path : path-like
        A DNG file (picamera2's ``save_dng``, PiDNG, rpicam-apps, any camera's DNG, or :func:`write_dng`).
    expected_shape : (height, width), optional
        The mosaic size the caller needs (the calibration's): another size is refused before decoding.

    Returns
    -------
    RawImage
        Mosaic of the visible area, the CFA pattern and per-site black levels as LibRaw reports them. The
        metadata holds, when the file has them: ``exposure_time_s``, ``iso``, ``timestamp`` (EXIF
        ``DateTimeOriginal``, ``"YYYY:MM:DD HH:MM:SS"``), ``make``, ``model``, ``unique_camera_model``, the
        colour tags ``as_shot_neutral`` (3 floats), ``color_matrix1`` and ``forward_matrix1`` (9 floats each,
        row-major) and ``calibration_illuminant1`` (int), and what picamcal recorded in the file.

    Raises
    ------
    RawFormatError
        Not a regular file, not a DNG, truncated, a size over :func:`picamcal.limits.max_pixels`, a tag that
        decides the pixels malformed, or LibRaw cannot decode it.
    CalibrationFileError
        The mosaic is not ``expected_shape``.

    Examples
    --------
    >>> raw = read_dng("white.dng")  # doctest: +SKIP
    >>> raw.pattern, raw.black_level  # doctest: +SKIP
    ('BGGR', (64.0, 64.0, 64.0, 64.0))
    >>> raw.metadata["as_shot_neutral"]  # doctest: +SKIP
    [0.5, 1.0, 0.97]
    >>> read_dng("white.dng", expected_shape=(1232, 1640))  # doctest: +SKIP
    Traceback (most recent call last):
    ...
    picamcal.errors.CalibrationFileError: white.dng: image does not match the calibration: size 3280x2464, ...
    """
    path = Path(path)
    require_regular_file(path)
    problems: list[str] = []
    try:
        with open(path, "rb") as f:
            tiff = _TiffFile(f, os.fstat(f.fileno()).st_size, path)
            ifd0 = tiff.ifd(tiff.first_ifd, "IFD 0")
            if tiff.tag(ifd0, _DNG_VERSION, (_BYTE,), 4) is None:
                raise RawFormatError("a TIFF file but not a DNG raw image (no DNGVersion tag)", path)
            _check_raw_ifd(tiff, _raw_ifd(tiff, ifd0))
            meta = _tag_metadata(tiff, ifd0, problems)
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from exc
    bayer, pattern, black, white, said = _decode(path, expected_shape, problems)
    if problems:
        warnings.warn(f"{path}: malformed metadata left out: {'; '.join(problems)}", PicamcalWarning, stacklevel=2)
    if said:
        warnings.warn(f"{path}: LibRaw reported a problem but read it: {said}", PicamcalWarning, stacklevel=2)
    meta["format"] = "dng"
    meta["path"] = str(path)
    sensor = (
        meta.pop("sensor", None)
        or find_sensor_name(meta.get("unique_camera_model"))
        or find_sensor_name(meta.get("model"))
    )
    return RawImage(bayer, pattern, black, white, max(white.bit_length(), 8), sensor, meta)  # type: ignore[arg-type]


# --- colour ----------------------------------------------------------------------------------------------------


def _d65_to_d50() -> np.ndarray:
    """Bradford adaptation from the sRGB white (D65) to the DNG profile connection space's D50."""
    x, y = _D50_XY
    d50 = np.array([x / y, 1.0, (1.0 - x - y) / y])
    d65 = _SRGB_TO_XYZ @ np.ones(3)
    cones = (_BRADFORD @ d50) / (_BRADFORD @ d65)
    return np.linalg.inv(_BRADFORD) @ np.diag(cones) @ _BRADFORD


def _vector(meta: Mapping[str, Any], key: str, length: int, source: str) -> np.ndarray | None:
    """``meta[key]`` as ``length`` finite floats, None if absent; anything else is an error naming the key."""
    value = meta.get(key)
    if value is None:
        return None
    try:
        array = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        array = np.empty(0)
    if array.size != length or not np.all(np.isfinite(array)):
        raise RawFormatError(f"metadata {key} must be {length} finite numbers, not {value!r}", source)
    return array


def _colour_tags(raw: RawImage) -> dict[str, Any]:
    """AsShotNeutral, ColorMatrix1, ForwardMatrix1 and CalibrationIlluminant1 from what ``raw`` knows.

    The neutral comes from ``colour_gains`` (else a DNG's ``as_shot_neutral``, else no balance); the matrices
    from ``colour_correction_matrix`` (else a DNG's own matrices, else the identity CCM).
    """
    meta, source = raw.metadata, raw.source
    gains = _vector(meta, "colour_gains", 2, source)
    neutral = _vector(meta, "as_shot_neutral", 3, source)
    if gains is not None:
        if np.any(gains <= 0):
            raise RawFormatError(f"metadata colour_gains must be positive, not {gains.tolist()}", source)
        neutral = np.array([1.0 / gains[0], 1.0, 1.0 / gains[1]])
    elif neutral is None:
        neutral = np.ones(3)
    elif np.any(neutral <= 0):
        raise RawFormatError(f"metadata as_shot_neutral must be positive, not {neutral.tolist()}", source)
    ccm = _vector(meta, "colour_correction_matrix", 9, source)
    kept = _vector(meta, "color_matrix1", 9, source)
    if ccm is None and kept is not None:  # a DNG read back without a CCM keeps its own calibration
        forward = _vector(meta, "forward_matrix1", 9, source)
        illuminant = int(meta.get("calibration_illuminant1") or _D65)
        return {"neutral": neutral, "color": kept.reshape(3, 3), "forward": forward, "illuminant": illuminant}
    ccm = np.eye(3) if ccm is None else ccm.reshape(3, 3)
    camera_to_xyz = _SRGB_TO_XYZ @ ccm @ np.diag(1.0 / neutral)
    if abs(np.linalg.det(camera_to_xyz)) < 1e-9:
        raise RawFormatError(f"metadata colour_correction_matrix is singular: {ccm.ravel().tolist()}", source)
    forward = _d65_to_d50() @ _SRGB_TO_XYZ @ ccm
    return {"neutral": neutral, "color": np.linalg.inv(camera_to_xyz), "forward": forward, "illuminant": _D65}


# --- writing ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Entry:
    """One IFD entry: tag code, field type, value count and the values' bytes (little-endian)."""

    code: int
    type: int
    count: int
    data: bytes


def _entry(code: int, kind: int, values: Any) -> _Entry:
    """Encode values of a field type: text for ASCII, bytes for BYTE/UNDEFINED, numbers otherwise."""
    if kind == _ASCII:
        data = str(values).encode("ascii", "replace") + b"\x00"
        return _Entry(code, kind, len(data), data)
    if kind in (_BYTE, _UNDEFINED):
        data = bytes(values)
        return _Entry(code, kind, len(data), data)
    numbers = list(values) if isinstance(values, Iterable) else [values]
    flat: list[int] = []
    for number in numbers:
        flat.extend(_rational(number, signed=kind == _SRATIONAL) if kind in (_RATIONAL, _SRATIONAL) else [number])
    data = struct.pack(f"<{len(flat)}{_STRUCT[kind][0]}", *flat)
    return _Entry(code, kind, len(numbers), data)


def _rational(value: float, *, signed: bool = False) -> tuple[int, int]:
    """The nearest fraction with a denominator up to 10**6 that fits the TIFF (S)RATIONAL field."""
    limit = 2**31 - 1 if signed else 2**32 - 1
    if not math.isfinite(value) or (value < 0 and not signed) or abs(value) > limit:
        raise OutputError(f"{value} does not fit a TIFF {'signed ' if signed else ''}rational")
    f = Fraction(value).limit_denominator(1_000_000)
    while abs(f.numerator) > limit or f.denominator > limit:
        f = f.limit_denominator(max(1, f.denominator // 10))
    return f.numerator, f.denominator


def _ifd(entries: Sequence[_Entry], offset: int) -> bytes:
    """An IFD placed at ``offset`` (even), followed by its values longer than 4 bytes, each at an even offset.

    Entries are written in ascending tag order (TIFF 6.0 section 2) and the next-IFD offset is 0.
    """
    entries = sorted(entries, key=lambda e: e.code)
    table = bytearray(struct.pack("<H", len(entries)))
    values = bytearray()
    values_at = offset + 2 + 12 * len(entries) + 4
    for e in entries:
        if len(e.data) <= 4:
            table += struct.pack("<HHI", e.code, e.type, e.count) + e.data.ljust(4, b"\x00")
        else:
            table += struct.pack("<HHII", e.code, e.type, e.count, values_at + len(values))
            values += e.data + b"\x00" * (len(e.data) % 2)
    return bytes(table + struct.pack("<I", 0) + values)


def _align(offset: int, to: int) -> int:
    return -(-offset // to) * to


def _exif_datetime(stamp: Any) -> tuple[str, str | None] | None:
    """An EXIF date ``"YYYY:MM:DD HH:MM:SS"`` and its UTC offset ``"+HH:MM"`` (if known) from a timestamp."""
    if isinstance(stamp, datetime):
        moment = stamp
    elif isinstance(stamp, str):
        text = stamp.strip("\x00 ")
        try:
            moment = datetime.strptime(text, "%Y:%m:%d %H:%M:%S")
        except ValueError:
            try:
                moment = datetime.fromisoformat(text)
            except ValueError:
                return None
    else:
        return None
    offset = moment.strftime("%z")
    return moment.strftime("%Y:%m:%d %H:%M:%S"), f"{offset[:3]}:{offset[3:]}" if offset else None


def _exif_entries(meta: Mapping[str, Any], written: tuple[str, str | None]) -> list[_Entry]:
    """The EXIF IFD: version, exposure time, ISO and capture date (the metadata's timestamp, else the write time)."""
    entries = [_entry(_EXIF_VERSION, _UNDEFINED, b"0232")]
    if meta.get("exposure_time_s"):
        entries.append(_entry(_EXPOSURE_TIME, _RATIONAL, float(meta["exposure_time_s"])))
    iso = round(100 * float(meta["analogue_gain"])) if meta.get("analogue_gain") else meta.get("iso")
    if iso:
        entries.append(_entry(_ISO, _SHORT, min(int(iso), 65535)))  # EXIF 2.32: 65535 means "at least"
    taken, offset = _exif_datetime(meta.get("timestamp")) or written
    entries.append(_entry(_DATE_TIME_ORIGINAL, _ASCII, taken))
    if offset:
        entries.append(_entry(_OFFSET_TIME_ORIGINAL, _ASCII, offset))
    if written[1]:
        entries.append(_entry(_OFFSET_TIME, _ASCII, written[1]))
    return entries


def _finite_json(value: Any) -> Any:
    """``value`` with NaN and infinities as null: JSON has no such numbers, and picamcal's reader refuses them.

    Metadata can hold them: an unknown black level is NaN (``declared_black_level`` after an override).
    """
    if isinstance(value, (np.ndarray, np.generic)):
        value = value.tolist()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {key: _finite_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_json(item) for item in value]
    return value


def write_dng(path: str | os.PathLike[str], raw: RawImage, overwrite: bool = True) -> Path:
    """Write a RawImage as an uncompressed DNG 1.4 file that raw editors render with the camera's colour.

    What goes where (docs/dng.md):

    - IFD 0: the mosaic (16 bits per sample, native values, one strip), ``CFAPattern``, per-site ``BlackLevel``,
      ``WhiteLevel``; ``Make`` (metadata ``make``, default "Raspberry Pi"), ``Model`` and ``UniqueCameraModel``
      (the sensor); ``DateTime`` (the write time); the colour tags ``AsShotNeutral`` (from metadata
      ``colour_gains``), ``ColorMatrix1`` and ``ForwardMatrix1`` (from ``colour_correction_matrix`` and the gains,
      see the module notes), ``CalibrationIlluminant1``; the metadata as JSON in ``ImageDescription``.
    - EXIF IFD: ``ExposureTime`` (``exposure_time_s``), ``ISOSpeedRatings`` (``round(100 * analogue_gain)``,
      else ``iso``), ``DateTimeOriginal`` (``timestamp``, EXIF or ISO 8601 text, else the write time).

    A RawImage read from a DNG without ``colour_gains`` or ``colour_correction_matrix`` keeps the file's
    ``as_shot_neutral`` and colour matrices. The file is written to a temporary name and renamed.

    Parameters
    ----------
    path : path-like
        The DNG file to write.
    raw : RawImage
        The mosaic and its metadata; its black level must be known.
    overwrite : bool
        Replace an existing file (default); if false, an existing file is an error.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    RawFormatError
        The black level is unknown (NaN), or the colour metadata is malformed.
    OutputError
        The file exists and ``overwrite`` is false, cannot be written, or the frame exceeds a TIFF's 4 GiB.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references  # doctest: +SKIP
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)))["white"]  # doctest: +SKIP
    >>> write_dng("white.dng", white)  # doctest: +SKIP
    PosixPath('white.dng')
    """
    path = Path(path)
    require_black_level(raw)
    colour = _colour_tags(raw)
    meta = {k: v for k, v in raw.metadata.items() if k not in ("path", "format", *_COLOUR_KEYS)}
    model = raw.sensor or str(meta.get("model", "unknown"))
    now = datetime.now().astimezone()
    written = _exif_datetime(now) or (now.strftime("%Y:%m:%d %H:%M:%S"), None)
    record = _finite_json({_METADATA_KEY: {"sensor": raw.sensor, **meta}})
    description = json.dumps(record, default=json_default, allow_nan=False)
    mosaic = np.ascontiguousarray(raw.bayer, dtype="<u2")
    ifd0 = [
        _entry(_NEW_SUBFILE_TYPE, _LONG, 0),
        _entry(_IMAGE_WIDTH, _LONG, raw.width),
        _entry(_IMAGE_LENGTH, _LONG, raw.height),
        _entry(_BITS_PER_SAMPLE, _SHORT, 16),
        _entry(_COMPRESSION, _SHORT, 1),
        _entry(_PHOTOMETRIC, _SHORT, _CFA_PHOTOMETRIC),
        _entry(_IMAGE_DESCRIPTION, _ASCII, description),
        _entry(_MAKE, _ASCII, str(meta.get("make", "Raspberry Pi"))),
        _entry(_MODEL, _ASCII, model),
        _entry(_ORIENTATION, _SHORT, 1),
        _entry(_SAMPLES_PER_PIXEL, _SHORT, 1),
        _entry(_ROWS_PER_STRIP, _LONG, raw.height),
        _entry(_STRIP_BYTE_COUNTS, _LONG, mosaic.nbytes),
        _entry(_PLANAR_CONFIGURATION, _SHORT, 1),
        _entry(_SOFTWARE, _ASCII, f"picamcal {__version__}"),
        _entry(_DATE_TIME, _ASCII, written[0]),
        _entry(_CFA_REPEAT_DIM, _SHORT, (2, 2)),
        _entry(_CFA_PATTERN, _BYTE, bytes(_CFA_CODES[c] for c in raw.pattern)),
        _entry(_DNG_VERSION, _BYTE, (1, 4, 0, 0)),
        _entry(_DNG_BACKWARD, _BYTE, (1, 1, 0, 0)),
        _entry(_UNIQUE_MODEL, _ASCII, model),
        _entry(_CFA_PLANE_COLOR, _BYTE, (0, 1, 2)),
        _entry(_CFA_LAYOUT, _SHORT, 1),
        _entry(_BLACK_REPEAT_DIM, _SHORT, (2, 2)),
        _entry(_BLACK_LEVEL, _RATIONAL, raw.black_level),
        _entry(_WHITE_LEVEL, _LONG, int(raw.white_level)),
        _entry(_COLOR_MATRIX1, _SRATIONAL, colour["color"].ravel()),
        _entry(_AS_SHOT_NEUTRAL, _RATIONAL, colour["neutral"]),
        _entry(_ILLUMINANT1, _SHORT, colour["illuminant"]),
    ]
    if colour["forward"] is not None:
        ifd0.append(_entry(_FORWARD_MATRIX1, _SRATIONAL, np.asarray(colour["forward"]).ravel()))
    exif = _exif_entries(meta, written)
    # Offsets are 4-byte fields whatever their value: lay out with zeros, then again with the real offsets.
    header = 8
    size0 = len(_ifd([*ifd0, _entry(_EXIF_IFD, _LONG, 0), _entry(_STRIP_OFFSETS, _LONG, 0)], header))
    exif_at = _align(header + size0, 2)
    exif_bytes = _ifd(exif, exif_at)
    strip_at = _align(exif_at + len(exif_bytes), _DATA_ALIGNMENT)
    if strip_at + mosaic.nbytes >= 2**32:
        raise OutputError(f"a {raw.width}x{raw.height} frame is too large for a DNG (TIFF files end at 4 GiB)", path)
    ifd0_bytes = _ifd([*ifd0, _entry(_EXIF_IFD, _LONG, exif_at), _entry(_STRIP_OFFSETS, _LONG, strip_at)], header)
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        f.write(b"II*\x00" + struct.pack("<I", header))
        f.write(ifd0_bytes.ljust(exif_at - header, b"\x00"))
        f.write(exif_bytes.ljust(strip_at - exif_at, b"\x00"))
        f.write(memoryview(mosaic).cast("B"))
    return path
