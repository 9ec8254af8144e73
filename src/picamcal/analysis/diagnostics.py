"""Is this calibration trustworthy? Checks with a pass/warn verdict and the numbers behind it.

Each check reads a :class:`~picamcal.calibration.Calibration` (no image files) and returns a :class:`Check`;
:func:`diagnose` runs them all. The array functions underneath (:func:`vignetting_centre`,
:func:`dust_residual`, :func:`find_dust`, :func:`roughness`, :func:`implied_tilt`) work on binned fields.

The checks follow the paper:

* ``vignetting_centre``: the vignetting comes from the lenslets' chief-ray-angle (CRA) compensation, so
  it moves when the light is not normally incident (section "Vignetting", Figure "straight_vs_tilted").
  The lenslet shift grows linearly with radius, ``s(r) = r tan(CRA_corner) / r_corner`` in units of the
  stack height, so a tilt ``theta`` moves the spot-on-photodiode point, and with it the vignetting
  centre, by ``d = r_corner tan(theta) / tan(CRA_corner)``; inverted per axis,
  ``theta = atan(d tan(CRA_corner) / r_corner)``.
* ``dust``: "any high-frequency components in these matrices probably indicate dirt in the optical
  system" (section "Colour crosstalk"); dust on the white reference darkens small patches that the flat
  field would then imprint on every corrected image.
* ``exposure``: clipped or dim references (section "Measuring the sensor's response").
* ``conditioning`` and ``noise_penalty``: how far the unmixing amplifies noise (Figure
  "unmixing_matrix_and_snr"; the paper's IMX219 loses about threefold in SNR at the edges).
* ``unmixing_smoothness``: high-frequency structure in the unmixing field itself. Grey dirt that dims all
  references alike cancels out of it (each bin's colour response is normalised to its white), so what
  shows here is noise, coloured dirt, or light that changed between the references.

A flat-field calibration (white only, ``Calibration.has_unmixing`` False) gets the checks that apply to a
flat field: ``vignetting_centre``, ``dust`` and ``exposure`` (of the white and the dark frame). The last
three are about the colour unmixing it does not have (:data:`UNMIXING_CHECKS`).

Examples
--------
>>> from picamcal import calibrate
>>> from picamcal.simulate import make_camera, simulate_references
>>> refs = simulate_references(make_camera("imx219", size=(320, 240)), noise=False)
>>> checks = diagnose(calibrate(*(refs[r] for r in ("white", "red", "green", "blue"))))
>>> [(c.name, c.verdict) for c in checks][:2]
[('vignetting_centre', 'pass'), ('dust', 'pass')]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy import polynomial
from numpy.typing import ArrayLike
from scipy import ndimage, optimize

from ..calibration import Calibration
from ..raw.model import CHANNELS, site_channels

__all__ = [
    "UNMIXING_CHECKS",
    "Check",
    "check_conditioning",
    "check_dust",
    "check_exposure",
    "check_noise_penalty",
    "check_unmixing_smoothness",
    "check_vignetting_centre",
    "diagnose",
    "dust_residual",
    "find_dust",
    "implied_tilt",
    "roughness",
    "vignetting_centre",
]

Verdict = Literal["pass", "warn"]
#: The checks about the colour-unmixing field, which a flat-field calibration (white only) does not have.
UNMIXING_CHECKS = ("conditioning", "noise_penalty", "unmixing_smoothness")

#: Vignetting centre offset (% of the half-diagonal) above which the check warns. With a CRA of about 27
#: degrees at the corner (tan = 0.5, the simulated IMX219) it is a tilt of 0.57 degrees, and moving the
#: simulated vignetting by it changes the flat field by up to 1.6 %, four levels of an 8-bit image: visible
#: on the uniform background of bright-field microscopy. The fit itself is good to 0.1 % (1 pixel).
MAX_CENTRE_OFFSET_PERCENT = 2.0
#: Dips shallower than this (fraction of the white) are not reported as dust, however clean the data:
#: 0.2 % is half a level of an 8-bit output, invisible in a corrected image.
MIN_DUST_DEPTH = 0.002
#: A dust speck must reach this many noise standard deviations (on the matched-filtered residual);
#: a Gaussian tail beyond 5 sigma holds 3e-7 of the bins, so a 200 x 150-bin field has <1 % chance of one.
DUST_SIGMA = 5.0
#: White median, as a fraction of the range between black and white level, below which the check warns
#: (calibrate refuses below 5 %): at 20 % a black-level error of 1 DN is 0.5 % of a 10-bit white.
MIN_WHITE_FRACTION = 0.2
#: Own-channel median of a red, green or blue reference below which the check warns. On the simulated
#: IMX219 (16-pixel bins, 10 bits) the unmixing field's roughness grows as the red reference dims: 0.0065 at
#: 24 % of the range, 0.0067 at 10 %, 0.0075 at 5 % and 0.010 (MAX_UNMIXING_ROUGHNESS) at 2.4 %; 10 % keeps
#: a factor of 4 in exposure in hand.
MIN_COLOUR_FRACTION = 0.1
#: Worst-bin Frobenius condition number of M above which the check warns. The identity has 3; a simulated
#: IMX219 tuned to the paper reaches 7.5 in its corners; calibrate gives up on a bin at 100.
MAX_CONDITION = 20.0
#: Worst-bin noise penalty of the "centre" mode above which the check warns. The paper's IMX219 loses about
#: threefold at the edges; the simulator tuned to it reaches 4.4 in the extreme corner bin of a full frame.
MAX_NOISE_PENALTY = 5.0
#: RMS of the unmixing elements' departure from a local quadratic (:func:`roughness`) above which the check
#: warns: 0.01 is a 1 % bin-to-bin colour error, about the smallest colour difference people notice. Clean
#: simulated calibrations with shot and read noise give 0.006 to 0.007 square-on and 0.008 to 0.0095 at 2 deg
#: tilt (16-pixel bins, 640 x 480 to 1280 x 960; IMX219, IMX477); noiseless ones 0.0006 to 0.006.
MAX_UNMIXING_ROUGHNESS = 0.01

_DEGREE = 4  # of the point-symmetric polynomial fitted to the flat field
_BACKGROUND_DEGREE = 6  # of the polynomial a dust residual is taken against
_BACKGROUND_BINS = 11  # median window (bins) that follows what the polynomial misses, but not dust
_NOISE_BINS = 21  # window (bins) of the local noise estimate
_MATCHED_SIGMA = 1.0  # bins: the Gaussian that a speck's binned dip looks like
_GROW_SIGMA = 2.5  # a speck's region: connected bins below this many sigma


@dataclass(frozen=True)
class Check:
    """The outcome of one diagnostic check.

    Attributes
    ----------
    name : str
        What was checked (``"vignetting_centre"``, ``"dust"``, ...).
    verdict : {"pass", "warn"}
    summary : str
        One line for people: the finding and, for a warning, what to do.
    values : dict
        The numbers behind the verdict, JSON-serialisable (thresholds included).

    Examples
    --------
    >>> Check("exposure", "pass", "all references well exposed", {"worst": 0.0}).to_dict()["verdict"]
    'pass'
    """

    name: str
    verdict: Verdict
    summary: str
    values: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable record ``{"name", "verdict", "summary", "values"}``."""
        return {"name": self.name, "verdict": self.verdict, "summary": self.summary, "values": _plain(self.values)}


