"""Plain DNGs (rpicam-still's, picamcal's), read straight from their strips instead of by LibRaw.

rpicam-still (rpicam-apps) and picamcal write the mosaic the same plain way: uncompressed 16-bit samples in
strips, a 1x1 or 2x2 whole-number BlackLevel and a WhiteLevel (picamera2's PiDNG packs 10 and 12-bit samples:
LibRaw unpacks those). LibRaw's unpacking of a plain file costs an 8 MP frame about 23 ms on this machine, eight
times the whole read of the file here (``benchmarks/run.py``, "Reading one raw frame"). So when the raw IFD,
checked by :mod:`~picamcal.raw.dng.reader` first, declares nothing else (no tiles, compression,
LinearizationTable, ActiveArea, MaskedAreas, BlackLevelDeltaH/V, SampleFormat, Predictor or FillOrder other
than 1), its strips are read into the mosaic here; the result is LibRaw's, bit for bit
(``tests/test_dng_plain.py`` compares the two on each layout). Any other DNG is LibRaw's to decode.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np

from ...errors import RawFormatError
from ...limits import check_size
from .libraw import Decoded
from .tags import (
    ACTIVE_AREA,
    BLACK_DELTA_H,
    BLACK_DELTA_V,
    FILL_ORDER,
    LINEARIZATION_TABLE,
    MASKED_AREAS,
    PREDICTOR,
    SAMPLE_FORMAT,
    SHORT,
    WHITE_LEVEL,
)
from .tiff import Field, TiffFile

#: Tags whose presence leaves the decoding to LibRaw: they change which samples are the image or their values.
_LIBRAW_ONLY = (LINEARIZATION_TABLE, BLACK_DELTA_H, BLACK_DELTA_V, ACTIVE_AREA, MASKED_AREAS)
#: Tags that must be absent or 1 (unsigned integers, no predictor, the usual bit order).
_ONE_OR_ABSENT = (SAMPLE_FORMAT, PREDICTOR, FILL_ORDER)


class Layout(NamedTuple):
    """What the checked raw IFD declares: the mosaic's size, sample bits and compression, its Bayer pattern,
    BlackLevel (``black_repeat`` rows x columns of values, row by row), WhiteLevel, and for strips, their offsets
    and rows (None for tiles)."""

    width: int
    height: int
    bits: int
    compression: int
    pattern: str
    black_repeat: tuple[int, int]
    black: tuple[float, ...]
    white: int
    strip_offsets: Sequence[int] | None
    rows_per_strip: int


def is_plain(tiff: TiffFile, ifd: Mapping[int, Field], layout: Layout) -> bool:
    """Whether the raw IFD ``ifd`` is one :func:`read_strips` reads exactly as LibRaw would."""
    return (
        layout.strip_offsets is not None
        and (layout.bits, layout.compression) == (16, 1)
        and layout.width >= 2
        and layout.height >= 2
        and WHITE_LEVEL in ifd
        and layout.black_repeat in ((1, 1), (2, 2))
        and all(float(b).is_integer() for b in layout.black)  # LibRaw truncates a fractional black level
        and not any(code in ifd for code in _LIBRAW_ONLY)
        and all(_one_or_absent(tiff, ifd, code) for code in _ONE_OR_ABSENT)
    )


def _one_or_absent(tiff: TiffFile, ifd: Mapping[int, Field], code: int) -> bool:
    field = ifd.get(code)
    if field is None:
        return True
    try:
        return bool(field.type == SHORT and tiff.tag(ifd, code, (SHORT,)) == [1])
    except RawFormatError:  # malformed: LibRaw's to judge
        return False


def read_strips(tiff: TiffFile, layout: Layout, expected_shape: Sequence[int] | None) -> Decoded:
    """The mosaic of a plain raw IFD (:func:`is_plain`), read from its strips; its even-sized visible area checked
    against ``expected_shape`` before anything is allocated.

    Examples
    --------
    >>> import os
    >>> from pathlib import Path
    >>> from picamcal.raw import RawImage, write_dng
    >>> from picamcal.raw.dng.reader import raw_layout
    >>> mosaic = np.arange(48 * 64, dtype=np.uint16).reshape(48, 64) % 1000 + 64
    >>> path = write_dng("x.dng", RawImage(mosaic, "GRBG", (64, 65, 66, 67), 1023, 10, "imx219"))
    >>> with open(path, "rb") as f:
    ...     tiff = TiffFile(f, os.fstat(f.fileno()).st_size, Path(path))
    ...     ifd, layout = raw_layout(tiff, tiff.ifd(tiff.first_ifd, "IFD 0"))
    ...     found = read_strips(tiff, layout, None) if is_plain(tiff, ifd, layout) else None
    >>> bool(np.array_equal(found.bayer, mosaic)), found.pattern, found.black, found.white
    (True, 'GRBG', (64.0, 65.0, 66.0, 67.0), 1023)
    """
    if layout.strip_offsets is None:
        raise ValueError("read_strips reads strips; this raw image is tiled")
    width, height = layout.width // 2 * 2, layout.height // 2 * 2
    check_size(tiff.path, width, height, expected_shape)
    mosaic = np.empty((layout.height, layout.width), np.uint16)
    row_bytes = 2 * layout.width
    into = mosaic.data.cast("B")
    for k, offset in enumerate(layout.strip_offsets):
        first = k * layout.rows_per_strip * row_bytes
        length = min(layout.rows_per_strip, layout.height - k * layout.rows_per_strip) * row_bytes
        tiff.f.seek(offset)
        if tiff.f.readinto(into[first : first + length]) != length:  # the file shrank while it was read
            raise RawFormatError(f"truncated file: strip {k + 1} of the raw image ends early", tiff.path)
    if not np.dtype(tiff.order + "u2").isnative:
        mosaic.byteswap(inplace=True)
    if (height, width) != mosaic.shape:
        mosaic = np.ascontiguousarray(mosaic[:height, :width])
    black = layout.black * 4 if layout.black_repeat == (1, 1) else layout.black
    return Decoded(mosaic, layout.pattern, (black[0], black[1], black[2], black[3]), layout.white, "")
