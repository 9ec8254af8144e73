"""A picamera2 raw buffer checked against its stream configuration, and decoded to a mosaic.

Rows are cropped to their pixel bytes (the stride is padded to 32 bytes on a Pi 4, 64 on a Pi 5). Unpacked
formats hold one byte per pixel at 8 bits, else one little-endian uint16; the Pi 5 front end writes ``S<order>16``
left-justified on a 16-bit scale, shifted back to the sensor's bit depth when the configuration gives it and the
low bits are zero. CSI-2 packed formats are unpacked by :mod:`picamcal.raw.packing`, PiSP-compressed ones by
:mod:`picamcal.raw.picamera2.pisp`.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import PicamcalWarning, RawFormatError, short
from ..packing import unpack
from .formats import RawFormat, max_stride, parse_raw_format
from .pisp import pisp_decompress

_UINT32 = 2**32 - 1  # libcamera's sizes, strides and frame sizes are unsigned 32-bit


def integer(value: Any, what: str, source: str, low: int = 0, high: int | None = None) -> int:
    """``value`` as an int from ``low`` to ``high``; anything else (a bool, a float, text) is an error naming it.

    Examples
    --------
    >>> integer(np.uint16(32), "the stride", "<picamera2>")
    32
    """
    bad = isinstance(value, bool) or not isinstance(value, (int, np.integer))
    if bad or value < low or (high is not None and value > high):
        limits = f">= {low}" if high is None else f"from {low} to {high}"
        raise RawFormatError(f"{what} must be an integer {limits}, not {short(value)}", source)
    return int(value)


@dataclass(frozen=True)
class Layout:
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


def read_stream(config: Any, source: str) -> tuple[RawFormat, int, int, int | None, Mapping[str, Any]]:
    """The raw stream's format, width, height and sensor bit depth (or None), and its configuration, checked.

    Examples
    --------
    >>> spec, width, height, bits, _ = read_stream({"format": "SRGGB12_CSI2P", "size": (4056, 3040)}, "<picamera2>")
    >>> spec.name, width, height, bits
    ('SRGGB12_CSI2P', 4056, 3040, None)
    """
    stream, sensor = _stream_config(config, source)
    fmt = stream["format"]
    if not isinstance(fmt, str):
        raise RawFormatError(f"the raw format must be a string such as 'SBGGR10_CSI2P', not {short(fmt)}", source)
    spec = parse_raw_format(fmt, source)

    size = stream.get("size")
    if not isinstance(size, (tuple, list)) or len(size) != 2:
        raise RawFormatError(f"the raw 'size' must be (width, height), not {short(size)}", source)
    width = integer(size[0], "the raw width", source, low=2, high=_UINT32)
    height = integer(size[1], "the raw height", source, low=2, high=_UINT32)
    if width % 2 or height % 2:
        raise RawFormatError(f"a Bayer image needs even width and height, not {width}x{height}", source)
    sensor_bits = sensor.get("bit_depth")
    if sensor_bits is not None:
        sensor_bits = integer(sensor_bits, "the sensor bit_depth", source, low=1)
        if not 8 <= sensor_bits <= 16:
            raise RawFormatError(f"a sensor bit_depth of {sensor_bits} is not between 8 and 16", source)
    return spec, width, height, sensor_bits, stream


def check_layout(array: Any, config: Any, source: str) -> Layout:
    """The buffer checked against its configuration (format, size, stride, frame size), nothing decoded yet.

    Examples
    --------
    >>> layout = check_layout(np.zeros((2, 32), np.uint8), {"format": "SBGGR10_CSI2P", "size": (4, 2)}, "<picamera2>")
    >>> layout.packing, layout.bits, layout.stride, layout.rows.shape
    ('csi2p', 10, 32, (2, 32))
    """
    spec, width, height, sensor_bits, stream = read_stream(config, source)
    what = "PiSP-compressed" if spec.packing == "pisp" else f"{spec.bits} bits"
    rows = _rows(array, stream, height, spec.row_bytes(width), f"{width} pixels at {what}", source)
    stride = rows.shape[1]
    return Layout(spec.name, spec.pattern, spec.packing, spec.bits, width, height, stride, sensor_bits, rows)


def buffer_array(array: Any) -> np.ndarray:
    """A buffer given as bytes as a flat uint8 array; anything else as it is (checked by the caller)."""
    if isinstance(array, (bytes, bytearray, memoryview)):
        return np.frombuffer(array, dtype=np.uint8)
    return array


def _rows(array: Any, stream: Mapping[str, Any], height: int, row_bytes: int, pixels: str, source: str) -> np.ndarray:
    """The buffer as uint8 rows of ``stride`` bytes, after checking it against the stream's stride and size."""
    array = buffer_array(array)
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
        stride = integer(stride, "the stride", source)
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
        framesize = integer(framesize, "the framesize", source)
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


def decode(layout: Layout, source: str) -> tuple[np.ndarray, int, int]:
    """The mosaic (an array of its own) at its bit depth, that bit depth and the white level.

    Examples
    --------
    >>> layout = check_layout(np.full((2, 8), 1, np.uint8), {"format": "SRGGB12", "size": (4, 2)}, "<picamera2>")
    >>> bayer, bits, white = decode(layout, "<picamera2>")
    >>> bayer.tolist(), bits, white
    ([[257, 257, 257, 257], [257, 257, 257, 257]], 12, 4095)
    """
    rows, width, bits = layout.rows, layout.width, layout.bits
    if layout.packing == "pisp":
        warnings.warn(
            f"{source}: {layout.name} is lossy compression (errors up to 256 on the 16-bit scale), not for "
            "calibration; configure an unpacked raw format such as SBGGR16",
            PicamcalWarning,
            stacklevel=3,
        )
        out_bits = layout.sensor_bits or 16
        return np.ascontiguousarray(pisp_decompress(rows, width, out_bits)), out_bits, (1 << out_bits) - 1
    if layout.packing == "csi2p":
        return np.ascontiguousarray(unpack(rows, width, bits)), bits, (1 << bits) - 1
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