def diagnose(
    calibration: Calibration,
    *,
    cra_corner_deg: float | None = None,
    max_noise_penalty: float = MAX_NOISE_PENALTY,
) -> list[Check]:
    """Run every check on a calibration.

    Parameters
    ----------
    calibration : Calibration
    cra_corner_deg : float, optional
        Chief ray angle of the sensor's lenslet compensation at the frame corner, in degrees (about 27
        for the simulated IMX219). With it the vignetting check reports the sensor tilt it implies.
    max_noise_penalty : float
        Worst-bin noise penalty of the "centre" mode above which :func:`check_noise_penalty` warns.

    Returns
    -------
    list of Check
        ``vignetting_centre``, ``dust``, ``exposure``, ``conditioning``, ``noise_penalty``,
        ``unmixing_smoothness``, in that order; for a flat-field calibration (white only) the first
        three (the others, :data:`UNMIXING_CHECKS`, are about the colour unmixing it does not have).

    Examples
    --------
    >>> checks = diagnose(cal, cra_corner_deg=26.6)  # doctest: +SKIP
    >>> [c.name for c in checks if c.verdict == "warn"]  # doctest: +SKIP
    ['dust']
    """
    checks = [
        check_vignetting_centre(calibration, cra_corner_deg=cra_corner_deg),
        check_dust(calibration),
        check_exposure(calibration),
    ]
    if not calibration.has_unmixing:
        return checks
    return [
        *checks,
        check_conditioning(calibration),
        check_noise_penalty(calibration, max_penalty=max_noise_penalty),
        check_unmixing_smoothness(calibration),
    ]


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


