"""Writing a RawImage as an uncompressed DNG 1.4 that LibRaw reads back bit-exactly (docs/dng.md).

IFD 0 holds the mosaic in one strip and the DNG colour tags, an EXIF IFD the exposure time, ISO and capture date.

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
import numbers
import os
import struct
from collections.abc import Mapping
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from ..._atomic import atomic_path
from ..._version import __version__
from ...errors import CalibrationFileError, OutputError, RawFormatError, short
from ...records import json_default
from ..model import METADATA_KINDS, RawImage, require_black_level
from .opcodes import FlatField, GainMap, encode_gain_map, flat_field_gain_map
from .tags import (
    AS_SHOT_NEUTRAL,
    ASCII,
    BITS_PER_SAMPLE,
    BLACK_LEVEL,
    BLACK_REPEAT_DIM,
    BYTE,
    CFA_CODES,
    CFA_LAYOUT,
    CFA_PATTERN,
    CFA_PHOTOMETRIC,
    CFA_PLANE_COLOR,
    CFA_REPEAT_DIM,
    COLOR_MATRIX1,
    COLOUR_KEYS,
    COMPRESSION,
    D65,
    DATE_TIME,
    DATE_TIME_ORIGINAL,
    DNG_BACKWARD,
    DNG_VERSION,
    EXIF_IFD,
    EXIF_VERSION,
    EXPOSURE_TIME,
    FORWARD_MATRIX1,
    ILLUMINANT1,
    IMAGE_DESCRIPTION,
    IMAGE_LENGTH,
    IMAGE_WIDTH,
    ISO,
    LONG,
    MAKE,
    METADATA_KEY,
    MODEL,
    NEW_SUBFILE_TYPE,
    OFFSET_TIME,
    OFFSET_TIME_ORIGINAL,
    OPCODE_LIST2,
    ORIENTATION,
    PHOTOMETRIC,
    PLANAR_CONFIGURATION,
    RATIONAL,
    ROWS_PER_STRIP,
    SAMPLES_PER_PIXEL,
    SHORT,
    SOFTWARE,
    SRATIONAL,
    STRIP_BYTE_COUNTS,
    STRIP_OFFSETS,
    UNDEFINED,
    UNIQUE_MODEL,
    WHITE_LEVEL,
)
from .tiff import Entry, align_up, entry, ifd_bytes

_DATA_ALIGNMENT = 16  # the strip starts on a 16-byte boundary (TIFF needs 2; aligned data maps cheaply)

# Linear sRGB (D65 white) to CIE XYZ, IEC 61966-2-1 (to 7 digits, as Bruce Lindbloom tabulates it).
_SRGB_TO_XYZ = np.array(
    [[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]]
)
# The Bradford cone response matrix, for the D65 -> D50 chromatic adaptation of the ForwardMatrix.
_BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])
_D50_XY = (0.3457, 0.3585)  # the DNG specification's D50, white of its profile connection space


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


def colour_tags(meta: Mapping[str, Any], source: str) -> dict[str, Any]:
    """AsShotNeutral, ColorMatrix1, ForwardMatrix1 and CalibrationIlluminant1 from a frame's metadata.

    The neutral comes from ``colour_gains`` (else a DNG's ``as_shot_neutral``, else no balance); the matrices
    from ``colour_correction_matrix`` (else a DNG's own matrices, else the identity CCM). ``source`` names the
    frame in messages.
    """
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
        illuminant = meta.get("calibration_illuminant1") or D65
        code = isinstance(illuminant, numbers.Integral) and not isinstance(illuminant, bool)
        if not code or not 0 < int(illuminant) < 1 << 16:
            raise RawFormatError(
                f"metadata calibration_illuminant1 must be an EXIF LightSource code, not {short(illuminant)}", source
            )
        illuminant = int(illuminant)
        return {"neutral": neutral, "color": kept.reshape(3, 3), "forward": forward, "illuminant": illuminant}
    ccm = np.eye(3) if ccm is None else ccm.reshape(3, 3)
    camera_to_xyz = _SRGB_TO_XYZ @ ccm @ np.diag(1.0 / neutral)
    if abs(np.linalg.det(camera_to_xyz)) < 1e-9:
        raise RawFormatError(f"metadata colour_correction_matrix is singular: {ccm.ravel().tolist()}", source)
    forward = _d65_to_d50() @ _SRGB_TO_XYZ @ ccm
    return {"neutral": neutral, "color": np.linalg.inv(camera_to_xyz), "forward": forward, "illuminant": D65}


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


def _known(meta: Mapping[str, Any], key: str, source: str) -> Any:
    """``meta[key]`` checked against :data:`~picamcal.raw.model.METADATA_KINDS`; None if absent or 0 (not known)."""
    value = meta.get(key)
    if value is None or (isinstance(value, numbers.Real) and not isinstance(value, bool) and value == 0):
        return None
    what, test = METADATA_KINDS[key]
    if not test(value):
        raise RawFormatError(f"metadata {key} must be {what}, not {short(value)}", source)
    return value


def exif_entries(meta: Mapping[str, Any], written: tuple[str, str | None], source: str) -> list[Entry]:
    """The EXIF IFD: version, exposure time, ISO and capture date (the metadata's timestamp, else the write time)."""
    entries = [entry(EXIF_VERSION, UNDEFINED, b"0232")]
    exposure = _known(meta, "exposure_time_s", source)
    if exposure is not None:
        entries.append(entry(EXPOSURE_TIME, RATIONAL, float(exposure)))
    gain = _known(meta, "analogue_gain", source)
    iso = round(100 * gain) if gain is not None else _known(meta, "iso", source)
    if iso:
        entries.append(entry(ISO, SHORT, min(int(iso), 65535)))  # EXIF 2.32: 65535 means "at least"
    taken, offset = _exif_datetime(meta.get("timestamp")) or written
    entries.append(entry(DATE_TIME_ORIGINAL, ASCII, taken))
    if offset:
        entries.append(entry(OFFSET_TIME_ORIGINAL, ASCII, offset))
    if written[1]:
        entries.append(entry(OFFSET_TIME, ASCII, written[1]))
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


def write_dng(
    path: str | os.PathLike[str], raw: RawImage, overwrite: bool = True, gain_map: GainMap | FlatField | None = None
) -> Path:
    """Write a RawImage as an uncompressed DNG 1.4 file that raw editors render with the camera's colour.

    What goes where (docs/dng.md):

    - IFD 0: the mosaic (16 bits per sample, native values, one strip), ``CFAPattern``, per-site ``BlackLevel``,
      ``WhiteLevel``; ``Make`` (metadata ``make``, default "Raspberry Pi"), ``Model`` and ``UniqueCameraModel``
      (the sensor); ``DateTime`` (the write time); the colour tags ``AsShotNeutral`` (from metadata
      ``colour_gains``), ``ColorMatrix1`` and ``ForwardMatrix1`` (from ``colour_correction_matrix`` and the gains,
      see the module notes), ``CalibrationIlluminant1``; the metadata as JSON in ``ImageDescription``.
    - EXIF IFD: ``ExposureTime`` (``exposure_time_s``), ``ISOSpeedRatings`` (``round(100 * analogue_gain)``,
      else ``iso``), ``DateTimeOriginal`` (``timestamp``, EXIF or ISO 8601 text, else the write time).
    - With ``gain_map``: ``OpcodeList2``, four GainMap opcodes (one per Bayer site) that raw editors apply before
      demosaicing, so that they show the frame flat-fielded; the mosaic itself is written unchanged
      (:mod:`~picamcal.raw.dng.opcodes`).

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
    gain_map : Calibration or GainMap, optional
        A calibration of this sensor, size and Bayer order, whose flat field becomes the gain map
        (:func:`~picamcal.raw.dng.opcodes.flat_field_gain_map`: the centre's colour kept, smallest gain 1), or a
        :class:`~picamcal.raw.dng.opcodes.GainMap` made for this size.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    RawFormatError
        The black level is unknown (NaN), or the colour, exposure or gain metadata is malformed.
    CalibrationFileError
        ``gain_map`` is for another size or Bayer order, or its flat field needs a gain above
        :data:`~picamcal.raw.dng.opcodes.MAX_GAIN` (naming the calibration file, or this file for a calibration
        made in memory); nothing is written.
    OutputError
        The file exists and ``overwrite`` is false, cannot be written, or the frame exceeds a TIFF's 4 GiB.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> write_dng("white.dng", white)
    PosixPath('white.dng')
    >>> picamcal.read_raw("white.dng").metadata["exposure_time_s"] == white.metadata["exposure_time_s"]
    True

    The same frame with the flat field of a calibration, for an editor to apply:

    >>> cal = picamcal.calibrate(white)  # the flat field alone
    >>> _ = write_dng("white-flat.dng", white, gain_map=cal)
    >>> bool(np.array_equal(picamcal.read_raw("white-flat.dng").bayer, white.bayer))
    True
    """
    path = Path(path)
    require_black_level(raw)
    opcodes = _gain_map_entries(raw, gain_map, path)
    mosaic = np.ascontiguousarray(raw.bayer, dtype="<u2")
    written = write_time()
    try:
        ifd0 = _ifd0_entries(raw, mosaic.nbytes, written[0])
        exif = exif_entries(raw.metadata, written, raw.source)
    except OutputError as exc:  # a value no TIFF field holds (an exposure of 2**40 s)
        raise OutputError(exc.problem, path) from None
    return write_tiff(path, [*ifd0, *opcodes], exif, mosaic, overwrite)


def write_time() -> tuple[str, str | None]:
    """Now, as an EXIF date and its UTC offset."""
    now = datetime.now().astimezone()
    return _exif_datetime(now) or (now.strftime("%Y:%m:%d %H:%M:%S"), None)


def write_tiff(path: Path, ifd0: list[Entry], exif: list[Entry], pixels: np.ndarray, overwrite: bool) -> Path:
    """Write IFD 0 (all but its EXIF and strip offsets), the EXIF IFD and ``pixels`` as one strip, atomically."""
    # Offsets are 4-byte fields whatever their value: lay out with zeros, then again with the real offsets.
    header = 8
    size0 = len(ifd_bytes([*ifd0, entry(EXIF_IFD, LONG, 0), entry(STRIP_OFFSETS, LONG, 0)], header))
    exif_at = align_up(header + size0, 2)
    exif_bytes = ifd_bytes(exif, exif_at)
    strip_at = align_up(exif_at + len(exif_bytes), _DATA_ALIGNMENT)
    if strip_at + pixels.nbytes >= 2**32:
        height, width = pixels.shape[:2]
        raise OutputError(f"a {width}x{height} frame is too large for a DNG (TIFF files end at 4 GiB)", path)
    ifd0_bytes = ifd_bytes([*ifd0, entry(EXIF_IFD, LONG, exif_at), entry(STRIP_OFFSETS, LONG, strip_at)], header)
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        f.write(b"II*\x00" + struct.pack("<I", header))
        f.write(ifd0_bytes.ljust(exif_at - header, b"\x00"))
        f.write(exif_bytes.ljust(strip_at - exif_at, b"\x00"))
        f.write(pixels.data)
    return path


def _gain_map_entries(raw: RawImage, gain_map: GainMap | FlatField | None, path: Path) -> list[Entry]:
    """OpcodeList2 with the four GainMap opcodes of ``gain_map`` (a calibration's flat field or a GainMap).

    A mismatch names the image's file (the file being written for a frame made in memory); a gain out of range
    names the calibration's file (the file being written for a calibration made in memory).
    """
    if gain_map is None:
        return []
    image = raw.metadata.get("path", path)
    if isinstance(gain_map, GainMap):
        if gain_map.size != (raw.width, raw.height):
            width, height = gain_map.size
            raise CalibrationFileError(
                f"image does not match the gain map: size {raw.width}x{raw.height}, gain map is for {width}x{height}",
                image,
            )
    else:
        try:
            gain_map.check_compatible(raw)
        except CalibrationFileError as exc:
            raise CalibrationFileError(exc.problem, image) from None
        try:
            gain_map = flat_field_gain_map(gain_map)
        except CalibrationFileError as exc:
            raise CalibrationFileError(exc.problem, exc.path or path) from None
    return [entry(OPCODE_LIST2, UNDEFINED, encode_gain_map(gain_map))]


def metadata_record(meta: Mapping[str, Any], sensor: str | None) -> str:
    """picamcal's JSON record of a frame for ImageDescription, ``{"picamcal": {"sensor": ..., ...}}``."""
    record = _finite_json({METADATA_KEY: {"sensor": sensor, **meta}})
    return json.dumps(record, default=json_default, allow_nan=False)


def _ifd0_entries(raw: RawImage, nbytes: int, written: str) -> list[Entry]:
    """IFD 0 but its offsets: the mosaic's layout (``nbytes`` in one strip), the DNG tags and picamcal's record."""
    colour = colour_tags(raw.metadata, raw.source)
    meta = {k: v for k, v in raw.metadata.items() if k not in ("path", "format", *COLOUR_KEYS)}
    model = raw.sensor or str(meta.get("model", "unknown"))
    description = metadata_record(meta, raw.sensor)
    entries = [
        entry(NEW_SUBFILE_TYPE, LONG, 0),
        entry(IMAGE_WIDTH, LONG, raw.width),
        entry(IMAGE_LENGTH, LONG, raw.height),
        entry(BITS_PER_SAMPLE, SHORT, 16),
        entry(COMPRESSION, SHORT, 1),
        entry(PHOTOMETRIC, SHORT, CFA_PHOTOMETRIC),
        entry(IMAGE_DESCRIPTION, ASCII, description),
        entry(MAKE, ASCII, str(meta.get("make", "Raspberry Pi"))),
        entry(MODEL, ASCII, model),
        entry(ORIENTATION, SHORT, 1),
        entry(SAMPLES_PER_PIXEL, SHORT, 1),
        entry(ROWS_PER_STRIP, LONG, raw.height),
        entry(STRIP_BYTE_COUNTS, LONG, nbytes),
        entry(PLANAR_CONFIGURATION, SHORT, 1),
        entry(SOFTWARE, ASCII, f"picamcal {__version__}"),
        entry(DATE_TIME, ASCII, written),
        entry(CFA_REPEAT_DIM, SHORT, (2, 2)),
        entry(CFA_PATTERN, BYTE, bytes(CFA_CODES[c] for c in raw.pattern)),
        entry(DNG_VERSION, BYTE, (1, 4, 0, 0)),
        entry(DNG_BACKWARD, BYTE, (1, 1, 0, 0)),
        entry(UNIQUE_MODEL, ASCII, model),
        entry(CFA_PLANE_COLOR, BYTE, (0, 1, 2)),
        entry(CFA_LAYOUT, SHORT, 1),
        entry(BLACK_REPEAT_DIM, SHORT, (2, 2)),
        entry(BLACK_LEVEL, RATIONAL, raw.black_level),
        entry(WHITE_LEVEL, LONG, int(raw.white_level)),
        entry(COLOR_MATRIX1, SRATIONAL, colour["color"].ravel()),
        entry(AS_SHOT_NEUTRAL, RATIONAL, colour["neutral"]),
        entry(ILLUMINANT1, SHORT, colour["illuminant"]),
    ]
    if colour["forward"] is not None:
        entries.append(entry(FORWARD_MATRIX1, SRATIONAL, np.asarray(colour["forward"]).ravel()))
    return entries
