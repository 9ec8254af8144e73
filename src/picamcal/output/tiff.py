"""Linear TIFF outputs, for measuring: float32 as the values are, uint16 with the white reference at 32768.

Both are one RGB image, interleaved (``PlanarConfiguration`` 1, contiguous) with ``PhotometricInterpretation`` RGB,
which every TIFF reader opens in colour. Neither carries a colour profile or colour-space tag: the values are the
camera's own linear RGB, not any standard space's (the sRGB formats, :mod:`picamcal.output.srgb`, are
colour-managed). The provenance JSON ``{"picamcal": {...}}`` is the ``ImageDescription`` tag, the picamcal version
the ``Software`` tag.

``float32-tiff``
    The values as they are (white reference 1.0).
``uint16-tiff``
    Linear, ``code = round(value * UINT16_WHITE)`` (:data:`picamcal.correct.UINT16_WHITE`; the codes
    ``picamcal.correct(..., dtype=np.uint16)`` returns): the white reference at 32768, so that values up to
    twice the white keep their headroom (clipped at 0 and 65535). What a code means is in the description:
    ``"scale": 32768`` and ``"encoding"`` (``value = code / 32768``), which photo tools leave alone. ImageMagick,
    GIMP, Photoshop and darktable open it as one 16-bit RGB image; Fiji (*File > Open*, or Bio-Formats) as a
    composite of three 16-bit channels, red, green and blue, with the description under *Image > Show Info*.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from .._atomic import atomic_path
from ..correct import UINT16_WHITE
from ..kernels import encode_codes
from .colour import check_rgb, strips
from .provenance import SOFTWARE

#: The TIFF formats (they take ``compression="zstd"``), and their file name suffix.
TIFF_FORMATS = ("float32-tiff", "uint16-tiff")
TIFF_SUFFIX = ".tiff"


def encode_uint16(rgb: np.ndarray) -> np.ndarray:
    """Linear RGB to ``uint16-tiff`` codes, (H, W, 3) as the image: ``round(value * UINT16_WHITE)``, clipped; NaN
    gives 0.

    Examples
    --------
    >>> encode_uint16(np.array([[[1.0, 0.5, 2.5]]], np.float32)).ravel()
    array([32768, 16384, 65535], dtype=uint16)
    """
    rgb = check_rgb(rgb)
    out = np.empty(rgb.shape, dtype=np.uint16)
    for rows in strips(rgb.shape):
        encode_codes(rgb[rows], UINT16_WHITE, out[rows])
    return out


def write_tiff(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    output_format: str = "float32-tiff",
    metadata: Mapping[str, Any] | None = None,
    *,
    overwrite: bool = False,
    compression: str | None = None,
) -> Path:
    """Write a corrected image as one of the :data:`TIFF_FORMATS`, atomically (:func:`picamcal.output.write_corrected`).

    ``rgb`` is the corrected (H, W, 3) image; for ``uint16-tiff`` a uint16 one is its codes already made
    (``picamcal.correct(..., dtype=np.uint16)``, :func:`encode_uint16`), written as they are. ``metadata`` is
    written as given (``uint16-tiff`` adds its ``encoding`` and ``scale``); ``compression="zstd"`` compresses
    losslessly with a predictor (needs imagecodecs).

    Examples
    --------
    >>> path = write_tiff("white.tiff", np.ones((4, 6, 3), np.float32), "uint16-tiff", {"source": "white.dng"})
    >>> with tifffile.TiffFile(path) as tif:
    ...     page = tif.pages.first
    ...     page.shape, page.dtype, page.photometric.name, json.loads(page.description)["picamcal"]["scale"]
    ((4, 6, 3), dtype('uint16'), 'RGB', 32768)
    >>> codes = np.full((4, 6, 3), UINT16_WHITE, np.uint16)  # as picamcal.correct(..., dtype=np.uint16) gives
    >>> path = write_tiff("codes.tiff", codes, "uint16-tiff", {"source": "white.dng"})
    >>> bool(np.array_equal(tifffile.imread(path), codes))
    True
    """
    if output_format not in TIFF_FORMATS:
        raise ValueError(f"{output_format!r} is not a TIFF format ({', '.join(TIFF_FORMATS)})")
    rgb = check_rgb(rgb)
    if rgb.dtype == np.uint16 and output_format != "uint16-tiff":
        raise ValueError(f"uint16 codes are written as uint16-tiff, not {output_format}")
    info = dict(metadata or {})
    if output_format == "float32-tiff":
        image = np.ascontiguousarray(rgb, dtype=np.float32)
    else:
        info.update(encoding=f"linear: value = code / {UINT16_WHITE} (the white reference at {UINT16_WHITE})")
        info.update(scale=UINT16_WHITE)
        image = np.ascontiguousarray(rgb) if rgb.dtype == np.uint16 else encode_uint16(rgb)
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        tifffile.imwrite(
            tmp,
            image,
            photometric="rgb",
            planarconfig="contig",
            description=json.dumps({"picamcal": info}),
            software=SOFTWARE,
            metadata=None,
            compression=compression,
            predictor=True if compression else None,
        )
    return path


__all__ = ["TIFF_FORMATS", "TIFF_SUFFIX", "UINT16_WHITE", "encode_uint16", "write_tiff"]
