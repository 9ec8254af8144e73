"""Writing corrected images: linear TIFF for measuring, colour-managed sRGB PNG and JPEG for looking at.

One function, :func:`write_corrected`, writes a corrected image (linear RGB in which the calibration's
white reference is 1.0) in one of :data:`OUTPUT_FORMATS`, atomically, with its provenance. Each kind of
file has its module:

:mod:`picamcal.output.tiff`
    ``float32-tiff`` (the values as they are) and ``uint16-tiff`` (the white reference at
    :data:`UINT16_WHITE`), each one interleaved RGB image.
:mod:`picamcal.output.srgb`
    ``srgb-png``, ``srgb-png16`` and ``srgb-jpeg``: colour-managed through a colour matrix
    (:mod:`picamcal.output.colour`: :func:`camera_to_srgb`, :func:`encode_srgb`), with an sRGB ICC profile.
:mod:`picamcal.output.ome_zarr`
    One chunked float32 OME-Zarr stack of many frames, written by many processes at once (``picamcal correct
    --zarr``).
:mod:`picamcal.output.provenance`
    The ``Software`` field every file carries, and :func:`is_picamcal_output`.

docs/outputs.md says what opens each format.

Examples
--------
>>> from picamcal.output import OUTPUT_SUFFIXES, write_corrected
>>> write_corrected("grey" + OUTPUT_SUFFIXES["srgb-jpeg"], np.full((8, 8, 3), 0.5, np.float32), "srgb-jpeg")
PosixPath('grey.jpg')
"""

from __future__ import annotations

from .colour import (
    NO_MATRIX,
    SRGB_TO_XYZ_D65,
    SRGB_WHITE_LEVEL,
    XYZ_D50_TO_SRGB,
    ColourMatrix,
    camera_to_srgb,
    color_matrix_to_srgb,
    encode_srgb,
    forward_matrix_to_srgb,
    srgb_transfer,
)
from .provenance import is_picamcal_output
from .srgb import JPEG_QUALITY, SRGB_FORMATS
from .tiff import TIFF_FORMATS, UINT16_WHITE, encode_uint16
from .write import (
    BATCH_FORMATS,
    DNG_FORMATS,
    OUTPUT_FORMATS,
    OUTPUT_SUFFIXES,
    output_bytes,
    write_corrected,
    write_rgb_tiff,
)

__all__ = [
    "BATCH_FORMATS",
    "DNG_FORMATS",
    "JPEG_QUALITY",
    "NO_MATRIX",
    "OUTPUT_FORMATS",
    "OUTPUT_SUFFIXES",
    "SRGB_FORMATS",
    "SRGB_TO_XYZ_D65",
    "SRGB_WHITE_LEVEL",
    "TIFF_FORMATS",
    "UINT16_WHITE",
    "XYZ_D50_TO_SRGB",
    "ColourMatrix",
    "camera_to_srgb",
    "color_matrix_to_srgb",
    "encode_srgb",
    "encode_uint16",
    "forward_matrix_to_srgb",
    "is_picamcal_output",
    "output_bytes",
    "srgb_transfer",
    "write_corrected",
    "write_rgb_tiff",
]
