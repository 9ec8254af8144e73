"""libcamera's raw format names (``SBGGR10_CSI2P``, ...) and the row layout each stands for."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

from ...errors import RawFormatError, closest, short
from ..model import PATTERNS
from ..packing import packed_row_bytes

__all__ = ["PISP_ALIGN", "RAW_FORMATS", "UNICAM_ALIGN", "RawFormat", "max_stride", "parse_raw_format"]

_ORDER = f"({'|'.join(PATTERNS)})"
_UNCOMPRESSED = re.compile(rf"S{_ORDER}(8|10|12|14|16)(_CSI2P)?")
# picamera2 spells it S<order>16_PISP_COMP1 (SensorFormat.format), libcamera <order>_PISP_COMP1.
_PISP = re.compile(rf"S?{_ORDER}(?:16)?_PISP_COMP1")
# libcamera's greyscale formats (R8, R10_CSI2P, ..., MONO_PISP_COMP1) and V4L2's names for them (Y10P, GREY).
_MONO = re.compile(r"(?:R|Y)(?:8|10|12|14|16)(?:_CSI2P|P)?|MONO(?:16)?_PISP_COMP1|GREY")
#: Every raw format name picamcal reads (libcamera's spelling; matched case-insensitively).
RAW_FORMATS: tuple[str, ...] = (
    *(f"S{order}{bits}" for order in PATTERNS for bits in (8, 10, 12, 14, 16)),
    *(f"S{order}{bits}_CSI2P" for order in PATTERNS for bits in (10, 12, 14)),
    *(f"{order}_PISP_COMP1" for order in PATTERNS),
)
_KNOWN_FORMATS = (
    "S<order>{8,10,12,14,16}, S<order>{10,12,14}_CSI2P or <order>_PISP_COMP1 with <order> "
    f"{', '.join(PATTERNS[:-1])} or {PATTERNS[-1]}"
)

#: Row alignment in bytes of libcamera's raw buffers on the Pi 4 and earlier (Unicam) and on the Pi 5 (PiSP front
#: end); :mod:`picamcal.raw.headless` cites the sources.
UNICAM_ALIGN = 32
PISP_ALIGN = 64


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
            return packed_row_bytes(width, self.bits)
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
    if match := re.fullmatch(rf"S{_ORDER}(10|12|14)P", key):  # V4L2's name of a packed format
        return f"; did you mean S{match[1]}{match[2]}_CSI2P?"
    near = closest(key, RAW_FORMATS, cutoff=0.75)
    if near is None:
        return ""
    order = next(o for o in PATTERNS if o in near)
    given = [o for o in PATTERNS if o in key]
    if len(given) == 1:  # the name says its Bayer order: the nearest format of that order
        return f"; did you mean {closest(key, [f for f in RAW_FORMATS if given[0] in f], cutoff=0) or near}?"
    # No order, or a misspelt one: the order is the data's, and guessing it would swap colours without a word.
    names = sorted(near.replace(order, o, 1) for o in PATTERNS)
    return (
        f"; did you mean {', '.join(names[:-1])} or {names[-1]}: the Bayer order is part of the format (rpicam-raw "
        "prints it: 'format NAME')"
    )
