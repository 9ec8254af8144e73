"""One entry point for every output format: :func:`write_corrected`, and what a batch needs to know of each format."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._version import __version__
from .colour import SRGB_WHITE_LEVEL, ColourMatrix, check_rgb
from .srgb import SRGB_FORMATS, SRGB_SUFFIXES, write_srgb
from .tiff import TIFF_FORMATS, TIFF_SUFFIX, write_tiff

#: DNG outputs for raw editors: the corrected image as a linear DNG (any mode), or the raw mosaic unchanged with
#: the calibration's flat field as GainMap opcodes (docs/dng.md).
DNG_FORMATS = ("linear-dng", "dng-gainmap")
#: What :func:`write_corrected` writes: linear float32 or uint16 TIFF, or colour-managed sRGB images.
OUTPUT_FORMATS = TIFF_FORMATS + SRGB_FORMATS
#: What ``picamcal correct --output-format`` writes: those, and DNG for raw editors (by :mod:`picamcal.raw.dng`).
BATCH_FORMATS = OUTPUT_FORMATS + DNG_FORMATS
#: File name suffix of each format.
OUTPUT_SUFFIXES = {**dict.fromkeys(TIFF_FORMATS, TIFF_SUFFIX), **SRGB_SUFFIXES, **dict.fromkeys(DNG_FORMATS, ".dng")}


def output_bytes(output_format: str, shape: tuple[int, ...]) -> int:
    """The size of one output of ``shape`` (H, W, 3) uncompressed, in bytes: what a batch reserves to check for room.

    The headers, metadata and ICC profile (a few kB) are left out; PNG and JPEG are usually much smaller.

    Examples
    --------
    >>> output_bytes("uint16-tiff", (3040, 4056, 3))
    73981440
    """
    if output_format == "dng-gainmap":  # the mosaic: one 16-bit sample per pixel
        return int(np.prod(shape[:2])) * 2
    per_sample = {"float32-tiff": 4, "uint16-tiff": 2, "srgb-png16": 2, "linear-dng": 2}.get(output_format, 1)
    return int(np.prod(shape)) * per_sample


def write_corrected(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    output_format: str = "float32-tiff",
    metadata: Mapping[str, Any] | None = None,
    *,
    colour_matrix: ColourMatrix | None = None,
    white_level: float = SRGB_WHITE_LEVEL,
    overwrite: bool = False,
    compression: str | None = None,
) -> Path:
    """Write a corrected image in one of :data:`OUTPUT_FORMATS`, atomically, with its provenance.

    The formats, their scales and their metadata are described in :mod:`picamcal.output` and in
    docs/outputs.md.

    Parameters
    ----------
    path : path-like
        The file to write (its suffix is not checked: :data:`OUTPUT_SUFFIXES` has the usual ones).
    rgb : ndarray (H, W, 3)
        Corrected linear RGB, the white reference at 1.0; or its codes, written as they are: for ``uint16-tiff``
        uint16 (H, W, 3) as ``picamcal.correct(..., dtype=np.uint16)`` gives them, for the sRGB formats uint8
        (``srgb-png``, ``srgb-jpeg``) or uint16 (``srgb-png16``) as ``picamcal.correct(...,
        encoding=srgb_encoding(colour_matrix, white_level=white_level, bits=8 or 16))`` gives them
        (:func:`picamcal.output.colour.srgb_encoding`; the colour matrix and white level are then recorded).
    output_format : str
        One of :data:`OUTPUT_FORMATS`.
    metadata : mapping, optional
        Provenance (source, calibration, mode, ...): JSON-serialisable. The sRGB and uint16 formats add
        ``output_format`` and ``picamcal_version`` and their scale; the sRGB ones add the colour matrix and
        its source, ``white_level`` and ``white_code``. float32 TIFFs keep it as given (their scale is
        1.0 by definition) and name the version in the TIFF ``Software`` tag, as every TIFF does.
    colour_matrix : ColourMatrix, optional
        sRGB formats: to linear sRGB (:func:`camera_to_srgb`); default the identity (:data:`NO_MATRIX`).
    white_level : float
        sRGB formats: the linear sRGB level of the white reference.
    overwrite : bool
        Replace an existing file; otherwise that is an :class:`~picamcal.errors.OutputError`.
    compression : {None, "zstd"}
        TIFF formats: lossless zstd with a predictor (needs imagecodecs; ImageJ's own TIFF reader cannot
        decompress it).

    Returns
    -------
    Path

    Raises
    ------
    OutputError
        The file exists (without ``overwrite``) or cannot be written.

    Examples
    --------
    >>> from picamcal.output import camera_to_srgb
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal = picamcal.calibrate(**refs)
    >>> rgb = picamcal.correct(refs["white"], cal, "flat")
    >>> write_corrected("white.png", rgb, "srgb-png", {"source": "white.dng"},
    ...                 colour_matrix=camera_to_srgb(refs["white"].metadata))
    PosixPath('white.png')
    """
    if output_format not in OUTPUT_FORMATS:
        raise ValueError(f"unknown output format {output_format!r}: choose one of {', '.join(OUTPUT_FORMATS)}")
    if compression is not None and (compression != "zstd" or output_format not in TIFF_FORMATS):
        raise ValueError(f"compression {compression!r} is for {' and '.join(TIFF_FORMATS)} only (zstd)")
    info = dict(metadata or {})
    if output_format != "float32-tiff":
        info.update(output_format=output_format, picamcal_version=__version__)
    if output_format in TIFF_FORMATS:  # write_tiff checks the image, and takes uint16-tiff codes as they are
        return write_tiff(path, rgb, output_format, info, overwrite=overwrite, compression=compression)
    return write_srgb(
        path,
        check_rgb(rgb),
        output_format,
        info,
        colour_matrix=colour_matrix,
        white_level=white_level,
        overwrite=overwrite,
    )


def write_rgb_tiff(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    metadata: dict[str, Any] | None = None,
    overwrite: bool = False,
    compression: str | None = None,
) -> Path:
    """Write a float32 (H, W, 3) linear RGB image as a TIFF, with a JSON description, atomically.

    The same as :func:`write_corrected` with ``"float32-tiff"``. ``compression="zstd"`` compresses
    losslessly with the floating-point predictor (needs imagecodecs).

    Examples
    --------
    >>> write_rgb_tiff("sample.tiff", np.ones((4, 6, 3), np.float32), {"mode": "centre"})
    PosixPath('sample.tiff')
    """
    return write_corrected(path, rgb, "float32-tiff", metadata, overwrite=overwrite, compression=compression)


__all__ = [
    "BATCH_FORMATS",
    "DNG_FORMATS",
    "OUTPUT_FORMATS",
    "OUTPUT_SUFFIXES",
    "output_bytes",
    "write_corrected",
    "write_rgb_tiff",
]
