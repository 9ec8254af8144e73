"""Reference images -> Calibration: the paper's maths (section "Analysis").

Notation follows the paper. For each bin b and channel p, ``W_p(b)`` is the black-subtracted white
response. Dividing by it applies the lens shading table and colour balance together,
``Cb_pp LST_p(b) = 1 / W_p(b)`` (paper, eq. for ``Cb LST``). The responses to the red, green and
blue primaries, each divided by the white, are the columns of the crosstalk matrix ``M(b)``;
its inverse unmixes to pure primaries, ``inv(M(b)) = Cx U(b)``, and normalising to the centre of the
sensor gives the unmixing field ``U(b) = M_centre inv(M(b))`` (paper, eq. for ``Unmixed``), which is
the identity at the centre. Matrices act on column vectors: ``out = U @ rgb``.

From a white alone (no colour references) only ``W``, ``LST`` and ``Cb`` are measured: a ``flat``
calibration (:attr:`picamcal.calibration.Calibration.kind`). Each role may have several frames of the
same scene; their bin means are averaged, and their temporal noise is measured and recorded.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from collections.abc import Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from ._version import __version__
from .bayer import bin_sites, centre_region, sites_to_channels
from .calibration import Calibration
from .calibration.fitting import (
    crosstalk_matrices,
    invert_3x3,
    least_squares_unmixing,
    noise_limited_unmixing,
)
from .errors import CalibrationFileError, CalibrationInputError, PicamcalWarning
from .geometry import SensorMode
from .raw import RawImage, read_raw
from .raw.model import raw_geometry, require_black_level
from .records import sha256_file
from .references import COLOUR_NAME, COLOURS, check_same_settings, colour_role

#: Fraction of clipped white pixels above which the white is refused.
MAX_CLIPPED_FRACTION = 1e-4
#: The white's median must use at least this fraction of the range between black and white level, or calibrate
#: refuses it (:func:`picamcal.analysis.diagnostics.check_exposure` warns from a higher level).
REFUSE_WHITE_FRACTION = 0.05
#: Bins whose crosstalk matrix has a larger (Frobenius) condition number are not trusted: filled from their
#: neighbours, and the calibration refused when more than a quarter are (the diagnostics warn from a lower one).
REFUSE_CONDITION = 100.0
#: The largest smoothing, as a fraction of the bin grid's shorter side (see :func:`check_smoothing`).
MAX_SMOOTHING_FRACTION = 0.25
#: A dark frame whose exposure time or gain differs from the white's by more than this fraction is warned of
#: (:func:`check_dark_settings`).
DARK_SETTINGS_TOLERANCE = 0.10

RawLike = RawImage | str | os.PathLike
#: A reference role: one frame, or several frames of the same scene (a sequence or any iterable) to average.
Frames = RawLike | Iterable[RawLike]


@dataclasses.dataclass
class _Reference:
    """One reference role after loading: its first frame, its bin means averaged over its frames, its record."""

    role: str
    raw: RawImage  # the first frame: geometry, levels and the name in messages
    sites: np.ndarray  # per-site bin means averaged over the frames, before black subtraction (nby, nbx, 4)
    info: dict  # its entry in the calibration's inputs


def _frames(ref: Frames) -> Iterable[RawLike]:
    return [ref] if isinstance(ref, (RawImage, str, os.PathLike)) else ref


def _frame_record(raw: RawImage, fallback: str) -> dict:
    """Name and checksum of the file a frame was read from, or ``fallback`` as its name (an array in memory)."""
    path = raw.metadata.get("path")
    if path and Path(path).is_file():
        return {"name": Path(path).name, "sha256": sha256_file(Path(path))}
    return {"name": fallback}


def _check_like(raw: RawImage, template: RawImage, what: str) -> None:
    if raw.bayer.shape != template.bayer.shape:
        raise CalibrationInputError(
            f"size {raw.width}x{raw.height} differs from the {what}'s {template.width}x{template.height}", raw.source
        )
    if raw.pattern != template.pattern:
        raise CalibrationInputError(
            f"Bayer pattern {raw.pattern} differs from the {what}'s {template.pattern}", raw.source
        )


def check_dark_settings(dark: RawImage, white: RawImage) -> None:
    """Warn if the dark frame was taken at another exposure time or gain than the white, where both files say.

    The dark frame is subtracted from the references as their black: the pedestal, the dark current (which grows
    with the exposure) and the offsets (which change with the gain). Taken at other settings it stands for another
    black. More than :data:`DARK_SETTINGS_TOLERANCE` apart (files round their settings by far less) is said in a
    ``PicamcalWarning`` naming the dark frame's file; the gain is the analogue gain, else the ISO.

    Examples
    --------
    >>> import warnings
    >>> white = RawImage(np.zeros((4, 4), np.uint16), "RGGB", 64, 1023, 10, None, {"exposure_time_s": 0.01})
    >>> dark = RawImage(white.bayer, "RGGB", 64, 1023, 10, None, {"exposure_time_s": 0.001, "path": "dark.dng"})
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     check_dark_settings(dark, white)
    >>> print(caught[0].message)
    dark.dng: the dark frame's exposure time, 1 ms, differs from the white's, 10 ms, by more than 10 %: ...
    """
    settings = [("exposure time", "exposure_time_s", 1e3, " ms")]
    gains = "analogue_gain" if all(raw.metadata.get("analogue_gain") for raw in (dark, white)) else "iso"
    settings.append(("analogue gain" if gains == "analogue_gain" else "ISO", gains, 1.0, ""))
    for what, key, scale, unit in settings:
        given = (dark.metadata.get(key), white.metadata.get(key))
        pair = [float(v) for v in given if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0]
        if len(pair) < 2:  # a file that does not say: nothing to compare
            continue
        if abs(pair[0] - pair[1]) > DARK_SETTINGS_TOLERANCE * pair[1]:
            values = [f"{scale * v:.4g}{unit}" for v in pair]
            warnings.warn(
                f"{dark.source}: the dark frame's {what}, {values[0]}, differs from the white's, {values[1]}, by more "
                f"than {100 * DARK_SETTINGS_TOLERANCE:g} %: its black (dark current, offsets) is not the white's; take "
                "the dark frame at the white's settings",
                PicamcalWarning,
                stacklevel=4,
            )


def _check_clipping(white: RawImage, clipped: int) -> None:
    if clipped > MAX_CLIPPED_FRACTION * white.bayer.size:
        ys, xs = np.nonzero(white.bayer >= white.white_level)
        raise CalibrationInputError(
            f"white reference is saturated: {clipped} pixels ({100 * clipped / white.bayer.size:.2f} %) at the white "
            f"level {white.white_level}, around x={int(np.median(xs))}, y={int(np.median(ys))}; reduce the exposure",
            white.source,
        )


def check_smoothing(smoothing: float, grid: tuple[int, int] | None = None, source: str | os.PathLike = "") -> None:
    """Raise unless ``smoothing`` (a Gaussian's standard deviation, in bins) can be applied to a ``grid`` of bins.

    The Gaussian is there to quieten noise and dust in the bin means, not to reshape the field. About 95 % of its
    weight lies within two standard deviations, so once ``2 * smoothing`` passes half the grid's shorter side the
    centre's bins are averaged with the edges' and the vignetting the calibration measures is smoothed away (and
    the filter's cost, which grows with its width, buys nothing): the largest smoothing is a quarter of the
    shorter side, :data:`MAX_SMOOTHING_FRACTION`. Without ``grid`` only the sign and finiteness are checked.

    Parameters
    ----------
    smoothing : float
        In bins.
    grid : (nby, nbx), optional
        Rows and columns of bins.
    source : path-like
        The file the grid comes from, named in the error.

    Raises
    ------
    CalibrationInputError
        Negative, not finite, or wider than the grid allows.

    Examples
    --------
    >>> check_smoothing(3.0, (154, 205))
    >>> check_smoothing(1e6, (15, 20))
    Traceback (most recent call last):
    ...
    picamcal.errors.CalibrationInputError: smoothing 1e+06 bins is over the limit of 3.75, a quarter of the 15x20 \
bin grid's shorter side: a wider Gaussian averages the centre with the edges and smooths away the vignetting it \
measures
    """
    if not (math.isfinite(smoothing) and smoothing >= 0):
        raise CalibrationInputError(f"smoothing {smoothing:g} is out of range: give 0 or more bins (0 = none)")
    if grid is None:
        return
    limit = MAX_SMOOTHING_FRACTION * min(grid)
    if smoothing > limit:
        raise CalibrationInputError(
            f"smoothing {smoothing:g} bins is over the limit of {limit:g}, a quarter of the {grid[0]}x{grid[1]} bin "
            "grid's shorter side: a wider Gaussian averages the centre with the edges and smooths away the vignetting "
            "it measures",
            source or None,
        )


def _load_reference(
    role: str, ref: Frames, bin_size: int, white: RawImage | None, smoothing: float = 0.0
) -> _Reference:
    """Read the frames of one role, check each (size and Bayer order against ``white``, clipping), average their bins.

    Several frames are averaged bin by bin (binning is linear, so this is the binned mean frame). Their
    temporal noise is measured from the frames' departures from their mean, pixel by pixel: the RMS over the
    frame of each pixel's sample standard deviation is one frame's noise, and the mean of N frames has
    ``1 / sqrt(N)`` of it. Only the first frame, a running sum of the bins and two float32 planes of sums
    (of each frame minus the first, and its square) are held, whatever the number of frames.
    """
    first: RawImage | None = None
    total: np.ndarray | None = None
    sums: np.ndarray | None = None  # of each frame after the first minus the first, and of its square
    squares: np.ndarray | None = None
    records: list[dict] = []
    for index, item in enumerate(_frames(ref)):
        raw = item if isinstance(item, RawImage) else read_raw(item)
        if first is None:
            if bin_size > min(raw.width, raw.height):
                raise CalibrationInputError(f"bin size {bin_size} is larger than the image", raw.source)
            if white is not None:
                _check_like(raw, white, "white reference")
            else:  # the white's first frame fixes the grid: the smoothing is checked before any binning
                check_smoothing(smoothing, (-(-raw.height // bin_size), -(-raw.width // bin_size)), raw.source)
            first = raw
        else:
            _check_like(raw, first, f"first {role} frame")
            check_same_settings(raw, first, role)
        clipped = int(np.count_nonzero(raw.bayer >= raw.white_level))
        if role == "white":
            _check_clipping(raw, clipped)
        sites = bin_sites(raw.bayer, bin_size)
        total = sites if total is None else total + sites
        if raw is not first:
            difference = raw.bayer.astype(np.float32) - first.bayer
            if sums is None or squares is None:
                sums, squares = difference, difference * difference
            else:
                sums += difference
                squares += difference * difference
        record = _frame_record(raw, f"<{role} array {index + 1}>")
        record.update(format=raw.metadata.get("format", "array"), clipped_fraction=clipped / raw.bayer.size)
        records.append(record)
    if first is None or total is None:
        raise CalibrationInputError(f"no frames given for the {role} reference")
    count = len(records)
    info: dict = {"role": role, "format": records[0]["format"]}
    if sums is None or squares is None:  # one frame
        info.update(records[0])
        if "sha256" not in info:
            info["name"] = f"<{role} array>"
    else:
        # Each pixel's variance across the frames: (sum d^2 - (sum d)^2 / N) / (N - 1), d = frame - first frame.
        variance = (squares - sums * sums / count) / (count - 1)
        noise = float(np.sqrt(np.mean(variance, dtype=np.float64)))
        info.update(
            name=", ".join(r["name"] for r in records),
            clipped_fraction=max(r["clipped_fraction"] for r in records),
            frames=records,
            frame_count=count,
            temporal_noise_dn=round(noise, 4),
            averaged_noise_dn=round(noise / float(np.sqrt(count)), 4),
        )
    return _Reference(role, first, total / count, info)


def _fill_ill_conditioned(fields: list[np.ndarray], bad: np.ndarray) -> None:
    """Replace the values of bad bins by those of the nearest good bin, in place."""
    if not bad.any():
        return
    from scipy import ndimage  # here: its import takes 0.2 s, and most calibrations need none

    _, (iy, ix) = ndimage.distance_transform_edt(bad, return_indices=True)
    for f in fields:
        f[bad] = f[iy[bad], ix[bad]]


def calibrate(
    white: Frames,
    red: Frames | None = None,
    green: Frames | None = None,
    blue: Frames | None = None,
    black: Frames | None = None,
    *,
    colours: Mapping[str, Frames] | None = None,
    max_noise_penalty: float | None = None,
    bin_size: int = 16,
    smoothing: float = 0.0,
    sensor_crop: tuple[int, int, int, int] | None = None,
    sensor_mode: str | None = None,
) -> Calibration:
    """Measure the flat field and, with colour references, the colour-unmixing field.

    With red, green and blue references the calibration is ``full`` (every correction mode); with the
    white alone (and optionally a dark frame) it is a ``flat`` calibration: the flat field and colour
    balance, for modes ``uncorrected`` and ``flat``, the lens shading exports and the report.

    Extra colour references (``colours``: LED mixtures, a monitor's own colours) make each bin's unmixing a
    least-squares fit over all K references instead of the paper's exact inversion of three
    (:func:`picamcal.calibration.fitting.least_squares_unmixing`, docs/method.md): ``U(b)`` maps each
    reference's white-normalised response in bin b as nearly as it can onto that reference's colour at the
    centre (the columns of ``M_centre`` for red, green and blue; the mean over the central ninth for an extra),
    the white exactly. Each reference's error is taken relative to its own brightness (weight
    ``1 / |r_k(centre)|^2``), so a dim one counts as much as a bright one. With red, green and blue alone this
    is the paper's ``U(b) = M_centre inv(M(b))``, computed as before. ``pure`` stays ``Cx U(b)`` with
    ``Cx = inv(M_centre)`` from the red, green and blue references (the primaries are theirs), and the stored
    crosstalk is ``M(b) = inv(U(b)) M_centre``, what the fit implies. Each colour reference's fit error (RMS
    over the bins of ``|P_k U r_k| / |r_k|``) is recorded as ``fit_residual`` in its ``inputs`` entry.

    ``max_noise_penalty`` bounds the centre mode's noise penalty (:meth:`Calibration.noise_penalty`, worst
    channel): where a bin's would exceed it, its unmixing is blended towards the flat-field-only correction,
    as little as meets the bound and smoothly across bins
    (:func:`picamcal.calibration.fitting.limit_noise_penalty`). The colour cost is the crosstalk this leaves,
    :meth:`Calibration.residual_crosstalk`; the bound and a summary are recorded in the provenance's
    ``noise_limit`` (:attr:`Calibration.noise_limit`).

    Parameters
    ----------
    white : RawImage or path, or a sequence of them
        Raw image of the bare sensor (or of the optics: a bright-field microscope with the sample removed, a
        diffuser in front of the lens) under uniform white light. Several frames of one role are checked
        one by one and averaged; their temporal noise is recorded in its ``inputs``.
    red, green, blue : RawImage or path, or a sequence of them, optional
        The same under uniform red, green and blue light: all three, or none for a flat calibration. Take
        every reference with the same frozen exposure, gains and white balance.
    black : RawImage or path, or a sequence of them, optional
        A dark frame at the same settings; subtracted bin by bin, and its per-site median becomes the
        calibration's black level (``black_level_source == "dark frame"``), so references and
        images whose black level is unknown (NaN) can be used. Without it each file's black level is used.
    colours : mapping of str to RawImage or path, or a sequence of them, optional
        Extra colour references by name (letters, digits and ``-``; role ``colour_<name>`` in ``inputs``), each
        under uniform light of another colour, taken with the same settings; they need red, green and blue.
    max_noise_penalty : float, optional
        The worst noise penalty the centre mode may have, at least 1 and at least the flat field's own worst
        penalty (its vignetting, ``max W_p(centre) / W_p(b)``); none by default. Needs the colour references.
    bin_size : int
        Bin edge in sensor pixels (even); the paper uses 16.
    smoothing : float
        Standard deviation in bins of a Gaussian applied to the binned responses (0 = none; the
        paper's code used 3 on the matrix field); at most a quarter of the bin grid's shorter side
        (:func:`check_smoothing`).
    sensor_crop, sensor_mode : optional
        Where on the sensor the references were taken, for files that do not say it: the area (x, y, width,
        height, in full-sensor pixels) or the registry's mode (``"1920x1080"``, ``"1920x1080:10"``), as
        :func:`picamcal.raw.model.raw_geometry` takes them. By default what the white's file or camera says, else the
        registry's mode of its size, else the whole sensor. Recorded as :attr:`Calibration.geometry`.

    Returns
    -------
    Calibration

    Raises
    ------
    CalibrationInputError
        References of different size, pattern or sensor mode, a saturated or too-dark white, black brighter than
        white, only some of the colour references, too many bins whose colour response cannot be inverted, or a
        smoothing out of range. Extra colour references without red, green and blue, with a bad or repeated
        name, too dark (brightest site's median under :data:`REFUSE_WHITE_FRACTION` of the range) or identical
        to another colour reference (the red, green and blue references, which must separate the colours as
        without extras, already span three colours; an extra adds a constraint, never a dimension). A
        ``max_noise_penalty`` below 1, not finite, without colour references, or below the flat field's own
        worst penalty.
    RawFormatError
        A reference whose black level is unknown, without a dark frame.

    Warns
    -----
    PicamcalWarning
        Some bins are ill-conditioned; they are filled from their nearest good neighbours and
        counted in its ``ill_conditioned_bins``.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, render, simulate_references
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> refs = simulate_references(camera, seed=1)  # white, red, green, blue and black RawImages
    >>> cal = calibrate(refs["white"], refs["red"], refs["green"], refs["blue"], refs["black"])
    >>> centre = cal.unmixing[cal.centre_slices].mean(axis=(0, 1))
    >>> cal.kind, cal.unmixing.shape, bool(np.allclose(centre, np.eye(3), atol=1e-3))  # U is I at the centre
    ('full', (15, 20, 3, 3), True)
    >>> flat = calibrate([render(camera, "white", rng=k) for k in (1, 2)], black=refs["black"])  # two white frames
    >>> flat.kind, [mode.value for mode in flat.modes], flat.inputs[0]["frame_count"]
    ('flat', ['uncorrected', 'flat'], 2)

    Two extra references (mixtures of the LEDs), and a bound on the noise penalty:

    >>> extras = {"cyan": render(camera, (0, 1, 1), rng=7), "amber": render(camera, (1, 0.5, 0), rng=8)}
    >>> bounded = calibrate(**refs, colours=extras, max_noise_penalty=2.5)
    >>> [i["role"] for i in bounded.inputs]
    ['white', 'red', 'green', 'blue', 'colour_cyan', 'colour_amber', 'black']
    >>> bool(bounded.noise_penalty("centre").max() <= 2.5), bounded.noise_limit["max_noise_penalty"]
    (True, 2.5)
    """
    if bin_size < 2 or bin_size % 2:
        raise CalibrationInputError(f"bin size must be an even number of pixels >= 2, got {bin_size}")
    check_smoothing(smoothing)
    check_noise_bound(max_noise_penalty)
    primaries = dict(zip(COLOURS, (red, green, blue), strict=True))
    missing = [role for role, ref in primaries.items() if ref is None]
    if 0 < len(missing) < 3:
        raise CalibrationInputError(
            f"no {' or '.join(missing)} reference: give red, green and blue references together, or none of them "
            "for a flat-field calibration (white only)"
        )
    extras = _colour_roles(colours or {})
    if missing and (extras or max_noise_penalty is not None):
        what = "extra colour references" if extras else "a noise-penalty bound (--max-noise-penalty)"
        raise CalibrationInputError(f"{what} need the colour unmixing: give red, green and blue references too")
    named = {"white": white, **primaries, **extras, "black": black}
    refs = _load_all({role: ref for role, ref in named.items() if ref is not None}, bin_size, smoothing)
    geometry = _geometry(refs, sensor_crop, sensor_mode)
    lights = refs[:-1] if black is not None else refs
    _check_distinct(lights)
    site_responses, black_level = _binned_responses(refs, black is not None, smoothing)
    arrays = _derive(site_responses, refs[0].raw.pattern, refs[1].raw.source if len(site_responses) > 1 else "")
    fit_residual = arrays.pop("fit_residual", None)
    if fit_residual is not None:
        for ref, residual in zip(lights[1:], fit_residual, strict=True):
            ref.info["fit_residual"] = round(float(np.sqrt(np.nanmean(residual**2))), 6)
    provenance = _provenance(refs, [r.info for r in refs])
    if max_noise_penalty is not None:
        y0, y1, x0, x1 = centre_region(*site_responses.shape[1:3])
        channel_white = arrays["white"].astype(np.float64)
        arrays["unmixing"], provenance["noise_limit"] = noise_limited_unmixing(
            arrays["unmixing"],
            arrays["crosstalk"],
            arrays["colour_response_inverse"],
            channel_white,
            channel_white[y0:y1, x0:x1].reshape(-1, 3).mean(axis=0),
            max_noise_penalty,
        )
        if provenance["noise_limit"]["limited_bins"]:  # else the field is unchanged, and so is inv(M)
            arrays["pure_unmixing"] = (arrays["colour_response_inverse"] @ arrays["unmixing"]).astype(np.float32)
    return Calibration(
        kind="full" if "unmixing" in arrays else "flat",
        **_record(refs, bin_size, smoothing, black_level, geometry),
        provenance=provenance,
        **arrays,
    )


def check_noise_bound(max_noise_penalty: float | None) -> None:
    """Raise unless ``max_noise_penalty`` is None or a finite number >= 1 (1: no amplification of noise at all).

    Examples
    --------
    >>> check_noise_bound(2.5)
    >>> check_noise_bound(0.5)
    Traceback (most recent call last):
    ...
    picamcal.errors.CalibrationInputError: max noise penalty 0.5 is out of range (--max-noise-penalty): give a \
number >= 1, the factor by which the correction may multiply noise at worst (1 = not at all)
    """
    if max_noise_penalty is not None and not (math.isfinite(max_noise_penalty) and max_noise_penalty >= 1):
        raise CalibrationInputError(
            f"max noise penalty {max_noise_penalty:g} is out of range (--max-noise-penalty): give a number >= 1, "
            "the factor by which the correction may multiply noise at worst (1 = not at all)"
        )


def _colour_roles(colours: Mapping[str, Frames]) -> dict[str, Frames]:
    """The extra colour references by role, ``colour_<name>`` (names checked, lower case)."""
    roles: dict[str, Frames] = {}
    for name, ref in colours.items():
        if not isinstance(name, str) or not COLOUR_NAME.fullmatch(name):
            raise CalibrationInputError(
                f"colour reference name {str(name)[:40]!r} is not a name of letters, digits and '-' (e.g. cyan)"
            )
        role = colour_role(name)
        if role in roles:
            raise CalibrationInputError(f"two colour references are named {name.lower()}: give each colour once")
        roles[role] = ref
    return roles


def _check_distinct(lights: list[_Reference]) -> None:
    """Refuse an extra colour reference identical (bin for bin) to another colour reference: it adds no colour."""
    colours = lights[1:]
    for index, ref in enumerate(colours):
        if not ref.role.startswith("colour_"):
            continue
        for other in colours[:index]:
            if np.array_equal(ref.sites, other.sites):
                raise CalibrationInputError(
                    f"the {ref.role} reference is identical to the {other.role} reference "
                    f"({other.info.get('name')}): two references of one colour do not span three colours; give "
                    "each colour once",
                    ref.raw.source,
                )


def calibrate_in_situ(
    white: Frames,
    unmixing_from: Calibration | str | os.PathLike,
    black: Frames | None = None,
    *,
    smoothing: float = 0.0,
) -> Calibration:
    """Combine a white image taken through the user's own optics with the unmixing measured in the jig.

    The paper's recommended compromise: the white reference is specific to each optical system and easy
    to take in situ (a bright-field microscope with the sample removed), while the colour crosstalk is a
    property of the sensor under near-normal incidence, measured once in the calibration jig. The result is
    the jig's calibration with the new white's flat field (``W``, ``LST``, ``Cb``), levels and provenance
    (``dataclasses.replace``): its crosstalk matrices ``M`` and unmixing field ``U`` carry over unchanged, and
    its colour responses, normalised by its white, are kept exactly in ``site_responses``.

    Parameters
    ----------
    white : RawImage or path, or a sequence of them
        The in-situ white reference (several frames are averaged), from the same sensor, size and Bayer
        order as the jig calibration.
    unmixing_from : Calibration or path
        A full calibration from the jig (:func:`calibrate` with colour references).
    black : RawImage or path, or a sequence of them, optional
        A dark frame at the in-situ white's settings.
    smoothing : float
        Gaussian smoothing of the new white, in bins (:func:`check_smoothing`).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, render, simulate_references
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> jig = calibrate(**simulate_references(camera, seed=1))
    >>> microscope_white = render(camera, (0.8, 0.8, 0.8), rng=5)  # a white through other optics
    >>> cal = calibrate_in_situ(microscope_white, jig)
    >>> cal.unmixing is jig.unmixing, [i["role"] for i in cal.inputs]
    (True, ['white', 'unmixing'])
    """
    from .calibration import load_calibration

    check_smoothing(smoothing)
    jig = unmixing_from if isinstance(unmixing_from, Calibration) else load_calibration(unmixing_from)
    if not jig.has_unmixing:
        raise CalibrationFileError(
            "a flat-field calibration (white only) has no colour unmixing to take: give a calibration made with "
            "red, green and blue references",
            jig.path,
        )
    named = {"white": white, "black": black}
    refs = _load_all({role: ref for role, ref in named.items() if ref is not None}, jig.bin_size, smoothing)
    first = refs[0].raw
    if (first.width, first.height) != (jig.width, jig.height):
        problem = f"size {first.width}x{first.height}, the jig calibration is for {jig.width}x{jig.height}"
    elif first.pattern != jig.pattern:
        problem = f"Bayer pattern {first.pattern}, the jig calibration is for {jig.pattern}"
    elif first.sensor and jig.sensor and first.sensor != jig.sensor and not _sensor_by_size(first):
        problem = f"sensor {first.sensor}, the jig calibration is for {jig.sensor}"
    else:
        problem = ""
    if problem:
        raise CalibrationInputError(f"the white does not fit the jig calibration: {problem}", first.source)
    responses, black_level = _binned_responses(refs, black is not None, smoothing)
    new_white = responses[0]
    jig_responses = jig.site_responses.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        colours = jig_responses[1:] / jig_responses[0] * new_white
    info = {"role": "unmixing", "format": "picamcal-calibration", "created": jig.provenance.get("created")}
    if not isinstance(unmixing_from, Calibration):
        info.update(name=Path(unmixing_from).name, sha256=sha256_file(Path(unmixing_from)))
    provenance = _provenance(refs, [*(r.info for r in refs), info])
    provenance["in_situ"] = {"unmixing_from": info, "jig_inputs": [i.get("name") for i in jig.inputs]}
    if jig.noise_limit is not None:  # the jig's bounded unmixing carries over; its bound was met with the jig's white
        provenance["in_situ"]["jig_noise_limit"] = jig.noise_limit
    record = _record(refs, jig.bin_size, smoothing, black_level)
    if record["geometry"].source == "assumed" and jig.geometry and jig.geometry.source != "assumed":
        record["geometry"] = jig.geometry  # the jig's word where the white's file says nothing
    elif (
        jig.geometry
        and jig.geometry.source not in ("assumed", "unknown")
        and (record["geometry"].area() != jig.geometry.area())
    ):
        raise CalibrationInputError(
            f"the white does not fit the jig calibration: it is {record['geometry'].describe()}, the jig's "
            f"{jig.geometry.describe()}",
            first.source,
        )
    if jig.sensor and (record["sensor"] is None or _sensor_by_size(first)):  # the jig's, where the white does not say
        record["sensor"] = jig.sensor
    return dataclasses.replace(
        jig,
        **record,
        provenance=provenance,
        site_responses=np.concatenate([new_white[None], colours]).astype(np.float32),
        **_flat_field(new_white, first.pattern),
    )


def _load_all(named: dict[str, Frames], bin_size: int, smoothing: float) -> list[_Reference]:
    """Read the references (white first; the black, when given, last), each checked against the white."""
    refs: list[_Reference] = []
    for role, ref in named.items():
        refs.append(_load_reference(role, ref, bin_size, refs[0].raw if refs else None, smoothing))
    return refs


def _binned_responses(
    refs: list[_Reference], has_black: bool, smoothing: float
) -> tuple[np.ndarray, tuple[float, ...]]:
    """Black-subtracted per-site bin means of every reference but the black, white first (n, nby, nbx, 4).

    The black is the dark frame's bins when there is one (then the references' own black levels may be
    unknown, NaN), else each reference's black level, which must be known. Returns the responses and the
    calibration's black level: the dark frame's per-site median over the bins, or the white's black level.

    Also records each reference's exposure (median and 99.9th percentile of its bin means above black, as
    fractions of the range from black to the white level) in its ``info``.
    """
    white = refs[0].raw
    lights = refs[:-1] if has_black else refs
    if has_black:
        dark = refs[-1]
        check_dark_settings(dark.raw, white)
        if np.median(dark.sites) >= np.median(refs[0].sites):
            raise CalibrationInputError(
                f"black frame (median {np.median(dark.sites):.0f} DN) is not darker than the white reference "
                f"(median {np.median(refs[0].sites):.0f} DN): were the files swapped?",
                dark.raw.source,
            )
        black_sites = [dark.sites] * len(lights)
        black_level = tuple(float(v) for v in np.median(dark.sites.reshape(-1, 4), axis=0))
    else:
        for ref in lights:
            require_black_level(ref.raw, dark_frame="--black FILE")
        black_sites = [np.broadcast_to(np.asarray(ref.raw.black_level), ref.sites.shape) for ref in lights]
        black_level = white.black_level
    black = float(np.median(black_level))
    usable = white.white_level - black
    for ref, below in zip(lights, black_sites, strict=True):
        # How well exposed each reference is, from its bin means (the diagnostics judge under-exposure by these).
        fraction = (ref.sites - below) / (ref.raw.white_level - black)
        ref.info["median_fraction"] = round(float(np.median(fraction)), 5)
        ref.info["p99_fraction"] = round(float(np.percentile(fraction, 99.9)), 5)
        peak = float(np.median(fraction.reshape(-1, 4), axis=0).max())
        if ref.role.startswith("colour_") and peak < REFUSE_WHITE_FRACTION:
            raise CalibrationInputError(
                f"{ref.role} reference is too dark: its brightest site's median is {100 * peak:.1f} % of the range "
                f"(at least {100 * REFUSE_WHITE_FRACTION:.0f} % needed); increase the light or the exposure",
                ref.raw.source,
            )
    signal = float(np.median(refs[0].sites - black_sites[0]))
    if signal <= 0:
        raise CalibrationInputError("white reference is not brighter than black", white.source)
    if signal < REFUSE_WHITE_FRACTION * usable:
        raise CalibrationInputError(
            f"white reference is too dark: median signal {signal:.1f} DN is {100 * signal / usable:.1f} % of the range "
            f"(at least {100 * REFUSE_WHITE_FRACTION:.0f} % needed); increase the exposure or the light",
            white.source,
        )
    site_responses = np.stack([ref.sites - below for ref, below in zip(lights, black_sites, strict=True)])
    if smoothing > 0:
        from scipy import ndimage

        site_responses = ndimage.gaussian_filter(site_responses, sigma=(0, smoothing, smoothing, 0), mode="nearest")
    if np.any(site_responses[0] <= 0):
        raise CalibrationInputError(
            f"white reference has {np.count_nonzero((site_responses[0] <= 0).any(-1))} bins with no signal above black",
            white.source,
        )
    return site_responses, black_level


def _flat_field(site_white: np.ndarray, pattern: str) -> dict[str, Any]:
    """The flat-field arrays of either kind: ``W`` per site and channel, ``LST`` and ``Cb`` (paper, Cb LST = 1 / W)."""
    channel_white = sites_to_channels(site_white, pattern)
    peak = channel_white.reshape(-1, 3).max(axis=0)
    return {
        "site_white": site_white.astype(np.float32),
        "white": channel_white.astype(np.float32),
        "lens_shading": (peak / channel_white).astype(np.float32),
        "colour_balance": (1.0 / peak).astype(np.float64),
    }


def _derive(site_responses: np.ndarray, pattern: str, colour_source: str) -> dict[str, Any]:
    """Every array of the calibration by name, from the binned responses: of the white alone (a flat calibration),
    or of the white, red, green and blue references and any extra colours (a full one; then ``fit_residual``,
    each colour reference's error per bin, too when there are extras)."""
    arrays = {"site_responses": site_responses[:4].astype(np.float32), **_flat_field(site_responses[0], pattern)}
    if len(site_responses) == 1:
        return arrays
    # float32 is what the calibration stores, and inverting in it is several times faster.
    m = crosstalk_matrices(site_responses[:4], pattern).astype(np.float32)
    pure, _ = invert_3x3(m)
    condition = _condition(m, pure)
    bad = ~np.isfinite(condition) | (condition > REFUSE_CONDITION) | ~np.isfinite(m).all(axis=(-1, -2))
    _refuse_or_warn(bad, colour_source, "the red, green and blue references do not separate the colours")
    _fill_ill_conditioned([m, pure], bad)
    condition = np.where(bad, np.nan, condition)
    _fill_ill_conditioned([condition], bad)
    nby, nbx = site_responses.shape[1:3]
    y0, y1, x0, x1 = centre_region(nby, nbx)
    m_centre = m[y0:y1, x0:x1].reshape(-1, 3, 3).mean(axis=0)
    cx, _ = invert_3x3(m_centre)
    unmixing = m_centre @ pure
    if len(site_responses) > 4:
        with np.errstate(divide="ignore", invalid="ignore"):
            responses = sites_to_channels(site_responses[1:] / site_responses[0], pattern)  # (K, nby, nbx, 3)
        centre = responses[:, y0:y1, x0:x1].reshape(len(responses), -1, 3).mean(axis=1)
        targets = np.concatenate([m_centre.T, centre[3:]])  # the primaries' own colours: the columns of M_centre
        fitted, residual = least_squares_unmixing(responses, targets, 1 / (centre**2).sum(axis=-1))
        unmixing = fitted.astype(np.float32)
        m, _ = invert_3x3(unmixing)
        m = (m @ m_centre).astype(np.float32)  # M(b) = inv(U(b)) M_centre, the crosstalk the fit implies
        pure = (cx @ unmixing).astype(np.float32)
        condition = _condition(m, pure)
        worse = ~bad & (~np.isfinite(condition) | (condition > REFUSE_CONDITION) | ~np.isfinite(unmixing).all((-1, -2)))
        _refuse_or_warn(worse, colour_source, "the colour references do not separate the colours", bad)
        bad |= worse
        _fill_ill_conditioned([m, pure, unmixing, condition], bad)
        arrays["fit_residual"] = residual
    return {
        **arrays,
        "crosstalk": m.astype(np.float32),
        "unmixing": unmixing.astype(np.float32),
        "pure_unmixing": pure.astype(np.float32),
        "condition_number": condition.astype(np.float32),
        "ill_conditioned": bad,
        "centre_response": m_centre.astype(np.float64),
        "colour_response_inverse": cx.astype(np.float64),
    }


def _condition(m: np.ndarray, inverse: np.ndarray) -> np.ndarray:
    """Frobenius condition number per bin, ``|M| |inv(M)|``."""
    return np.sqrt((m**2).sum(axis=(-1, -2)) * (inverse**2).sum(axis=(-1, -2)))


def _refuse_or_warn(bad: np.ndarray, source: str, refusal: str, already: np.ndarray | None = None) -> None:
    """Refuse when more than a quarter of the bins (with those ``already`` bad) cannot be trusted; warn for a few."""
    nbad = int(np.count_nonzero(bad))
    total = nbad + (0 if already is None else int(np.count_nonzero(already)))
    if total > 0.25 * bad.size:
        raise CalibrationInputError(
            f"{refusal}: {total} of {bad.size} bins have an ill-conditioned crosstalk matrix (condition > "
            f"{REFUSE_CONDITION:g}); check the illumination colours and the Bayer order (--pattern)",
            source,
        )
    if nbad:
        ys, xs = np.nonzero(bad)
        warnings.warn(
            f"{nbad} of {bad.size} bins have an ill-conditioned crosstalk matrix (condition > {REFUSE_CONDITION:g}), "
            f"in bins y {ys.min()}..{ys.max()}, x {xs.min()}..{xs.max()}; filled from their nearest good neighbours",
            PicamcalWarning,
            stacklevel=4,
        )


def _sensor_by_size(raw: RawImage) -> bool:
    """Whether ``raw``'s sensor was taken from its frame size (:func:`picamcal.raw.read_raw`), not named."""
    return raw.metadata.get("sensor_source") == "size"


def _geometry(
    refs: list[_Reference], sensor_crop: tuple[int, int, int, int] | None = None, sensor_mode: str | None = None
) -> SensorMode:
    """Where the references lie on the sensor: the white's (:func:`raw_geometry`, with the user's options, which
    then stand for every reference), which every other reference whose file says must share (one that says nothing,
    its geometry assumed, is taken to be of the white's mode)."""
    first = refs[0].raw
    geometry = raw_geometry(first, sensor_crop=sensor_crop, sensor_mode=sensor_mode)
    if sensor_crop is not None or sensor_mode is not None:
        return geometry
    for ref in refs[1:]:
        other = raw_geometry(ref.raw)
        if "assumed" not in (other.source, geometry.source) and other.area() != geometry.area():
            raise CalibrationInputError(
                f"references from different sensor modes: {Path(first.source).name} is {geometry.describe()}, "
                f"{Path(ref.raw.source).name} is {other.describe()}; take every reference in one mode",
                ref.raw.source,
            )
    return geometry


def _record(
    refs: list[_Reference],
    bin_size: int,
    smoothing: float,
    black_level: tuple[float, ...],
    geometry: SensorMode | None = None,
) -> dict[str, Any]:
    """The calibration's record fields (geometry and levels) from its references, the white first."""
    first = refs[0].raw
    return {
        "geometry": geometry or _geometry(refs),
        # A sensor a file names (or --sensor) before one taken from a frame's size.
        "sensor": next((r.sensor for r in sorted((r.raw for r in refs), key=_sensor_by_size) if r.sensor), None),
        "pattern": first.pattern,
        "width": first.width,
        "height": first.height,
        "bin_size": bin_size,
        "centre_region": centre_region(-(-first.height // bin_size), -(-first.width // bin_size)),
        "black_level": tuple(round(float(v), 4) for v in black_level),
        "black_level_source": "dark frame" if refs[-1].role == "black" else "references",
        "white_level": first.white_level,
        "bit_depth": first.bit_depth,
        "smoothing": smoothing,
    }


def _provenance(refs: list[_Reference], inputs: list[dict]) -> dict[str, Any]:
    """Where the calibration came from: its inputs, when and by which picamcal, and whether a dark frame was used."""
    return {
        "software_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "black_frame": refs[-1].role == "black",
        "inputs": inputs,
    }
