"""Reference images -> Calibration: the paper's maths (section "Analysis").

Notation follows the paper. For each bin b and channel p, ``W_p(b)`` is the black-subtracted white
response. Dividing by it applies the lens shading table and colour balance together,
``Cb_pp LST_p(b) = 1 / W_p(b)`` (paper, eq. for ``Cb LST``). The responses to the red, green and
blue primaries, each divided by the white, are the columns of the crosstalk matrix ``M(b)``;
its inverse unmixes to pure primaries, ``inv(M(b)) = Cx U(b)``, and normalising to the centre of the
sensor gives the unmixing field ``U(b) = M_centre inv(M(b))`` (paper, eq. for ``Unmixed``), which is
the identity at the centre. Matrices act on column vectors: ``out = U @ rgb``.
"""

from __future__ import annotations

import os
import warnings
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from scipy import ndimage

from ._files import sha256_file
from ._version import __version__
from .bayer import bin_sites, sites_to_channels
from .calibration import Calibration
from .errors import CalibrationInputError, PicamcalWarning
from .raw import RawImage, read_raw

REFERENCE_ROLES = ("white", "red", "green", "blue", "black")
#: Fraction of clipped white pixels above which the white is refused.
MAX_CLIPPED_FRACTION = 1e-4
#: The white's median must use at least this fraction of the range between black and white level.
MIN_WHITE_FRACTION = 0.05
#: Bins whose crosstalk matrix has a larger (Frobenius) condition number are not trusted.
MAX_CONDITION = 100.0

RawLike = RawImage | str | os.PathLike


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


