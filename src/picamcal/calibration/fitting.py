"""Fitting the unmixing field: least squares over more than three colour references, and the noise limit.

Array functions of the calibration's maths that go beyond the paper's exact 3 x 3 inversion
(:func:`picamcal.calibrate.calibrate` calls them; docs/method.md derives them):

- :func:`least_squares_unmixing`: the per-bin 3 x 3 matrix that best maps a bin's responses to K >= 3 colour
  references onto their responses at the centre of the sensor, keeping the white exact;
- :func:`penalty_field`: the noise penalty of a matrix field (what :meth:`Calibration.noise_penalty` reports);
- :func:`limit_noise_penalty`: the unmixing field blended towards the flat-field-only correction, per bin as
  little as keeps the noise penalty within a bound;
- :func:`residual_crosstalk`: the crosstalk a (bounded) unmixing leaves, the colour cost of the bound;
- :func:`noise_limited_unmixing`: the last two together, as :func:`picamcal.calibrate` records them.

Matrices act on column vectors (``out = U @ rgb``), rows are output channels, as everywhere in picamcal.
"""

from __future__ import annotations

import numpy as np

from ..bayer import sites_to_channels
from ..errors import CalibrationInputError

__all__ = [
    "crosstalk_matrices",
    "invert_3x3",
    "least_squares_unmixing",
    "limit_noise_penalty",
    "noise_limited_unmixing",
    "penalty_field",
    "residual_crosstalk",
]

# U @ (1, 1, 1) = (1, 1, 1) as three linear constraints on the row-major unknowns U_pq: row p sums to 1.
_WHITE_CONSTRAINT = np.kron(np.eye(3), np.ones((1, 3)))
# The noise limit aims this fraction below the bound, so that storing the field in float32 cannot push a bin over.
_BOUND_MARGIN = 1e-5


# Index pairs (p, q, r, s) of the flattened 3x3 matrix whose products a_p a_q - a_r a_s give each element
# of the adjugate, row-major.
_ADJUGATE = (
    (4, 8, 5, 7),
    (2, 7, 1, 8),
    (1, 5, 2, 4),
    (5, 6, 3, 8),
    (0, 8, 2, 6),
    (2, 3, 0, 5),
    (3, 7, 4, 6),
    (1, 6, 0, 7),
    (0, 4, 1, 3),
)


