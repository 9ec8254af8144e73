"""DNG raw files: read through LibRaw (rawpy) and tifffile, written by a small TIFF writer of this module.

Only this module knows the DNG tag layout. The reader takes the mosaic, CFA pattern, per-site black levels and
white level from LibRaw, and the exposure, capture date and colour tags from the TIFF tags. The writer makes an
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

import json
import math
import os
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from .._atomic import atomic_path
from .._files import json_default
from .._version import __version__
from ..errors import OutputError, RawFormatError
from ..sensors import find_sensor_name
from .model import PATTERNS, RawImage, require_black_level

__all__ = ["is_dng", "read_dng", "write_dng"]

# TIFF 6.0 / TIFF-EP / EXIF 2.32 / DNG 1.4 tag codes.
_NEW_SUBFILE_TYPE, _IMAGE_WIDTH, _IMAGE_LENGTH, _BITS_PER_SAMPLE, _COMPRESSION = 254, 256, 257, 258, 259
_PHOTOMETRIC, _IMAGE_DESCRIPTION, _MAKE, _MODEL, _STRIP_OFFSETS = 262, 270, 271, 272, 273
_ORIENTATION, _SAMPLES_PER_PIXEL, _ROWS_PER_STRIP, _STRIP_BYTE_COUNTS = 274, 277, 278, 279
_PLANAR_CONFIGURATION, _SOFTWARE, _DATE_TIME = 284, 305, 306
_CFA_REPEAT_DIM, _CFA_PATTERN, _EXIF_IFD = 33421, 33422, 34665
_EXPOSURE_TIME, _ISO, _EXIF_VERSION, _DATE_TIME_ORIGINAL = 33434, 34855, 36864, 36867
_OFFSET_TIME, _OFFSET_TIME_ORIGINAL = 36880, 36881
_DNG_VERSION, _DNG_BACKWARD, _UNIQUE_MODEL, _CFA_PLANE_COLOR, _CFA_LAYOUT = 50706, 50707, 50708, 50710, 50711
_BLACK_REPEAT_DIM, _BLACK_LEVEL, _WHITE_LEVEL = 50713, 50714, 50717
_COLOR_MATRIX1, _AS_SHOT_NEUTRAL, _ILLUMINANT1, _FORWARD_MATRIX1 = 50721, 50728, 50778, 50964

# TIFF field types and the struct code of one value (a rational is two).
_BYTE, _ASCII, _SHORT, _LONG, _RATIONAL, _UNDEFINED, _SRATIONAL = 1, 2, 3, 4, 5, 7, 10
_STRUCT = {_BYTE: "B", _ASCII: "B", _SHORT: "H", _LONG: "I", _RATIONAL: "II", _UNDEFINED: "B", _SRATIONAL: "ii"}

_CFA_CODES = {"R": 0, "G": 1, "B": 2}
_METADATA_KEY = "picamcal"
_CFA_PHOTOMETRIC = 32803
_D65 = 21  # EXIF LightSource / DNG CalibrationIlluminant code
_DATA_ALIGNMENT = 16  # the strip starts on a 16-byte boundary (TIFF needs 2; aligned data maps cheaply)

# Linear sRGB (D65 white) to CIE XYZ, IEC 61966-2-1 (to 7 digits, as Bruce Lindbloom tabulates it).
_SRGB_TO_XYZ = np.array(
    [[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]]
)
# The Bradford cone response matrix, for the D65 -> D50 chromatic adaptation of the ForwardMatrix.
_BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])
_D50_XY = (0.3457, 0.3585)  # the DNG specification's D50, white of its profile connection space

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


# --- reading ---------------------------------------------------------------------------------------------------


def _numbers(tag: tifffile.TiffTag | None, count: int | None = None) -> list[float] | None:
    """A tag's values as floats (rationals divided out), or None if absent, malformed or of another count."""
    if tag is None:
        return None
    value = tag.value
    values = list(value) if isinstance(value, (tuple, list, np.ndarray)) else [value]
    try:
        if int(tag.dtype) in (_RATIONAL, _SRATIONAL):
            if len(values) % 2:
                return None
            pairs = [(float(values[i]), float(values[i + 1])) for i in range(0, len(values), 2)]
            if any(den == 0 for _, den in pairs):
                return None
            numbers = [num / den for num, den in pairs]
        else:
            numbers = [float(v) for v in values]
    except (TypeError, ValueError):
        return None
    if count is not None and len(numbers) != count:
        return None
    return numbers if all(math.isfinite(v) for v in numbers) else None


def _exif_number(exif: Mapping[str, Any], name: str, *, rational: bool) -> float | None:
    """The (first) value of an EXIF tag as tifffile decodes it: a rational is a (numerator, denominator) pair."""
    value = exif.get(name)
    values = list(value) if isinstance(value, (tuple, list)) else [value]
    try:
        if rational and len(values) >= 2:
            num, den = float(values[0]), float(values[1])
            number = num / den if den else math.nan
        else:
            number = float(values[0])
    except (TypeError, ValueError, IndexError):
        return None
    return number if math.isfinite(number) else None


