"""Reading a DNG: its TIFF structure checked by picamcal first, then the mosaic decoded by LibRaw, or read from
its strips when it is plain 16-bit samples.

Every tag that decides the pixels, their colours or their levels is checked against the DNG specification 1.4
(type, count and value), and the raw image's declared size against :func:`picamcal.limits.check_size`, before
anything is decoded: by LibRaw (:mod:`~picamcal.raw.dng.libraw`), or for the plain DNGs of rpicam-still and
picamcal, uncompressed 16-bit strips, by :mod:`~picamcal.raw.dng.plain`, which gives LibRaw's
result about eight times faster. The exposure, capture date, colour tags and picamcal's own JSON record are
informative: a malformed one is left out with a warning.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..._json import parse_json
from ...errors import PicamcalWarning, RawFormatError
from ...limits import check_size, require_regular_file
from ...sensors import SENSORS, find_sensor_name
from ..model import METADATA_KINDS, PATTERNS, RawImage, sensor_black_level
from .libraw import decode
from .plain import Layout, is_plain, read_strips
from .tags import (
    AS_SHOT_NEUTRAL,
    ASCII,
    BITS_PER_SAMPLE,
    BLACK_LEVEL,
    BLACK_REPEAT_DIM,
    BYTE,
    CFA_LAYOUT,
    CFA_PATTERN,
    CFA_PHOTOMETRIC,
    CFA_PLANE_COLOR,
    CFA_REPEAT_DIM,
    COLOR_MATRIX1,
    COMPRESSION,
    DATE_TIME_ORIGINAL,
    DNG_VERSION,
    EXIF_IFD,
    EXPOSURE_TIME,
    FORWARD_MATRIX1,
    IFD,
    ILLUMINANT1,
    IMAGE_DESCRIPTION,
    IMAGE_LENGTH,
    IMAGE_WIDTH,
    ISO,
    LINEAR_RAW,
    LONG,
    MAKE,
    METADATA_KEY,
    MODEL,
    NEW_SUBFILE_TYPE,
    PHOTOMETRIC,
    PLANAR_CONFIGURATION,
    RATIONAL,
    ROWS_PER_STRIP,
    SAMPLES_PER_PIXEL,
    SHORT,
    SRATIONAL,
    STRIP_BYTE_COUNTS,
    STRIP_OFFSETS,
    SUB_IFDS,
    TAG_NAMES,
    TILE_BYTE_COUNTS,
    TILE_LENGTH,
    TILE_OFFSETS,
    TILE_WIDTH,
    UNDEFINED,
    UNIQUE_MODEL,
    WHITE_LEVEL,
)
from .tiff import Field, TiffFile, shown

# Limits of what the reader believes a DNG declares: its raw image is in IFD 0 or one of a few SubIFDs, its black
# level repeats over a few pixels (LibRaw holds 4096 values at most).
_MAX_SUB_IFDS = 16
_MAX_BLACK_REPEAT = 4096


def _raw_ifd(tiff: TiffFile, ifd0: Mapping[int, Field]) -> Mapping[int, Field]:
    """The IFD of the raw mosaic: IFD 0 or the first SubIFD whose NewSubFileType is 0 (DNG 1.4, chapter 3)."""
    if tiff.one(ifd0, NEW_SUBFILE_TYPE, (SHORT, LONG), default=0) == 0:
        return ifd0
    offsets = tiff.tag(ifd0, SUB_IFDS, (LONG, IFD), default=[])
    if len(offsets) > _MAX_SUB_IFDS:
        raise RawFormatError(f"DNG tag SubIFDs lists {len(offsets)} images, more than a DNG holds", tiff.path)
    for n, offset in enumerate(offsets):
        ifd = tiff.ifd(offset, f"SubIFD {n + 1}")
        if tiff.one(ifd, NEW_SUBFILE_TYPE, (SHORT, LONG), default=0) == 0:
            return ifd
    raise RawFormatError("no raw image in it: no IFD has NewSubFileType 0 (the DNG's main image)", tiff.path)


def raw_layout(tiff: TiffFile, ifd0: Mapping[int, Field]) -> tuple[Mapping[int, Field], Layout]:
    """The raw image's IFD (``ifd0`` or a SubIFD) and what it declares, checked before anything is decoded: the
    size first, then the mosaic's tags and data.

    Every tag that decides the pixels, their colours or their levels must be as the DNG specification gives it;
    strips and tiles must lie inside the file and, uncompressed, hold the rows they declare.
    """
    ifd = _raw_ifd(tiff, ifd0)
    path, integer = tiff.path, (SHORT, LONG)
    width, height = tiff.one(ifd, IMAGE_WIDTH, integer), tiff.one(ifd, IMAGE_LENGTH, integer)
    if width is None or height is None:
        raise RawFormatError("the raw image has no ImageWidth or ImageLength tag", path)
    check_size(path, width, height)
    if tiff.one(ifd, SAMPLES_PER_PIXEL, (SHORT,), default=1) != 1:
        raise RawFormatError("DNG tag SamplesPerPixel is not 1: not a colour filter array mosaic", path)
    photometric = tiff.one(ifd, PHOTOMETRIC, (SHORT,))
    if photometric != CFA_PHOTOMETRIC:
        kind = (
            "LinearRaw, already demosaiced" if photometric == LINEAR_RAW else f"PhotometricInterpretation {photometric}"
        )
        raise RawFormatError(f"not a Bayer mosaic ({kind}): picamcal reads colour filter array raw images", path)
    bits = tiff.one(ifd, BITS_PER_SAMPLE, (SHORT,), default=1)
    if not 1 <= bits <= 16:
        raise RawFormatError(f"DNG tag BitsPerSample is {bits}: LibRaw reads integer samples of 1 to 16 bits", path)
    compression = tiff.one(ifd, COMPRESSION, (SHORT,), default=1)
    if tiff.one(ifd, PLANAR_CONFIGURATION, (SHORT,), default=1) not in (1, 2):
        raise RawFormatError("DNG tag PlanarConfiguration is neither 1 nor 2", path)
    pattern = _check_cfa(tiff, ifd)
    repeat = tiff.tag(ifd, BLACK_REPEAT_DIM, (SHORT,), 2, default=[1, 1], positive=True)
    if repeat[0] * repeat[1] > _MAX_BLACK_REPEAT:
        raise RawFormatError(f"DNG tag BlackLevelRepeatDim is {repeat[0]}x{repeat[1]}, larger than LibRaw reads", path)
    sites = repeat[0] * repeat[1]
    black = tiff.tag(ifd, BLACK_LEVEL, (SHORT, LONG, RATIONAL), sites, default=[0] * sites)  # DNG: 0 by default
    white = tiff.one(ifd, WHITE_LEVEL, integer, default=(1 << bits) - 1)
    if not max(black) < white <= 0xFFFF:
        raise RawFormatError(f"DNG tag WhiteLevel {white} is not between the black level {max(black)} and 65535", path)
    offsets, rows = _check_data(tiff, ifd, width, height, bits, compression)
    levels = tuple(float(b) for b in black)
    return ifd, Layout(width, height, bits, compression, pattern, (repeat[0], repeat[1]), levels, white, offsets, rows)


def _check_cfa(tiff: TiffFile, ifd: Mapping[int, Field]) -> str:
    """A 2x2 Bayer pattern of red, green and blue on a rectangular grid (CFA tags of TIFF/EP and DNG)."""
    path = tiff.path
    dims = tiff.tag(ifd, CFA_REPEAT_DIM, (SHORT,), 2)
    codes = tiff.tag(ifd, CFA_PATTERN, (BYTE, UNDEFINED))
    if dims is None or codes is None:
        raise RawFormatError("the raw image has no CFARepeatPatternDim or CFAPattern tag", path)
    if dims != [2, 2] or len(codes) != 4:
        raise RawFormatError(
            f"DNG tags CFARepeatPatternDim {dims} and CFAPattern {shown(codes)}: picamcal reads 2x2 Bayer patterns",
            path,
        )
    planes = tiff.tag(ifd, CFA_PLANE_COLOR, (BYTE,), 3, default=[0, 1, 2])
    if sorted(planes) != [0, 1, 2]:
        raise RawFormatError(f"DNG tag CFAPlaneColor {planes} is not red, green and blue", path)
    pattern = "".join("RGB"[planes[c]] if c < 3 else "?" for c in codes)
    if pattern not in PATTERNS:
        raise RawFormatError(f"DNG tag CFAPattern {codes} is not a Bayer pattern ({pattern})", path)
    if tiff.one(ifd, CFA_LAYOUT, (SHORT,), default=1) != 1:
        raise RawFormatError("DNG tag CFALayout is not 1: picamcal reads rectangular colour filter arrays", path)
    return pattern


def _check_data(
    tiff: TiffFile, ifd: Mapping[int, Field], width: int, height: int, bits: int, compression: int
) -> tuple[list[int] | None, int]:
    """Strips or tiles inside the file; uncompressed, each as long as the rows it declares. The strips' offsets
    and rows per strip (None and 0 for tiles)."""
    path, integer = tiff.path, (SHORT, LONG)
    row_bytes = -(-width * bits // 8)
    if TILE_WIDTH in ifd or TILE_OFFSETS in ifd:
        unit, codes = "tile", (TILE_OFFSETS, TILE_BYTE_COUNTS)
        tile_width, tile_length = tiff.one(ifd, TILE_WIDTH, integer), tiff.one(ifd, TILE_LENGTH, integer)
        if not (tile_width and tile_length):
            raise RawFormatError("DNG tags TileWidth and TileLength must be given and positive", path)
        count = -(-width // tile_width) * -(-height // tile_length)
    else:
        unit, codes = "strip", (STRIP_OFFSETS, STRIP_BYTE_COUNTS)
        rows = min(tiff.one(ifd, ROWS_PER_STRIP, integer, default=height), height)
        if rows < 1:
            raise RawFormatError("DNG tag RowsPerStrip is 0", path)
        count = -(-height // rows)
    # Read (and so bounded by the largest tag) before anything is allocated per strip or tile.
    offsets, lengths = (tiff.tag(ifd, code, integer, count) for code in codes)
    if offsets is None or lengths is None:
        raise RawFormatError(f"the raw image has no {TAG_NAMES[codes[0]]} or {TAG_NAMES[codes[1]]} tag", path)
    lengths = np.asarray(lengths, dtype=np.int64)
    ends = np.asarray(offsets, dtype=np.int64) + lengths
    if ends.max() > tiff.size:
        k = int(np.argmax(ends > tiff.size))
        raise RawFormatError(
            f"truncated file: {unit} {k + 1} of {count} of the raw image ends at byte {ends[k]}, "
            f"but the file has {tiff.size} bytes",
            path,
        )
    strips = (list(offsets), rows) if unit == "strip" else (None, 0)
    if compression != 1:
        return strips
    if unit == "tile":
        needed = np.full(count, tile_length * -(-tile_width * bits // 8), dtype=np.int64)
    else:
        needed = np.minimum(rows, height - rows * np.arange(count, dtype=np.int64)) * row_bytes
    if np.any(lengths < needed):
        k = int(np.argmax(lengths < needed))
        raise RawFormatError(
            f"DNG tag {TAG_NAMES[codes[1]]}: uncompressed {unit} {k + 1} holds {lengths[k]} bytes, "
            f"but its {bits}-bit samples need {needed[k]}",
            path,
        )
    return strips


def _optional(problems: list[str], read: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``read(*args)``, or None with the reason noted in ``problems`` if the metadata it reads is malformed."""
    try:
        return read(*args, **kwargs)
    except RawFormatError as exc:
        problems.append(exc.problem)
        return None


