"""Raw buffers from picamera2 (libcamera on Raspberry Pi OS): arrays, ``.npy`` dumps, and a capture helper.

picamera2's ``capture_array("raw")`` returns the raw stream's bytes as a uint8 ``(height, stride)`` array; what
they mean is in the stream configuration (``picam2.camera_configuration()["raw"]``: ``format``, ``size``,
``stride``, ``framesize``) and the request metadata (``SensorBlackLevels``, ``ExposureTime``, ...). This package
turns the three into a :class:`~picamcal.raw.model.RawImage` (FORMATS.md section 3). Only this package knows
picamera2's layouts:

- ``S<order><8|10|12|14|16>``: unpacked, one byte per pixel at 8 bits, else one little-endian uint16 per pixel.
  Pi 4 and earlier store the sensor's bits right-justified; the Pi 5 front end only writes ``S<order>16``,
  left-justified on a 16-bit scale, which is shifted back to the sensor's bit depth when the configuration
  gives it (``config["sensor"]["bit_depth"]``) and the low bits are zero (it is then exact).
- ``S<order><10|12|14>_CSI2P``: MIPI CSI-2 RAW10/RAW12/RAW14 packing (:mod:`picamcal.raw.packing`).
- ``<order>_PISP_COMP1``: the Pi 5's default, a lossy 8-bit-per-pixel compression (:mod:`.pisp`); see
  :func:`from_picamera2`.

Rows are cropped to their pixel bytes (the stride is padded to 32 bytes on a Pi 4, 64 on a Pi 5). The Bayer
order comes from the format string, which already includes any flips. picamera2 itself is never imported
here except inside :func:`capture_raw`, which is given a camera object.

Modules: :mod:`.formats` (the format names), :mod:`.buffer` (a buffer checked against its configuration, and
decoded), :mod:`.pisp` (PiSP decompression), :mod:`.metadata` (the request metadata and the sensor's name),
:mod:`.convert` (buffer and RawImage, both ways) and :mod:`.dump` (``.npy`` files with a JSON sidecar).
"""

from __future__ import annotations

from ..model import require_colour_sensor
from ..npy import is_npy
from .convert import capture_raw, from_picamera2, to_picamera2
from .dump import SIDECAR_FORMAT, SIDECAR_VERSION, read_picamera2_npy, write_picamera2_npy, write_raw_as_picamera2_npy
from .formats import PISP_ALIGN, RAW_FORMATS, UNICAM_ALIGN, RawFormat, max_stride, parse_raw_format

__all__ = [
    "PISP_ALIGN",
    "RAW_FORMATS",
    "SIDECAR_FORMAT",
    "SIDECAR_VERSION",
    "UNICAM_ALIGN",
    "RawFormat",
    "capture_raw",
    "from_picamera2",
    "is_npy",
    "max_stride",
    "parse_raw_format",
    "read_picamera2_npy",
    "require_colour_sensor",
    "to_picamera2",
    "write_picamera2_npy",
    "write_raw_as_picamera2_npy",
]
