"""Figures of merit for a correction: colour differences between colour wheels, flatness, previews.

The paper judges its corrections by photographing a target of colour wheels and comparing the wheels in
the corners of the frame with the one in the centre (Figure "matrix_correction_wheels_and_polar"): after a
good correction the six segments of every wheel have the same colour, which shows as small CIEDE2000
differences, no hue shift and a saturation ratio of one.  A white image should also become flat after
correction; :func:`flatness` measures how nearly it does.

All images here are float arrays of *linear* camera RGB, normalised so that the calibration's white is
(1, 1, 1).  For colour differences they are treated as linear sRGB with a D65 white: this is not a
colorimetric characterisation of the camera, but it puts the centre and corner wheels on the same
perceptual scale, which is all a comparison between them needs.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._atomic import atomic_path
from ..bayer import block_mean
from ..colour_wheel import CENTRE_WHEEL
from ..errors import PicamcalError
from ..output.colour import SRGB_TO_XYZ_D65

__all__ = [
    "delta_e2000",
    "delta_e2000_lab",
    "encode_srgb",
    "flatness",
    "hue_saturation",
    "linear_to_lab",
    "save_preview",
    "segment_colours",
    "wheel_figures",
]


#: The L*a*b* white: the XYZ of RGB (1, 1, 1) through IEC 61966-2-1's matrix, whose chromaticity differs from the
#: tabulated D65 by 2e-5; using it makes the calibration's white exactly neutral.
_WHITE_XYZ = SRGB_TO_XYZ_D65 @ np.ones(3)


def _lab_f(t: np.ndarray) -> np.ndarray:
    """CIE 1976's function of a tristimulus ratio (CIE 015:2018, 8.2.1): the cube root above (6/29)**3, else the
    line ``t * 841 / 108 + 4 / 29`` that meets it."""
    return np.where(t > (6 / 29) ** 3, np.cbrt(t), t * (841 / 108) + 4 / 29)


def linear_to_lab(rgb: ArrayLike) -> np.ndarray:
    """Convert linear RGB (white at (1, 1, 1)) to CIE L*a*b*, treating it as linear sRGB under D65.

    The RGB is taken through the IEC 61966-2-1 sRGB matrix to CIE XYZ and then to CIE 1976 L*a*b* (CIE 015:2018,
    8.2.1) relative to the XYZ of RGB (1, 1, 1), so white has L* = 100 and a* = b* = 0.  Values outside [0, 1] are
    not clipped. The same numbers as colour-science's ``XYZ_to_Lab(RGB_to_XYZ(rgb, "sRGB"), white)``, in numpy (a
    command that measures colours does not pay colour-science's import, seconds).

    Parameters
    ----------
    rgb : array_like, shape (..., 3)
        Linear RGB.

    Returns
    -------
    ndarray of float64, shape (..., 3)
        L* (0 to 100 for black to white), a*, b*.

    Examples
    --------
    >>> np.round(linear_to_lab([1.0, 1.0, 1.0]), 6).tolist()
    [100.0, 0.0, 0.0]
    >>> round(float(linear_to_lab([0.18, 0.18, 0.18])[0]), 2)
    49.5
    """
    rgb = _as_colours(rgb, "rgb")
    f = _lab_f((rgb @ SRGB_TO_XYZ_D65.T) / _WHITE_XYZ)
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    return np.stack([116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz)], axis=-1)


def delta_e2000_lab(lab_a: ArrayLike, lab_b: ArrayLike) -> np.ndarray:
    """CIEDE2000 colour difference between CIE L*a*b* colours (Sharma, Wu and Dalal 2005, equations 2 to 22).

    Parameters
    ----------
    lab_a, lab_b : array_like, shape (..., 3)
        L*a*b* colours; the shapes must broadcast.

    Returns
    -------
    ndarray of float64, shape (...)
        Delta E 2000 (k_L = k_C = k_H = 1).

    Examples
    --------
    Pair 1 of Sharma et al.'s test data has a published difference of 2.0425:

    >>> round(float(delta_e2000_lab([50.0, 2.6772, -79.7751], [50.0, 0.0, -82.7485])), 4)
    2.0425
    """
    lab_a, lab_b = np.broadcast_arrays(_as_colours(lab_a, "lab_a"), _as_colours(lab_b, "lab_b"))
    (l1, a1, b1), (l2, a2, b2) = np.moveaxis(lab_a, -1, 0), np.moveaxis(lab_b, -1, 0)
    c_mean7 = ((np.hypot(a1, b1) + np.hypot(a2, b2)) / 2) ** 7
    g = 0.5 * (1 - np.sqrt(c_mean7 / (c_mean7 + 25.0**7)))  # (4)
    a1, a2 = (1 + g) * a1, (1 + g) * a2  # (5)
    c1, c2 = np.hypot(a1, b1), np.hypot(a2, b2)  # (6)
    h1, h2 = np.degrees(np.arctan2(b1, a1)) % 360, np.degrees(np.arctan2(b2, a2)) % 360  # (7): 0 where a = b = 0
    chromatic = c1 * c2 != 0
    dh = h2 - h1  # (10)
    dh = np.where(dh > 180, dh - 360, np.where(dh < -180, dh + 360, dh)) * chromatic
    dl, dc = l2 - l1, c2 - c1  # (8), (9)
    dhh = 2 * np.sqrt(c1 * c2) * np.sin(np.radians(dh) / 2)  # (11)
    l_mean, c_mean = (l1 + l2) / 2, (c1 + c2) / 2  # (12), (13)
    h_sum = h1 + h2  # (14)
    h_mean = np.where(np.abs(h1 - h2) <= 180, h_sum / 2, np.where(h_sum < 360, h_sum + 360, h_sum - 360) / 2)
    h_mean = np.where(chromatic, h_mean, h_sum)
    t = (  # (15)
        1
        - 0.17 * np.cos(np.radians(h_mean - 30))
        + 0.24 * np.cos(np.radians(2 * h_mean))
        + 0.32 * np.cos(np.radians(3 * h_mean + 6))
        - 0.20 * np.cos(np.radians(4 * h_mean - 63))
    )
    d_theta = 30 * np.exp(-(((h_mean - 275) / 25) ** 2))  # (16)
    r_c = 2 * np.sqrt(c_mean**7 / (c_mean**7 + 25.0**7))  # (17)
    s_l = 1 + 0.015 * (l_mean - 50) ** 2 / np.sqrt(20 + (l_mean - 50) ** 2)  # (18)
    s_c, s_h = 1 + 0.045 * c_mean, 1 + 0.015 * c_mean * t  # (19), (20)
    r_t = -np.sin(np.radians(2 * d_theta)) * r_c  # (21)
    terms = (dl / s_l) ** 2 + (dc / s_c) ** 2 + (dhh / s_h) ** 2 + r_t * (dc / s_c) * (dhh / s_h)
    return np.sqrt(terms)  # (22)


def delta_e2000(rgb_a: ArrayLike, rgb_b: ArrayLike) -> np.ndarray:
    """CIEDE2000 colour difference between linear RGB colours, treated as linear sRGB under D65.

    Parameters
    ----------
    rgb_a, rgb_b : array_like, shape (..., 3)
        Linear RGB with white at (1, 1, 1); the shapes must broadcast.

    Returns
    -------
    ndarray of float64, shape (...)
        Delta E 2000 of :func:`linear_to_lab` of each pair (about 1 is a just-noticeable difference).

    Examples
    --------
    >>> float(delta_e2000([0.2, 0.4, 0.6], [0.2, 0.4, 0.6]))
    0.0
    >>> round(float(delta_e2000([1.0, 1.0, 1.0], [0.18, 0.18, 0.18])), 1)
    37.0
    """
    return delta_e2000_lab(linear_to_lab(rgb_a), linear_to_lab(rgb_b))


def hue_saturation(rgb: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Hue angle and saturation of linear RGB colours, for polar plots of wheel segments.

    Both come from CIE L*a*b* (see :func:`linear_to_lab`): the hue is the CIE hue angle
    h_ab = atan2(b*, a*) and the saturation is the CIE 1976 saturation s_ab = C*_ab / L*
    (CIE 015:2018, 8.2.2), the chroma relative to the lightness, so that a colour and a dimmer copy of it
    have nearly the same saturation.

    Parameters
    ----------
    rgb : array_like, shape (..., 3)
        Linear RGB with white at (1, 1, 1).

    Returns
    -------
    hue_deg : ndarray of float64, shape (...)
        h_ab in degrees, in [0, 360); meaningless for neutral colours (a* = b* = 0).
    saturation : ndarray of float64, shape (...)
        C*_ab / L*; NaN where L* <= 0.

    Examples
    --------
    >>> hue, sat = hue_saturation([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    >>> np.round(hue).tolist()
    [40.0, 136.0, 306.0]
    >>> np.round(sat, 2).tolist()
    [1.96, 1.37, 4.14]
    """
    lab = linear_to_lab(rgb)
    lightness = lab[..., 0]
    chroma = np.hypot(lab[..., 1], lab[..., 2])
    hue = np.degrees(np.arctan2(lab[..., 2], lab[..., 1])) % 360.0
    saturation = np.full_like(chroma, np.nan)
    np.divide(chroma, lightness, out=saturation, where=lightness > 0)
    return hue, saturation