def _tag_metadata(tiff: TiffFile, ifd0: Mapping[int, Field], problems: list[str]) -> dict[str, Any]:
    """Make, model, exposure, capture date, colour tags and picamcal's own record, from IFD 0 and the EXIF IFD.

    All of these are informative: a malformed one is left out and noted in ``problems`` (which become one
    warning), never an error.
    """
    meta: dict[str, Any] = {}
    for code, key in ((MAKE, "make"), (MODEL, "model"), (UNIQUE_MODEL, "unique_camera_model")):
        text = _optional(problems, tiff.tag, ifd0, code, (ASCII,))
        if text:
            meta[key] = text
    exif: Mapping[int, Field] = {}
    exif_at = _optional(problems, tiff.one, ifd0, EXIF_IFD, (LONG, IFD))
    if exif_at is not None:
        exif = _optional(problems, tiff.ifd, exif_at, "the EXIF IFD") or {}
    # Earlier picamcal DNGs (and some other writers) put the exposure tags in IFD 0: keep reading those.
    for key, code, types in (("exposure_time_s", EXPOSURE_TIME, (RATIONAL,)), ("iso", ISO, (SHORT, LONG))):
        for ifd in (exif, ifd0):
            values = _optional(
                problems, tiff.tag, ifd, code, types, 1 if key == "exposure_time_s" else None, positive=True
            )
            if values is not None:
                meta[key] = values[0] if key == "exposure_time_s" else int(values[0])
                break
    stamp = _optional(problems, tiff.tag, exif, DATE_TIME_ORIGINAL, (ASCII,))
    if stamp:
        meta["timestamp"] = stamp
    colour = {
        "as_shot_neutral": _optional(problems, tiff.tag, ifd0, AS_SHOT_NEUTRAL, (SHORT, RATIONAL), 3, positive=True),
        "color_matrix1": _optional(problems, tiff.tag, ifd0, COLOR_MATRIX1, (SRATIONAL,), 9),
        "forward_matrix1": _optional(problems, tiff.tag, ifd0, FORWARD_MATRIX1, (SRATIONAL,), 9),
        "calibration_illuminant1": _optional(problems, tiff.one, ifd0, ILLUMINANT1, (SHORT,)),
    }
    description = _optional(problems, tiff.tag, ifd0, IMAGE_DESCRIPTION, (ASCII,))
    meta.update(_recorded(description, problems))
    # The tags are the truth for colour: a JSON copy could only disagree.
    meta.update({key: values for key, values in colour.items() if values is not None})
    return meta


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
    ours = record.get(METADATA_KEY) if isinstance(record, dict) else None
    if ours is None:
        return {}
    if not isinstance(ours, dict):
        problems.append(f"ImageDescription's {METADATA_KEY!r} record is not a JSON object")
        return {}
    kept = {}
    for key, value in ours.items():
        what, test = METADATA_KINDS.get(key, ("", lambda v: True))
        if value is None and key in METADATA_KINDS:
            continue  # not known (the writer records NaN so)
        if test(value):
            kept[key] = value
        else:
            problems.append(f"ImageDescription's {key} is {shown(value)}, not {what}")
    return kept