def invert_3x3(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Invert a stack of 3x3 matrices in one vectorised step (adjugate over determinant).

    The paper inverted each bin's matrix with ``numpy.linalg.inv`` in a Python loop; this works on
    nine contiguous planes of all the bins at once (``benchmarks/run.py`` measures the difference).

    Parameters
    ----------
    m : ndarray, shape (..., 3, 3)
        Computed in its own precision if float32, else in float64.

    Returns
    -------
    inverse : ndarray, shape (..., 3, 3)
        Non-finite where the determinant is zero.
    det : ndarray, shape (...)

    Examples
    --------
    >>> inv, det = invert_3x3(np.diag([2.0, 4.0, 5.0]))
    >>> np.diag(inv).tolist(), float(det)
    ([0.5, 0.25, 0.2], 40.0)
    """
    shape = np.shape(m)
    dtype = np.float32 if np.asarray(m).dtype == np.float32 else np.float64
    planes = np.ascontiguousarray(np.reshape(m, (-1, 9)).T, dtype=dtype)  # (9, n)
    adjugate = np.empty_like(planes)
    scratch = np.empty_like(planes[0])
    for k, (p, q, r, s) in enumerate(_ADJUGATE):
        np.multiply(planes[p], planes[q], out=adjugate[k])
        adjugate[k] -= np.multiply(planes[r], planes[s], out=scratch)
    det = planes[0] * adjugate[0]
    det += np.multiply(planes[1], adjugate[3], out=scratch)
    det += np.multiply(planes[2], adjugate[6], out=scratch)
    with np.errstate(divide="ignore", invalid="ignore"):
        adjugate /= det
    return adjugate.T.reshape(shape), det.reshape(shape[:-2])


def crosstalk_matrices(site_responses: np.ndarray, pattern: str) -> np.ndarray:
    """White-normalised crosstalk matrices M(b), shape (nby, nbx, 3, 3), with ``M(b) @ (1, 1, 1) = 1``.

    Column l is the response to primary l divided by the white, per site, then averaged per channel
    (so it matches the flat-fielded image the correction unmixes). The columns are then rescaled per
    bin so that the white is one unit of each primary: the white reference defines neutral.

    Parameters
    ----------
    site_responses : ndarray, shape (4, nby, nbx, 4)
        Black-subtracted bin means of the white, red, green and blue references per Bayer site.
    pattern : str
        Bayer pattern.

    Examples
    --------
    >>> white = np.ones((1, 1, 4))
    >>> red, green, blue = (np.array([a, b, b, c], float).reshape(1, 1, 4) for a, b, c in np.eye(3))
    >>> crosstalk_matrices(np.stack([white, red, green, blue]), "RGGB")[0, 0].tolist()  # no crosstalk: identity
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    white = site_responses[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        normalised = site_responses[1:] / white  # (3 primaries, nby, nbx, 4 sites)
    columns = sites_to_channels(normalised, pattern)  # (3 primaries, nby, nbx, 3 channels)
    m = np.moveaxis(columns, 0, -1)  # (nby, nbx, channel, primary)
    inverse, _ = invert_3x3(m)
    amounts = inverse.sum(axis=-1)  # inv(M) @ 1: how much of each primary the white holds
    return m * amounts[..., None, :]


def least_squares_unmixing(
    responses: np.ndarray, targets: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-bin 3x3 matrices ``U(b)`` taking the references' responses to their centre colours, white kept exact.

    Generalises the paper's ``U(b) = M_centre inv(M(b))`` (paper, eq. for ``Unmixed``) from the red, green and
    blue references to K >= 3. Reference k's white-normalised response in bin b, ``r_k(b)``, should map onto
    the direction of its target ``t_k`` (its response at the centre); its brightness relative to the white may
    vary over the frame (each light has its own spatial profile), so only the component of ``U r_k`` across
    ``t_k`` is an error, ``e_k = P_k U r_k`` with ``P_k = I - t_k t_k^T / |t_k|^2``. The white, which defines
    neutral, maps to itself exactly: ``U @ 1 = 1``. Per bin this is

        minimise  sum_k w_k |P_k U r_k(b)|^2   subject to   U(b) @ (1, 1, 1) = (1, 1, 1)

    whose normal equations in the nine unknowns ``u = vec(U)`` (row-major) are ``N u + C^T mu = 0``,
    ``C u = 1`` with ``N = sum_k w_k P_k (x) r_k r_k^T`` (Kronecker product) and ``C = I (x) (1, 1, 1)``: a
    12 x 12 system per bin, solved for all bins at once. With exactly three references the error can be
    zero, and the solution is the paper's ``M_centre inv(M(b))`` when the targets are the columns of
    ``M_centre``.

    Parameters
    ----------
    responses : ndarray, shape (K, ..., 3)
        White-normalised channel responses of the K references per bin (the flat-fielded reference images).
    targets : ndarray, shape (K, 3)
        What each reference should look like: its colour at the centre of the sensor (only the direction
        counts).
    weights : ndarray, shape (K,), optional
        Weight of each reference's squared error; equal by default. Errors scale with a reference's
        brightness, so ``1 / |r_k(centre)|^2`` makes each one's error relative to its own brightness (what
        :func:`picamcal.calibrate.calibrate` does, so that a dim reference does not count less for being dim).

    Returns
    -------
    unmixing : ndarray of float64, shape (..., 3, 3)
        ``U(b)``; NaN in bins whose references do not span three colours (a singular system).
    residual : ndarray of float64, shape (K, ...)
        ``|P_k U r_k(b)| / |r_k(b)|``: each reference's error in bin b, as a fraction of its response (0 for
        references a 3x3 matrix fits exactly).

    Examples
    --------
    Four references through a bin whose crosstalk is ``m``, targets those of a bin without crosstalk:

    >>> m = np.array([[0.9, 0.1, 0.0], [0.1, 0.8, 0.1], [0.0, 0.1, 0.9]])
    >>> colours = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0.5, 0.5]])  # red, green, blue, cyan
    >>> responses = (colours @ m.T)[:, None, :]  # one bin
    >>> u, residual = least_squares_unmixing(responses, colours)
    >>> bool(np.allclose(u[0], np.linalg.inv(m))), float(residual.max()) < 1e-12
    (True, True)
    """
    responses = np.asarray(responses, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    count = responses.shape[0]
    weights = np.ones(count) if weights is None else np.asarray(weights, dtype=np.float64)
    direction = targets / np.linalg.norm(targets, axis=-1, keepdims=True)
    across = np.eye(3) - direction[:, :, None] * direction[:, None, :]  # P_k, (K, 3, 3)
    grid = responses.shape[1:-1]
    flat = responses.reshape(count, -1, 3)  # (K, n, 3)
    outer = flat[..., :, None] * flat[..., None, :]  # r_k r_k^T, (K, n, 3, 3)
    # N[3p + q, 3p' + q'] = sum_k w_k P_k[p, p'] r_k[q] r_k[q']
    normal = np.einsum("k,kac,knbd->nabcd", weights, across, outer).reshape(-1, 9, 9)
    system = np.zeros((normal.shape[0], 12, 12))
    system[:, :9, :9] = normal
    system[:, 9:, :9] = _WHITE_CONSTRAINT
    system[:, :9, 9:] = _WHITE_CONSTRAINT.T
    rhs = np.zeros((normal.shape[0], 12, 1))
    rhs[:, 9:] = 1.0
    unknowns = _solve_each(system, rhs)
    unmixing = unknowns[:, :9, 0].reshape(-1, 3, 3)
    errors = np.einsum("kac,ncd,knd->kna", across, unmixing, flat)
    with np.errstate(divide="ignore", invalid="ignore"):
        residual = np.linalg.norm(errors, axis=-1) / np.linalg.norm(flat, axis=-1)
    return unmixing.reshape(*grid, 3, 3), residual.reshape(count, *grid)


def _solve_each(system: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``solve(system, rhs)`` for a stack; NaN for the singular ones instead of failing the whole stack."""
    try:
        return np.linalg.solve(system, rhs)
    except np.linalg.LinAlgError:
        out = np.full(rhs.shape, np.nan)
        for i in range(system.shape[0]):
            try:
                out[i] = np.linalg.solve(system[i], rhs[i])
            except np.linalg.LinAlgError:
                continue
        return out