def centre_region(nby: int, nbx: int) -> tuple[int, int, int, int]:
    """Bin index range (y0, y1, x0, x1) of the central ninth of the frame (middle third in each axis).

    The paper's 2019 code took rows 4/9 to the bottom edge; this is the central ninth it meant.

    Examples
    --------
    >>> centre_region(154, 205)
    (51, 103, 68, 137)
    """
    return nby // 3, max(2 * nby // 3, nby // 3 + 1), nbx // 3, max(2 * nbx // 3, nbx // 3 + 1)


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
    """
    white = site_responses[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        normalised = site_responses[1:] / white  # (3 primaries, nby, nbx, 4 sites)
    columns = sites_to_channels(normalised, pattern)  # (3 primaries, nby, nbx, 3 channels)
    m = np.moveaxis(columns, 0, -1)  # (nby, nbx, channel, primary)
    inverse, _ = invert_3x3(m)
    amounts = inverse.sum(axis=-1)  # inv(M) @ 1: how much of each primary the white holds
    return m * amounts[..., None, :]


def _load(role: str, ref: RawLike) -> tuple[RawImage, dict]:
    raw = ref if isinstance(ref, RawImage) else read_raw(ref)
    info: dict = {"role": role, "format": raw.metadata.get("format", "array")}
    info["clipped_fraction"] = float(np.count_nonzero(raw.bayer >= raw.white_level)) / raw.bayer.size
    path = raw.metadata.get("path")
    if path and Path(path).is_file():
        info.update(name=Path(path).name, sha256=sha256_file(Path(path)))
    else:
        info["name"] = f"<{role} array>"
    return raw, info


def _check_white(white: RawImage, black_sites: np.ndarray) -> None:
    clipped = np.count_nonzero(white.bayer >= white.white_level)
    if clipped > MAX_CLIPPED_FRACTION * white.bayer.size:
        ys, xs = np.nonzero(white.bayer >= white.white_level)
        raise CalibrationInputError(
            f"white reference is saturated: {clipped} pixels ({100 * clipped / white.bayer.size:.2f} %) at the white "
            f"level {white.white_level}, around x={int(np.median(xs))}, y={int(np.median(ys))}; reduce the exposure",
            white.source,
        )
    signal = np.median(white.bayer[::4, ::4]) - float(np.median(black_sites))
    usable = white.white_level - float(np.median(black_sites))
    if signal <= 0:
        raise CalibrationInputError("white reference is not brighter than black", white.source)
    if signal < MIN_WHITE_FRACTION * usable:
        raise CalibrationInputError(
            f"white reference is too dark: median signal {signal:.1f} DN is {100 * signal / usable:.1f} % of the range "
            f"(at least {100 * MIN_WHITE_FRACTION:.0f} % needed); increase the exposure or the light",
            white.source,
        )


def _fill_ill_conditioned(fields: list[np.ndarray], bad: np.ndarray) -> None:
    """Replace the values of bad bins by those of the nearest good bin, in place."""
    _, (iy, ix) = ndimage.distance_transform_edt(bad, return_indices=True)
    for f in fields:
        f[bad] = f[iy[bad], ix[bad]]


def calibrate(
    white: RawLike,
    red: RawLike,
    green: RawLike,
    blue: RawLike,
    black: RawLike | None = None,
    *,
    bin_size: int = 16,
    smoothing: float = 0.0,
) -> Calibration:
    """Measure the flat field and colour-unmixing field from reference images.

    Parameters
    ----------
    white, red, green, blue : RawImage or path
        Raw images of the bare sensor under uniform white, red, green and blue illumination, taken
        with the same frozen exposure, gains and white balance.
    black : RawImage or path, optional
        A dark frame at the same settings; subtracted bin by bin. Without it each file's black level is used.
    bin_size : int
        Bin edge in sensor pixels (even); the paper uses 16.
    smoothing : float
        Standard deviation in bins of a Gaussian applied to the binned responses (0 = none; the
        paper's code used 3 on the matrix field).

    Returns
    -------
    Calibration

    Raises
    ------
    CalibrationInputError
        References of different size or pattern, a saturated or too-dark white, black brighter than
        white, or too many bins whose colour response cannot be inverted.

    Warns
    -----
    PicamcalWarning
        Some bins are ill-conditioned; they are filled from their nearest good neighbours and
        counted in ``meta["ill_conditioned_bins"]``.

    Examples
    --------
    >>> import picamcal
    >>> cal = picamcal.calibrate("white.dng", "red.dng", "green.dng", "blue.dng", "black.dng")  # doctest: +SKIP
    >>> cal.unmixing[77, 102].round(3)  # the identity at the centre  # doctest: +SKIP
    """
    if bin_size < 2 or bin_size % 2:
        raise CalibrationInputError(f"bin size must be an even number of pixels >= 2, got {bin_size}")
    named = {"white": white, "red": red, "green": green, "blue": blue, "black": black}
    raws, infos = _load_consistent({role: ref for role, ref in named.items() if ref is not None})
    site_responses = _binned_responses(raws, infos, black is not None, bin_size, smoothing)
    arrays = _derive(site_responses, raws[0].pattern, raws[1].source)
    return Calibration(arrays, _meta(raws, infos, bin_size, smoothing, black is not None, arrays))


def calibrate_in_situ(
    white: RawLike,
    unmixing_from: Calibration | str | os.PathLike,
    black: RawLike | None = None,
    *,
    smoothing: float = 0.0,
) -> Calibration:
    """Combine a white image taken through the user's own optics with the unmixing measured in the jig.

    The paper's recommended compromise: the white reference is specific to each optical system and easy
    to take in situ (a bright-field microscope with the sample removed), while the colour crosstalk is a
    property of the sensor under near-normal incidence, measured once in the calibration jig. The jig's
    colour responses, normalised by its white, are kept exactly, so its crosstalk matrices ``M`` and
    unmixing field ``U`` carry over; the flat field (``W``, ``LST``, ``Cb``) is the new white's.

    Parameters
    ----------
    white : RawImage or path
        The in-situ white reference, from the same sensor, size and Bayer order as the jig calibration.
    unmixing_from : Calibration or path
        A full calibration from the jig (:func:`calibrate`).
    black : RawImage or path, optional
        A dark frame at the in-situ white's settings.
    smoothing : float
        Gaussian smoothing of the new white, in bins.

    Examples
    --------
    >>> jig = picamcal.load_calibration("jig.npz")  # doctest: +SKIP
    >>> cal = calibrate_in_situ("microscope_white.dng", jig)  # doctest: +SKIP
    """
    from .calibration import load_calibration

    jig = unmixing_from if isinstance(unmixing_from, Calibration) else load_calibration(unmixing_from)
    named = {"white": white, "black": black}
    raws, infos = _load_consistent({role: ref for role, ref in named.items() if ref is not None})
    first = raws[0]
    if (first.width, first.height) != (jig.width, jig.height):
        problem = f"size {first.width}x{first.height}, the jig calibration is for {jig.width}x{jig.height}"
    elif first.pattern != jig.pattern:
        problem = f"Bayer pattern {first.pattern}, the jig calibration is for {jig.pattern}"
    elif first.sensor and jig.sensor and first.sensor != jig.sensor:
        problem = f"sensor {first.sensor}, the jig calibration is for {jig.sensor}"
    else:
        problem = ""
    if problem:
        raise CalibrationInputError(f"the white does not fit the jig calibration: {problem}", first.source)
    new_white = _binned_responses(raws, infos, black is not None, jig.bin_size, smoothing)[0]
    jig_responses = jig.site_responses.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        colours = jig_responses[1:] / jig_responses[0] * new_white
    site_responses = np.concatenate([new_white[None], colours])
    arrays = _derive(site_responses, first.pattern, first.source)
    info = {"role": "unmixing", "format": "picamcal-calibration", "created": jig.meta.get("created")}
    if not isinstance(unmixing_from, Calibration):
        info.update(name=Path(unmixing_from).name, sha256=sha256_file(Path(unmixing_from)))
    meta = _meta(raws, [*infos, info], jig.bin_size, smoothing, black is not None, arrays)
    meta["in_situ"] = {"unmixing_from": info, "jig_inputs": [i.get("name") for i in jig.meta.get("inputs", [])]}
    return Calibration(arrays, meta)


def _load_consistent(named: dict[str, RawLike]) -> tuple[list[RawImage], list[dict]]:
    """Read the references (white first) and check they share size and Bayer order."""
    loaded = [_load(role, ref) for role, ref in named.items()]
    raws = [raw for raw, _ in loaded]
    first = raws[0]
    for raw in raws[1:]:
        if raw.bayer.shape != first.bayer.shape:
            raise CalibrationInputError(
                f"size {raw.width}x{raw.height} differs from the white reference's {first.width}x{first.height}",
                raw.source,
            )
        if raw.pattern != first.pattern:
            raise CalibrationInputError(
                f"Bayer pattern {raw.pattern} differs from the white reference's {first.pattern}", raw.source
            )
    return raws, [info for _, info in loaded]


def _binned_responses(
    raws: list[RawImage], infos: list[dict], has_black: bool, bin_size: int, smoothing: float
) -> np.ndarray:
    """Black-subtracted per-site bin means of every reference but the black, white first (n, nby, nbx, 4).

    Also records each reference's exposure (median and 99.9th percentile of its bin means, as fractions
    of the range from black to the white level) in its ``infos`` entry.
    """
    first = raws[0]
    if bin_size > min(first.width, first.height):
        raise CalibrationInputError(f"bin size {bin_size} is larger than the image", first.source)
    binned = [bin_sites(raw.bayer, bin_size) for raw in raws]
    for raw, sites, info in zip(raws, binned, infos, strict=True):
        # How well exposed each reference is, from its bin means (the diagnostics judge under-exposure by these).
        black = float(np.median(raw.black_level))
        fraction = (sites - black) / (raw.white_level - black)
        info["median_fraction"] = round(float(np.median(fraction)), 5)
        info["p99_fraction"] = round(float(np.percentile(fraction, 99.9)), 5)
    if has_black:
        black_sites = binned.pop()
        black_raw = raws[-1]
        if np.median(black_sites) >= np.median(binned[0]):
            raise CalibrationInputError(
                f"black frame (median {np.median(black_raw.bayer):.0f} DN) is not darker than the white reference "
                f"(median {np.median(first.bayer):.0f} DN): were the files swapped?",
                black_raw.source,
            )
    else:
        black_sites = np.stack([np.broadcast_to(np.asarray(r.black_level), binned[0].shape) for r in raws])
    _check_white(first, black_sites[0] if not has_black else black_sites)
    site_responses = np.stack(binned) - black_sites
    if smoothing > 0:
        site_responses = ndimage.gaussian_filter(site_responses, sigma=(0, smoothing, smoothing, 0), mode="nearest")
    if np.any(site_responses[0] <= 0):
        raise CalibrationInputError(
            f"white reference has {np.count_nonzero((site_responses[0] <= 0).any(-1))} bins with no signal above black",
            first.source,
        )
    return site_responses


def _derive(site_responses: np.ndarray, pattern: str, colour_source: str) -> dict[str, np.ndarray]:
    """Every field of the calibration from the binned responses of the white, red, green and blue references."""
    site_white = site_responses[0]
    # float32 is what the calibration stores, and inverting in it is several times faster.
    m = crosstalk_matrices(site_responses, pattern).astype(np.float32)
    pure, _ = invert_3x3(m)
    condition = np.sqrt((m**2).sum(axis=(-1, -2)) * (pure**2).sum(axis=(-1, -2)))
    bad = ~np.isfinite(condition) | (condition > MAX_CONDITION) | ~np.isfinite(m).all(axis=(-1, -2))
    nbad = int(np.count_nonzero(bad))
    if nbad > 0.25 * bad.size:
        raise CalibrationInputError(
            f"the red, green and blue references do not separate the colours: {nbad} of {bad.size} bins have an "
            f"ill-conditioned crosstalk matrix (condition > {MAX_CONDITION:g}); check the illumination colours and the "
            "Bayer order (--pattern)",
            colour_source,
        )
    if nbad:
        ys, xs = np.nonzero(bad)
        warnings.warn(
            f"{nbad} of {bad.size} bins have an ill-conditioned crosstalk matrix (condition > {MAX_CONDITION:g}), "
            f"in bins y {ys.min()}..{ys.max()}, x {xs.min()}..{xs.max()}; filled from their nearest good neighbours",
            PicamcalWarning,
            stacklevel=3,
        )
        _fill_ill_conditioned([m, pure], bad)
        condition = np.where(bad, np.nan, condition)
        _fill_ill_conditioned([condition], bad)
    nby, nbx = site_white.shape[:2]
    y0, y1, x0, x1 = centre_region(nby, nbx)
    m_centre = m[y0:y1, x0:x1].reshape(-1, 3, 3).mean(axis=0)
    cx, _ = invert_3x3(m_centre)
    channel_white = sites_to_channels(site_white, pattern)
    peak = channel_white.reshape(-1, 3).max(axis=0)
    return {
        "site_responses": site_responses.astype(np.float32),
        "site_white": site_white.astype(np.float32),
        "white": channel_white.astype(np.float32),
        "lens_shading": (peak / channel_white).astype(np.float32),
        "crosstalk": m.astype(np.float32),
        "unmixing": (m_centre @ pure).astype(np.float32),
        "pure_unmixing": pure.astype(np.float32),
        "condition_number": condition.astype(np.float32),
        "ill_conditioned": bad,
        "colour_balance": (1.0 / peak).astype(np.float64),
        "centre_response": m_centre.astype(np.float64),
        "colour_response_inverse": cx.astype(np.float64),
    }


def _meta(raws: list[RawImage], infos: list[dict], bin_size: int, smoothing: float, black: bool, arrays: dict) -> dict:
    first = raws[0]
    nby, nbx = arrays["white"].shape[:2]
    return {
        "software_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "sensor": next((r.sensor for r in raws if r.sensor), None),
        "pattern": first.pattern,
        "width": first.width,
        "height": first.height,
        "bin_size": bin_size,
        "black_level": list(first.black_level),
        "black_frame": black,
        "white_level": first.white_level,
        "bit_depth": first.bit_depth,
        "smoothing": smoothing,
        "centre_region": list(centre_region(nby, nbx)),
        "ill_conditioned_bins": int(np.count_nonzero(arrays["ill_conditioned"])),
        "inputs": infos,
    }
