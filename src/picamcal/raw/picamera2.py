"""Raw buffers from picamera2 (libcamera on Raspberry Pi OS): arrays, ``.npy`` dumps, and a capture helper.

picamera2's ``capture_array("raw")`` returns the raw stream's bytes as a uint8 ``(height, stride)`` array; what
they mean is in the stream configuration (``picam2.camera_configuration()["raw"]``: ``format``, ``size``,
``stride``, ``framesize``) and the request metadata (``SensorBlackLevels``, ``ExposureTime``, ...). This module
turns the three into a :class:`RawImage` (FORMATS.md section 3). Only this module knows picamera2's layouts:

- ``S<order><8|10|12|14|16>``: unpacked, one byte per pixel at 8 bits, else one little-endian uint16 per pixel.
  Pi 4 and earlier store the sensor's bits right-justified; the Pi 5 front end only writes ``S<order>16``,
  left-justified on a 16-bit scale, which is shifted back to the sensor's bit depth when the configuration
  gives it (``config["sensor"]["bit_depth"]``) and the low bits are zero (it is then exact).
- ``S<order><10|12|14>_CSI2P``: MIPI CSI-2 RAW10/RAW12/RAW14 packing (:mod:`picamcal.raw.packing`).
- ``<order>_PISP_COMP1``: the Pi 5's default, a lossy 8-bit-per-pixel compression; see :func:`from_picamera2`.

Rows are cropped to their pixel bytes (the stride is padded to 32 bytes on a Pi 4, 64 on a Pi 5). The Bayer
order comes from the format string, which already includes any flips. picamera2 itself is never imported
here except inside :func:`capture_raw`, which is given a camera object.
"""

from __future__ import annotations

import functools
import json
import math
import os
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_path
from ..errors import OutputError, PicamcalWarning, RawFormatError, closest, short
from ..limits import check_size, require_regular_file
from ..sensors import black_level_at, find_sensor_name, get_sensor
from .model import RawImage
from .npy import read_array_data, read_npy_header
from .packing import pack, packed_row_bytes, unpack

__all__ = [
    "RAW_FORMATS",
    "RawFormat",
    "capture_raw",
    "from_picamera2",
    "is_npy",
    "max_stride",
    "parse_raw_format",
    "read_picamera2_npy",
    "write_picamera2_npy",
]

SIDECAR_FORMAT = "picamcal-picamera2"
SIDECAR_VERSION = 1

_ORDERS = ("RGGB", "GRBG", "GBRG", "BGGR")
_UNCOMPRESSED = re.compile(rf"S({'|'.join(_ORDERS)})(8|10|12|14|16)(_CSI2P)?")
_PISP = re.compile(rf"({'|'.join(_ORDERS)})(?:16)?_PISP_COMP1")
# libcamera's greyscale formats (R8, R10_CSI2P, ..., MONO_PISP_COMP1) and V4L2's names for them (Y10P, GREY).
_MONO = re.compile(r"(?:R|Y)(?:8|10|12|14|16)(?:_CSI2P|P)?|MONO(?:16)?_PISP_COMP1|GREY")
#: Every raw format name picamcal reads (libcamera's spelling; matched case-insensitively).
RAW_FORMATS: tuple[str, ...] = (
    *(f"S{order}{bits}" for order in _ORDERS for bits in (8, 10, 12, 14, 16)),
    *(f"S{order}{bits}_CSI2P" for order in _ORDERS for bits in (10, 12, 14)),
    *(f"{order}_PISP_COMP1" for order in _ORDERS),
)
_KNOWN_FORMATS = (
    "S<order>{8,10,12,14,16}, S<order>{10,12,14}_CSI2P or <order>_PISP_COMP1 with <order> RGGB, GRBG, GBRG or BGGR"
)

# PiSP compression as libcamera configures it for the raw stream: mode 1 with an offset of 2048 on the 16-bit
# scale (libcamera pipeline/rpi/pisp/pisp.cpp DefaultCompressionOffset/Mode; rpicam-apps image/dng.cpp).
_PISP_OFFSET = 2048
_PISP_MAX_Q = 640  # decoded quantisation levels stay below this in every mode (largest: 511 + 127 = 638)

_MAX_SIDECAR_BYTES = 16 << 20
_METADATA_SCALARS = {  # libcamera control -> (RawImage metadata key, scale)
    "ExposureTime": ("exposure_time_s", 1e-6),
    "AnalogueGain": ("analogue_gain", 1.0),
    "DigitalGain": ("digital_gain", 1.0),
    "ColourTemperature": ("colour_temperature", 1.0),
    "Lux": ("lux", 1.0),
}
_METADATA_VECTORS = {"ColourGains": ("colour_gains", 2), "ColourCorrectionMatrix": ("colour_correction_matrix", 9)}