def penalty_field(
    matrices: np.ndarray, white: np.ndarray, centre_white: np.ndarray, channel_noise: np.ndarray | None = None
) -> np.ndarray:
    """Noise penalty per bin and output channel of the matrix field ``matrices`` after the flat field.

    ``penalty_p(b) = W_p(centre) sqrt(sum_q (A_pq(b) sigma_q / W_q(b))^2) / sigma_p`` (paper, section "Colour
    crosstalk"; :meth:`picamcal.calibration.Calibration.noise_penalty` says more).

    Parameters
    ----------
    matrices : ndarray, shape (nby, nbx, 3, 3)
    white : ndarray, shape (nby, nbx, 3)
        ``W``, the white response per channel.
    centre_white : ndarray, shape (3,)
        ``W`` averaged over the centre region.
    channel_noise : ndarray, shape (3,), optional
        Relative read noise of the input channels; equal by default.

    Examples
    --------
    >>> white = np.full((1, 1, 3), 50.0)  # half as bright as the centre
    >>> penalty_field(np.eye(3)[None, None], white, np.full(3, 100.0)).tolist()
    [[[2.0, 2.0, 2.0]]]
    """
    sigma = np.ones(3) if channel_noise is None else np.asarray(channel_noise, dtype=float)
    coefficients = matrices * (sigma / white)[..., None, :]
    return centre_white / sigma * np.sqrt((coefficients**2).sum(axis=-1))