def _surface(coef: np.ndarray, y: np.ndarray, x: np.ndarray, centre: ArrayLike, scale: float) -> np.ndarray:
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
        residual = z - _surface(coef, y, x, centre, scale)
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
    plane, y, x = _check_plane(plane, y, x)
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


def check_vignetting_centre(
    calibration: Calibration,
    *,
    cra_corner_deg: float | None = None,
    max_offset_percent: float = MAX_CENTRE_OFFSET_PERCENT,
) -> Check:
    """Where the green flat field peaks, against the sensor centre; with the CRA, the sensor tilt.

    Warns when the offset exceeds ``max_offset_percent`` of the half-diagonal: the light was not normally
    incident (a tilted sensor or jig, or off-axis optics), and the calibration then holds for that angle
    only. ``shift_error_percent`` is how much the flat field at the worst bin would be wrong if the
    vignetting sat at the sensor centre instead (the fitted surface moved there).

    Examples
    --------
    >>> check_vignetting_centre(cal, cra_corner_deg=26.6).values["tilt_x_deg"]  # doctest: +SKIP
    2.0
    """
    y, x = calibration.bin_centres
    plane, y, x = _check_plane(calibration.white[..., 1], y, x)
    cx, cy = (calibration.width - 1) / 2.0, (calibration.height - 1) / 2.0
    half_diagonal = math.hypot(cx, cy)
    centre, coef, good = _fit_symmetric_surface(plane, y, x, half_diagonal)
    model = _surface(coef, y, x, centre, half_diagonal)
    dx, dy = float(centre[0] - cx), float(centre[1] - cy)
    offset = math.hypot(dx, dy)
    percent = 100.0 * offset / half_diagonal
    # The same surface centred on the sensor: what a square-on sensor's flat field would look like.
    shifted = _surface(coef, y, x, (cx, cy), half_diagonal)
    shift_error = 100.0 * float(np.max(np.abs(shifted / model - 1.0)))
    fit_rms = float(np.sqrt(np.mean((plane[good] / model[good] - 1.0) ** 2)))
    values: dict[str, Any] = {
        "channel": "G",
        "x_px": float(centre[0]),
        "y_px": float(centre[1]),
        "sensor_centre_x_px": cx,
        "sensor_centre_y_px": cy,
        "offset_x_px": dx,
        "offset_y_px": dy,
        "offset_px": offset,
        "half_diagonal_px": half_diagonal,
        "offset_percent": percent,
        "max_offset_percent": max_offset_percent,
        "shift_error_percent": shift_error,
        "fit_rms_percent": 100.0 * fit_rms,
        "cra_corner_deg": cra_corner_deg,
        "tilt_x_deg": None,
        "tilt_y_deg": None,
    }
    where = f"vignetting centre at ({centre[0]:.0f}, {centre[1]:.0f}) px, {offset:.0f} px ({percent:.1f} % of the "
    where += "half-diagonal) from the sensor centre"
    if cra_corner_deg is not None:
        tx = implied_tilt(dx, half_diagonal, cra_corner_deg)
        ty = implied_tilt(dy, half_diagonal, cra_corner_deg)
        values.update(tilt_x_deg=tx, tilt_y_deg=ty)
        where += f", implying a tilt of {tx:+.2f} deg in x and {ty:+.2f} deg in y"
    if percent > max_offset_percent:
        summary = (
            f"{where}: the light was not normally incident; the flat field would be off by up to "
            f"{shift_error:.1f} % for square-on light; check that the sensor sits square to the optics"
        )
        return Check("vignetting_centre", "warn", summary, values)
    return Check("vignetting_centre", "pass", where, values)


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
    plane, y, x = _check_plane(plane, y, x)
    degree = min(_BACKGROUND_DEGREE, plane.shape[0] - 1, plane.shape[1] - 1)
    a = polynomial.legendre.legvander2d(*np.meshgrid(_unit(y), _unit(x), indexing="ij"), (degree, degree))
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