@dataclass(frozen=True)
class RawFormat:
    """What a libcamera raw format name says about the bytes (:func:`parse_raw_format`).

    Attributes
    ----------
    name : str
        The name as libcamera spells it (``"SBGGR10_CSI2P"``).
    pattern : str
        Bayer order of the top-left 2x2 block.
    packing : str
        ``"unpacked"``, ``"csi2p"`` or ``"pisp"``.
    bits : int
        Bits per stored sample (16 for PiSP compression: it decompresses to a 16-bit scale).
    """

    name: str
    pattern: str
    packing: str
    bits: int

    def row_bytes(self, width: int) -> int:
        """Bytes of pixel data in a row of ``width`` pixels, before any stride padding.

        Examples
        --------
        >>> parse_raw_format("SBGGR10_CSI2P").row_bytes(3280), parse_raw_format("SRGGB16").row_bytes(3280)
        (4100, 6560)
        """
        if self.packing == "pisp":
            return -(-width // 8) * 8  # each 8-pixel block is 8 bytes; rows are padded to whole blocks
        if self.packing == "csi2p":
            return -(-width // 4) * 7 if self.bits == 14 else packed_row_bytes(width, self.bits)
        return width if self.bits == 8 else 2 * width


def parse_raw_format(name: str, source: str | os.PathLike[str] | None = None) -> RawFormat:
    """The layout a libcamera raw format name stands for (case-insensitive).

    Parameters
    ----------
    name : str
        ``S<order><8|10|12|14|16>`` (unpacked), ``S<order><10|12|14>_CSI2P`` (MIPI CSI-2 packed) or
        ``<order>_PISP_COMP1`` (the Pi 5's compressed format), ``<order>`` one of RGGB, GRBG, GBRG, BGGR.
    source : str or path-like, optional
        The file the name is for, named in errors.

    Raises
    ------
    RawFormatError
        A greyscale format (``R10_CSI2P``, ...: picamcal calibrates colour Bayer sensors), or a name it does not
        know (the message lists the known ones and the nearest).

    Examples
    --------
    >>> parse_raw_format("sbggr10_csi2p")
    RawFormat(name='SBGGR10_CSI2P', pattern='BGGR', packing='csi2p', bits=10)
    """
    if not isinstance(name, str):
        raise RawFormatError(f"a raw format is a name such as 'SBGGR10_CSI2P', not {short(name)}", source)
    key = name.strip().upper()
    if match := _UNCOMPRESSED.fullmatch(key):
        bits, packing = int(match[2]), "csi2p" if match[3] else "unpacked"
        if packing == "unpacked" or bits in (10, 12, 14):
            return RawFormat(key, match[1], packing, bits)
    elif match := _PISP.fullmatch(key):
        return RawFormat(f"{match[1]}_PISP_COMP1", match[1], "pisp", 16)
    elif _MONO.fullmatch(key):
        raise RawFormatError(
            f"{name} is a monochrome (greyscale) format: picamcal calibrates colour Bayer sensors, and a "
            "monochrome sensor has no colour crosstalk to unmix (a colour sensor's format is S<order>...)",
            source,
        )
    raise RawFormatError(f"unknown raw format {name!r} (expected {_KNOWN_FORMATS}){_nearest_format(key)}", source)


def max_stride(row_bytes: int) -> int:
    """The longest row stride picamcal accepts for rows of ``row_bytes`` bytes of pixels.

    libcamera pads a row to 32 bytes (Pi 4) or 64 (Pi 5); twice the row plus 256 bytes leaves room for any other
    tool's alignment while keeping what a forged stride can make picamcal read to about two frames.

    Examples
    --------
    >>> max_stride(4100)
    8456
    """
    return 2 * row_bytes + 256


def _nearest_format(key: str) -> str:
    if match := re.fullmatch(rf"S({'|'.join(_ORDERS)})(10|12|14)P", key):  # V4L2's name of a packed format
        return f"; did you mean S{match[1]}{match[2]}_CSI2P?"
    near = closest(key, RAW_FORMATS, cutoff=0.75)
    return f"; did you mean {near}?" if near else ""


@dataclass(frozen=True)
class _Layout:
    """A raw buffer checked against its configuration: what the bytes are and where the pixels lie."""

    name: str
    pattern: str
    packing: str  # "unpacked", "csi2p" or "pisp"
    bits: int  # bits per stored sample (16 for PiSP: it decompresses to a 16-bit scale)
    width: int
    height: int
    stride: int
    sensor_bits: int | None
    rows: np.ndarray  # uint8 (height, >= row bytes)


def from_picamera2(
    array: np.ndarray | bytes,
    config: Mapping[str, Any],
    metadata: Mapping[str, Any] | None = None,
    *,
    sensor: str | None = None,
    source: str | os.PathLike[str] = "<picamera2>",
) -> RawImage:
    """Make a RawImage from a picamera2 raw buffer, its stream configuration and its request metadata.

    Parameters
    ----------
    array : ndarray of uint8, shape (height, stride)
        What ``Picamera2.capture_array("raw")`` returns; a uint16 ``(height, stride / 2)`` view of it and the flat
        buffer of ``capture_buffer("raw")`` are accepted too. It is never modified nor shared with the result.
    config : mapping
        The raw stream configuration, ``picam2.camera_configuration()["raw"]``
        (``{"format": "SBGGR10_CSI2P", "size": (width, height), "stride": ..., "framesize": ...}``), or the whole
        camera configuration with ``"raw"`` and ``"sensor"`` (``{"bit_depth": 10, ...}``) keys. A ``"model"`` key
        (picamera2's ``camera_properties["Model"]``, e.g. ``"imx708_wide"``) names the sensor.
    metadata : mapping, optional
        The request metadata (``request.get_metadata()``). ``SensorBlackLevels`` (R, Gr, Gb, B on a 16-bit
        scale, 4096 = 64 at 10 bits) gives the black level of each 2x2 site; ``ExposureTime`` (µs),
        ``AnalogueGain``, ``DigitalGain``, ``ColourGains``, ``ColourCorrectionMatrix``, ``ColourTemperature``,
        ``Lux`` and ``SensorTimestamp`` are kept as ``exposure_time_s``, ``analogue_gain``, ... in
        ``RawImage.metadata``.
    sensor : str, optional
        Sensor name; by default found in ``config["model"]``.
    source : str or path-like
        What to call the data in messages and ``metadata["path"]``.

    Returns
    -------
    RawImage
        The mosaic at the sensor's bit depth, its pattern (from the format string, flips included), per-site black
        levels (``SensorBlackLevels``, else the sensor registry's, else NaN: unknown, an error where a black level
        is needed) and white level.

    Raises
    ------
    RawFormatError
        One line naming ``source`` for an unknown format, a stride too short for the width, an array smaller than
        the configuration says, inconsistent sizes, or malformed metadata.

    Notes
    -----
    ``<order>_PISP_COMP1``, the Pi 5's default raw format, is lossy (errors up to 256 on the 16-bit scale, 4 DN
    at 10 bits) and not for calibration: configure an unpacked raw format (``raw={"format": "SBGGR16"}`` on a Pi 5)
    instead. It is decoded anyway, with a :class:`PicamcalWarning`, following the Linux kernel's description
    ("Raspberry Pi PiSP compressed 8-bit Bayer formats", ``V4L2_PIX_FMT_PISP_COMP1_*``) and rpicam-apps'
    ``image/dng.cpp`` decoder: each 8-byte block holds 8 pixels as two little-endian 32-bit words (even pixels,
    then odd); a word's 2 low bits pick a quantisation mode (0: steps of 16 up to level 320, then 32; 1: 64;
    2: 128; 3: an escape coding each pair in 15 bits with steps of 256, then 512), the inner two samples are
    coded as a minimum and a difference and the outer two relative to their inner neighbour. libcamera compresses
    with an offset of 2048 (mode 1), added back with saturation at 65535. The decoded values are on a 16-bit
    scale; with ``config["sensor"]["bit_depth"]`` = b they are returned at b bits as
    ``min(2**b - 1, (v + 2**(15 - b)) >> (16 - b))`` (rounded to the nearest DN), else as 16-bit values.

    Examples
    --------
    >>> import numpy as np
    >>> buffer = np.zeros((2, 32), np.uint8)  # 2 rows of 4 RAW10 pixels, stride padded to 32 bytes
    >>> buffer[:, :5] = [0xFF, 0x00, 0x80, 0x01, 0b11_10_01_00]
    >>> config = {"format": "SBGGR10_CSI2P", "size": (4, 2), "stride": 32, "framesize": 64}
    >>> raw = from_picamera2(buffer, config, {"SensorBlackLevels": (4096, 4096, 4096, 4096)})
    >>> raw.bayer[0].tolist(), raw.pattern, raw.black_level, raw.white_level
    ([1020, 1, 514, 7], 'BGGR', (64.0, 64.0, 64.0, 64.0), 1023)
    """
    source = str(source)
    layout = _layout(array, config, source)
    if metadata is None:
        metadata = {}
    if not isinstance(metadata, Mapping):
        raise RawFormatError(f"request metadata must be a dict, not {type(metadata).__name__}", source)
    name, model = _resolve_sensor(sensor, config, metadata, source)
    meta: dict[str, Any] = {"format": "picamera2", "path": source, "raw_format": layout.name, "stride": layout.stride}
    if model is not None:
        meta["model"] = model
    if layout.sensor_bits is not None:
        meta["sensor_bit_depth"] = layout.sensor_bits
    if layout.packing == "pisp":
        meta["lossy_compression"] = "PISP_COMP1"
    meta.update(_exposure_metadata(metadata, source))
    levels = _sensor_black_levels(metadata, source)
    bayer, bit_depth, white = _decode(layout, source)
    black, meta["black_level_source"] = _black_levels(levels, layout.pattern, bit_depth, name)
    try:
        return RawImage(bayer, layout.pattern, black, white, bit_depth, name, meta)
    except RawFormatError as exc:
        raise RawFormatError(exc.problem, source) from None


def to_picamera2(raw: RawImage, *, packed: bool = True, align: int = 32) -> tuple[np.ndarray, dict, dict]:
    """The buffer, configuration and metadata picamera2 would give for ``raw``: the inverse of :func:`from_picamera2`.

    Packed ``S<order><bits>_CSI2P`` for 10 and 12 bits (unpacked ``S<order><bits>`` otherwise: one byte per pixel
    at 8 bits, else little-endian uint16), rows padded to ``align`` bytes (32 on a Pi 4, 64 on a Pi 5),
    ``SensorBlackLevels`` on the 16-bit scale (left out when the black level is unknown).

    Examples
    --------
    >>> array, config, metadata = to_picamera2(raw)  # doctest: +SKIP
    >>> config["raw"]["format"]  # doctest: +SKIP
    'SBGGR10_CSI2P'
    """
    bits = raw.bit_depth
    packed = packed and bits in (10, 12)
    row_bytes = packed_row_bytes(raw.width, bits) if packed else raw.width if bits == 8 else 2 * raw.width
    stride = -(-row_bytes // align) * align
    if packed:
        array = pack(raw.bayer, bits, stride)
    else:
        array = np.zeros((raw.height, stride), dtype=np.uint8)
        samples = raw.bayer.astype(np.uint8) if bits == 8 else raw.bayer.astype("<u2").view(np.uint8)
        array[:, :row_bytes] = samples.reshape(raw.height, -1)
    names = [c if c != "G" else ("Gr" if raw.pattern[site ^ 1] == "R" else "Gb") for site, c in enumerate(raw.pattern)]
    by_name = dict(zip(names, raw.black_level, strict=True))
    scale = 2.0 ** (16 - bits)
    config = {
        "raw": {
            "format": f"S{raw.pattern}{bits}{'_CSI2P' if packed else ''}",
            "size": (raw.width, raw.height),
            "stride": stride,
            "framesize": stride * raw.height,
        },
        "sensor": {"bit_depth": bits, "output_size": (raw.width, raw.height)},
        "model": raw.sensor,
    }
    metadata: dict[str, Any] = {}
    if all(math.isfinite(b) for b in raw.black_level):  # an unknown (NaN) black level stays unknown
        metadata["SensorBlackLevels"] = [round(by_name[n] * scale) for n in ("R", "Gr", "Gb", "B")]
    if raw.metadata.get("exposure_time_s"):
        metadata["ExposureTime"] = round(1e6 * float(raw.metadata["exposure_time_s"]))
    if raw.metadata.get("analogue_gain"):
        metadata["AnalogueGain"] = float(raw.metadata["analogue_gain"])
    return array, config, metadata


def write_raw_as_picamera2_npy(path: str | os.PathLike[str], raw: RawImage, overwrite: bool = True) -> Path:
    """Write ``raw`` as picamera2 would capture it (packed buffer), as ``.npy`` with its JSON sidecar.

    Examples
    --------
    >>> write_raw_as_picamera2_npy("white.npy", raw)  # doctest: +SKIP
    """
    array, config, metadata = to_picamera2(raw)
    return write_picamera2_npy(path, array, config, metadata, sensor=raw.sensor, overwrite=overwrite)


def is_npy(head: bytes) -> bool:
    """True if the first bytes of a file are a NumPy ``.npy`` header.

    Examples
    --------
    >>> is_npy(b"\\x93NUMPY\\x01\\x00"), is_npy(b"II*\\x00")
    (True, False)
    """
    return head[:6] == b"\x93NUMPY"


def write_picamera2_npy(
    path: str | os.PathLike[str],
    array: np.ndarray,
    config: Mapping[str, Any],
    metadata: Mapping[str, Any] | None = None,
    *,
    sensor: str | None = None,
    overwrite: bool = True,
) -> Path:
    """Dump a picamera2 raw buffer as captured to ``.npy`` with a JSON sidecar, both written atomically.

    The buffer goes to ``path`` (``np.save``; ``.npy`` is appended to a name without it), the rest to
    ``path.with_suffix(".json")``::

        {"format": "picamcal-picamera2", "version": 1,
         "config": {...},    # the configuration as given (tuples become lists, other objects strings)
         "metadata": {...},  # the request metadata, likewise
         "sensor": "imx708"} # the sensor name (from ``sensor`` or config["model"]) or null

    The configuration is checked against the buffer first, so that only readable dumps are written.

    Parameters
    ----------
    path : path-like
        The ``.npy`` file to write; the sidecar goes beside it.
    array, config, metadata, sensor
        As for :func:`from_picamera2`: the buffer as captured and what picamera2 reports about it.
    overwrite : bool
        Replace existing files (default); if false, an existing ``.npy`` or sidecar is an error.

    Returns
    -------
    Path
        The ``.npy`` file written.

    Raises
    ------
    RawFormatError
        The buffer does not fit its configuration (see :func:`from_picamera2`).
    OutputError
        A file exists already and ``overwrite`` is false, or the folder is not writable.

    Examples
    --------
    >>> write_picamera2_npy("white.npy", picam2.capture_array("raw"), picam2.camera_configuration())  # doctest: +SKIP
    PosixPath('white.npy')
    """
    path = Path(path)
    if path.suffix != ".npy":
        path = path.with_name(path.name + ".npy")
    sidecar = path.with_suffix(".json")
    if metadata is not None and not isinstance(metadata, Mapping):
        raise RawFormatError(f"request metadata must be a dict, not {type(metadata).__name__}", path)
    _layout(array, config, str(path))
    name, _ = _resolve_sensor(sensor, config, metadata or {}, str(path), warn=False)
    record = {
        "format": SIDECAR_FORMAT,
        "version": SIDECAR_VERSION,
        "config": _jsonable(config),
        "metadata": _jsonable(metadata or {}),
        "sensor": name or sensor,
    }
    text = json.dumps(record, indent=1)
    if not overwrite:
        for target in (path, sidecar):
            if target.exists():
                raise OutputError("exists already (use --overwrite to replace it)", target)
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        np.save(f, _buffer_array(array))
    with atomic_path(sidecar, overwrite=overwrite) as tmp:
        tmp.write_text(text + "\n", encoding="utf-8")
    return path


def read_picamera2_npy(path: str | os.PathLike[str], *, expected_shape: tuple[int, int] | None = None) -> RawImage:
    """Read a raw buffer dumped by :func:`write_picamera2_npy` (the ``.npy`` and its ``.json`` sidecar).

    Nothing is allocated before the sizes are checked: the ``.npy`` header's against the file's size, the frame size
    the sidecar declares against :func:`picamcal.limits.check_size` (and ``expected_shape``), and the buffer's
    bytes against what that frame can take (:func:`max_stride` per row). No pickles are loaded.

    Parameters
    ----------
    path : path-like
        The ``.npy`` file.
    expected_shape : (height, width), optional
        The Bayer size the caller needs (a calibration's): another size raises ``CalibrationFileError`` before the
        buffer is read.

    Returns
    -------
    RawImage
        As :func:`from_picamera2` makes it, with ``metadata["format"]`` ``"picamera2-npy"`` and ``path`` the file.

    Raises
    ------
    RawFormatError
        One line naming the file: missing or corrupt ``.npy``, missing or corrupt sidecar, a declared size over
        the pixel limit, or a buffer that does not fit its configuration.
    CalibrationFileError
        The sidecar's frame size is not ``expected_shape``.

    Examples
    --------
    >>> raw = read_picamera2_npy("white.npy")  # doctest: +SKIP
    >>> raw.metadata["format"], raw.pattern  # doctest: +SKIP
    ('picamera2-npy', 'BGGR')
    """
    path = Path(path)
    header = _npy_header(path)
    record = _load_sidecar(path)
    spec, width, height, _, _ = _stream(record["config"], str(path))
    check_size(path, width, height, expected_shape)
    frame = f"{width}x{height} {spec.name}"
    array = _load_npy(path, header, height * max_stride(spec.row_bytes(width)), frame)
    raw = from_picamera2(array, record["config"], record["metadata"], sensor=record["sensor"], source=path)
    raw.metadata["format"] = "picamera2-npy"
    return raw


def capture_raw(picam2: Any, *, sensor: str | None = None) -> RawImage:
    """Capture one raw frame from a running ``Picamera2`` camera (on the Pi) as a RawImage.

    Parameters
    ----------
    picam2 : picamera2.Picamera2
        A camera configured with a raw stream and started. The sensor's bit depth comes from
        ``camera_configuration()["sensor"]`` and its name from ``camera_properties["Model"]``.
    sensor : str, optional
        Sensor name, if the camera's model is not enough.

    Returns
    -------
    RawImage
        As :func:`from_picamera2` makes it; the request is released whatever happens.

    Examples
    --------
    >>> from picamera2 import Picamera2  # doctest: +SKIP
    >>> picam2 = Picamera2()  # doctest: +SKIP
    >>> picam2.configure(picam2.create_still_configuration(raw={"format": "SBGGR16"}))  # doctest: +SKIP
    >>> picam2.start()  # doctest: +SKIP
    >>> raw = capture_raw(picam2)  # doctest: +SKIP
    """
    config = dict(picam2.camera_configuration())
    model = picam2.camera_properties.get("Model")
    if model is not None:
        config["model"] = model
    request = picam2.capture_request()
    try:  # decoded before the buffer goes back to the camera, in case the array shares its memory
        return from_picamera2(
            request.make_array("raw"), config, request.get_metadata(), sensor=sensor, source="<picamera2 capture>"
        )
    finally:
        request.release()


_UINT32 = 2**32 - 1  # libcamera's sizes, strides and frame sizes are unsigned 32-bit


def _integer(value: Any, what: str, source: str, low: int = 0, high: int | None = None) -> int:
    bad = isinstance(value, bool) or not isinstance(value, (int, np.integer))
    if bad or value < low or (high is not None and value > high):
        limits = f">= {low}" if high is None else f"from {low} to {high}"
        raise RawFormatError(f"{what} must be an integer {limits}, not {short(value)}", source)
    return int(value)


def _stream_config(config: Any, source: str) -> tuple[Mapping[str, Any], Mapping[str, Any]]:
    """The raw stream's configuration and the sensor's, from either form picamera2 reports."""
    if not isinstance(config, Mapping):
        raise RawFormatError(f"the configuration must be a dict, not {type(config).__name__}", source)
    stream = config
    if "format" not in config:
        if "raw" not in config:
            raise RawFormatError("the configuration has neither a 'format' nor a 'raw' stream", source)
        stream = config["raw"]
        if not isinstance(stream, Mapping) or "format" not in stream:
            raise RawFormatError("the configuration's 'raw' stream is missing or has no 'format'", source)
    sensor = config.get("sensor")
    if sensor is None:
        sensor = {}
    if not isinstance(sensor, Mapping):
        raise RawFormatError(f"the configuration's 'sensor' must be a dict, not {short(sensor)}", source)
    return stream, sensor


def _stream(config: Any, source: str) -> tuple[RawFormat, int, int, int | None, Mapping[str, Any]]:
    """The raw stream's format, width, height and sensor bit depth (or None), and its configuration, checked."""
    stream, sensor = _stream_config(config, source)
    fmt = stream["format"]
    if not isinstance(fmt, str):
        raise RawFormatError(f"the raw format must be a string such as 'SBGGR10_CSI2P', not {short(fmt)}", source)
    spec = parse_raw_format(fmt, source)

    size = stream.get("size")
    if not isinstance(size, (tuple, list)) or len(size) != 2:
        raise RawFormatError(f"the raw 'size' must be (width, height), not {short(size)}", source)
    width = _integer(size[0], "the raw width", source, low=2, high=_UINT32)
    height = _integer(size[1], "the raw height", source, low=2, high=_UINT32)
    if width % 2 or height % 2:
        raise RawFormatError(f"a Bayer image needs even width and height, not {width}x{height}", source)
    sensor_bits = sensor.get("bit_depth")
    if sensor_bits is not None:
        sensor_bits = _integer(sensor_bits, "the sensor bit_depth", source, low=1)
        if not 8 <= sensor_bits <= 16:
            raise RawFormatError(f"a sensor bit_depth of {sensor_bits} is not between 8 and 16", source)
    return spec, width, height, sensor_bits, stream


def _layout(array: Any, config: Any, source: str) -> _Layout:
    spec, width, height, sensor_bits, stream = _stream(config, source)
    what = "PiSP-compressed" if spec.packing == "pisp" else f"{spec.bits} bits"
    rows = _rows(array, stream, height, spec.row_bytes(width), f"{width} pixels at {what}", source)
    stride = rows.shape[1]
    return _Layout(spec.name, spec.pattern, spec.packing, spec.bits, width, height, stride, sensor_bits, rows)


def _buffer_array(array: Any) -> np.ndarray:
    if isinstance(array, (bytes, bytearray, memoryview)):
        return np.frombuffer(array, dtype=np.uint8)
    return array


def _rows(array: Any, stream: Mapping[str, Any], height: int, row_bytes: int, pixels: str, source: str) -> np.ndarray:
    """The buffer as uint8 rows of ``stride`` bytes, after checking it against the stream's stride and size."""
    array = _buffer_array(array)
    if not isinstance(array, np.ndarray):
        raise RawFormatError(f"the raw buffer must be a numpy array, not {type(array).__name__}", source)
    if array.dtype.kind != "u" or array.dtype.itemsize not in (1, 2) or array.ndim not in (1, 2):
        raise RawFormatError(
            f"the raw buffer must be a 2-D uint8 (or uint16) array, not {array.ndim}-D {array.dtype}", source
        )
    if array.dtype.itemsize == 2:  # a uint16 view of the little-endian bytes
        array = np.ascontiguousarray(array, dtype="<u2").view(np.uint8)
    stride = stream.get("stride")
    if stride is not None:
        stride = _integer(stride, "the stride", source)
    elif array.ndim == 2:
        stride = array.shape[1]
    else:
        stride = row_bytes
    if stride < row_bytes:
        raise RawFormatError(f"stride of {stride} bytes is too short for {pixels} ({row_bytes} bytes)", source)
    if stride > max_stride(row_bytes):
        raise RawFormatError(
            f"stride of {stride} bytes is longer than a camera pads {pixels} ({row_bytes} bytes, at most "
            f"{max_stride(row_bytes)})",
            source,
        )
    framesize = stream.get("framesize")
    if framesize is not None:
        framesize = _integer(framesize, "the framesize", source)
        if framesize < (height - 1) * stride + row_bytes:
            raise RawFormatError(f"framesize of {framesize} bytes is less than {height} rows of {stride}", source)
    if array.ndim == 1:
        if array.size < height * stride:
            raise RawFormatError(
                f"buffer of {array.size} bytes is smaller than {height} rows x {stride} bytes per row", source
            )
        return array[: height * stride].reshape(height, stride)
    if array.shape[0] < height or array.shape[1] < row_bytes:
        raise RawFormatError(
            f"array of {array.shape[0]} x {array.shape[1]} bytes is smaller than {height} rows x {row_bytes} bytes",
            source,
        )
    if array.shape != (height, stride):
        raise RawFormatError(
            f"array of {array.shape[0]} x {array.shape[1]} bytes does not match {height} rows of stride {stride}",
            source,
        )
    return array


def _decode(layout: _Layout, source: str) -> tuple[np.ndarray, int, int]:
    """The mosaic (an array of its own) at its bit depth, that bit depth and the white level."""
    rows, width, bits = layout.rows, layout.width, layout.bits
    if layout.packing == "pisp":
        warnings.warn(
            f"{source}: {layout.name} is lossy compression (errors up to 256 on the 16-bit scale), not for "
            "calibration; configure an unpacked raw format such as SBGGR16",
            PicamcalWarning,
            stacklevel=3,
        )
        out_bits = layout.sensor_bits or 16
        return np.ascontiguousarray(_pisp_decompress(rows, width, out_bits)), out_bits, (1 << out_bits) - 1
    if layout.packing == "csi2p":
        bayer = _unpack_raw14(rows, width) if bits == 14 else unpack(rows, width, bits)
        return np.ascontiguousarray(bayer), bits, (1 << bits) - 1
    if bits == 8:
        return rows[:, :width].astype(np.uint16), 8, 255
    bayer = np.ascontiguousarray(rows[:, : 2 * width]).view("<u2").astype(np.uint16)
    if bits < 16:
        top = int(bayer.max())
        if top >> bits:
            raise RawFormatError(f"values up to {top} do not fit the {bits} bits of {layout.name}", source)
        return bayer, bits, (1 << bits) - 1
    native = layout.sensor_bits
    if native is None or native == 16:
        return bayer, 16, 65535
    shift = 16 - native
    if int(np.bitwise_or.reduce(bayer, axis=None)) & ((1 << shift) - 1):
        warnings.warn(
            f"{source}: {layout.name} values are not multiples of {1 << shift}, so not {native}-bit data "
            "left-justified as the sensor bit_depth says; kept at 16 bits",
            PicamcalWarning,
            stacklevel=3,
        )
        return bayer, 16, 65535
    return bayer >> shift, native, (1 << native) - 1


def _unpack_raw14(rows: np.ndarray, width: int) -> np.ndarray:
    """CSI-2 RAW14: 4 pixels in 7 bytes, the 8 MSBs of each, then their 6 LSBs as one little-endian 24-bit word.

    Linux kernel V4L2_PIX_FMT_SBGGR14P (pixfmt-srggb14p): byte 4 holds pixel 0's bits 5-0 and pixel 1's 1-0,
    byte 5 pixel 1's bits 5-2 and pixel 2's 3-0, byte 6 pixel 2's bits 5-4 and pixel 3's 5-0.
    """
    groups = rows[:, : -(-width // 4) * 7].reshape(rows.shape[0], -1, 7).astype(np.uint32)
    low = groups[..., 4] | groups[..., 5] << 8 | groups[..., 6] << 16
    out = np.empty((rows.shape[0], groups.shape[1], 4), dtype=np.uint16)
    for k in range(4):
        out[..., k] = groups[..., k] << 6 | (low >> (6 * k)) & 0x3F
    return out.reshape(rows.shape[0], -1)[:, :width]


@functools.lru_cache(maxsize=16)
def _pisp_levels(bits: int) -> np.ndarray:
    """Decoded value of every (quantisation mode, level) as ``mode * _PISP_MAX_Q + level``, at ``bits`` bits.

    Dequantisation per the kernel's description (FSD = 65536) and rpicam-apps' ``dequantize``, then the
    compression offset added back with saturation (``postprocess``), then rounding to ``bits`` bits.
    """
    q = np.arange(_PISP_MAX_Q, dtype=np.int64)
    levels = np.stack(
        [
            np.where(q < 320, 16 * q, 32 * (q - 160)),  # mode 0: 321 levels of FSD/4096, then FSD/2048
            64 * q,  # mode 1: FSD/1024
            128 * q,  # mode 2: FSD/512
            np.where(q < 94, 256 * q, 512 * (q - 47)),  # mode 3 escape: 95 levels of FSD/256, then FSD/128
        ]
    )
    values = np.minimum(np.minimum(levels, 0xFFFF) + _PISP_OFFSET, 0xFFFF)
    if bits < 16:
        shift = 16 - bits
        values = np.minimum((values + (1 << (shift - 1))) >> shift, (1 << bits) - 1)
    return values.astype(np.uint16).ravel()


def _pisp_decompress(rows: np.ndarray, width: int, bits: int = 16) -> np.ndarray:
    """Decode PiSP compression mode 1 rows (uint8, >= 8 * ceil(width / 8) bytes each) to a uint16 mosaic.

    Each 8-pixel block is two little-endian 32-bit words, the even pixels then the odd ones; the fields of a word,
    from its least significant bit: quantisation mode (2 bits), then for modes 0-2 the inner pair as min(q1, q2)
    (9 bits) and q2 - q1 + 64 (7 bits), then q0 and q3 relative to their inner neighbour (7 bits each); for mode 3
    two 15-bit fields 2816 * (qa >> 4) + 16 * qb + (qa & 15) for (q0, q1) and (q2, q3).
    """
    height, blocks = rows.shape[0], -(-width // 8)
    words = np.ascontiguousarray(rows[:, : blocks * 8]).view("<u4").reshape(height, blocks, 2)  # (.., phase)
    mode = (words & 3).astype(np.int32)
    field0 = ((words >> 2) & 511).astype(np.int32)
    difference = ((words >> 11) & 127).astype(np.int32) - 64  # q2 - q1
    q = np.empty((4, *words.shape), dtype=np.int32)
    np.subtract(field0, np.minimum(difference, 0), out=q[1])
    np.add(field0, np.maximum(difference, 0), out=q[2])
    # Mode 2 codes an inner pair with both samples in [384, 511] as q1 (9 bits) and q2 - 384 (7 bits).
    high_pair = np.nonzero((mode == 2) & (field0 >= 384))
    q[1][high_pair] = field0[high_pair]
    q[2][high_pair] = difference[high_pair] + 64 + 384
    # The outer samples are offsets from max(0, inner - 64), capped at 384 in mode 2.
    cap = np.where(mode == 2, 384, _PISP_MAX_Q)
    q[0] = np.minimum(np.maximum(q[1] - 64, 0), cap) + ((words >> 18) & 127)
    q[3] = np.minimum(np.maximum(q[2] - 64, 0), cap) + ((words >> 25) & 127)
    escape = np.nonzero(mode == 3)  # the "7.5-bit" escape; rare in real images, so decoded where it occurs
    if escape[0].size:
        for k, shift in ((0, 2), (2, 17)):
            pair = ((words[escape] >> shift) & 32767).astype(np.int32)
            q[k][escape] = (pair & 15) + 16 * ((pair >> 8) // 11)
            q[k + 1][escape] = (pair >> 4) % 176
    q += mode * _PISP_MAX_Q
    levels = _pisp_levels(bits)
    out = np.empty((height, blocks, 4, 2), dtype=np.uint16)  # (.., k, phase) holds pixel 8 * block + 2 * k + phase
    for k in range(4):
        out[:, :, k, :] = levels[q[k]]
    return out.reshape(height, blocks * 8)[:, :width]


def _sensor_black_levels(metadata: Mapping[str, Any], source: str) -> list[float] | None:
    """``SensorBlackLevels`` (R, Gr, Gb, B on the 16-bit scale), checked, or None."""
    levels = metadata.get("SensorBlackLevels")
    if levels is None:
        return None
    if not isinstance(levels, (list, tuple, np.ndarray)) or len(levels) != 4:
        raise RawFormatError(f"SensorBlackLevels must be 4 numbers (R, Gr, Gb, B), not {short(levels)}", source)
    values = [_number(v, "SensorBlackLevels", source) for v in levels]
    if min(values) < 0 or max(values) > 65535:
        raise RawFormatError(f"SensorBlackLevels {short(levels)} are outside the 16-bit range", source)
    return values


def _black_levels(
    levels: list[float] | None, pattern: str, bit_depth: int, sensor: str | None
) -> tuple[tuple[float, float, float, float], str]:
    """Per-site black levels at ``bit_depth`` bits, and where they came from."""
    if levels is not None:
        by_name = dict(zip(("R", "Gr", "Gb", "B"), levels, strict=True))
        # A green site is Gr when it shares its row of the 2x2 block with red.
        names = [c if c != "G" else ("Gr" if pattern[site ^ 1] == "R" else "Gb") for site, c in enumerate(pattern)]
        scale = 2.0 ** (bit_depth - 16)
        return tuple(by_name[n] * scale for n in names), "SensorBlackLevels"  # type: ignore[return-value]
    if sensor is not None:
        return (black_level_at(get_sensor(sensor), bit_depth),) * 4, "registry"
    # Unknown, not 0: the error comes where a black level is needed (picamcal.raw.model.require_black_level).
    return (math.nan,) * 4, "none"


def _number(value: Any, key: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise RawFormatError(f"metadata {key} must be numeric, not {short(value)}", source)
    try:
        number = float(value)
    except OverflowError:  # an integer beyond any float
        number = math.inf
    if not math.isfinite(number):
        raise RawFormatError(f"metadata {key} is {short(value)}, not a finite number", source)
    return number


def _exposure_metadata(metadata: Mapping[str, Any], source: str) -> dict[str, Any]:
    """The request metadata picamcal keeps, under its own names and units."""
    meta: dict[str, Any] = {}
    for control, (key, scale) in _METADATA_SCALARS.items():
        if metadata.get(control) is not None:
            value = _number(metadata[control], control, source)
            if value < 0:
                raise RawFormatError(f"metadata {control} is negative ({value})", source)
            meta[key] = value * scale
    for control, (key, length) in _METADATA_VECTORS.items():
        values = metadata.get(control)
        if values is not None:
            if not isinstance(values, (list, tuple, np.ndarray)) or len(values) != length:
                raise RawFormatError(f"metadata {control} must be {length} numbers, not {short(values)}", source)
            meta[key] = [_number(v, control, source) for v in values]
    if metadata.get("SensorTimestamp") is not None:
        meta["sensor_timestamp_ns"] = _integer(metadata["SensorTimestamp"], "metadata SensorTimestamp", source)
    return meta


def _resolve_sensor(
    sensor: Any, config: Mapping[str, Any], metadata: Mapping[str, Any], source: str, warn: bool = True
) -> tuple[str | None, str | None]:
    """The registry name of the sensor and the model text it was found in."""
    if sensor is not None:
        if not isinstance(sensor, str):
            raise RawFormatError(f"sensor must be a name such as 'imx219', not {short(sensor)}", source)
        name = find_sensor_name(sensor)
        require_colour_sensor(name, source)
        if name is None and warn:
            warnings.warn(
                f"{source}: sensor {sensor!r} is not in picamcal's registry; its constants are unknown",
                PicamcalWarning,
                stacklevel=3,
            )
        return name, sensor
    for holder in (config, metadata):
        for key in ("model", "Model"):
            text = holder.get(key)
            if isinstance(text, str) and text:
                name = find_sensor_name(text)
                require_colour_sensor(name, source)
                return name, text
    return None, None


def require_colour_sensor(name: str | None, source: str | os.PathLike[str]) -> None:
    """Raise if the registry knows ``name`` as a monochrome sensor: there is no colour to calibrate.

    Examples
    --------
    >>> require_colour_sensor("imx219", "white.raw")
    """
    if name is not None and get_sensor(name).monochrome:
        raise RawFormatError(
            f"the {name.upper()} is a monochrome sensor: picamcal calibrates colour Bayer sensors, and a monochrome "
            "sensor has no colour crosstalk to unmix",
            source,
        )


def _jsonable(value: Any) -> Any:
    """A JSON-ready copy: mappings to dicts with string keys, sequences and arrays to lists, objects to strings."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


@dataclass(frozen=True)
class _NpyHeader:
    """What a ``.npy`` file declares, checked against the file's size; nothing of that size read yet."""

    shape: tuple[int, ...]
    fortran: bool
    dtype: np.dtype
    offset: int  # where the data starts

    @property
    def nbytes(self) -> int:
        return math.prod(self.shape) * self.dtype.itemsize


def _npy_header(path: Path) -> _NpyHeader:
    """The ``.npy`` header of a raw buffer dump: a 1-D or 2-D unsigned 8 or 16-bit array the file holds whole."""
    require_regular_file(path)
    try:
        with open(path, "rb") as f:
            shape, fortran, dtype = read_npy_header(f, path)
            offset = f.tell()
            available = os.fstat(f.fileno()).st_size - offset
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from None
    if dtype.kind != "u" or dtype.itemsize not in (1, 2) or len(shape) not in (1, 2) or min(shape) < 1:
        raise RawFormatError(f"a {dtype} array of shape {shape}, not a raw buffer (2-D uint8)", path)
    header = _NpyHeader(shape, fortran, dtype, offset)
    if available < header.nbytes:
        raise RawFormatError(f"truncated .npy: {available} of {header.nbytes} bytes of data", path)
    return header


def _load_npy(path: Path, header: _NpyHeader, max_bytes: int, frame: str) -> np.ndarray:
    """The buffer a checked header declares, refused unread if larger than ``max_bytes`` (what ``frame`` needs)."""
    if header.nbytes > max_bytes:
        raise RawFormatError(
            f"a buffer of {header.nbytes} bytes is larger than a {frame} frame can be (at most {max_bytes} bytes)",
            path,
        )
    try:
        with open(path, "rb") as f:
            f.seek(header.offset)
            data = read_array_data(f, header.dtype, math.prod(header.shape), path, ".npy")
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from None
    return data.reshape(header.shape, order="F" if header.fortran else "C")


def _load_sidecar(path: Path) -> dict[str, Any]:
    sidecar = path.with_suffix(".json")
    what = f"sidecar of {path.name}"
    try:
        if require_regular_file(sidecar) > _MAX_SIDECAR_BYTES:
            raise RawFormatError(f"{what} is larger than {_MAX_SIDECAR_BYTES >> 20} MB", sidecar)
        record = json.loads(sidecar.read_text(encoding="utf-8"))
    except RawFormatError:
        if not sidecar.exists():
            raise RawFormatError(
                f"no JSON sidecar {sidecar.name} beside it (written by write_picamera2_npy)", path
            ) from None
        raise
    except (OSError, ValueError, RecursionError) as exc:
        raise RawFormatError(f"corrupt {what} ({type(exc).__name__}: {short(str(exc))})", sidecar) from exc
    if not isinstance(record, dict) or record.get("format") != SIDECAR_FORMAT:
        raise RawFormatError(f'not a picamcal {what} (no "format": "{SIDECAR_FORMAT}")', sidecar)
    if record.get("version") != SIDECAR_VERSION:
        raise RawFormatError(f"unsupported {what} version {short(record.get('version'))}", sidecar)
    if not isinstance(record.get("config"), dict) or not isinstance(record.get("metadata", {}), dict):
        raise RawFormatError(f"corrupt {what}: 'config' and 'metadata' must be objects", sidecar)
    if not isinstance(record.get("sensor"), (str, type(None))):
        raise RawFormatError(f"corrupt {what}: 'sensor' must be a name or null", sidecar)
    return {"config": record["config"], "metadata": record.get("metadata") or {}, "sensor": record.get("sensor")}
