"""DNG raw files: checked and read through LibRaw (rawpy), written by a small TIFF writer of this package.

Only this package knows the DNG tag layout (:mod:`~picamcal.raw.dng.tags`). The reader
(:mod:`~picamcal.raw.dng.reader`) first reads the TIFF structure itself (:mod:`~picamcal.raw.dng.tiff`), only the
bytes it needs, and checks every tag it relies on (type, count and value, DNG specification 1.4) and the raw
image's declared size (:func:`picamcal.limits.check_size`) before anything is decoded; then it takes the mosaic,
CFA pattern, per-site black levels and white level from LibRaw (:mod:`~picamcal.raw.dng.libraw`), and the
exposure, capture date and colour tags from the TIFF tags. The writer (:mod:`~picamcal.raw.dng.writer`) makes an
uncompressed DNG 1.4 that LibRaw reads back bit-exactly: IFD 0 with the mosaic in one strip and the DNG colour
tags (their maths is in the writer's notes), and an EXIF IFD with the exposure time, ISO and capture date
(docs/dng.md). With a calibration it adds the flat field as GainMap opcodes that raw editors apply
(:mod:`~picamcal.raw.dng.opcodes`); :mod:`~picamcal.raw.dng.linear` writes corrected RGB as a LinearRaw DNG.
A DNG without a BlackLevel tag whose sensor is known takes the registry's level
(:func:`~picamcal.raw.dng.reader.with_sensor_black_level`).
"""

from __future__ import annotations

from .linear import write_linear_dng
from .opcodes import GainMap, flat_field_gain_map, read_gain_map
from .reader import read_dng, with_sensor_black_level
from .tiff import is_dng
from .writer import write_dng

__all__ = [
    "GainMap",
    "flat_field_gain_map",
    "is_dng",
    "read_dng",
    "read_gain_map",
    "with_sensor_black_level",
    "write_dng",
    "write_linear_dng",
]