def check_dust(calibration: Calibration) -> Check:
    """Dust and dirt: small dark specks in the white reference, which the flat field would imprint.

    Works on the sum of the four Bayer sites (dust darkens every colour alike); see :func:`dust_residual`
    and :func:`find_dust`. Warns when any speck is found. Reliable from about 30 x 40 bins (640 x 480 pixels
    in 16-pixel bins); below 5 bins in either direction it does not look.

    Examples
    --------
    >>> [round(s["x"]) for s in check_dust(cal).values["specks"]]  # doctest: +SKIP
    [541, 304, 92]
    """
    y, x = calibration.bin_centres
    if min(y.size, x.size) < 5:
        summary = f"too few bins ({y.size} x {x.size}) to tell dust from the vignetting"
        return Check("dust", "pass", summary, {"count": 0, "specks": [], "noise_percent": None})
    residual = dust_residual(calibration.site_white.sum(axis=-1), y, x)
    specks, noise = find_dust(residual, y, x, calibration.bin_size)
    values = {
        "count": len(specks),
        "specks": specks,
        "noise_percent": 100.0 * noise,
        "sigma": DUST_SIGMA,
        "min_depth_percent": 100.0 * MIN_DUST_DEPTH,
    }
    if not specks:
        return Check("dust", "pass", f"no dust found (bin noise {100 * noise:.2f} %)", values)
    listed = ", ".join(f"({s['x']:.0f}, {s['y']:.0f}) {s['depth_percent']:.1f} %" for s in specks[:5])
    more = f" and {len(specks) - 5} more" if len(specks) > 5 else ""
    summary = (
        f"{len(specks)} dark speck{'s' if len(specks) > 1 else ''} in the white reference at {listed}{more}: "
        "dust or dirt, which the flat field imprints on every corrected image; clean the sensor, "
        "optics and diffuser and take the white again"
    )
    return Check("dust", "warn", summary, values)


# Exposure ---------------------------------------------------------------------------------------------


