"""Colour-managed sRGB outputs, to look at: PNG (8 or 16 bit) and JPEG, each with an sRGB ICC profile.

``srgb-png``, ``srgb-png16``, ``srgb-jpeg``
    Colour-managed (:func:`picamcal.output.colour.encode_srgb`): the corrected RGB to linear sRGB through a
    3x3 colour matrix (:func:`picamcal.output.colour.camera_to_srgb`), the white reference at linear
    :data:`~picamcal.output.colour.SRGB_WHITE_LEVEL` (0.8: code 231 of 255, 59396 of 65535), values outside
    0-1 clipped, the sRGB transfer function (IEC 61966-2-1), and an sRGB ICC profile embedded. Provenance in
    a PNG ``iTXt`` chunk ``picamcal`` (JSON) and ``tEXt Software``; in the JPEG's EXIF ``ImageDescription``
    (JSON) and ``Software``. JPEG at quality 95 without chroma subsampling (4:4:4).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_path
from .colour import NO_MATRIX, SRGB_WHITE_LEVEL, ColourMatrix, check_rgb, encode_srgb, srgb_transfer
from .encoders import write_jpeg, write_png

#: The colour-managed formats (they need a colour matrix), and the file name suffix of each.
SRGB_SUFFIXES = {"srgb-png": ".png", "srgb-png16": ".png", "srgb-jpeg": ".jpg"}
SRGB_FORMATS = tuple(SRGB_SUFFIXES)
#: JPEG quality of ``srgb-jpeg`` (Pillow's scale, 1-95).
JPEG_QUALITY = 95

_ICC_DATE = bytes.fromhex("07e8 0001 0001 0000 0000 0000")  # 2024-01-01 00:00:00, see _srgb_profile


def write_srgb(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    output_format: str = "srgb-png",
    metadata: Mapping[str, Any] | None = None,
    *,
    colour_matrix: ColourMatrix | None = None,
    white_level: float = SRGB_WHITE_LEVEL,
    overwrite: bool = False,
) -> Path:
    """Write a corrected image as one of the :data:`SRGB_FORMATS`, atomically (:func:`picamcal.output.write_corrected`).

    ``rgb`` is the corrected float image, or its codes already made (uint8 for ``srgb-png`` and ``srgb-jpeg``,
    uint16 for ``srgb-png16``: ``picamcal.correct(..., encoding=srgb_encoding(colour_matrix, white_level=...,
    bits=...))``), written as they are; ``colour_matrix`` and ``white_level`` are then those they were made with,
    for the metadata. ``metadata`` gains the encoding, the white level and code, and the colour matrix and its
    source.

    Examples
    --------
    >>> from PIL import Image
    >>> path = write_srgb("white.jpg", np.ones((8, 8, 3), np.float32), "srgb-jpeg")
    >>> json.loads(Image.open(path).getexif()[0x010E])["picamcal"]["white_code"]
    231
    >>> codes = np.full((8, 8, 3), 231, np.uint8)  # as picamcal.correct(..., encoding=srgb_encoding()) gives
    >>> Image.open(write_srgb("codes.png", codes, "srgb-png")).getpixel((0, 0))
    (231, 231, 231)
    """
    if output_format not in SRGB_FORMATS:
        raise ValueError(f"{output_format!r} is not an sRGB format ({', '.join(SRGB_FORMATS)})")
    bits, rgb = (16 if output_format == "srgb-png16" else 8), check_rgb(rgb)
    code_type = np.dtype(np.uint8 if bits == 8 else np.uint16)
    if rgb.dtype.kind in "ui" and rgb.dtype != code_type:
        raise ValueError(f"{output_format} is written from {code_type} codes or a float image, not {rgb.dtype}")
    colour_matrix = colour_matrix if colour_matrix is not None else ColourMatrix(np.eye(3), NO_MATRIX)
    info = dict(metadata or {})
    info.update(
        encoding="sRGB (IEC 61966-2-1), sRGB ICC profile embedded",
        white_level=white_level,
        white_code=int(np.rint((2**bits - 1) * srgb_transfer(np.array(min(white_level, 1.0))))),
        colour_matrix=np.round(colour_matrix.matrix, 6).tolist(),
        colour_matrix_source=colour_matrix.source,
    )
    if rgb.dtype == code_type:
        codes = np.ascontiguousarray(rgb)
    else:
        codes = encode_srgb(rgb, colour_matrix, white_level=white_level, bits=bits)
    description = json.dumps({"picamcal": info})
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        if output_format == "srgb-jpeg":
            _write_jpeg(tmp, codes, description)
        else:
            _write_png(tmp, codes, description)
    return path


def _srgb_profile() -> bytes:
    """LittleCMS's built-in sRGB profile (through Pillow), with a fixed creation date.

    LittleCMS stamps the profile with the time it was made; a fixed one keeps the outputs the same bytes in
    every worker and run (the profile has no ID checksum over the header: its ID field is zero).
    """
    from PIL import ImageCms

    profile = bytearray(ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes())
    profile[24:36] = _ICC_DATE
    return bytes(profile)


def _write_jpeg(path: Path, codes: np.ndarray, description: str) -> None:
    write_jpeg(path, codes, quality=JPEG_QUALITY, description=description, icc_profile=_srgb_profile())


def _write_png(path: Path, codes: np.ndarray, description: str) -> None:
    """8 or 16 bit, deflated on the kernel threads (:func:`picamcal.output.encoders.write_png`)."""
    write_png(path, codes, description=description, icc_profile=_srgb_profile())


__all__ = ["JPEG_QUALITY", "SRGB_FORMATS", "SRGB_SUFFIXES", "write_srgb"]
