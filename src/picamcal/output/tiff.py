"""Linear TIFF outputs, for measuring: float32 as the values are, uint16 as an ImageJ hyperstack.

``float32-tiff``
    The values as they are (white reference 1.0), interleaved RGB; ``ImageDescription`` JSON
    ``{"picamcal": {...}}``.
``uint16-tiff``
    Linear, ``code = round(value * UINT16_WHITE)`` (:data:`picamcal.correct.UINT16_WHITE`; the codes
    ``picamcal.correct(..., dtype=np.uint16)`` returns): the white reference at 32768, so that values up to
    twice the white keep their headroom (clipped at 0 and 65535). An ImageJ hyperstack (channels R, G, B,
    composite display, each channel's display range 0-32768) with ImageJ's calibration function set to
    ``value = code / 32768`` (unit "white"), so that Fiji opens it as three channels and measures in units
    of the white reference; the provenance JSON is the ImageJ ``Info`` property.
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
    """Linear RGB to ``uint16-tiff`` codes, planar (3, H, W): ``round(value * UINT16_WHITE)``, clipped; NaN gives 0.

    Examples
    --------
    >>> encode_uint16(np.array([[[1.0, 0.5, 2.5]]], np.float32)).ravel()
    array([32768, 16384, 65535], dtype=uint16)
    """
    rgb = check_rgb(rgb)
    out = np.empty((3, *rgb.shape[:2]), dtype=np.uint16)
    for rows in strips(rgb.shape):
        encode_codes(rgb[rows], UINT16_WHITE, out[:, rows])
    return out


def _is_codes(image: np.ndarray) -> bool:
    """Whether ``image`` is ``uint16-tiff`` codes, planar (3, H, W), rather than a corrected (H, W, 3) image."""
    return image.dtype == np.uint16 and image.ndim == 3 and image.shape[0] == 3


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

    ``rgb`` is the corrected (H, W, 3) image, or for ``uint16-tiff`` its codes already made, planar (3, H, W)
    uint16 (``picamcal.correct(..., dtype=np.uint16)``, :func:`encode_uint16`), written as they are.
    ``metadata`` is written as given (``uint16-tiff`` adds its ``encoding`` and ``scale``); ``compression="zstd"``
    compresses losslessly with a predictor (needs imagecodecs).

    Examples
    --------
    >>> path = write_tiff("white.tiff", np.ones((4, 6, 3), np.float32), "uint16-tiff", {"source": "white.dng"})
    >>> tifffile.imread(path).shape, int(tifffile.imread(path).max())
    ((3, 4, 6), 32768)
    >>> codes = np.full((3, 4, 6), UINT16_WHITE, np.uint16)  # as picamcal.correct(..., dtype=np.uint16) gives
    >>> path = write_tiff("codes.tiff", codes, "uint16-tiff", {"source": "white.dng"})
    >>> bool(np.array_equal(tifffile.imread(path), codes))
    True
    """
    if output_format not in TIFF_FORMATS:
        raise ValueError(f"{output_format!r} is not a TIFF format ({', '.join(TIFF_FORMATS)})")
    if _is_codes(np.asarray(rgb)):
        if output_format != "uint16-tiff":
            raise ValueError(f"uint16 codes (3, H, W) are written as uint16-tiff, not {output_format}")
        codes = np.asarray(rgb)
    else:
        rgb = check_rgb(rgb)
        codes = None
    path = Path(path)
    info = dict(metadata or {})
    predictor = True if compression else None
    if output_format == "float32-tiff":
        with atomic_path(path, overwrite=overwrite) as tmp:
            tifffile.imwrite(
                tmp,
                np.ascontiguousarray(rgb, dtype=np.float32),
                photometric="rgb",
                description=json.dumps({"picamcal": info}),
                software=SOFTWARE,
                metadata=None,
                compression=compression,
                predictor=predictor,
            )
        return path
    info.update(encoding=f"linear: value = code / {UINT16_WHITE} (the white reference at {UINT16_WHITE})")
    info.update(scale=UINT16_WHITE)
    if codes is None:
        codes = encode_uint16(rgb)
    with atomic_path(path, overwrite=overwrite) as tmp:
        tifffile.imwrite(
            tmp,
            codes,
            imagej=True,
            software=SOFTWARE,
            metadata={
                "axes": "CYX",
                "mode": "composite",
                "Ranges": [0.0, float(UINT16_WHITE)] * 3,
                "Labels": ["red", "green", "blue"],
                "cf": 0,  # ImageJ's straight-line calibration: value = c0 + c1 * code
                "c0": 0.0,
                "c1": 1.0 / UINT16_WHITE,
                "vunit": "white",
                "Info": json.dumps({"picamcal": info}, indent=1),
            },
            compression=compression,
            predictor=predictor,
        )
    return path


__all__ = ["TIFF_FORMATS", "TIFF_SUFFIX", "UINT16_WHITE", "encode_uint16", "write_tiff"]