def read_dng(path: str | os.PathLike[str], *, expected_shape: Sequence[int] | None = None) -> RawImage:
    """Read a DNG file's Bayer mosaic and metadata, checking what it declares before decoding anything.

    First the file's TIFF structure is read and checked by picamcal itself, only the bytes it needs: the raw
    image's declared size against :func:`picamcal.limits.check_size`, its strips or tiles against the file's
    length, and every tag that decides the pixels or their levels (SamplesPerPixel, BitsPerSample,
    PhotometricInterpretation, CFARepeatPatternDim, CFAPattern, CFAPlaneColor, CFALayout, BlackLevelRepeatDim,
    BlackLevel, WhiteLevel, the strip or tile tags, SubIFDs, NewSubFileType) against the DNG specification's
    types, counts and values. A plain mosaic (uncompressed 16-bit strips, as rpicam-still and
    picamcal write; :mod:`~picamcal.raw.dng.plain`) is then read from its strips, LibRaw's result bit for bit.
    Any other is decoded by LibRaw (rawpy): the sizes it finds are checked again, and against
    ``expected_shape``, before it decodes the mosaic, and what it prints on stderr is folded into the error (or
    into a warning, if the read still succeeds).

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
    >>> from picamcal.raw import write_dng
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> _ = write_dng("white.dng", white)
    >>> raw = read_dng("white.dng")
    >>> raw.bayer.shape, raw.pattern, raw.black_level, raw.sensor
    ((240, 320), 'BGGR', (64.0, 64.0, 64.0, 64.0), 'imx219')
    >>> bool(np.array_equal(raw.bayer, white.bayer)), raw.metadata["format"], len(raw.metadata["as_shot_neutral"])
    (True, 'dng', 3)
    >>> read_dng("white.dng", expected_shape=(1232, 1640))
    Traceback (most recent call last):
    ...
    picamcal.errors.CalibrationFileError: white.dng: image does not match the calibration: size 320x240, ...
    """
    path = Path(path)
    require_regular_file(path)
    problems: list[str] = []
    try:
        with open(path, "rb") as f:
            tiff = TiffFile(f, os.fstat(f.fileno()).st_size, path)
            ifd0 = tiff.ifd(tiff.first_ifd, "IFD 0")
            if tiff.tag(ifd0, DNG_VERSION, (BYTE,), 4) is None:
                raise RawFormatError("a TIFF file but not a DNG raw image (no DNGVersion tag)", path)
            ifd, layout = raw_layout(tiff, ifd0)
            meta = _tag_metadata(tiff, ifd0, problems)
            # Without the tag the level is the DNG default, 0, whatever the sensor's: check_metadata weighs it.
            meta["black_level_source"] = "file" if BLACK_LEVEL in ifd else "DNG default"
            found = read_strips(tiff, layout, expected_shape) if is_plain(tiff, ifd, layout) else None
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from exc
    if found is None:
        found = decode(path, expected_shape, problems)
    if problems:
        warnings.warn(f"{path}: malformed metadata left out: {'; '.join(problems)}", PicamcalWarning, stacklevel=2)
    if found.said:
        warnings.warn(f"{path}: LibRaw reported a problem but read it: {found.said}", PicamcalWarning, stacklevel=2)
    meta["format"] = "dng"
    meta["path"] = str(path)
    sensor = (
        meta.pop("sensor", None)
        or find_sensor_name(meta.get("unique_camera_model"))
        or find_sensor_name(meta.get("model"))
    )
    bit_depth = max(found.white.bit_length(), 8)
    return RawImage(found.bayer, found.pattern, found.black, found.white, bit_depth, sensor, meta)


