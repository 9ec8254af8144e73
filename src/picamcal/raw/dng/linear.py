"""Corrected images as LinearRaw DNGs: demosaiced linear RGB that raw editors develop like the source frame.

:func:`picamcal.correct` gives linear RGB in which the calibration's white reference is 1.0 in every channel: the
camera's own colour space, white-balanced to the calibration's white (modes ``uncorrected``, ``flat`` and
``centre``), or, in mode ``pure``, the colour-unmixed primaries, which the calibration's ``centre_response``
``M_centre`` takes back to the camera's colours. A LinearRaw DNG (PhotometricInterpretation 34892, DNG 1.4
chapter 6) carries such an image with the colour tags an editor needs to render it as the source frame:

- the samples: 16 bits, three per pixel, ``round(rgb * 16384)`` (:data:`WHITE_CODE`): the white reference at a
  quarter of the range, two stops of headroom for what is brighter (speculars, a scene lit more than the white
  reference); BlackLevel 0, WhiteLevel 65535; values below 0 (noise) and above 4 are clipped;
  ``BaselineExposure`` +2 tells an editor that honours it to show the white reference at full scale;
- ``AsShotNeutral = 1 1 1``: the image is white-balanced already;
- ``ColorMatrix1 = T^-1 diag(1/n) CM`` and ``ForwardMatrix1 = FM T``, with ``CM``, ``FM`` and the neutral ``n`` that
  :func:`~picamcal.raw.dng.writer.write_dng` writes for the source frame (from its ``colour_correction_matrix``
  and ``colour_gains``, or the DNG's own tags) and ``T`` the matrix from the image's RGB to the camera's
  white-balanced RGB (the identity, or ``M_centre`` for mode ``pure``): XYZ goes to the image's RGB as it went to
  the source's raw RGB, less the white balance the correction has applied.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..._version import __version__
from ...errors import OutputError
from .tags import (
    AS_SHOT_NEUTRAL,
    ASCII,
    BASELINE_EXPOSURE,
    BITS_PER_SAMPLE,
    BLACK_LEVEL,
    BLACK_REPEAT_DIM,
    BYTE,
    COLOR_MATRIX1,
    COLOUR_KEYS,
    COMPRESSION,
    DATE_TIME,
    DNG_BACKWARD,
    DNG_VERSION,
    FORWARD_MATRIX1,
    ILLUMINANT1,
    IMAGE_DESCRIPTION,
    IMAGE_LENGTH,
    IMAGE_WIDTH,
    LINEAR_RAW,
    LONG,
    MAKE,
    MODEL,
    NEW_SUBFILE_TYPE,
    ORIENTATION,
    PHOTOMETRIC,
    PLANAR_CONFIGURATION,
    RATIONAL,
    ROWS_PER_STRIP,
    SAMPLES_PER_PIXEL,
    SHORT,
    SOFTWARE,
    SRATIONAL,
    STRIP_BYTE_COUNTS,
    UNIQUE_MODEL,
    WHITE_LEVEL,
)
from .tiff import Entry, entry
from .writer import colour_tags, exif_entries, metadata_record, write_tiff, write_time

#: The 16-bit code of 1.0, the calibration's white reference: two stops below the white level.
WHITE_CODE = 16384
#: The white level of a linear DNG: values up to 65535 / 16384 (about 4) times the white reference are kept.
WHITE_LEVEL_CODE = 65535
#: Rows converted at a time: the float temporaries stay a few tens of MB whatever the frame's size.
_BAND_ROWS = 256


def write_linear_dng(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    *,
    metadata: Mapping[str, Any] | None = None,
    sensor: str | None = None,
    to_camera: np.ndarray | None = None,
    overwrite: bool = True,
) -> Path:
    """Write corrected linear RGB as a LinearRaw DNG that raw editors render like the source frame.

    Parameters
    ----------
    path : path-like
        The DNG file to write.
    rgb : ndarray, shape (H, W, 3)
        Linear RGB with the calibration's white reference at 1.0 (what :func:`picamcal.correct` returns).
    metadata : mapping, optional
        The source frame's metadata (``RawImage.metadata``): its colour (``colour_gains``,
        ``colour_correction_matrix``, or a DNG's ``as_shot_neutral`` and ``color_matrix1``), exposure and date go
        into the file as :func:`~picamcal.raw.dng.writer.write_dng` writes them; without colour the image's RGB is
        shown as linear sRGB.
    sensor : str, optional
        The source's sensor (``RawImage.sensor``): the DNG's Model and UniqueCameraModel.
    to_camera : ndarray, shape (3, 3), optional
        The matrix from the image's RGB to the camera's white-balanced RGB: ``calibration.centre_response`` for
        mode ``pure``, the identity (default) for the other modes.
    overwrite : bool
        Replace an existing file (default); if false, an existing file is an error.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputError
        ``rgb`` is not an (H, W, 3) array of finite numbers, ``to_camera`` not an invertible 3 x 3 matrix, the
        file exists and ``overwrite`` is false, or it cannot be written.
    RawFormatError
        The colour, exposure or gain metadata is malformed (as :func:`~picamcal.raw.dng.writer.write_dng`).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal = picamcal.calibrate(**refs)
    >>> white = refs["white"]
    >>> rgb = picamcal.correct(white, cal, "centre")
    >>> write_linear_dng("white-centre.dng", rgb, metadata=white.metadata, sensor=white.sensor)
    PosixPath('white-centre.dng')
    >>> import tifffile
    >>> samples = tifffile.imread("white-centre.dng")  # the white reference at 1.0, 16384, in every channel
    >>> samples.shape, (samples[100:140, 140:180].mean(axis=(0, 1)) / WHITE_CODE).round(2).tolist()
    ((240, 320, 3), [1.0, 1.0, 1.0])
    """
    path = Path(path)
    image = np.asarray(rgb)
    if image.ndim != 3 or image.shape[2] != 3 or 0 in image.shape or not np.issubdtype(image.dtype, np.number):
        raise OutputError(f"a linear DNG holds an (H, W, 3) RGB image, not an array of shape {image.shape}", path)
    if np.iscomplexobj(image):
        raise OutputError("the image to write as a linear DNG has complex values", path)
    meta = dict(metadata or {})
    colour = colour_tags(meta, str(meta.get("path", path)))
    matrix = _to_camera(to_camera, path)
    written = write_time()
    try:
        exif = exif_entries(meta, written, str(meta.get("path", path)))
        ifd0 = _ifd0_entries(image.shape[1], image.shape[0], meta, sensor, colour, matrix, written[0])
    except OutputError as exc:
        raise OutputError(exc.problem, path) from None
    return write_tiff(path, ifd0, exif, _samples(image, path), overwrite)


def _samples(image: np.ndarray, path: Path) -> np.ndarray:
    """``round(image * WHITE_CODE)`` clipped to 16 bits, a band of rows at a time (no full-size float temporaries)."""
    samples = np.empty(image.shape, dtype="<u2")
    for top in range(0, image.shape[0], _BAND_ROWS):
        band = image[top : top + _BAND_ROWS].astype(np.float64) * WHITE_CODE
        if not np.all(np.isfinite(band)):
            raise OutputError("the image to write as a linear DNG has values that are not finite (NaN, inf)", path)
        np.rint(np.clip(band, 0, WHITE_LEVEL_CODE, out=band), out=samples[top : top + _BAND_ROWS], casting="unsafe")
    return samples


def _to_camera(to_camera: np.ndarray | None, path: Path) -> np.ndarray:
    if to_camera is None:
        return np.eye(3)
    matrix = np.asarray(to_camera, dtype=np.float64)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)) or abs(np.linalg.det(matrix)) < 1e-9:
        raise OutputError(f"to_camera must be an invertible 3 x 3 matrix, not {np.asarray(to_camera).tolist()}", path)
    return matrix


def _ifd0_entries(
    width: int,
    height: int,
    meta: Mapping[str, Any],
    sensor: str | None,
    colour: Mapping[str, Any],
    to_camera: np.ndarray,
    written: str,
) -> list[Entry]:
    """IFD 0 of a linear DNG but its offsets: three 16-bit samples per pixel in one strip, and the colour tags."""
    kept = {k: v for k, v in meta.items() if k not in ("path", "format", *COLOUR_KEYS)}
    model = sensor or str(kept.get("model", "unknown"))
    color = np.linalg.inv(to_camera) @ np.diag(1.0 / colour["neutral"]) @ colour["color"]
    entries = [
        entry(NEW_SUBFILE_TYPE, LONG, 0),
        entry(IMAGE_WIDTH, LONG, width),
        entry(IMAGE_LENGTH, LONG, height),
        entry(BITS_PER_SAMPLE, SHORT, (16, 16, 16)),
        entry(COMPRESSION, SHORT, 1),
        entry(PHOTOMETRIC, SHORT, LINEAR_RAW),
        entry(IMAGE_DESCRIPTION, ASCII, metadata_record({**kept, "white_code": WHITE_CODE}, sensor)),
        entry(MAKE, ASCII, str(kept.get("make", "Raspberry Pi"))),
        entry(MODEL, ASCII, model),
        entry(ORIENTATION, SHORT, 1),
        entry(SAMPLES_PER_PIXEL, SHORT, 3),
        entry(ROWS_PER_STRIP, LONG, height),
        entry(STRIP_BYTE_COUNTS, LONG, width * height * 6),
        entry(PLANAR_CONFIGURATION, SHORT, 1),
        entry(SOFTWARE, ASCII, f"picamcal {__version__}"),
        entry(DATE_TIME, ASCII, written),
        entry(DNG_VERSION, BYTE, (1, 4, 0, 0)),
        entry(DNG_BACKWARD, BYTE, (1, 1, 0, 0)),
        entry(UNIQUE_MODEL, ASCII, model),
        entry(BLACK_REPEAT_DIM, SHORT, (1, 1)),
        entry(BLACK_LEVEL, RATIONAL, (0, 0, 0)),
        entry(WHITE_LEVEL, LONG, (WHITE_LEVEL_CODE,) * 3),
        entry(COLOR_MATRIX1, SRATIONAL, color.ravel()),
        entry(AS_SHOT_NEUTRAL, RATIONAL, (1, 1, 1)),
        entry(BASELINE_EXPOSURE, SRATIONAL, np.log2(65536 / WHITE_CODE)),
        entry(ILLUMINANT1, SHORT, colour["illuminant"]),
    ]
    if colour["forward"] is not None:
        forward = np.asarray(colour["forward"], dtype=np.float64).reshape(3, 3)  # a read DNG gives it flat
        entries.append(entry(FORWARD_MATRIX1, SRATIONAL, (forward @ to_camera).ravel()))
    return entries
