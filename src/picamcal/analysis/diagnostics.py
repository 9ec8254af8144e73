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
  ``theta = atan(d tan(CRA_corner) / r_corner)``. That is the jig's reading (a bare sensor under light meant to
  be normally incident); for a white taken through the optics (white alone, or in situ) the centre is where their
  axis meets the sensor, reported as such (:data:`OPTICS_KINDS`).
* ``dust``: "any high-frequency components in these matrices probably indicate dirt in the optical
  system" (section "Colour crosstalk"); dust on the white reference darkens small patches that the flat
  field would then imprint on every corrected image.
* ``exposure``: clipped or dim references (section "Measuring the sensor's response").
* ``conditioning`` and ``noise_penalty``: how far the unmixing amplifies noise (Figure
  "unmixing_matrix_and_snr"; the paper's IMX219 loses about threefold in SNR at the edges).
* ``noise_limit`` (only for a calibration made with ``max_noise_penalty``): the bound on the centre mode's
  noise penalty, and what it costs in colour, as CIEDE2000 on saturated primaries.
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

from ..calibrate import REFUSE_CONDITION, REFUSE_WHITE_FRACTION
from ..calibration import Calibration
from ..errors import CalibrationFileError
from ..raw.model import CHANNELS, site_channels
from ..references import COLOURS
from .fields import (
    DUST_SIGMA,
    MIN_DUST_DEPTH,
    _as_plane,
    _fit_symmetric_surface,
    _symmetric_surface,
    dust_residual,
    find_dust,
    implied_tilt,
    roughness,
    vignetting_centre,
)
from .verdicts import workflow_kind

__all__ = [
    "OPTICS_KINDS",
    "UNMIXING_CHECKS",
    "Check",
    "check_conditioning",
    "check_dust",
    "check_exposure",
    "check_noise_limit",
    "check_noise_penalty",
    "check_unmixing_smoothness",
    "check_vignetting_centre",
    "diagnose",
    "dust_residual",
    "find_dust",
    "implied_tilt",
    "noise_limit_cost",
    "roughness",
    "vignetting_centre",
]

Verdict = Literal["pass", "warn"]
#: The checks about the colour-unmixing field, which a flat-field calibration (white only) does not have.
UNMIXING_CHECKS = ("conditioning", "noise_penalty", "unmixing_smoothness")
#: The calibrations (:func:`picamcal.analysis.verdicts.workflow_kind`) whose white was taken through the optics, so
#: that the vignetting centre is the optics' axis rather than the light's angle on the jig.
OPTICS_KINDS = ("flat", "in-situ")

#: Vignetting centre offset (% of the half-diagonal) above which the check warns. With a CRA of about 27
#: degrees at the corner (tan = 0.5, the simulated IMX219) it is a tilt of 0.57 degrees, and moving the
#: simulated vignetting by it changes the flat field by up to 1.6 %, four levels of an 8-bit image: visible
#: on the uniform background of bright-field microscopy. The fit itself is good to 0.1 % (1 pixel).
WARN_CENTRE_OFFSET_PERCENT = 2.0
#: White median, as a fraction of the range between black and white level, below which the check warns
#: (calibrate refuses below :data:`picamcal.calibrate.REFUSE_WHITE_FRACTION`, 5 %): at 20 % a black-level error
#: of 1 DN is 0.5 % of a 10-bit white.
WARN_WHITE_FRACTION = 0.2
#: Own-channel median of a red, green or blue reference below which the check warns. On the simulated
#: IMX219 (16-pixel bins, 10 bits) the unmixing field's roughness grows as the red reference dims: 0.0065 at
#: 24 % of the range, 0.0067 at 10 %, 0.0075 at 5 % and 0.010 (WARN_UNMIXING_ROUGHNESS) at 2.4 %; 10 % keeps
#: a factor of 4 in exposure in hand.
WARN_COLOUR_FRACTION = 0.1
#: Worst-bin Frobenius condition number of M above which the check warns. The identity has 3; a simulated
#: IMX219 tuned to the paper reaches 7.5 in its corners; calibrate gives up on a bin above
#: :data:`picamcal.calibrate.REFUSE_CONDITION` (100).
WARN_CONDITION = 20.0
#: Worst-bin noise penalty of the "centre" mode above which the check warns. The paper's IMX219 loses about
#: threefold at the edges; the simulator tuned to it reaches 4.4 in the extreme corner bin of a full frame.
WARN_NOISE_PENALTY = 5.0
#: Worst-bin CIEDE2000 on saturated primaries above which the ``noise_limit`` check warns: a bound on the noise
#: penalty leaves that much colour error in the corners (:func:`noise_limit_cost`). 2 is about twice a
#: just-noticeable difference. On the simulated IMX219 (320 x 240, unbounded worst penalty 3.6) a bound of 3.5
#: costs 0.7 at the worst bin, 3.0 costs 4.0 and 2.5 costs 7.7 (0.02, 0.15 and 0.45 on average over the bins).
WARN_NOISE_LIMIT_DELTA_E = 2.0
#: RMS of the unmixing elements' departure from a local quadratic (:func:`roughness`) above which the check
#: warns: 0.01 is a 1 % bin-to-bin colour error, about the smallest colour difference people notice. Clean
#: simulated calibrations with shot and read noise give 0.006 to 0.007 square-on and 0.008 to 0.0095 at 2 deg
#: tilt (16-pixel bins, 640 x 480 to 1280 x 960; IMX219, IMX477); noiseless ones 0.0006 to 0.006.
WARN_UNMIXING_ROUGHNESS = 0.01


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
    max_noise_penalty: float = WARN_NOISE_PENALTY,
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
        ``unmixing_smoothness``, in that order, and ``noise_limit`` last for a calibration made with a bound on
        its noise penalty (``Calibration.noise_limit``); for a flat-field calibration (white only) the first
        three (the others, :data:`UNMIXING_CHECKS`, are about the colour unmixing it does not have).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> camera = make_camera("imx219", size=(640, 480), tilt=(2.0, 0.0))  # light 2 degrees off normal
    >>> cal = picamcal.calibrate(**simulate_references(camera, seed=1, dust=2))  # and two specks of dust
    >>> checks = diagnose(cal, cra_corner_deg=26.6)
    >>> [c.name for c in checks if c.verdict == "warn"]
    ['vignetting_centre', 'dust', 'noise_penalty']
    """
    checks = [
        check_vignetting_centre(calibration, cra_corner_deg=cra_corner_deg),
        check_dust(calibration),
        check_exposure(calibration),
    ]
    if not calibration.has_unmixing:
        return checks
    checks += [
        check_conditioning(calibration),
        check_noise_penalty(calibration, max_penalty=max_noise_penalty),
        check_unmixing_smoothness(calibration),
    ]
    return checks if calibration.noise_limit is None else [*checks, check_noise_limit(calibration)]


# Vignetting centre ------------------------------------------------------------------------------------


def check_vignetting_centre(
    calibration: Calibration,
    *,
    cra_corner_deg: float | None = None,
    max_offset_percent: float = WARN_CENTRE_OFFSET_PERCENT,
) -> Check:
    """Where the green flat field peaks, against the sensor centre: for the jig a tilt, through optics their axis.

    What the offset means depends on how the calibration was made (:func:`picamcal.analysis.verdicts.workflow_kind`):

    - references on the jig (``full``, ``least-squares``): the bare sensor under light meant to be normally
      incident, so an offset above ``max_offset_percent`` of the half-diagonal warns that the light was not (a
      tilted sensor or jig), and the calibration then holds for that angle only; with ``cra_corner_deg`` the tilt
      it implies is given.
    - a white through the optics (``flat``: a white alone; ``in-situ``): the vignetting is the optics' own, and its
      centre is where their axis meets the sensor. An offset is reported as that (``values["meaning"]`` is
      ``"optical axis"``) and passes: the flat field corrects it as it is, for as long as the optics and camera
      stay as they were. No tilt is given.

    ``shift_error_percent`` is how much the flat field at the worst bin would be wrong if the vignetting sat at the
    sensor centre instead (the fitted surface moved there).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> camera = make_camera("imx219", size=(640, 480), tilt=(2.0, 0.0))  # light 2 degrees off normal in x
    >>> refs = simulate_references(camera, seed=1)
    >>> check = check_vignetting_centre(picamcal.calibrate(**refs), cra_corner_deg=26.6)
    >>> check.verdict, round(check.values["tilt_x_deg"], 1), round(check.values["tilt_y_deg"], 1)
    ('warn', 2.0, 0.0)
    >>> through_optics = check_vignetting_centre(picamcal.calibrate(refs["white"]))  # the same white alone
    >>> through_optics.verdict, through_optics.values["meaning"], round(through_optics.values["offset_x_px"])
    ('pass', 'optical axis', 28)
    """
    y, x = calibration.bin_centres
    plane, y, x = _as_plane(calibration.white[..., 1], y, x)
    cx, cy = (calibration.width - 1) / 2.0, (calibration.height - 1) / 2.0
    half_diagonal = math.hypot(cx, cy)
    centre, coef, good = _fit_symmetric_surface(plane, y, x, half_diagonal)
    model = _symmetric_surface(coef, y, x, centre, half_diagonal)
    dx, dy = float(centre[0] - cx), float(centre[1] - cy)
    offset = math.hypot(dx, dy)
    percent = 100.0 * offset / half_diagonal
    # The same surface centred on the sensor: what a square-on sensor's flat field would look like.
    shifted = _symmetric_surface(coef, y, x, (cx, cy), half_diagonal)
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
    if workflow_kind(calibration) in OPTICS_KINDS:
        values["meaning"] = "optical axis"
        return Check("vignetting_centre", "pass", _optical_axis(calibration, values), values)
    values["meaning"] = "tilt"
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


def _optical_axis(calibration: Calibration, values: dict[str, Any]) -> str:
    """The vignetting centre of a white taken through the optics, said as where their axis meets the sensor."""
    dx, dy = values["offset_x_px"], values["offset_y_px"]
    where = (
        f"vignetting centre at ({values['x_px']:.0f}, {values['y_px']:.0f}) px: the optical axis meets the sensor "
        f"{dx:+.0f} px ({100 * dx / calibration.width:+.1f} % of the width) in x and {dy:+.0f} px "
        f"({100 * dy / calibration.height:+.1f} % of the height) in y from its centre"
    )
    if values["offset_percent"] <= values["max_offset_percent"]:
        return f"{where}: centred"
    return (
        f"{where}, a property of the optics (their alignment on the camera), which the flat field corrects as it "
        "is while they stay as they were calibrated"
    )


# Dust -------------------------------------------------------------------------------------------------


def check_dust(calibration: Calibration) -> Check:
    """Dust and dirt: small dark specks in the white reference, which the flat field would imprint.

    Works on the sum of the four Bayer sites (dust darkens every colour alike); see :func:`dust_residual`
    and :func:`find_dust`. Warns when any speck is found. Reliable from about 30 x 40 bins (640 x 480 pixels
    in 16-pixel bins); below 5 bins in either direction it does not look.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(640, 480)), seed=1, dust=2))
    >>> [(round(s["x"]), round(s["y"])) for s in check_dust(cal).values["specks"]]
    [(510, 369), (178, 207)]
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
    min_white_fraction: float = WARN_WHITE_FRACTION,
    min_colour_fraction: float = WARN_COLOUR_FRACTION,
    max_clipped_fraction: float = 0.0,
) -> Check:
    """Clipped and under-exposed references.

    Clipping comes from the calibration's ``inputs`` (``clipped_fraction``, counted on the full mosaic; calibrations
    that predate it are not judged on it): a reference with more than ``max_clipped_fraction`` of its
    pixels at the white level warns, naming it. The default, none, also catches a few hot pixels; raise
    it for a sensor known to have some. Levels come from the binned black-subtracted responses,
    as a fraction of the range between black and white level: the white's median over all pixels, and
    each colour reference's median in its own channel (red pixels under the red light, ...); a
    flat-field calibration has the white's only. Calibrate refuses a white below
    :data:`~picamcal.calibrate.REFUSE_WHITE_FRACTION` of the range; this warns from ``min_white_fraction``.

    Raises
    ------
    CalibrationFileError
        The calibration does not record the references' white level (no file picamcal wrote lacks it).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> check = check_exposure(cal)
    >>> check.verdict, round(check.values["levels"]["white"], 2)
    ('pass', 0.58)
    """
    if calibration.white_level is None:
        raise CalibrationFileError(
            "the calibration does not record its references' white level, so their exposure cannot be judged: "
            "calibrate again",
            calibration.path,
        )
    black = float(np.median(calibration.black_level))
    usable = float(calibration.white_level) - black
    responses = calibration.site_responses
    sites = site_channels(calibration.pattern)
    colours = COLOURS[: len(responses) - 1]
    levels = {"white": float(np.median(responses[0])) / usable}
    for index, role in enumerate(colours):
        levels[role] = float(np.median(responses[1 + index][..., sites == index])) / usable
    inputs = {str(info.get("role")): info for info in calibration.inputs}
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
    for role in colours:
        if levels[role] < min_colour_fraction:
            problems.append(
                f"{role} reference is too dim to measure crosstalk: the median of its {role} pixels is "
                f"{100 * levels[role]:.1f} % of the range (aim for {100 * min_colour_fraction:.0f} % or more)"
            )
    values = {
        "levels": levels,
        "clipped_fraction": clipped,
        "min_white_fraction": min_white_fraction,
        "refuse_white_fraction": REFUSE_WHITE_FRACTION,
        "min_colour_fraction": min_colour_fraction,
        "max_clipped_fraction": max_clipped_fraction,
        "problems": problems,
    }
    if problems:
        return Check("exposure", "warn", "; ".join(problems), values)
    summary = "references well exposed and unclipped: " + ", ".join(f"{r} {100 * v:.0f} %" for r, v in levels.items())
    return Check("exposure", "pass", summary, values)