def limit_noise_penalty(
    unmixing: np.ndarray, white: np.ndarray, centre_white: np.ndarray, bound: float
) -> tuple[np.ndarray, np.ndarray]:
    """The unmixing field blended towards the identity (flat field only) where its noise penalty exceeds ``bound``.

    In each bin the blend ``U_lambda = (1 - lambda) U + lambda I`` keeps the white exact (both map it to itself)
    and trades colour for noise: at ``lambda = 0`` the full unmixing, at ``lambda = 1`` the flat-field-only
    correction, whose penalty is the vignetting's, ``W_p(centre) / W_p(b)``. Each row's penalty is the norm of a
    linear function of ``lambda``, so it is convex in it and the smallest ``lambda`` meeting the bound is a
    root of a quadratic, per row; a bin takes the largest of its three rows'. So that the field stays smooth,
    the blend weights are then widened (a 3 x 3 maximum filter) and smoothed (a Gaussian of one bin, cut at two), never
    below what each bin needs: a larger ``lambda`` still meets the bound, as the bound holds from the needed
    one to 1. Where the bound is met nowhere, the field comes back unchanged.

    Parameters
    ----------
    unmixing : ndarray, shape (nby, nbx, 3, 3)
        ``U``, the unbounded field (mode ``centre``).
    white : ndarray, shape (nby, nbx, 3)
        ``W``.
    centre_white : ndarray, shape (3,)
        ``W`` averaged over the centre region.
    bound : float
        The largest noise penalty allowed (equal read noise in the channels, as ``Calibration.noise_penalty``
        by default); at least the flat field's own worst penalty (``max W_p(centre) / W_p(b)``), which no blend
        goes below.

    Returns
    -------
    unmixing : ndarray of float64, shape (nby, nbx, 3, 3)
        ``U_lambda``: its penalty is at most ``bound`` (aimed a fraction 1e-5 below it, against rounding).
    blend : ndarray of float64, shape (nby, nbx)
        ``lambda`` per bin, 0 (unchanged) to 1 (flat field only).

    Raises
    ------
    ValueError
        ``bound`` is below the flat field's worst penalty (the caller says which option to change).

    Examples
    --------
    One bin at half the centre's brightness whose unmixing borrows from the other channels:

    >>> u = np.array([[1.6, -0.3, -0.3], [-0.3, 1.6, -0.3], [-0.3, -0.3, 1.6]])[None, None]
    >>> white, centre = np.full((1, 1, 3), 50.0), np.full(3, 100.0)
    >>> round(float(penalty_field(u, white, centre).max()), 2)
    3.31
    >>> limited, blend = limit_noise_penalty(u, white, centre, 2.5)
    >>> round(float(penalty_field(limited, white, centre).max()), 4), round(float(blend[0, 0]), 3)
    (2.5, 0.602)
    """
    target = bound * (1 - _BOUND_MARGIN) / centre_white  # per output row, in units of 1 / W
    rows = unmixing / white[..., None, :]  # v = U_p / W, (nby, nbx, p, q)
    identity = np.broadcast_to(np.eye(3), unmixing.shape) / white[..., None, :]  # e_p / W
    floor = float((centre_white / white).max())
    if floor > bound * (1 - _BOUND_MARGIN):
        raise ValueError(f"{bound:g} is below the flat field's own worst noise penalty {floor:.3f}")
    step = identity - rows
    a = (step**2).sum(axis=-1)
    b = (rows * step).sum(axis=-1)
    c = (rows**2).sum(axis=-1) - target**2
    # Smallest root of a l^2 + 2 b l + c in its stable form c / (-b + sqrt(b^2 - a c)); c <= 0 needs none.
    with np.errstate(divide="ignore", invalid="ignore"):
        root = c / (-b + np.sqrt(np.maximum(b * b - a * c, 0.0)))
    needed = np.clip(np.where(c > 0, root, 0.0), 0.0, 1.0).max(axis=-1)
    if not needed.any():
        return unmixing.astype(np.float64), needed
    from scipy import ndimage  # here, not for every load of a calibration

    widened = ndimage.maximum_filter(needed, size=3, mode="nearest")
    widened = ndimage.gaussian_filter(widened, 1.0, mode="nearest", truncate=2.0)
    blend = np.clip(np.maximum(needed, widened), 0.0, 1.0)
    return unmixing + blend[..., None, None] * (np.eye(3) - unmixing), blend