def segment_colours(
    image: ArrayLike,
    layout: Mapping[str, Any],
    *,
    pixel_scale: float = 1.0,
    centres: tuple[ArrayLike, ArrayLike] | None = None,
    inner: float = 0.3,
    outer: float = 0.85,
    margin_deg: float = 8.0,
) -> dict[str, np.ndarray]:
    """Median linear RGB of each segment of each colour wheel in an image of a wheel target.

    Each segment is sampled over an annular sector: radii from ``inner`` to ``outer`` times the wheel's
    radius (away from the blurred centre and the rim) and angles ``margin_deg`` inside the segment's edges.
    A pixel belongs to the sector if its centre does.  The colour is the per-channel median over the
    sector, which ignores the few pixels (or bins) that straddle an edge, dust and hot pixels.

    Angles follow the layout's convention: ``atan2(-(y - cy), x - cx)`` in degrees, counter-clockwise from
    +x as seen on screen (y grows downwards), a segment covering [start_deg, end_deg).

    Parameters
    ----------
    image : array_like, shape (h, w, 3)
        Linear RGB image of the target, at full resolution or binned.
    layout : mapping
        The wheel layout: ``width`` and ``height`` in layout pixels, ``segments`` (each with ``name``,
        ``start_deg``, ``end_deg``) and ``wheels`` (each with ``name``, ``x``, ``y``, ``radius`` in layout
        pixels).
    pixel_scale : float, default 1.0
        Layout pixels per image pixel: 1 for a full-resolution image, the bin size for an image binned in
        square bins from the top-left corner.  Image pixel (i, j) is centred at layout pixel
        ((j + 0.5) * pixel_scale - 0.5, (i + 0.5) * pixel_scale - 0.5).  Ignored if ``centres`` is given.
    centres : (y_centres, x_centres), optional
        Explicit layout coordinates of the image's row and column centres, of lengths h and w, e.g.
        ``picamcal.bayer.bin_centres(height, bin_size)`` and ``bin_centres(width, bin_size)`` for binned
        images whose last bin is partial (the order of ``Calibration.bin_centres``).
    inner, outer : float, default 0.3 and 0.85
        Radii of the sampled annulus, as fractions of each wheel's radius.
    margin_deg : float, default 8
        Angle kept clear of each segment's edges, in degrees.

    Returns
    -------
    dict of str to ndarray of float64, shape (n_segments, 3)
        For each wheel name, the colour of each segment in the layout's order.

    Raises
    ------
    PicamcalError
        If the image does not fit the layout at this scale, a wheel's sampled annulus lies partly outside
        the image, or a sector contains no pixel centre.

    Examples
    --------
    >>> layout = {"width": 64, "height": 64, "wheels": [{"name": "centre", "x": 31.5, "y": 31.5, "radius": 30}],
    ...           "segments": [{"name": "top", "start_deg": 0, "end_deg": 180},
    ...                        {"name": "bottom", "start_deg": 180, "end_deg": 360}]}
    >>> image = np.zeros((64, 64, 3))
    >>> image[:32] = [1.0, 0.5, 0.0]
    >>> segment_colours(image, layout)["centre"].tolist()
    [[1.0, 0.5, 0.0], [0.0, 0.0, 0.0]]
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 3 or img.shape[2] != 3:
        raise PicamcalError(f"expected an (h, w, 3) RGB image, got an array of shape {img.shape}")
    if not 0.0 <= inner < outer:
        raise PicamcalError(f"need 0 <= inner < outer, got inner={inner}, outer={outer}")
    ys, xs = _image_centres(img.shape[:2], layout, pixel_scale, centres)
    segments = _segments(layout, margin_deg)
    if not layout.get("wheels"):
        raise PicamcalError("the layout has no wheels")

    result: dict[str, np.ndarray] = {}
    for wheel in layout["wheels"]:
        name = str(wheel["name"])
        cx, cy, radius = float(wheel["x"]), float(wheel["y"]), float(wheel["radius"])
        reach = outer * radius
        x_lo, x_hi = _extent(xs)
        y_lo, y_hi = _extent(ys)
        if cx - reach < x_lo or cx + reach > x_hi or cy - reach < y_lo or cy + reach > y_hi:
            raise PicamcalError(
                f"wheel {name!r} (centre ({cx:g}, {cy:g}), sampled out to radius {reach:g}) falls outside the image, "
                f"which covers x {x_lo:g} to {x_hi:g} and y {y_lo:g} to {y_hi:g} in layout pixels"
            )
        cols = np.flatnonzero(np.abs(xs - cx) <= reach)
        rows = np.flatnonzero(np.abs(ys - cy) <= reach)
        dx = xs[cols][np.newaxis, :] - cx
        dy = ys[rows][:, np.newaxis] - cy
        rho = np.hypot(dx, dy) / radius
        angle = np.degrees(np.arctan2(-dy, dx))
        in_annulus = (rho >= inner) & (rho <= outer)
        pixels = img[np.ix_(rows, cols)]
        colours = np.empty((len(segments), 3))
        for k, (segment_name, start, span) in enumerate(segments):
            offset = (angle - start) % 360.0
            sector = in_annulus & (offset >= margin_deg) & (offset < span - margin_deg)
            if not sector.any():
                raise PicamcalError(
                    f"segment {segment_name!r} of wheel {name!r} has no pixels between radii {inner:g} and "
                    f"{outer:g} and {margin_deg:g} degrees inside its edges; the image is too coarse for this wheel"
                )
            colours[k] = np.median(pixels[sector], axis=0)
        result[name] = colours
    return result


def wheel_figures(image: ArrayLike, layout: Mapping[str, Any], **kwargs: Any) -> dict[str, Any]:
    """Compare each colour wheel with the centre wheel: colour difference, hue shift and saturation ratio.

    Segment colours come from :func:`segment_colours`; each is compared with the same segment of the wheel
    named ``"centre"`` using :func:`delta_e2000` (which includes any difference in lightness, so residual
    vignetting counts too) and :func:`hue_saturation`.

    Parameters
    ----------
    image : array_like, shape (h, w, 3)
        Linear RGB image of the wheel target, white at (1, 1, 1).
    layout : mapping
        The wheel layout (see :func:`segment_colours`); it must have a wheel named ``"centre"``.
    **kwargs
        Passed to :func:`segment_colours` (``pixel_scale``, ``centres``, ``inner``, ``outer``,
        ``margin_deg``).

    Returns
    -------
    dict
        JSON-serialisable (NaN where the centre segment is black or grey):

        - ``"segments"``: segment names, the order of every per-segment list;
        - ``"wheels"``: for each wheel other than the centre, a dict of ``"delta_e"`` (list),
          ``"mean_delta_e"``, ``"max_delta_e"``, ``"hue_shift_deg"`` (list; wheel minus centre, signed,
          in [-180, 180)), ``"mean_hue_shift_deg"``, ``"mean_abs_hue_shift_deg"``,
          ``"saturation_ratio"`` (list; wheel / centre) and ``"mean_saturation_ratio"``;
        - ``"max_delta_e"``, ``"mean_delta_e"``, ``"mean_saturation_ratio"``: over all segments of all
          wheels other than the centre.

    Raises
    ------
    PicamcalError
        If there is no centre wheel or no other wheel, or as :func:`segment_colours`.

    Examples
    --------
    >>> layout = {"width": 96, "height": 32, "segments": [{"name": "all", "start_deg": 0, "end_deg": 360}],
    ...           "wheels": [{"name": "centre", "x": 15.5, "y": 15.5, "radius": 15},
    ...                      {"name": "right", "x": 63.5, "y": 15.5, "radius": 15}]}
    >>> image = np.full((32, 96, 3), [0.8, 0.2, 0.1])
    >>> wheel_figures(image, layout)["max_delta_e"]
    0.0
    """
    colours = segment_colours(image, layout, **kwargs)
    if CENTRE_WHEEL not in colours:
        raise PicamcalError(f"the layout has no wheel named {CENTRE_WHEEL!r} to compare the others with")
    others = [name for name in colours if name != CENTRE_WHEEL]
    if not others:
        raise PicamcalError(f"the layout has no wheel other than {CENTRE_WHEEL!r} to compare")

    reference_lab = linear_to_lab(colours[CENTRE_WHEEL])
    reference_hue, reference_saturation = hue_saturation(colours[CENTRE_WHEEL])
    wheels: dict[str, dict[str, Any]] = {}
    all_delta_e, all_ratio = [], []
    for name in others:
        delta_e = delta_e2000_lab(linear_to_lab(colours[name]), reference_lab)
        hue, saturation = hue_saturation(colours[name])
        hue_shift = (hue - reference_hue + 180.0) % 360.0 - 180.0
        ratio = np.full_like(saturation, np.nan)
        np.divide(saturation, reference_saturation, out=ratio, where=reference_saturation > 0)
        wheels[name] = {
            "delta_e": delta_e.tolist(),
            "mean_delta_e": float(np.mean(delta_e)),
            "max_delta_e": float(np.max(delta_e)),
            "hue_shift_deg": hue_shift.tolist(),
            "mean_hue_shift_deg": float(np.mean(hue_shift)),
            "mean_abs_hue_shift_deg": float(np.mean(np.abs(hue_shift))),
            "saturation_ratio": ratio.tolist(),
            "mean_saturation_ratio": float(np.mean(ratio)),
        }
        all_delta_e.append(delta_e)
        all_ratio.append(ratio)
    return {
        "segments": [str(segment["name"]) for segment in layout["segments"]],
        "wheels": wheels,
        "max_delta_e": float(np.max(all_delta_e)),
        "mean_delta_e": float(np.mean(all_delta_e)),
        "mean_saturation_ratio": float(np.mean(all_ratio)),
    }


def flatness(image_or_plane: ArrayLike, *, bin_size: int | None = None) -> float | np.ndarray:
    """Coefficient of variation (standard deviation / mean) of an image that should be uniform.

    The whole frame counts, edges and corners included, since that is where vignetting and crosstalk are
    worst.  With ``bin_size`` the image is first averaged over square bins of that many pixels (a partial
    bin at the right and bottom edges averages the pixels it has), which removes pixel noise and leaves
    the shading.  The standard deviation is the population one (ddof = 0).

    Parameters
    ----------
    image_or_plane : array_like, shape (h, w) or (h, w, c)
        A (corrected) image of a uniform target.
    bin_size : int, optional
        Edge length in pixels of the bins to average over first.

    Returns
    -------
    float or ndarray of float64, shape (c,)
        The coefficient of variation of the plane, or of each channel.

    Raises
    ------
    PicamcalError
        If the array is not 2-D or 3-D, or a mean is not positive.

    Examples
    --------
    >>> flatness(np.full((4, 6), 0.5))
    0.0
    >>> flatness(np.array([[1.0, 3.0]]))
    0.5
    """
    values = np.asarray(image_or_plane, dtype=np.float64)
    if values.ndim not in (2, 3) or values.size == 0:
        raise PicamcalError(f"expected a non-empty (h, w) plane or (h, w, c) image, got shape {values.shape}")
    if bin_size is not None:
        if int(bin_size) != bin_size or bin_size < 1:
            raise PicamcalError(f"bin size must be a whole number of pixels >= 1, got {bin_size}")
        values = block_mean(values, int(bin_size))
    samples = values.reshape(values.shape[0] * values.shape[1], -1)
    mean = samples.mean(axis=0)
    if np.any(~(mean > 0)):
        raise PicamcalError(f"flatness needs a positive mean in every channel, got {mean.tolist()}")
    cv = samples.std(axis=0) / mean
    return float(cv[0]) if values.ndim == 2 else cv


def encode_srgb(linear: ArrayLike, *, exposure: float = 1.0) -> np.ndarray:
    """Encode linear RGB as 8-bit sRGB for previews: scale, clip to [0, 1], apply the sRGB transfer function.

    Parameters
    ----------
    linear : array_like, shape (h, w, 3)
        Linear RGB, white at (1, 1, 1); NaN becomes black.
    exposure : float, default 1.0
        Factor applied before clipping.

    Returns
    -------
    ndarray of uint8, same shape
        IEC 61966-2-1 encoded values, rounded to the nearest integer.

    Examples
    --------
    >>> encode_srgb(np.array([0.0, 0.0031308, 0.18, 1.0, 2.0])).tolist()
    [0, 10, 118, 255, 255]
    """
    scaled = np.nan_to_num(np.asarray(linear, dtype=np.float64) * exposure, nan=0.0, posinf=1.0, neginf=0.0)
    scaled = np.clip(scaled, 0.0, 1.0)
    # The transfer function of IEC 61966-2-1 as colour-science writes it (colour.cctf_encoding, function="sRGB"),
    # operation for operation, so the codes are the same; without importing colour-science (1 s) to draw a target.
    encoded = np.where(scaled <= 0.0031308, scaled * 12.92, 1.055 * scaled ** (1 / 2.4) - 0.055)
    return np.rint(encoded * 255.0).astype(np.uint8)


def save_preview(
    path: str | os.PathLike[str], linear: ArrayLike, *, max_size: int = 1024, exposure: float = 1.0
) -> Path:
    """Write a linear RGB image as an sRGB PNG preview no larger than ``max_size`` on its long side.

    The image is reduced by averaging square blocks in linear light (by the smallest whole factor that
    fits), encoded with :func:`encode_srgb` and written atomically, so a reader never sees half a file.

    Parameters
    ----------
    path : path-like
        The PNG to write; it is replaced if it exists.
    linear : array_like, shape (h, w, 3)
        Linear RGB, white at (1, 1, 1).
    max_size : int, default 1024
        Largest allowed width or height of the preview, in pixels.
    exposure : float, default 1.0
        Passed to :func:`encode_srgb`.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    PicamcalError
        If the image is not (h, w, 3) or ``max_size`` is below 1; OutputError if it cannot be written.

    Examples
    --------
    >>> from PIL import Image
    >>> Image.open(save_preview("preview.png", np.ones((300, 200, 3)), max_size=100)).size
    (67, 100)
    """
    from PIL import Image

    values = np.asarray(linear, dtype=np.float64)
    if values.ndim != 3 or values.shape[2] != 3 or values.size == 0:
        raise PicamcalError(f"expected an (h, w, 3) RGB image, got an array of shape {values.shape}")
    if max_size < 1:
        raise PicamcalError(f"max_size must be at least 1 pixel, got {max_size}")
    factor = math.ceil(max(values.shape[:2]) / max_size)
    if factor > 1:
        values = block_mean(values, factor)
    picture = Image.fromarray(encode_srgb(values, exposure=exposure))
    target = Path(path)
    with atomic_path(target) as tmp:
        picture.save(tmp, format="PNG")
    return target


def _as_colours(values: ArrayLike, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim == 0 or array.shape[-1] != 3:
        raise PicamcalError(f"{name} must have 3 components in its last axis, got shape {array.shape}")
    return array


def _image_centres(
    shape: tuple[int, int],
    layout: Mapping[str, Any],
    pixel_scale: float,
    centres: tuple[ArrayLike, ArrayLike] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Layout coordinates (y of each row, x of each column) of the image's pixel centres."""
    h, w = shape
    if centres is not None:
        ys, xs = (np.asarray(c, dtype=np.float64) for c in centres)
        if ys.shape != (h,) or xs.shape != (w,):
            raise PicamcalError(
                f"centres give {ys.shape} row and {xs.shape} column positions for an image of {h} x {w} pixels"
            )
        return ys, xs
    if not pixel_scale > 0:
        raise PicamcalError(f"pixel_scale must be positive, got {pixel_scale}")
    width, height = int(layout["width"]), int(layout["height"])
    fits_w = math.floor(width / pixel_scale) <= w <= math.ceil(width / pixel_scale)
    fits_h = math.floor(height / pixel_scale) <= h <= math.ceil(height / pixel_scale)
    if not (fits_w and fits_h):
        raise PicamcalError(
            f"an image of {w} x {h} pixels does not fit a layout of {width} x {height} at pixel_scale "
            f"{pixel_scale:g} (give the bin size as pixel_scale, or explicit centres)"
        )
    return (np.arange(h) + 0.5) * pixel_scale - 0.5, (np.arange(w) + 0.5) * pixel_scale - 0.5


def _extent(positions: np.ndarray) -> tuple[float, float]:
    """Range of layout coordinates covered by pixels centred at ``positions`` (half a pixel either side)."""
    half = 0.5 * float(np.min(np.abs(np.diff(positions)))) if positions.size > 1 else 0.5
    return float(np.min(positions)) - half, float(np.max(positions)) + half


def _segments(layout: Mapping[str, Any], margin_deg: float) -> list[tuple[str, float, float]]:
    """(name, start, angular width) of each segment, checking the margin leaves something of each."""
    if not layout.get("segments"):
        raise PicamcalError("the layout has no segments")
    segments = []
    for segment in layout["segments"]:
        start, end = float(segment["start_deg"]), float(segment["end_deg"])
        span = (end - start) % 360.0 or 360.0
        if not 0.0 <= margin_deg < span / 2.0:
            raise PicamcalError(
                f"margin_deg={margin_deg:g} leaves nothing of segment {segment['name']!r}, {span:g} degrees wide"
            )
        segments.append((str(segment["name"]), start % 360.0, span))
    return segments