# Conditioning and noise -------------------------------------------------------------------------------


def check_conditioning(calibration: Calibration, *, max_condition: float = WARN_CONDITION) -> Check:
    """Ill-conditioned bins (filled from their neighbours by calibrate) and the worst condition number.

    Warns above ``max_condition`` (:data:`WARN_CONDITION`); calibrate does not trust a bin above
    :data:`~picamcal.calibrate.REFUSE_CONDITION`.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> check = check_conditioning(cal)
    >>> check.verdict, round(check.values["worst_condition"], 1), check.values["ill_conditioned_bins"]
    ('pass', 6.4, 0)
    """
    unmixing = calibration.require_unmixing("the conditioning check")
    bad = unmixing.ill_conditioned
    nbad = int(np.count_nonzero(bad))
    condition = np.where(bad, -np.inf, unmixing.condition_number)
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
        "refuse_condition": REFUSE_CONDITION,
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


def check_noise_penalty(calibration: Calibration, *, max_penalty: float = WARN_NOISE_PENALTY) -> Check:
    """How much the corrections multiply read noise, worst bin (Calibration.noise_penalty).

    Reports the vignetting correction (``flat``), unmixing to the centre's colours (``centre``, the
    verdict) and to pure primaries (``pure``, the paper's further factor of about 2.3).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> check = check_noise_penalty(cal)
    >>> check.verdict, round(check.values["flat_max"], 1) < round(check.values["centre_max"], 1)
    ('pass', True)
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


def noise_limit_cost(calibration: Calibration) -> np.ndarray:
    """CIEDE2000 that the centre mode's residual crosstalk costs saturated primaries, per bin and primary.

    A saturated primary ``l`` (one unit of one LED, as in the red, green and blue references) should come out of
    mode ``centre`` with its colour at the centre of the sensor, ``M_centre e_l``; with the residual crosstalk
    ``C(b)`` of :meth:`Calibration.residual_crosstalk` it comes out as ``M_centre (I + C(b)) e_l``. The two are
    compared as linear sRGB under D65 (white = (1, 1, 1); :func:`picamcal.analysis.metrics.delta_e2000`). Zero
    (to rounding) for a calibration without a bound on its noise penalty.

    Returns
    -------
    ndarray of float64, shape (nby, nbx, 3)
        CIEDE2000 of the red, green and blue primaries in each bin.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> bounded = picamcal.calibrate(**refs, max_noise_penalty=3.0)
    >>> round(float(noise_limit_cost(bounded).max()), 1)  # at the worst bin
    4.0
    """
    from .metrics import delta_e2000

    unmixing = calibration.require_unmixing("the colour cost of a noise limit")
    centre = unmixing.centre_response
    wanted = np.broadcast_to(centre.T, (*calibration.bins, 3, 3))  # row l: primary l's centre colour
    got = np.swapaxes(centre @ (np.eye(3) + calibration.residual_crosstalk()), -1, -2)
    return delta_e2000(got, wanted)


def check_noise_limit(calibration: Calibration, *, max_delta_e: float = WARN_NOISE_LIMIT_DELTA_E) -> Check:
    """The bound on the centre mode's noise penalty (``Calibration.noise_limit``) and its colour cost.

    Reports the bound, the worst penalty without it and with it, how many bins were blended towards the flat
    field, the largest residual crosstalk (the fraction of one primary left in another) and the CIEDE2000 it
    costs saturated primaries (:func:`noise_limit_cost`) at the worst bin and on average. Warns when the worst
    bin's CIEDE2000 exceeds ``max_delta_e`` (:data:`WARN_NOISE_LIMIT_DELTA_E`): the bound then visibly
    desaturates the corners, and a higher one, or more light (less noise to begin with), may serve better.

    Raises
    ------
    CalibrationFileError
        The calibration has no colour unmixing or was made without a bound.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> check = check_noise_limit(picamcal.calibrate(**refs, max_noise_penalty=3.5))
    >>> check.verdict, check.values["max_noise_penalty"], round(check.values["worst_delta_e"], 1)
    ('pass', 3.5, 0.7)
    """
    limit = calibration.noise_limit
    if limit is None:
        raise CalibrationFileError(
            "the calibration has no bound on its noise penalty (calibrate --max-noise-penalty)", calibration.path
        )
    cost = noise_limit_cost(calibration).max(axis=-1)
    iy, ix = np.unravel_index(int(np.argmax(cost)), cost.shape)
    y, x = calibration.bin_centres
    values = {
        **dict(limit),
        "max_penalty": float(calibration.noise_penalty("centre").max()),
        "worst_delta_e": float(cost[iy, ix]),
        "mean_delta_e": float(cost.mean()),
        "worst_x_px": float(x[ix]),
        "worst_y_px": float(y[iy]),
        "max_delta_e": max_delta_e,
    }
    line = (
        f"noise penalty bounded at {limit['max_noise_penalty']:g}x (worst {values['max_penalty']:.2f}x, "
        f"{limit.get('unbounded_max_penalty', float('nan')):.2f}x without the bound) in "
        f"{limit.get('bins_over_bound', 0)} of {cost.size} bins; colour cost on saturated primaries: CIEDE2000 "
        f"{values['worst_delta_e']:.2f} at worst ({x[ix]:.0f}, {y[iy]:.0f}) px, {values['mean_delta_e']:.2f} on "
        f"average; residual crosstalk up to {100 * limit.get('max_residual_crosstalk', 0.0):.1f} %"
    )
    if values["worst_delta_e"] > max_delta_e:
        summary = (
            f"{line}: above {max_delta_e:g}, saturated colours visibly lose saturation there; raise the bound, or "
            "lower the noise (more light, longer exposure, averaged frames) instead"
        )
        return Check("noise_limit", "warn", summary, values)
    return Check("noise_limit", "pass", line, values)


# Smoothness -------------------------------------------------------------------------------------------


def check_unmixing_smoothness(calibration: Calibration, *, max_rms: float = WARN_UNMIXING_ROUGHNESS) -> Check:
    """High-frequency structure in the unmixing field ("centre" mode), which indicates dirt or noise.

    The verdict is on the RMS of :func:`roughness` over the nine elements and all bins; the bin with the
    largest departure is reported too. The roughness of a smooth field is its noise, which the unmixing
    amplifies towards the corners: tilted light raises it as well.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> check = check_unmixing_smoothness(cal)
    >>> check.verdict, check.values["rms"] < check.values["max_rms"]
    ('pass', True)
    """
    unmixing = calibration.require_unmixing("the unmixing smoothness check").unmixing
    nby, nbx = unmixing.shape[:2]
    if min(nby, nbx) < 5:
        summary = f"too few bins ({nby} x {nbx}) to judge the smoothness of the unmixing field"
        return Check("unmixing_smoothness", "pass", summary, {"rms": None, "max_rms": max_rms})
    rough = roughness(unmixing)
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