def check_exposure(
    calibration: Calibration,
    *,
    min_white_fraction: float = MIN_WHITE_FRACTION,
    min_colour_fraction: float = MIN_COLOUR_FRACTION,
    max_clipped_fraction: float = 0.0,
) -> Check:
    """Clipped and under-exposed references.

    Clipping comes from ``meta["inputs"]`` (``clipped_fraction``, counted on the full mosaic; calibrations
    that predate it are not judged on it): a reference with more than ``max_clipped_fraction`` of its
    pixels at the white level warns, naming it. The default, none, also catches a few hot pixels; raise
    it for a sensor known to have some. Levels come from the binned black-subtracted responses,
    as a fraction of the range between black and white level: the white's median over all pixels, and
    each colour reference's median in its own channel (red pixels under the red light, ...); a
    flat-field calibration has the white's only.

    Examples
    --------
    >>> check_exposure(cal).values["levels"]["white"]  # doctest: +SKIP
    0.61
    """
    black = float(np.median(calibration.meta.get("black_level", [0.0])))
    usable = float(calibration.meta["white_level"]) - black
    responses = calibration.site_responses
    sites = site_channels(calibration.pattern)
    levels = {"white": float(np.median(responses[0])) / usable}
    for index, role in enumerate(("red", "green", "blue")[: len(responses) - 1]):
        levels[role] = float(np.median(responses[1 + index][..., sites == index])) / usable
    inputs = {str(info.get("role")): info for info in calibration.meta.get("inputs", [])}
    clipped = {role: float(info["clipped_fraction"]) for role, info in inputs.items() if "clipped_fraction" in info}
    problems = []
    for role, fraction in clipped.items():
        if fraction > max_clipped_fraction:
            problems.append(
                f"{role} reference ({inputs[role].get('name', role)}) is clipped: {100 * fraction:.3g} % of its "
                "pixels at the white level; reduce the exposure"
            )
    if levels["white"] < min_white_fraction:
        problems.append(
            f"white reference is dim: median {100 * levels['white']:.0f} % of the range "
            f"(aim for {100 * min_white_fraction:.0f} % or more); increase the exposure"
        )
    for role in ("red", "green", "blue")[: len(responses) - 1]:
        if levels[role] < min_colour_fraction:
            problems.append(
                f"{role} reference is too dim to measure crosstalk: the median of its {role} pixels is "
                f"{100 * levels[role]:.1f} % of the range (aim for {100 * min_colour_fraction:.0f} % or more)"
            )
    values = {
        "levels": levels,
        "clipped_fraction": clipped,
        "min_white_fraction": min_white_fraction,
        "min_colour_fraction": min_colour_fraction,
        "max_clipped_fraction": max_clipped_fraction,
        "problems": problems,
    }
    if problems:
        return Check("exposure", "warn", "; ".join(problems), values)
    summary = "references well exposed and unclipped: " + ", ".join(f"{r} {100 * v:.0f} %" for r, v in levels.items())
    return Check("exposure", "pass", summary, values)


# Conditioning and noise -------------------------------------------------------------------------------


def check_conditioning(calibration: Calibration, *, max_condition: float = MAX_CONDITION) -> Check:
    """Ill-conditioned bins (filled from their neighbours by calibrate) and the worst condition number.

    Examples
    --------
    >>> check_conditioning(cal).values["worst_condition"]  # doctest: +SKIP
    6.9
    """
    calibration.require_unmixing("the conditioning check")
    bad = np.asarray(calibration.ill_conditioned, dtype=bool)
    nbad = int(calibration.meta.get("ill_conditioned_bins", np.count_nonzero(bad)))
    condition = np.where(bad, -np.inf, calibration.condition_number)
    iy, ix = np.unravel_index(int(np.argmax(condition)), condition.shape)
    y, x = calibration.bin_centres
    worst = float(condition[iy, ix]) if np.isfinite(condition[iy, ix]) else float("nan")
    values = {
        "ill_conditioned_bins": nbad,
        "bins": int(bad.size),
        "worst_condition": worst,
        "worst_x_px": float(x[ix]),
        "worst_y_px": float(y[iy]),
        "max_condition": max_condition,
    }
    problems = []
    if nbad:
        problems.append(
            f"{nbad} of {bad.size} bins have a crosstalk matrix that cannot be trusted (filled from neighbours)"
        )
    if not worst <= max_condition:
        problems.append(
            f"worst condition number {worst:.1f} at ({x[ix]:.0f}, {y[iy]:.0f}) px exceeds {max_condition:g}"
        )
    if problems:
        return Check("conditioning", "warn", "; ".join(problems) + "; check the colour references", values)
    return Check("conditioning", "pass", f"crosstalk matrices well conditioned (worst {worst:.1f})", values)