def _tag_metadata(path: Path) -> dict[str, Any]:
    meta: dict[str, Any] = {}
    broken = (tifffile.TiffFileError, IndexError, OSError, ValueError)
    try:
        tif = tifffile.TiffFile(path)
    except broken as exc:
        raise RawFormatError(f"corrupt TIFF/DNG structure ({exc or type(exc).__name__})", path) from exc
    with tif:
        try:
            tags = tif.pages.first.tags
        except broken as exc:
            raise RawFormatError(f"corrupt TIFF/DNG structure ({exc or type(exc).__name__})", path) from exc
        if _DNG_VERSION not in tags:
            raise RawFormatError("a TIFF file but not a DNG raw image (no DNGVersion tag)", path)
        for code, key in ((_MAKE, "make"), (_MODEL, "model"), (_UNIQUE_MODEL, "unique_camera_model")):
            if code in tags:
                meta[key] = str(tags[code].value).strip("\x00 ")
        exif = tags[_EXIF_IFD].value if _EXIF_IFD in tags else {}
        exif = exif if isinstance(exif, dict) else {}
        # Earlier picamcal DNGs (and some other writers) put the exposure tags in IFD 0: keep reading those.
        exposure = _exif_number(exif, "ExposureTime", rational=True)
        if exposure is None:
            exposure = (_numbers(tags.get(_EXPOSURE_TIME), 1) or [None])[0]
        if exposure is not None:
            meta["exposure_time_s"] = exposure
        iso = _exif_number(exif, "ISOSpeedRatings", rational=False)
        if iso is None:
            iso = (_numbers(tags.get(_ISO)) or [None])[0]
        if iso is not None:
            meta["iso"] = int(iso)
        stamp = exif.get("DateTimeOriginal")
        if isinstance(stamp, str) and stamp.strip("\x00 "):
            meta["timestamp"] = stamp.strip("\x00 ")
        colour = {
            "as_shot_neutral": _numbers(tags.get(_AS_SHOT_NEUTRAL), 3),
            "color_matrix1": _numbers(tags.get(_COLOR_MATRIX1), 9),
            "forward_matrix1": _numbers(tags.get(_FORWARD_MATRIX1), 9),
            "calibration_illuminant1": _numbers(tags.get(_ILLUMINANT1), 1),
        }
        if _IMAGE_DESCRIPTION in tags:
            try:
                extra = json.loads(tags[_IMAGE_DESCRIPTION].value)
            except (TypeError, ValueError):
                extra = None
            if isinstance(extra, dict) and isinstance(extra.get(_METADATA_KEY), dict):
                meta.update(extra[_METADATA_KEY])
    for key, values in colour.items():
        if values is not None:
            meta[key] = int(values[0]) if key == "calibration_illuminant1" else values
    return meta


def read_dng(path: str | os.PathLike[str]) -> RawImage:
    """Read a DNG file's Bayer mosaic and metadata.

    Parameters
    ----------
    path : path-like
        A DNG file (picamera2's ``save_dng``, PiDNG, rpicam-apps, any camera's DNG, or :func:`write_dng`).

    Returns
    -------
    RawImage
        Mosaic of the visible area, the CFA pattern and per-site black levels as LibRaw reports them. The
        metadata holds, when the file has them: ``exposure_time_s``, ``iso``, ``timestamp`` (EXIF
        ``DateTimeOriginal``, ``"YYYY:MM:DD HH:MM:SS"``), ``make``, ``model``, ``unique_camera_model``, the
        colour tags ``as_shot_neutral`` (3 floats), ``color_matrix1`` and ``forward_matrix1`` (9 floats each,
        row-major) and ``calibration_illuminant1`` (int), and what picamcal recorded in the file.

    Examples
    --------
    >>> raw = read_dng("white.dng")  # doctest: +SKIP
    >>> raw.pattern, raw.black_level  # doctest: +SKIP
    ('BGGR', (64.0, 64.0, 64.0, 64.0))
    >>> raw.metadata["as_shot_neutral"]  # doctest: +SKIP
    [0.5, 1.0, 0.97]
    """
    import rawpy

    path = Path(path)
    meta = _tag_metadata(path)
    try:
        with rawpy.imread(str(path)) as rp:
            if rp.raw_pattern is None or rp.num_colors != 3:
                raise RawFormatError("not a Bayer raw image (LibRaw finds no 2x2 colour filter pattern)", path)
            bayer = np.array(rp.raw_image_visible, dtype=np.uint16, copy=True)
            desc = rp.color_desc.decode("ascii")
            # The colours of the visible area's first 2x2 block (raw_pattern refers to the uncropped sensor).
            cfa = rp.raw_colors_visible[:2, :2]
            pattern = "".join(desc[i] for i in cfa.ravel())
            per_channel = list(rp.black_level_per_channel)
            black = tuple(float(per_channel[i]) for i in cfa.ravel())
            white = int(rp.white_level)
    except (rawpy.LibRawError, OSError) as exc:
        raise RawFormatError(f"LibRaw cannot read it as a raw image ({type(exc).__name__}: {exc})", path) from exc
    if pattern not in PATTERNS:
        raise RawFormatError(f"unsupported colour filter pattern {pattern!r}", path)
    if bayer.shape[0] % 2 or bayer.shape[1] % 2:
        bayer = bayer[: bayer.shape[0] // 2 * 2, : bayer.shape[1] // 2 * 2]
    meta["format"] = "dng"
    meta["path"] = str(path)
    sensor = (
        meta.pop("sensor", None)
        or find_sensor_name(meta.get("unique_camera_model"))
        or find_sensor_name(meta.get("model"))
    )
    return RawImage(bayer, pattern, black, white, max(int(white).bit_length(), 8), sensor, meta)  # type: ignore[arg-type]


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
    description = json.dumps({_METADATA_KEY: {"sensor": raw.sensor, **meta}}, default=json_default)
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