def residual_crosstalk(unmixing: np.ndarray, crosstalk: np.ndarray, colour_response_inverse: np.ndarray) -> np.ndarray:
    """What a correction leaves of the crosstalk: ``Cx U(b) M(b) - I`` per bin, in amounts of the primaries.

    ``M(b)`` takes amounts of the primaries to the flat-fielded response and ``Cx U(b)`` (mode ``pure``) takes
    it back, so for the full unmixing ``Cx M_centre inv(M(b)) M(b) = I`` and this is zero (to rounding). A
    noise-limited unmixing (:func:`limit_noise_penalty`) leaves ``lambda (Cx M(b) - I)``: element ``(p, l)`` is
    the fraction of primary ``l`` that shows as primary ``p`` (off the diagonal, colour that leaks; on it,
    saturation lost or gained), relative to the centre's colours.

    Examples
    --------
    >>> m = np.array([[0.9, 0.1, 0.0], [0.1, 0.8, 0.1], [0.0, 0.1, 0.9]])[None]
    >>> full = residual_crosstalk(np.linalg.inv(m), m, np.eye(3))
    >>> float(np.abs(full).max()) < 1e-12
    True
    >>> half = residual_crosstalk(0.5 * np.linalg.inv(m) + 0.5 * np.eye(3), m, np.eye(3))
    >>> round(float(half[0, 1, 0]), 3)  # half of M's 0.1 leak of green into red is left
    0.05
    """
    return colour_response_inverse @ unmixing @ crosstalk - np.eye(3)


def noise_limited_unmixing(
    unmixing: np.ndarray,
    crosstalk: np.ndarray,
    colour_response_inverse: np.ndarray,
    white: np.ndarray,
    centre_white: np.ndarray,
    bound: float,
) -> tuple[np.ndarray, dict]:
    """:func:`limit_noise_penalty` of a calibration's field, and the record of the bound and its colour cost.

    Returns
    -------
    unmixing : ndarray of float32, shape (nby, nbx, 3, 3)
        The bounded field.
    record : dict
        ``Calibration.noise_limit``: the bound, the unbounded worst penalty, the bins over the bound and those
        blended, the largest blend weight, and the largest and mean (over the bins) of each bin's largest
        off-diagonal :func:`residual_crosstalk` with the bin where it is largest.

    Raises
    ------
    CalibrationInputError
        ``bound`` is below the flat field's own worst penalty.

    Examples
    --------
    >>> m = np.array([[0.8, 0.15, 0.05], [0.15, 0.7, 0.15], [0.05, 0.15, 0.8]])
    >>> u = np.broadcast_to(np.linalg.inv(m), (1, 2, 3, 3))
    >>> white = np.array([[[100.0] * 3, [60.0] * 3]])  # a bright bin and a dim one
    >>> _, record = noise_limited_unmixing(u, np.broadcast_to(m, u.shape), np.eye(3), white, np.full(3, 100.0), 2.5)
    >>> record["bins_over_bound"], record["limited_bins"]  # the dim bin, and the other to keep the field smooth
    (1, 2)
    """
    unbounded = np.asarray(unmixing, dtype=np.float64)
    try:
        limited, blend = limit_noise_penalty(unbounded, white, centre_white, bound)
    except ValueError as exc:
        raise CalibrationInputError(
            f"max noise penalty {exc}: the flat field alone amplifies noise that much where the vignetting is "
            "deepest, and the bound limits only the colour unmixing; give --max-noise-penalty at least that"
        ) from None
    residual = residual_crosstalk(limited, np.asarray(crosstalk, dtype=np.float64), colour_response_inverse)
    leak = np.abs(residual * (1 - np.eye(3))).max(axis=(-1, -2))
    iy, ix = np.unravel_index(int(np.argmax(leak)), leak.shape)
    penalty = penalty_field(unbounded, white, centre_white).max(axis=-1)
    record = {
        "max_noise_penalty": float(bound),
        "unbounded_max_penalty": round(float(penalty.max()), 5),
        "bins_over_bound": int(np.count_nonzero(penalty > bound)),
        "limited_bins": int(np.count_nonzero(blend)),
        "max_blend": round(float(blend.max()), 6),
        "max_residual_crosstalk": round(float(leak.max()), 6),
        "mean_residual_crosstalk": round(float(leak.mean()), 6),
        "worst_bin": [int(iy), int(ix)],
    }
    return limited.astype(np.float32), record
