"""Array functions on binned calibration fields, underneath the checks of :mod:`picamcal.analysis.diagnostics`.

* :func:`vignetting_centre` and :func:`implied_tilt`: where a flat field peaks (a robust point-symmetric surface
  with a free centre), and the tilt of the light that moves it there (paper, section "Vignetting").
* :func:`dust_residual` and :func:`find_dust`: small dark specks against a smooth background (section "Colour
  crosstalk": high-frequency structure "probably indicates dirt in the optical system").
* :func:`roughness`: bin-to-bin structure of any field, its departure from a local quadratic.

They take plain arrays (a plane of bins and the bins' centres in sensor pixels), not a calibration.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

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
#: A dust speck must reach this many noise standard deviations (on the matched-filtered residual). The
#: statistic's tail is heavier than a Gaussian's (the background fit leaves out what stands off it): on white
#: noise in 205 x 154 bins (a full IMX219 frame in 16-pixel bins), 7 % of fields had a false speck at 5 sigma,
#: 1 % at 5.5 (200 fields); at 40 x 30 bins none at 5.5 (300 fields).
DUST_SIGMA = 5.5

_DEGREE = 4  # of the point-symmetric polynomial fitted to the flat field
_BACKGROUND_DEGREE = 3  # of the local polynomial a dust residual is taken against, along each axis
_BACKGROUND_BINS = 13  # its window (bins): follows a microscope's shading into the corners, but not dust
_START_BINS = 9  # running median (bins) the background's first fit is of: wider than most specks
_NOISE_BINS = 21  # blocks (bins) of the local noise estimate
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
    smooth = _smooth(np.where(good, z, np.nanmedian(z)), 2.0)
    top = smooth >= np.percentile(smooth, 97)
    centre = np.array([xx[top].mean(), yy[top].mean()])

    def coefficients(c: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = _even_basis((xx[mask] - c[0]) / scale, (yy[mask] - c[1]) / scale, degree)
        coef = _lstsq(a, z[mask])
        return coef, z[mask] - a @ coef

    for _ in range(3):
        mask = good.copy()
        centre = _levenberg_marquardt(functools.partial(_residual_of, coefficients, mask), centre, 1e-6 * scale)
        coef, _ = coefficients(centre, mask)
        residual = z - _symmetric_surface(coef, y, x, centre, scale)
        sigma = _robust_std(residual[mask])
        good = np.isfinite(z) & (np.abs(residual) <= max(5.0 * sigma, 1e-6))
        if np.array_equal(good, mask):
            break
    return centre, coef * level, good


def _residual_of(
    coefficients: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]], mask: np.ndarray, c: np.ndarray
) -> np.ndarray:
    return coefficients(c, mask)[1]


def _levenberg_marquardt(
    residual: Callable[[np.ndarray], np.ndarray], start: np.ndarray, tolerance: float, iterations: int = 100
) -> np.ndarray:
    """The parameters (a few) that minimise ``sum(residual(p)**2)``, by Levenberg-Marquardt with a forward-difference
    Jacobian; stops when a step moves them less than ``tolerance``. numpy's, not scipy.optimize's (whose import,
    0.3 to 0.6 s, cost every calibrate command more than the whole search)."""
    p = np.asarray(start, dtype=np.float64)
    r = residual(p)
    cost, damping = float(r @ r), 1e-3
    for _ in range(iterations):
        steps = np.sqrt(np.finfo(np.float64).eps) * np.maximum(1.0, np.abs(p))
        jacobian = np.stack([(residual(p + h) - r) / h[i] for i, h in enumerate(np.diag(steps))], axis=1)
        normal, gradient = jacobian.T @ jacobian, jacobian.T @ r
        while damping < 1e12:
            lhs = normal + damping * np.diag(np.maximum(np.diag(normal), 1e-12))
            try:
                step = np.linalg.solve(lhs, -gradient)
            except np.linalg.LinAlgError:
                damping *= 10
                continue
            trial = residual(p + step)
            if (trial_cost := float(trial @ trial)) <= cost:
                p, r, cost, damping = p + step, trial, trial_cost, max(damping / 3, 1e-12)
                break
            damping *= 4
        else:
            return p  # no step lowers the cost: a minimum
        if np.max(np.abs(step)) < tolerance:
            break
    return p


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

    The smooth version is a local polynomial, cubic along each axis, fitted by least squares over the 13 x 13 bins
    around each bin (a two-dimensional Savitzky-Golay filter); at the frame's edges the window stays inside the
    frame and its polynomial is evaluated at the bin, so the shading is followed into the corners. A microscope's,
    2.5 times darker in the farthest corner, its centre up to a quarter of the frame off the frame's (falling off as
    r**2 or r**4), leaves under 0.01 % below it and 0.14 % above at 103 x 77 bins (1640 x 1232 pixels in 16-pixel
    bins); at 40 x 30 bins, where the window spans a third of the frame, 0.17 % below and up to 1.8 % above, in the
    farthest corner (too bright there: no false dust, and dust there must be that much deeper). So that specks do
    not pull it down, the first fit is of a 9-bin running median (along each axis
    in turn, extrapolated linearly past the edges), then bins more than 3 robust sigma off the fit are replaced by
    it and the fit repeated (three passes). A speck's wings, each bin less than 3 sigma off, would still bend a
    cubic near the frame's edge into a false speck there: within 3 bins of two or more neighbouring outliers, bins
    1.5 sigma off are replaced too (on either side, so that noise is left alone).

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
    >>> flat[19, 0] *= 0.9  # in the corner too
    >>> [round(float(v), 3) for v in dust_residual(flat, yc, xc)[[10, 19], [5, 0]]]
    [-0.1, -0.1]
    """
    plane, y, x = _as_plane(plane, y, x)
    z = plane / np.median(plane)
    fit = _local_fit(_running_median(z, _START_BINS))
    for _ in range(3):
        off = np.abs(z - fit) / max(_robust_std(z - fit), 1e-9)
        outliers = off > 3.0
        padded = np.pad(outliers, 1)
        clustered = outliers & (padded[:-2, 1:-1] | padded[2:, 1:-1] | padded[1:-1, :-2] | padded[1:-1, 2:])
        fit = _local_fit(np.where(outliers | (_grow(clustered, 3) & (off > 1.5)), fit, z))
    return z / fit - 1.0


