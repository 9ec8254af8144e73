"""Smooth upsampling of bin-resolution fields to sensor pixels.

A field sampled at bin centres is interpolated with a cubic spline along each axis (extrapolated
smoothly over the outer half-bin). The spline is linear in the data, so along one axis it is a
matrix of shape (n_pixels, n_bins); a 2-D field F upsamples as ``Ay @ F @ Ax.T``. This keeps the
cost at two matrix products and gives a C2-smooth gain surface with no block edges.

The same spline is also a cubic B-spline (knots at the bin centres, the end ones fourfold, less the
second and the second-last, which not-a-knot removes), and that form is local: a value at any position depends on
only 4 coefficients along each axis. :func:`spline_coefficients` solves for the coefficients once
per field, :func:`spline_taps` gives each position's 4 coefficient indices and weights, and a 2-D
field evaluates at a pixel as ``sum_ab wy[a] * C[iy + a, ix + b] * wx[b]`` (16 taps), which is how
the correction kernels interpolate on the fly without a full-resolution field.
"""

from __future__ import annotations

import numpy as np

#: Degree of the splines.
_K = 3
#: Half the knot span of the constant spline through a single sample, in pixels.
_WIDE = 2.0**20


def interpolation_matrix(centres: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Matrix that maps values at ``centres`` to their cubic-spline interpolation at ``positions``.

    Parameters
    ----------
    centres : ndarray, shape (n,)
        Increasing sample positions (bin centres, in sensor pixels).
    positions : ndarray, shape (m,)
        Where to evaluate (sensor pixel coordinates).

    Returns
    -------
    ndarray of float64, shape (m, n)

    Examples
    --------
    >>> A = interpolation_matrix(np.array([0.0, 1.0, 2.0, 3.0]), np.array([1.5]))
    >>> float((A @ np.array([0.0, 1.0, 2.0, 3.0]))[0])
    1.5
    """
    centres = np.asarray(centres, dtype=float)
    positions = np.asarray(positions, dtype=float)
    n = centres.size
    if n == 1:
        return np.ones((positions.size, 1))
    # The spline of each unit sample, in its B-spline form: scipy's CubicSpline(centres, eye(n)) to rounding.
    knots, coefficients = _spline(centres, np.eye(n), 0)
    first, weights = spline_taps(knots, positions)
    matrix = np.zeros((positions.size, n))
    for tap in range(_K + 1):
        matrix += weights[:, tap, None] * coefficients[first + tap]
    return matrix


def upsample(field: np.ndarray, ay: np.ndarray, ax: np.ndarray) -> np.ndarray:
    """Upsample a field of shape (nby, nbx, ...) to (len(ay), len(ax), ...) with interpolation matrices.

    Examples
    --------
    >>> f = np.arange(6.0).reshape(2, 3)
    >>> upsample(f, np.eye(2), np.eye(3)).tolist() == f.tolist()
    True
    """
    nby, nbx = field.shape[:2]
    rest = field.shape[2:]
    flat = field.reshape(nby, nbx, -1)
    rows = np.tensordot(ay, flat, axes=(1, 0))  # (m, nbx, k)
    out = np.tensordot(ax, rows, axes=(1, 1))  # (mx, m, k)
    return np.moveaxis(out, 0, 1).reshape((ay.shape[0], ax.shape[0], *rest))


def _spline(centres: np.ndarray, values: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Knots and B-spline coefficients (along ``axis``) of the cubic spline through ``values`` at ``centres``.

    The boundary conditions are those of :func:`interpolation_matrix`: not-a-knot, natural for 2 or 3
    samples; one sample is a constant (a cubic Bezier piece with 4 equal coefficients). The knots and the
    coefficients are scipy's ``make_interp_spline``'s (to rounding), solved here with numpy: this is on the way
    of every correction, and importing scipy.interpolate costs more than the rest of a command's start.
    """
    values = np.moveaxis(np.asarray(values, dtype=np.float64), axis, 0)
    n, knots = centres.size, spline_knots(centres)
    if n == 1:  # equal coefficients make a constant whatever the knots
        return knots, np.moveaxis(np.repeat(values, _K + 1, axis=0), 0, axis)
    first, weights = spline_taps(knots, centres)
    size = knots.size - _K - 1
    system = np.zeros((size, size))
    rows = np.arange(n) + (size - n) // 2
    for tap in range(_K + 1):
        system[rows, first + tap] = weights[:, tap]
    rhs = np.zeros((size, *values.shape[1:]))
    rhs[rows] = values
    if size > n:  # natural ends: the second derivative of a clamped cubic B-spline at its end knot is 0 (to a factor)
        a, b = 1 / (knots[_K + 1] - knots[0]), 1 / (knots[_K + 2] - knots[0])
        system[0, :3] = a, -a - b, b
        a, b = 1 / (knots[-1] - knots[-_K - 3]), 1 / (knots[-1] - knots[-_K - 2])
        system[-1, -3:] = a, -a - b, b
    coefficients = _solve_banded(system, rhs.reshape(size, -1)).reshape(rhs.shape)
    return knots, np.moveaxis(coefficients, 0, axis)


def _solve_banded(system: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``solve(system, rhs)`` for a banded system (a B-spline collocation matrix: at most 4 entries a row), by
    Gaussian elimination within the band.

    Without pivoting, which a collocation matrix does not need (it is totally positive, de Boor); its natural ends'
    rows keep positive pivots. A few milliseconds where a dense solve took tens, and no BLAS threads, which slow to a
    crawl when other work keeps the cores busy.
    """
    a, b = system.copy(), rhs.astype(np.float64, copy=True)
    size = a.shape[0]
    rows, cols = np.nonzero(a)
    lower, upper = int(np.max(rows - cols, initial=0)), int(np.max(cols - rows, initial=0))
    for k in range(size):
        pivot = a[k, k]
        if abs(pivot) < 1e-12 * np.abs(a[k]).max(initial=0.0):  # not a collocation matrix after all
            return np.linalg.solve(system, rhs)
        end = min(size, k + upper + 1)
        for i in range(k + 1, min(size, k + lower + 1)):
            if factor := a[i, k] / pivot:
                a[i, k:end] -= factor * a[k, k:end]
                b[i] -= factor * b[k]
    for k in range(size - 1, -1, -1):
        end = min(size, k + upper + 1)
        b[k] = (b[k] - a[k, k + 1 : end] @ b[k + 1 : end]) / a[k, k]
    return b


def spline_knots(centres: np.ndarray) -> np.ndarray:
    """Knot vector of the cubic B-spline form of :func:`interpolation_matrix`'s spline on ``centres``.

    Examples
    --------
    >>> spline_knots(np.array([0.0, 1.0, 2.0, 3.0, 4.0])).tolist()
    [0.0, 0.0, 0.0, 0.0, 2.0, 4.0, 4.0, 4.0, 4.0]
    """
    centres = np.asarray(centres, dtype=float)
    if centres.size == 1:
        # For a constant (equal coefficients), a span far wider than any sensor keeps every position near its
        # middle, where the weights are all positive (no cancellation).
        return np.repeat([centres[0] - _WIDE, centres[0] + _WIDE], _K + 1)
    # not-a-knot: no knot at the second and the second-last centre; natural (2-3 centres): a knot at every centre
    inner = centres[2:-2] if centres.size > 3 else centres[1:-1]
    return np.concatenate([np.repeat(centres[0], _K + 1), inner, np.repeat(centres[-1], _K + 1)])


def spline_coefficients(field: np.ndarray, centres_y: np.ndarray, centres_x: np.ndarray) -> np.ndarray:
    """B-spline coefficients of a field sampled at bin centres, interpolated as :func:`interpolation_matrix` does.

    Parameters
    ----------
    field : ndarray, shape (nby, nbx, ...)
        Samples at ``centres_y`` x ``centres_x``.
    centres_y, centres_x : ndarray
        Increasing sample positions along each axis.

    Returns
    -------
    ndarray of float64, shape (ncy, ncx, ...)
        Coefficients for the knots :func:`spline_knots` gives for each axis (``ncy == nby`` for 4 or
        more samples, ``nby + 2`` for 2 or 3, 4 for 1).

    Examples
    --------
    >>> c = np.arange(5.0)
    >>> f = np.add.outer(c, 2 * c)  # a plane is its own spline
    >>> C = spline_coefficients(f, c, c)
    >>> iy, wy = spline_taps(spline_knots(c), np.array([1.5]))
    >>> ix, wx = spline_taps(spline_knots(c), np.array([3.25]))
    >>> round(float(wy[0] @ C[iy[0] : iy[0] + 4, ix[0] : ix[0] + 4] @ wx[0]), 12)
    8.0
    """
    field = np.asarray(field, dtype=np.float64)
    along_y = _spline(np.asarray(centres_y, dtype=float), field, 0)[1]
    return _spline(np.asarray(centres_x, dtype=float), along_y, 1)[1]


def spline_taps(knots: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the first of the 4 B-spline coefficients that act at each position, and their weights.

    Positions outside the knots get the end pieces' polynomials continued, as
    :func:`interpolation_matrix` extrapolates (de Boor's recurrence on the nearest knot interval).

    Parameters
    ----------
    knots : ndarray
        From :func:`spline_knots`.
    positions : ndarray, shape (m,)

    Returns
    -------
    first : ndarray of int64, shape (m,)
    weights : ndarray of float64, shape (m, 4)
        The value at ``positions[i]`` is ``weights[i] @ coefficients[first[i] : first[i] + 4]``.

    Examples
    --------
    >>> first, weights = spline_taps(np.repeat([0.0, 1.0], 4), np.array([0.5]))
    >>> first.tolist(), weights.tolist()
    ([0], [[0.125, 0.375, 0.375, 0.125]])
    """
    t = np.asarray(knots, dtype=float)
    x = np.asarray(positions, dtype=float)
    n_coefficients = t.size - _K - 1
    span = np.clip(np.searchsorted(t, x, side="right") - 1, _K, n_coefficients - 1)
    # de Boor's triangle (The NURBS Book, algorithm A2.2), vectorised over positions.
    weights = np.zeros((x.size, _K + 1))
    weights[:, 0] = 1.0
    left = np.empty((x.size, _K + 1))
    right = np.empty((x.size, _K + 1))
    for j in range(1, _K + 1):
        left[:, j] = x - t[span + 1 - j]
        right[:, j] = t[span + j] - x
        saved = np.zeros(x.size)
        for r in range(j):
            temp = weights[:, r] / (right[:, r + 1] + left[:, j - r])
            weights[:, r] = saved + right[:, r + 1] * temp
            saved = left[:, j - r] * temp
        weights[:, j] = saved
    return span - _K, weights
