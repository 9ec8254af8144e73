"""Array functions on binned calibration fields, underneath the checks of :mod:`picamcal.analysis.diagnostics`.

* :func:`vignetting_centre` and :func:`implied_tilt`: where a flat field peaks (a robust point-symmetric surface
  with a free centre), and the tilt of the light that moves it there (paper, section "Vignetting").
* :func:`dust_residual` and :func:`find_dust`: small dark specks against a smooth background (section "Colour
  crosstalk": high-frequency structure "probably indicates dirt in the optical system").
* :func:`roughness`: bin-to-bin structure of any field, its departure from a local quadratic.

They take plain arrays (a plane of bins and the bins' centres in sensor pixels), not a calibration.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy import polynomial
from scipy import ndimage, optimize

__all__ = [
    "DUST_SIGMA",
    "MIN_DUST_DEPTH",
    "dust_residual",
    "find_dust",
    "implied_tilt",
    "roughness",
    "vignetting_centre",
]

#: Dips shallower than this (fraction of the white) are not reported as dust, however clean the data:
#: 0.2 % is half a level of an 8-bit output, invisible in a corrected image.
MIN_DUST_DEPTH = 0.002
#: A dust speck must reach this many noise standard deviations (on the matched-filtered residual);
#: a Gaussian tail beyond 5 sigma holds 3e-7 of the bins, so a 200 x 150-bin field has <1 % chance of one.
DUST_SIGMA = 5.0

_DEGREE = 4  # of the point-symmetric polynomial fitted to the flat field
_BACKGROUND_DEGREE = 6  # of the polynomial a dust residual is taken against
_BACKGROUND_BINS = 11  # median window (bins) that follows what the polynomial misses, but not dust
_NOISE_BINS = 21  # window (bins) of the local noise estimate
_MATCHED_SIGMA = 1.0  # bins: the Gaussian that a speck's binned dip looks like
_GROW_SIGMA = 2.5  # a speck's region: connected bins below this many sigma


# Vignetting centre ------------------------------------------------------------------------------------


def _even_basis(u: np.ndarray, v: np.ndarray, degree: int) -> np.ndarray:
    """Monomials u^i v^j with i + j even and <= degree: surfaces symmetric under (u, v) -> (-u, -v)."""
    pu, pv = [np.ones_like(u)], [np.ones_like(v)]
    for _ in range(degree):
        pu.append(pu[-1] * u)
        pv.append(pv[-1] * v)
    return np.stack([pu[d - i] * pv[i] for d in range(0, degree + 1, 2) for i in range(d + 1)], axis=-1)


def _lstsq(a: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Least-squares coefficients by the normal equations: fast, and exact enough for these few, tame terms."""
    try:
        return np.linalg.solve(a.T @ a, a.T @ z)
    except np.linalg.LinAlgError:  # too few bins for the terms: the minimum-norm solution
        return np.linalg.lstsq(a, z, rcond=None)[0]


def _symmetric_surface(
    coef: np.ndarray, y: np.ndarray, x: np.ndarray, centre: Sequence[float] | np.ndarray, scale: float
) -> np.ndarray:
    """A point-symmetric surface with coefficients ``coef`` about ``centre`` (x, y), on the bin grid."""
    yy, xx = np.meshgrid(y, x, indexing="ij")
    degree = 2 * (math.isqrt(len(coef)) - 1)  # degree d has (d / 2 + 1)**2 even terms
    return _even_basis((xx - centre[0]) / scale, (yy - centre[1]) / scale, degree) @ coef


