"""Array functions on Bayer mosaics: per-site planes, binning and channel averaging."""

from __future__ import annotations

import numpy as np


def bin_edges(n_pixels: int, bin_size: int) -> np.ndarray:
    """Start index (in sensor pixels) of each bin along an axis, plus the end; the last bin may be partial.

    Examples
    --------
    >>> bin_edges(40, 16).tolist()
    [0, 16, 32, 40]
    """
    return np.append(np.arange(0, n_pixels, bin_size), n_pixels)


def bin_centres(n_pixels: int, bin_size: int, site: int | None = None) -> np.ndarray:
    """Centre (in sensor pixel coordinates, pixel centres at integers) of each bin along an axis.

    With ``site`` (0 or 1, the position within the 2x2 Bayer block along this axis) it is the mean
    position of that site's pixels in the bin, half a pixel off the bin's centre: a per-site bin mean
    is a sample there.

    Examples
    --------
    >>> bin_centres(40, 16).tolist()
    [7.5, 23.5, 35.5]
    >>> bin_centres(40, 16, site=1).tolist()
    [8.0, 24.0, 36.0]
    """
    edges = bin_edges(n_pixels, bin_size)
    if site is None:
        return (edges[:-1] + edges[1:] - 1) / 2.0
    first = edges[:-1] + site
    last = first + 2 * ((edges[1:] - 1 - first) // 2)
    return (first + last) / 2.0


def centre_region(nby: int, nbx: int) -> tuple[int, int, int, int]:
    """Bin index range (y0, y1, x0, x1) of the central ninth of the frame (middle third in each axis).

    The reference region of the paper's colour unmixing (``M_centre``, the colours the ``centre`` mode restores)
    and of every "centre" figure. The paper's 2019 code took rows 4/9 to the bottom edge; this is the central ninth
    it meant. At least one bin in each axis, however small the grid.

    Examples
    --------
    >>> centre_region(154, 205)
    (51, 102, 68, 136)
    >>> centre_region(2, 2)
    (0, 1, 0, 1)
    """
    return nby // 3, max(2 * nby // 3, nby // 3 + 1), nbx // 3, max(2 * nbx // 3, nbx // 3 + 1)


def block_mean(values: np.ndarray, block: int, *, partial: bool = True, dtype: type = np.float64) -> np.ndarray:
    """Mean over square blocks of ``block`` x ``block`` pixels from the top-left, per channel.

    The one block average of picamcal: bins of an RGB image, reduced images for searches, noise maps.

    Parameters
    ----------
    values : ndarray, shape (H, W) or (H, W, ...)
    block : int
        Block edge length in pixels, >= 1.
    partial : bool
        Keep the partial blocks at the bottom and right edges (averaging the pixels they have), or drop them.
    dtype : numpy float type
        Accumulation and result type (float32 halves the memory of a reduction of a large image).

    Returns
    -------
    ndarray, shape (ceil(H / block), ceil(W / block), ...) or, without ``partial``, (H // block, W // block, ...)

    Examples
    --------
    >>> v = np.arange(15, dtype=float).reshape(3, 5)
    >>> block_mean(v, 2).tolist()
    [[3.0, 5.0, 6.5], [10.5, 12.5, 14.0]]
    >>> block_mean(v, 2, partial=False).tolist()
    [[3.0, 5.0]]
    """
    if int(block) != block or block < 1:
        raise ValueError(f"block must be a whole number of pixels >= 1, got {block}")
    block = int(block)
    if not partial:
        values = values[: values.shape[0] // block * block, : values.shape[1] // block * block]
    height, width = values.shape[:2]
    nby, nbx = -(-height // block), -(-width // block)
    # Strided sums of each block's rows, then columns (several times faster than reduceat on a 12-megapixel image);
    # a partial last block gets fewer terms.
    strips = np.zeros((nby, *values.shape[1:]), dtype=dtype)
    for i in range(min(block, height)):
        part = values[i::block]
        strips[: len(part)] += part
    sums = np.zeros((nby, nbx, *values.shape[2:]), dtype=dtype)
    for i in range(min(block, width)):
        part = strips[:, i::block]
        sums[:, : part.shape[1]] += part
    if height % block == 0 and width % block == 0:
        return sums / dtype(block * block)
    rows = np.minimum(block, height - np.arange(0, height, block))
    cols = np.minimum(block, width - np.arange(0, width, block))
    counts = np.outer(rows, cols)
    return sums / counts.reshape(counts.shape + (1,) * (values.ndim - 2)).astype(dtype)


def bin_sites(mosaic: np.ndarray, bin_size: int) -> np.ndarray:
    """Mean of each 2x2 Bayer site over square bins of ``bin_size`` sensor pixels.

    Parameters
    ----------
    mosaic : ndarray, shape (H, W)
        A Bayer mosaic (any numeric dtype; black-subtracted float for calibration).
    bin_size : int
        Even bin edge length in sensor pixels; a partial bin at the right and bottom edges is kept.

    Returns
    -------
    ndarray of float64, shape (ceil(H / bin_size), ceil(W / bin_size), 4)
        Per-bin mean of sites (0, 0), (0, 1), (1, 0), (1, 1) of the 2x2 block.

    Examples
    --------
    >>> m = np.arange(16, dtype=float).reshape(4, 4)
    >>> bin_sites(m, 2)[0, 0].tolist()
    [0.0, 1.0, 4.0, 5.0]
    """
    if bin_size < 2 or bin_size % 2:
        raise ValueError(f"bin_size must be an even number of pixels >= 2, got {bin_size}")
    # A bin of bin_size sensor pixels is a block of bin_size / 2 pixels of each site's plane. numpy, not numba: a
    # 12 MP frame takes about 50 ms, less than numba's start (0.3 s or more) costs a command that bins a few frames.
    return np.stack([block_mean(mosaic[sy::2, sx::2], bin_size // 2) for sy in (0, 1) for sx in (0, 1)], axis=-1)


def sites_to_channels(sites: np.ndarray, pattern: str) -> np.ndarray:
    """Average per-site values (..., 4) into R, G, B channels (..., 3); the two greens are averaged.

    Examples
    --------
    >>> sites_to_channels(np.array([1.0, 2.0, 4.0, 3.0]), "RGGB").tolist()
    [1.0, 3.0, 3.0]
    """
    # Imported here: picamcal.raw's own modules use bayer, and importing raw.model first runs all of raw.
    from .raw.model import site_channels

    idx = site_channels(pattern)
    out = np.zeros((*sites.shape[:-1], 3), dtype=np.result_type(sites.dtype, np.float32))
    counts = np.bincount(idx, minlength=3)
    for site, channel in enumerate(idx):
        out[..., channel] += sites[..., site]
    return out / counts


def central_half(height: int, width: int) -> tuple[slice, slice]:
    """Rows and columns of the central half of a frame (each side), on whole 2x2 blocks.

    Where a camera's white balance is measured on the white reference: ``picamcal acquire`` freezes its
    ``ColourGains`` there, and the simulator its ``colour_gains`` (:func:`balance_gains`).

    Examples
    --------
    >>> central_half(240, 320)
    (slice(60, 180, None), slice(80, 240, None))
    """
    y0, x0 = height // 8 * 2, width // 8 * 2
    return slice(y0, height - y0), slice(x0, width - x0)


def balance_gains(white: np.ndarray, pattern: str) -> tuple[float, float]:
    """The white balance (green / red, green / blue) of a black-subtracted white mosaic over its central half.

    Examples
    --------
    >>> balance_gains(np.tile([[1.0, 2.0], [2.0, 4.0]], (4, 4)), "RGGB")
    (2.0, 0.5)
    """
    rows, cols = central_half(*white.shape)
    centre = white[rows, cols]
    sites = np.array([centre[k // 2 :: 2, k % 2 :: 2].mean(dtype=np.float64) for k in range(4)])
    red, green, blue = sites_to_channels(sites, pattern)
    return float(green / red), float(green / blue)
