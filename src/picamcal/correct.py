"""Calibration + raw image -> corrected linear RGB (paper, section "Colour crosstalk", eqs. for
``Pure`` and ``Unmixed``).

The pipeline per image: subtract black; divide each Bayer site by its white response interpolated
smoothly from the bins (lens shading and colour balance, ``Cb LST = 1 / W``); demosaic (Malvar,
He and Cutler 2004, from the colour-demosaicing library); apply the interpolated 3x3 matrix field
per pixel. Modes:

``balance``
    colour balance only (one gain per channel, from the centre of the white): the uncorrected image.
``flat``
    vignetting and colour balance: the white reference becomes 1.0 everywhere.
``centre``
    ``flat`` then the unmixing field U, which restores the colours of the sensor centre everywhere
    (the paper's recommended correction).
``pure``
    ``flat`` then ``Cx U``, unmixing to pure primaries (more saturated and noisier).
"""

from __future__ import annotations

import numpy as np

from .bayer import bin_centres, bin_sites, sites_to_channels
from .calibration import MODES, Calibration
from .interpolate import interpolation_matrix, upsample
from .raw.model import RawImage

#: Rows per block when applying the matrix field, to bound memory (9 float32 planes per block).
_ROW_BLOCK = 256


def _site_gain_mosaic(calibration: Calibration, mode: str, height: int, width: int) -> np.ndarray:
    """Per-pixel gain mosaic: 1 / white per Bayer site, the white interpolated from the bins (constant for balance)."""
    gains = np.empty((height, width), dtype=np.float32)
    centre = calibration.centre_white()
    for site in range(4):
        sy, sx = divmod(site, 2)
        if mode == "balance":
            gains[sy::2, sx::2] = 1.0 / centre[site]
            continue
        size = calibration.bin_size
        ay = interpolation_matrix(bin_centres(height, size, sy), np.arange(sy, height, 2))
        ax = interpolation_matrix(bin_centres(width, size, sx), np.arange(sx, width, 2))
        # Interpolate the white itself, then invert: vignetting is smoother than its reciprocal.
        gains[sy::2, sx::2] = 1.0 / upsample(calibration.site_white[..., site].astype(np.float64), ay, ax)
    return gains


def demosaic(mosaic: np.ndarray, pattern: str) -> np.ndarray:
    """Demosaic a float Bayer mosaic to (H, W, 3) float32 with Malvar-He-Cutler (2004).

    Examples
    --------
    >>> rgb = demosaic(np.ones((8, 8), np.float32), "BGGR")
    >>> rgb.shape, float(rgb.min()), float(rgb.max())
    ((8, 8, 3), 1.0, 1.0)
    """
    from colour_demosaicing import demosaicing_CFA_Bayer_Malvar2004

    return np.asarray(demosaicing_CFA_Bayer_Malvar2004(mosaic, pattern), dtype=np.float32)


def apply_matrix_field(rgb: np.ndarray, matrices: np.ndarray, centres: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Apply a bin-resolution 3x3 matrix field to a full-resolution image, in place, block by block.

    Each pixel gets ``out = U(y, x) @ rgb`` with U interpolated by cubic splines from the bin
    centres; the full-resolution field is never held in memory at once.
    """
    height, width = rgb.shape[:2]
    ax = interpolation_matrix(centres[1], np.arange(width))
    ay_all = interpolation_matrix(centres[0], np.arange(height))
    for y0 in range(0, height, _ROW_BLOCK):
        y1 = min(y0 + _ROW_BLOCK, height)
        u = upsample(matrices.astype(np.float64), ay_all[y0:y1], ax).astype(np.float32)  # (rows, W, 3, 3)
        rgb[y0:y1] = np.einsum("yxpq,yxq->yxp", u, rgb[y0:y1])
    return rgb


def correct(raw: RawImage, calibration: Calibration, mode: str = "centre", binned: bool = False) -> np.ndarray:
    """Correct a raw image's vignetting and colour crosstalk.

    Parameters
    ----------
    raw : RawImage
        The image, from the same sensor, size and Bayer pattern as the calibration's references.
    calibration : Calibration
        From :func:`picamcal.calibrate` or :func:`picamcal.load_calibration`.
    mode : {"centre", "flat", "pure", "balance"}
        See the module docstring; ``centre`` is the paper's recommended correction.
    binned : bool
        Return the bin-resolution image (one value per bin and channel, no demosaicing) instead of
        the full-resolution one.

    Returns
    -------
    ndarray of float32, shape (H, W, 3) or (nby, nbx, 3)
        Linear RGB in which the calibration's white reference is 1.0 (``flat``, ``centre`` and ``pure``).

    Examples
    --------
    >>> import picamcal
    >>> cal = picamcal.load_calibration("cal.npz")  # doctest: +SKIP
    >>> rgb = picamcal.correct(picamcal.read_raw("sample.dng"), cal, mode="centre")  # doctest: +SKIP
    """
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}: choose one of {', '.join(MODES)}")
    calibration.check_compatible(raw)
    matrices = calibration.matrices(mode)
    if binned:
        sites = bin_sites(raw.black_subtracted(), calibration.bin_size)
        white = (
            np.broadcast_to(calibration.centre_white(), sites.shape) if mode == "balance" else calibration.site_white
        )
        rgb = sites_to_channels(sites / white, raw.pattern)
        if matrices is not None:
            rgb = np.einsum("yxpq,yxq->yxp", matrices.astype(np.float64), rgb)
        return rgb.astype(np.float32)
    mosaic = raw.black_subtracted()
    mosaic *= _site_gain_mosaic(calibration, mode, raw.height, raw.width)
    rgb = demosaic(mosaic, raw.pattern)
    del mosaic
    if matrices is not None:
        apply_matrix_field(rgb, matrices, calibration.bin_centres)
    return rgb