def with_sensor_black_level(raw: RawImage, stacklevel: int = 2) -> RawImage:
    """A DNG without a BlackLevel tag, of a registry sensor, at that sensor's black level, said in a warning.

    Without the tag a DNG's black level is 0 (the DNG default, as LibRaw reads it), but every sensor of the registry
    has a pedestal: :func:`picamcal.raw.read_raw` gives a DNG that names its sensor (picamera2's later DNGs have
    its name as Model), or whose sensor is told by its size or given, the registry's level at its bit depth
    (``metadata["black_level_source"]`` ``"registry"``); :func:`read_dng` reads the file as LibRaw does. The
    warning names the sensor and the level, not the file: a folder of such files gives it once. A level given
    (``metadata["declared_black_level"]``), a DNG with the tag and one of an unknown sensor are returned as they
    are.

    Examples
    --------
    >>> bayer = np.full((4, 4), 70, np.uint16)
    >>> dng = RawImage(bayer, "BGGR", 0, 1023, 10, "imx219", {"black_level_source": "DNG default"})
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     raw = with_sensor_black_level(dng)
    >>> raw.black_level, raw.metadata["black_level_source"]
    ((64.0, 64.0, 64.0, 64.0), 'registry')
    >>> print(caught[0].message)
    DNGs of the imx219 without a BlackLevel tag are taken at the sensor's black level, 64 DN at 10 bits (not the
    DNG default, 0): give --black-level N if theirs is another
    """
    meta = raw.metadata
    if meta.get("black_level_source") != "DNG default" or "declared_black_level" in meta:
        return raw
    sensor = SENSORS.get((raw.sensor or "").lower())
    if sensor is None or sensor.monochrome:
        return raw
    black, source = sensor_black_level(sensor.name, raw.bit_depth)
    warnings.warn(
        f"DNGs of the {sensor.name} without a BlackLevel tag are taken at the sensor's black level, {black[0]:g} DN "
        f"at {raw.bit_depth} bits (not the DNG default, 0): give --black-level N if theirs is another",
        PicamcalWarning,
        stacklevel=stacklevel,
    )
    return dataclasses.replace(raw, black_level=black, metadata={**meta, "black_level_source": source})
