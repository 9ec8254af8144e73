"""Writing corrected images: float32 linear RGB TIFF through tifffile, atomically."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from ._atomic import atomic_path

#: What ``picamcal correct --output-format`` writes: linear float32 or uint16 TIFF, or colour-managed sRGB images.
OUTPUT_FORMATS = ("float32-tiff", "uint16-tiff", "srgb-png", "srgb-png16", "srgb-jpeg")


def write_rgb_tiff(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    metadata: dict[str, Any] | None = None,
    overwrite: bool = False,
    compression: str | None = None,
) -> Path:
    """Write a float32 (H, W, 3) linear RGB image as a TIFF, with a JSON description, atomically.

    ``compression="zstd"`` compresses losslessly with the floating-point predictor (needs imagecodecs).

    Examples
    --------
    >>> write_rgb_tiff("out/sample.tiff", rgb, {"mode": "centre"})  # doctest: +SKIP
    """
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        tifffile.imwrite(
            tmp,
            np.ascontiguousarray(rgb, dtype=np.float32),
            photometric="rgb",
            description=json.dumps({"picamcal": metadata or {}}),
            software="picamcal",
            metadata=None,
            **({"compression": compression, "predictor": True} if compression else {}),
        )
    return path