def check_noise_penalty(calibration: Calibration, *, max_penalty: float = MAX_NOISE_PENALTY) -> Check:
    """How much the corrections multiply read noise, worst bin (Calibration.noise_penalty).

    Reports the vignetting correction (``flat``), unmixing to the centre's colours (``centre``, the
    verdict) and to pure primaries (``pure``, the paper's further factor of about 2.3).

    Examples
    --------
    >>> check_noise_penalty(cal).values["centre_max"]  # doctest: +SKIP
    3.3
    """
    calibration.require_unmixing("the noise penalty check")
    y, x = calibration.bin_centres
    values: dict[str, Any] = {"max_penalty": max_penalty}
    for mode in ("flat", "centre", "pure"):
        penalty = calibration.noise_penalty(mode)
        iy, ix, ic = np.unravel_index(int(np.argmax(penalty)), penalty.shape)
        values[f"{mode}_max"] = float(penalty[iy, ix, ic])
        values[f"{mode}_channel_max"] = [float(v) for v in penalty.reshape(-1, 3).max(axis=0)]
        values[f"{mode}_where"] = {"x_px": float(x[ix]), "y_px": float(y[iy]), "channel": CHANNELS[ic]}
    worst, where = values["centre_max"], values["centre_where"]
    line = (
        f"worst noise penalty {worst:.1f}x ({where['channel']} at ({where['x_px']:.0f}, {where['y_px']:.0f}) px) "
        f"for unmixing to the centre's colours; {values['flat_max']:.1f}x for the flat field alone, "
        f"{values['pure_max']:.1f}x for pure primaries"
    )
    if worst > max_penalty:
        return Check("noise_penalty", "warn", f"{line}: above {max_penalty:g}x, the edges will be very noisy", values)
    return Check("noise_penalty", "pass", line, values)


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


def check_unmixing_smoothness(calibration: Calibration, *, max_rms: float = MAX_UNMIXING_ROUGHNESS) -> Check:
    """High-frequency structure in the unmixing field ("centre" mode), which indicates dirt or noise.

    The verdict is on the RMS of :func:`roughness` over the nine elements and all bins; the bin with the
    largest departure is reported too. The roughness of a smooth field is its noise, which the unmixing
    amplifies towards the corners: tilted light raises it as well.

    Examples
    --------
    >>> check_unmixing_smoothness(cal).values["rms"]  # doctest: +SKIP
    0.0064
    """
    calibration.require_unmixing("the unmixing smoothness check")
    nby, nbx = calibration.unmixing.shape[:2]
    if min(nby, nbx) < 5:
        summary = f"too few bins ({nby} x {nbx}) to judge the smoothness of the unmixing field"
        return Check("unmixing_smoothness", "pass", summary, {"rms": None, "max_rms": max_rms})
    rough = roughness(calibration.unmixing)
    rms = float(np.sqrt(np.mean(rough**2)))
    magnitude = np.abs(rough).max(axis=(-1, -2))
    iy, ix = np.unravel_index(int(np.argmax(magnitude)), magnitude.shape)
    y, x = calibration.bin_centres
    values = {
        "rms": rms,
        "max_rms": max_rms,
        "worst": float(magnitude[iy, ix]),
        "worst_x_px": float(x[ix]),
        "worst_y_px": float(y[iy]),
    }
    line = (
        f"bin-to-bin scatter of the unmixing field {rms:.4f} RMS (largest {values['worst']:.3f} at "
        f"({x[ix]:.0f}, {y[iy]:.0f}) px)"
    )
    if rms > max_rms:
        summary = (
            f"{line}, above {max_rms:g}: high-frequency structure from dirt, noise or light that changed between "
            "the references; clean the optics, expose the colour references longer or use larger bins"
        )
        return Check("unmixing_smoothness", "warn", summary, values)
    return Check("unmixing_smoothness", "pass", line, values)


# Helpers ----------------------------------------------------------------------------------------------


def _check_plane(plane: np.ndarray, y: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def _plain(value: Any) -> Any:
    """Numbers, lists and dicts JSON can write: NumPy scalars and arrays become Python ones, NaN None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