def _fit_symmetric_surface(
    plane: np.ndarray, y: np.ndarray, x: np.ndarray, scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust fit of a surface point-symmetric about a free centre: (centre (x, y), coefficients, inliers).

    For a trial centre the surface is linear in its coefficients (solved by least squares), so only the
    centre is searched (variable projection). Bins more than 5 robust sigma off the fit (dust) are
    dropped and the fit repeated. The coefficients are for ``plane`` itself, in units of ``scale``.
    """
    yy, xx = np.meshgrid(y, x, indexing="ij")
    # A quartic has 9 terms; fewer than 4 bins per term (a frame of a few bins) gets a quadratic.
    degree = _DEGREE if plane.size >= 36 else 2
    level = float(np.median(plane))
    z = plane / level
    good = np.isfinite(z)
    # Start from the brightest part of the smoothed field, so a centre far off the frame's is found too.
    smooth = ndimage.gaussian_filter(np.where(good, z, np.nanmedian(z)), 2.0, mode="nearest")
    top = smooth >= np.percentile(smooth, 97)
    centre = np.array([xx[top].mean(), yy[top].mean()])

    def coefficients(c: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = _even_basis((xx[mask] - c[0]) / scale, (yy[mask] - c[1]) / scale, degree)
        coef = _lstsq(a, z[mask])
        return coef, z[mask] - a @ coef

    for _ in range(3):
        mask = good.copy()
        centre = optimize.least_squares(lambda c, m=mask: coefficients(c, m)[1], centre, x_scale=0.05 * scale).x
        coef, _ = coefficients(centre, mask)
        residual = z - _symmetric_surface(coef, y, x, centre, scale)
        sigma = _robust_std(residual[mask])
        good = np.isfinite(z) & (np.abs(residual) <= max(5.0 * sigma, 1e-6))
        if np.array_equal(good, mask):
            break
    return centre, coef * level, good


def vignetting_centre(plane: np.ndarray, y: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """Where a binned flat field peaks: the centre of a robust point-symmetric quartic surface fit.

    The CRA-compensation vignetting is (to a good approximation) point-symmetric about the place where
    the lenslets' spots sit on their photodiodes, also when that place is off the frame centre. The fit
    is a sum of the even monomials ``u^i v^j`` (``i + j`` = 0, 2, 4, ``u = x - x0``, ``v = y - y0``) with
    the centre ``(x0, y0)`` free; bins more than 5 robust standard deviations off the fit (dust) are
    left out. On simulated frames it recovers the true centre to within 1 pixel.

    Parameters
    ----------
    plane : ndarray, shape (nby, nbx)
        A binned flat field, e.g. ``calibration.white[..., 1]`` (green).
    y, x : ndarray
        Bin centres in sensor pixels (``calibration.bin_centres``).

    Returns
    -------
    (float, float)
        x, y of the centre in sensor pixels (may lie outside the frame for a strongly tilted sensor).

    Examples
    --------
    >>> yc, xc = np.arange(8) * 16 + 7.5, np.arange(10) * 16 + 7.5
    >>> flat = 1 - 1e-5 * ((xc[None, :] - 90) ** 2 + (yc[:, None] - 60) ** 2)
    >>> [round(v, 3) for v in vignetting_centre(flat, yc, xc)]
    [90.0, 60.0]
    """
    plane, y, x = _as_plane(plane, y, x)
    scale = math.hypot(float(x[-1] - x[0]), float(y[-1] - y[0])) / 2 or 1.0
    centre, _, _ = _fit_symmetric_surface(plane, y, x, scale)
    return float(centre[0]), float(centre[1])


def implied_tilt(offset_px: float, half_diagonal_px: float, cra_corner_deg: float) -> float:
    """The tilt of the incident light (degrees) that moves the vignetting centre by ``offset_px``.

    The lenslet shift grows linearly with radius and reaches ``tan(CRA_corner)`` stack heights at the
    corner, so the spot that a tilt ``theta`` moves by ``tan(theta)`` stack heights is back on its
    photodiode at ``d = r_corner tan(theta) / tan(CRA_corner)``: ``theta = atan(d tan(CRA_corner) / r_corner)``.

    Examples
    --------
    >>> round(implied_tilt(27.93, 400.0, math.degrees(math.atan(0.5))), 2)
    2.0
    """
    if not 0 < cra_corner_deg < 90:
        raise ValueError(f"the chief ray angle at the corner must be in (0, 90) degrees, got {cra_corner_deg}")
    return math.degrees(math.atan(offset_px * math.tan(math.radians(cra_corner_deg)) / half_diagonal_px))


# Dust -------------------------------------------------------------------------------------------------


def dust_residual(plane: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Small-scale relative structure of a binned flat field: ``plane / smooth(plane) - 1``.

    The smooth version is a robust 2-D polynomial of total degree 6 (Legendre basis over the frame; bins more
    than 5 robust sigma off are refitted without) times an 11-bin median of what it leaves over, which
    follows any shading the polynomial misses but not specks of a few bins.

    Parameters
    ----------
    plane : ndarray, shape (nby, nbx)
        A binned white, e.g. ``calibration.site_white.sum(-1)`` (all pixels, the best signal-to-noise).
    y, x : ndarray
        Bin centres in sensor pixels.

    Returns
    -------
    ndarray of float64, shape (nby, nbx)
        Dust shows as negative dips (a fraction: -0.05 is 5 % darker than its surroundings).

    Examples
    --------
    >>> yc, xc = np.arange(20) * 16 + 7.5, np.arange(30) * 16 + 7.5
    >>> flat = 1 - 1e-6 * ((xc[None, :] - 240) ** 2 + (yc[:, None] - 160) ** 2)
    >>> flat[10, 5] *= 0.9
    >>> round(float(dust_residual(flat, yc, xc)[10, 5]), 3)
    -0.1
    """
    plane, y, x = _as_plane(plane, y, x)
    degree = min(_BACKGROUND_DEGREE, plane.shape[0] - 1, plane.shape[1] - 1)
    uy, ux = np.meshgrid(_unit(y), _unit(x), indexing="ij")
    a = polynomial.legendre.legvander2d(uy, ux, [degree, degree])
    i, j = np.divmod(np.arange((degree + 1) ** 2), degree + 1)
    a = a.reshape(-1, a.shape[-1])[:, i + j <= degree]  # total degree: no x^8 y^8 wiggles
    z = (plane / np.median(plane)).ravel()
    good = np.ones(z.shape, dtype=bool)
    for _ in range(4):
        coef = _lstsq(a[good], z[good])
        residual = z - a @ coef
        inliers = np.abs(residual) <= max(5.0 * _robust_std(residual[good]), 1e-6)
        if np.array_equal(inliers, good):
            break
        good = inliers
    ratio = (z / (a @ coef)).reshape(plane.shape)
    return ratio / ndimage.median_filter(ratio, size=_BACKGROUND_BINS, mode="reflect") - 1.0


def _unit(centres: np.ndarray) -> np.ndarray:
    """Bin centres mapped onto [-1, 1], where a Legendre basis is well conditioned."""
    span = float(centres[-1] - centres[0]) or 1.0
    return 2.0 * (centres - centres[0]) / span - 1.0


def find_dust(
    residual: np.ndarray,
    y: np.ndarray,
    x: np.ndarray,
    bin_size: float,
    *,
    sigma: float = DUST_SIGMA,
    min_depth: float = MIN_DUST_DEPTH,
) -> tuple[list[dict[str, float]], float]:
    """Dark specks in a flat-field residual: dips well below the noise, one per local minimum.

    1. The residual is divided by its local noise (robust: 1.4826 times the median of ``|residual|`` over
       21 x 21 bins), since the corners of a vignetted white are noisier than its centre.
    2. That is smoothed with a 1-bin Gaussian, a matched filter for a speck spread over a few bins, scaled
       to unit noise also at the frame edges; bins below ``-2.5`` (smoothed) noise sigma form candidate
       regions.
    3. Every local minimum (3 x 3) of the unsmoothed residual that is at least ``min_depth`` deep and
       where the smoothed residual reaches ``-sigma`` noise sigma is a speck, unless a deeper one lies in
       the same region with no ridge of 3 noise sigma between them (then both are one speck).
    4. Region bins belong to the nearest speck; its position is the dip-weighted centroid.

    Parameters
    ----------
    residual : ndarray, shape (nby, nbx)
        From :func:`dust_residual`.
    y, x : ndarray
        Bin centres in sensor pixels.
    bin_size : float
        Bin edge in sensor pixels.
    sigma, min_depth : float
        Detection thresholds (noise sigmas of the smoothed residual, fraction of the white).

    Returns
    -------
    specks : list of dict
        Deepest first: ``x``, ``y`` (dip-weighted centroid, pixels), ``radius_px`` (``sqrt(deficit / (2 pi
        depth))``: the radius of a Gaussian speck of this depth and deficit, over-estimated for specks
        smaller than a bin), ``area_radius_px`` (equivalent radius of its region), ``depth_percent``
        (deepest binned dip), ``deficit_px2`` (light lost in pixel areas, ``depth * 2 pi radius**2`` for a
        Gaussian speck).
    noise : float
        Median local noise of the residual (fraction).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> res = 0.001 * rng.standard_normal((30, 40))
    >>> res[10, 20] -= 0.03
    >>> yc, xc = np.arange(30) * 16 + 7.5, np.arange(40) * 16 + 7.5
    >>> specks, noise = find_dust(res, yc, xc, 16)
    >>> [(round(s["x"]), round(s["y"]), round(s["depth_percent"])) for s in specks]
    [(329, 167, 3)]
    """
    residual = np.asarray(residual, dtype=np.float64)
    local = 1.4826 * ndimage.median_filter(np.abs(residual), size=_NOISE_BINS, mode="reflect")
    local = np.maximum(local, 1e-6)
    smooth = _matched_filter(residual / local)
    noise_smooth = _robust_std(smooth)
    labels, _ = ndimage.label(smooth < -_GROW_SIGMA * noise_smooth)
    minima = residual == ndimage.minimum_filter(residual, size=3, mode="nearest")
    seeds = minima & (residual < -min_depth) & (smooth < -sigma * noise_smooth) & (labels > 0)
    sy, sx = _separate(residual, local, labels, *np.nonzero(seeds))
    # Each bin of a region belongs to the nearest speck in it: neighbouring specks whose dips touch stay apart.
    owner = np.full(residual.shape, -1)
    for label in np.unique(labels[sy, sx]):
        iy, ix = np.nonzero(labels == label)
        mine = np.flatnonzero(labels[sy, sx] == label)
        distance = (iy[:, None] - sy[mine]) ** 2 + (ix[:, None] - sx[mine]) ** 2
        owner[iy, ix] = mine[np.argmin(distance, axis=1)]
    area = float(bin_size) ** 2
    specks = []
    for k in range(sy.size):
        iy, ix = np.nonzero(owner == k)
        weights = np.clip(-residual[iy, ix], 0, None)
        depth = float(weights.max())
        deficit = float(weights.sum()) * area
        specks.append(
            {
                "x": float(np.sum(weights * x[ix]) / weights.sum()),
                "y": float(np.sum(weights * y[iy]) / weights.sum()),
                "radius_px": math.sqrt(deficit / (2 * math.pi * depth)),
                "area_radius_px": math.sqrt(iy.size * area / math.pi),
                "depth_percent": 100.0 * depth,
                "deficit_px2": deficit,
            }
        )
    specks.sort(key=lambda s: -s["depth_percent"])
    return specks, float(np.median(local))


def _matched_filter(z: np.ndarray) -> np.ndarray:
    """Gaussian-weighted sum of ``z`` over the bins around each bin, over its standard deviation for white noise.

    Normalising by ``sqrt(sum w**2)`` over the bins inside the frame keeps the statistic's noise the same at
    the edges, where fewer bins contribute (replicating edge bins instead would make edge noise look like dust).
    """
    reach = math.ceil(3 * _MATCHED_SIGMA)
    offsets = np.arange(-reach, reach + 1)
    kernel = np.exp(-(offsets[:, None] ** 2 + offsets[None, :] ** 2) / (2 * _MATCHED_SIGMA**2))
    total = ndimage.correlate(z, kernel, mode="constant")
    power = ndimage.correlate(np.ones_like(z), kernel**2, mode="constant")
    return total / np.sqrt(power)


def _separate(
    residual: np.ndarray, local: np.ndarray, labels: np.ndarray, sy: np.ndarray, sx: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Keep the minima (deepest first) that no deeper kept minimum of their region joins without a ridge.

    A ridge is a point on the straight line between two minima at least 3 local noise sigma above the
    shallower one; without one, the shallower minimum is noise on the same speck.
    """
    order = np.argsort(residual[sy, sx])
    kept: list[int] = []
    for k in order:
        joined = False
        for j in kept:
            if labels[sy[j], sx[j]] != labels[sy[k], sx[k]]:
                continue
            steps = 2 * max(abs(int(sy[j]) - int(sy[k])), abs(int(sx[j]) - int(sx[k]))) + 1
            ly = np.rint(np.linspace(sy[k], sy[j], steps)).astype(int)
            lx = np.rint(np.linspace(sx[k], sx[j], steps)).astype(int)
            if residual[ly, lx].max() - residual[sy[k], sx[k]] < 3.0 * local[sy[k], sx[k]]:
                joined = True
                break
        if not joined:
            kept.append(int(k))
    kept.sort()
    return sy[kept], sx[kept]


# Smoothness -------------------------------------------------------------------------------------------


def roughness(field: np.ndarray, half_width: int = 2) -> np.ndarray:
    """High-frequency part of a binned field: its residual from a local quadratic surface.

    Each bin's value is compared with a quadratic in x and y (6 terms) fitted by least squares to the
    ``(2 h + 1) x (2 h + 1)`` bins around it (a 2-D Savitzky-Golay filter); at the frame edges the window
    is moved inside the frame and the quadratic evaluated at the bin. A smooth field leaves only its
    third and higher derivatives (RMS 0.0006 to 0.0013 for the unmixing field of a noiseless simulated
    IMX219, 1280 x 960 to 640 x 480 pixels in 16-pixel bins). Independent noise keeps 0.92 of its standard
    deviation and a one-bin spike 0.85 of its height; a Gaussian bump keeps 37 % of its height at a
    1-bin sigma and 6 % at 2 bins: this measures bin-to-bin structure, not gentle bumps.

    Parameters
    ----------
    field : ndarray, shape (nby, nbx, ...)
        Trailing axes (e.g. the 3 x 3 matrix elements) are treated separately; at least
        ``2 h + 1`` bins each way.
    half_width : int
        ``h``, in bins.

    Returns
    -------
    ndarray of float64, same shape

    Examples
    --------
    >>> yy, xx = np.mgrid[0:8, 0:9].astype(float)
    >>> smooth = 1 + 0.1 * xx - 0.02 * yy**2 + 0.01 * xx * yy
    >>> float(np.abs(roughness(smooth)).max()) < 1e-12
    True
    >>> smooth[4, 4] += 0.05
    >>> round(float(roughness(smooth)[4, 4]), 3)
    0.042
    """
    field = np.asarray(field, dtype=np.float64)
    ny, nx = field.shape[:2]
    h = int(half_width)
    if min(ny, nx) < 2 * h + 1:
        raise ValueError(f"need at least {2 * h + 1} x {2 * h + 1} bins, got {ny} x {nx}")
    flat = field.reshape(ny, nx, -1)
    offsets = np.arange(-h, h + 1, dtype=np.float64)
    oy, ox = np.meshgrid(offsets, offsets, indexing="ij")
    basis = _quadratic(ox.ravel(), oy.ravel())  # (window bins, 6)
    projector = np.linalg.pinv(basis)  # coefficients = projector @ window values
    windows = np.lib.stride_tricks.sliding_window_view(flat, (2 * h + 1, 2 * h + 1), axis=(0, 1))
    coef = np.einsum("kw,yxcw->yxck", projector, windows.reshape(*windows.shape[:3], -1))
    # Window centre of each bin: itself inside, the nearest full window at the edges.
    cy = np.clip(np.arange(ny), h, ny - 1 - h)
    cx = np.clip(np.arange(nx), h, nx - 1 - h)
    at = _quadratic((np.arange(nx) - cx)[None, :], (np.arange(ny) - cy)[:, None])  # (ny, nx, 6)
    fit = np.einsum("yxck,yxk->yxc", coef[np.ix_(cy - h, cx - h)], at)
    return (flat - fit).reshape(field.shape)


def _quadratic(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    u, v = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
    return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)


# Helpers ----------------------------------------------------------------------------------------------


def _as_plane(plane: np.ndarray, y: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    plane = np.asarray(plane, dtype=np.float64)
    y, x = np.asarray(y, dtype=np.float64), np.asarray(x, dtype=np.float64)
    if plane.ndim != 2 or plane.shape != (y.size, x.size):
        raise ValueError(f"plane of shape {plane.shape} does not match {y.size} x {x.size} bin centres")
    if min(plane.shape) < 3:
        raise ValueError(f"need at least 3 x 3 bins, got {plane.shape[0]} x {plane.shape[1]}")
    return plane, y, x


def _robust_std(values: np.ndarray) -> float:
    """Standard deviation from the median absolute deviation (unaffected by a few outliers)."""
    return float(1.4826 * np.median(np.abs(values - np.median(values))))