def _grow(mask: np.ndarray, reach: int) -> np.ndarray:
    """``mask`` and every bin within ``reach`` bins of it along x and y (a square)."""
    for axis in (1, 0):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (reach, reach)
        mask = np.asarray(sliding_window_view(np.pad(mask, pad), 2 * reach + 1, axis=axis).any(axis=-1))
    return mask


def _running_median(z: np.ndarray, n: int) -> np.ndarray:
    """Median of the ``n`` (odd) bins around each bin along x, then of those along y; past the frame's edges the bins
    are mirrored about the edge bin in value too (``2 edge - mirrored``), which continues a slope."""
    for axis in (1, 0):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (n // 2, n // 2)
        padded = np.pad(z, pad, mode="reflect", reflect_type="odd")
        z = np.partition(sliding_window_view(padded, n, axis=axis), n // 2, axis=-1)[..., n // 2]
    return z


def _local_fit(z: np.ndarray) -> np.ndarray:
    """At each bin, the value there of the polynomial of :data:`_BACKGROUND_DEGREE` fitted by least squares to the
    :data:`_BACKGROUND_BINS` bins around it along x (the window kept inside the frame), then the same along y."""
    for axis in (1, 0):
        n = z.shape[axis]
        window = min(_BACKGROUND_BINS, n)
        degree = min(_BACKGROUND_DEGREE, window - 1)
        half = (window - 1) / 2
        basis = np.vander((np.arange(window) - half) / max(half, 1.0), degree + 1)
        starts = np.clip(np.arange(n) - window // 2, 0, n - window)
        at = np.vander((np.arange(n) - starts - half) / max(half, 1.0), degree + 1)  # each bin in its window
        weights = at @ np.linalg.pinv(basis)  # (n, window): each bin's fit from its window's samples
        along = (slice(None), None) if axis == 0 else (None, slice(None))
        # Tap by tap, not as a matrix product: on a busy machine BLAS threads make products this small 30 times slower
        z = sum(weights[:, k][along] * np.take(z, starts + k, axis=axis) for k in range(window))
    return z


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

    1. The residual is divided by its local noise (robust: 1.4826 times the median of ``|residual|`` in blocks
       of 21 x 21 bins, interpolated between the blocks' centres), since the corners of a vignetted white are
       noisier than its centre.
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
    local = np.maximum(_local_noise(residual), 1e-6)
    smooth = _matched_filter(residual / local)
    noise_smooth = _robust_std(smooth)
    labels = _label(smooth < -_GROW_SIGMA * noise_smooth)
    edged = np.pad(residual, 1, mode="edge")
    minima = residual == sliding_window_view(edged, (3, 3)).min(axis=(-2, -1))
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
    kernel = _gaussian(_MATCHED_SIGMA)
    return _correlate(z, kernel) / np.sqrt(_correlate(np.ones_like(z), kernel**2))


def _gaussian(sigma: float) -> np.ndarray:
    """A Gaussian's weights out to 3 sigma, one per bin."""
    offsets = np.arange(-math.ceil(3 * sigma), math.ceil(3 * sigma) + 1)
    return np.exp(-(offsets**2) / (2 * sigma**2))


def _correlate(z: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """The sum over the bins around each bin, inside the frame, weighted by ``kernel`` along x and along y."""
    for axis in (1, 0):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (kernel.size // 2, kernel.size // 2)
        z = np.einsum("...k,k->...", sliding_window_view(np.pad(z, pad), kernel.size, axis=axis), kernel)
    return z


def _smooth(z: np.ndarray, sigma: float) -> np.ndarray:
    """``z`` smoothed by a Gaussian of ``sigma`` bins, its weights renormalised inside the frame."""
    kernel = _gaussian(sigma)
    return _correlate(z, kernel) / _correlate(np.ones_like(z), kernel)


def _local_noise(residual: np.ndarray) -> np.ndarray:
    """Robust standard deviation of ``residual`` in blocks of about :data:`_NOISE_BINS` bins each way, interpolated
    linearly between the blocks' centres (held beyond the outer ones)."""
    ny, nx = residual.shape
    ey = np.linspace(0, ny, max(1, round(ny / _NOISE_BINS)) + 1).astype(int)
    ex = np.linspace(0, nx, max(1, round(nx / _NOISE_BINS)) + 1).astype(int)
    blocks = np.array(
        [[np.median(np.abs(residual[a:b, c:d])) for c, d in itertools.pairwise(ex)] for a, b in itertools.pairwise(ey)]
    )
    cy, cx = (ey[:-1] + ey[1:] - 1) / 2, (ex[:-1] + ex[1:] - 1) / 2
    along_x = np.array([np.interp(np.arange(nx), cx, row) for row in blocks])
    return 1.4826 * np.array([np.interp(np.arange(ny), cy, column) for column in along_x.T]).T


def _label(mask: np.ndarray) -> np.ndarray:
    """Connected regions of ``mask`` (4-connected), each given one positive number (not consecutive); 0 outside."""
    far = mask.size + 1
    labels = np.where(mask, np.arange(1, mask.size + 1).reshape(mask.shape), far)
    while True:
        padded = np.pad(labels, 1, constant_values=far)
        least = np.minimum.reduce([labels, padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]])
        least = np.where(mask, least, far)
        # A label is a bin's number in its region: taking that bin's label jumps along chains of them.
        least = np.where(mask, np.append(least.ravel(), far)[np.minimum(least, far) - 1].reshape(mask.shape), far)
        if np.array_equal(least, labels):
            return np.where(mask, labels, 0)
        labels = least


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
