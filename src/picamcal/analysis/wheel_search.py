"""Finding colour wheels in an image by themselves: the white background, round blobs, rims and orientations.

Finding the wheels must work on the uncorrected image, whose corners are darker and less saturated than
its centre, and whose white need not even be balanced. Everything here therefore works on the image
divided by its own white background, ``n = rgb / background``: the background is the upper envelope of
each channel (a grey-scale morphological closing wider than a wheel, on a reduced copy of the image),
since on the target every colour is at most as bright as the white paper or screen around it in every
channel. ``n`` is about (1, 1, 1) on the white whatever the vignetting; a segment has at least one channel
near 1 and one well below it (less so in uncorrected corners), so its chroma ``max(n) - min(n)`` stands
out, and a black fiducial mark has ``max(n)`` near 0.

:func:`detect_wheels` finds every wheel and measures it at full resolution; :func:`name_by_position` names
them by where they lie; :func:`picamcal.analysis.wheels.find_wheels` puts them together.

Coordinates are pixels of the image with pixel centres at integer coordinates; angles are
``atan2(-(y - cy), x - cx)`` in degrees, counter-clockwise from +x as seen on screen, as in
:mod:`picamcal.colour_wheel`.

Examples
--------
>>> from picamcal.colour_wheel import wheel_layout, wheel_scene
>>> image = as_image(wheel_scene(wheel_layout(320, 240)))
>>> wheels = name_by_position(image, detect_wheels(image, ReducedImage(image)))
>>> [w["name"] for w in wheels][:4]
['centre', 'top-left', 'top', 'top-right']
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

from ..bayer import block_mean
from ..colour_wheel import CENTRE_WHEEL, WHEEL_POSITIONS
from ..errors import PicamcalError

__all__ = [
    "CHROMA_THRESHOLD",
    "ReducedImage",
    "as_image",
    "chroma_of",
    "consensus",
    "detect_wheels",
    "hex_hue",
    "name_by_position",
    "round_blobs",
    "window_around",
    "wrap_deg",
]

# Names of the positions round the centre wheel: the target's own, and "middle" for a second wheel there.
_POSITION_NAMES = {(col, row): name for name, col, row in WHEEL_POSITIONS if (col, row) != (0, 0)}
_POSITION_NAMES[(0, 0)] = "middle"

_DETECT_SIZE = 800  # long side of the reduced image the search runs on, in pixels
_BACKGROUND_SIZE = 160  # long side of the grid the white background is estimated on
_CLOSING_FRACTION = 0.35  # closing element, of the grid's short side: wider than a wheel of radius 0.15
#: Chroma ``max(n) - min(n)`` above which a pixel is coloured: white is ~0.05 with noise, the palest corner segment
#: ~0.45.
CHROMA_THRESHOLD = 0.2
_MIN_WHEEL_RADIUS = 4.0  # in pixels of the reduced image
_MAX_ELONGATION = 1.35  # ratio of the principal axes of a wheel or mark in the image
_MIN_HUE_ORDER = 0.6  # resultant length of the hue-versus-angle fit that makes a blob a wheel
_RAYS = 180  # rays from the centre on which each wheel's rim is located


def as_image(rgb: ArrayLike) -> np.ndarray:
    image = np.asarray(rgb)
    if image.ndim != 3 or image.shape[2] != 3 or min(image.shape[:2]) < 16:
        raise PicamcalError(f"expected an (h, w, 3) RGB image at least 16 pixels wide, got shape {image.shape}")
    if image.dtype != np.float32:
        image = image.astype(np.float32)
    return image


def _block_mean(image: np.ndarray, factor: int) -> np.ndarray:
    """Means over ``factor`` x ``factor`` blocks from the top-left, a partial last block dropped, in float32.

    float32 halves the memory and time of reducing a 12-megapixel image; the search needs no more precision.
    """
    return block_mean(image, factor, partial=False, dtype=np.float32)


class ReducedImage:
    """An image reduced for the search, and its white background per channel at any resolution.

    The image is reduced by block means to about 800 pixels on its long side. The background is estimated
    on a coarser grid of about 160 pixels: the closing (dilation then erosion) of each channel with a
    square wider than a wheel fills the wheels and marks with the white around them. The grid is padded
    by replicating its edges first, so that the closing is exact up to the borders for a background that
    falls monotonically away from a centre, as vignetting does.
    """

    def __init__(self, image: np.ndarray) -> None:
        self.factor = max(1, math.ceil(max(image.shape[:2]) / _DETECT_SIZE))
        self.image = _block_mean(image, self.factor)
        coarse = max(1, math.ceil(max(self.image.shape[:2]) / _BACKGROUND_SIZE))
        grid = _block_mean(self.image, coarse)
        self.grid_factor = self.factor * coarse
        size = max(3, int(_CLOSING_FRACTION * min(grid.shape[:2])) | 1)
        padded = np.pad(grid, ((size, size), (size, size), (0, 0)), mode="edge")
        closed = np.stack([ndimage.grey_closing(padded[..., c], size=(size, size)) for c in range(3)], axis=-1)
        closed = ndimage.uniform_filter(closed, size=(3, 3, 1), mode="nearest")[size:-size, size:-size]
        floor = max(float(np.percentile(closed, 99)) * 1e-3, 1e-12)
        # At least two grid points along each axis, for the bilinear interpolation.
        grow = ((0, max(0, 2 - closed.shape[0])), (0, max(0, 2 - closed.shape[1])), (0, 0))
        self.grid = np.pad(np.maximum(closed, floor), grow, mode="edge")

    def background(self, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
        """Background (len(ys), len(xs), 3) at full-resolution rows ``ys`` and columns ``xs`` (bilinear)."""
        iy, wy = self._weights(ys, self.grid.shape[0])
        ix, wx = self._weights(xs, self.grid.shape[1])
        columns = self.grid[:, ix] * (1 - wx)[None, :, None] + self.grid[:, ix + 1] * wx[None, :, None]
        return columns[iy] * (1 - wy)[:, None, None] + columns[iy + 1] * wy[:, None, None]

    def _weights(self, positions: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        g = np.clip((np.asarray(positions, dtype=np.float64) + 0.5) / self.grid_factor - 0.5, 0, n - 1)
        i = np.minimum(g.astype(np.intp), n - 2)
        return i, (g - i).astype(np.float32)

    def normalised(self, image: np.ndarray, y0: int, y1: int, x0: int, x1: int, step: int = 1) -> np.ndarray:
        """``image[y0:y1, x0:x1] / background``, at full resolution or in block means of ``step`` pixels."""
        window = _block_mean(image[y0:y1, x0:x1], step)
        offset = (step - 1) / 2
        ys, xs = y0 + offset + step * np.arange(window.shape[0]), x0 + offset + step * np.arange(window.shape[1])
        return window / self.background(ys, xs)

    def normalised_reduced(self) -> np.ndarray:
        """The reduced image divided by the background at its blocks' centres."""
        h, w = self.image.shape[:2]
        offset = (self.factor - 1) / 2
        return self.image / self.background(np.arange(h) * self.factor + offset, np.arange(w) * self.factor + offset)

    def to_full(self, value: float) -> float:
        """A coordinate of the reduced image in full-resolution pixels."""
        return (value + 0.5) * self.factor - 0.5


def chroma_of(normalised: np.ndarray) -> np.ndarray:
    r, g, b = normalised[..., 0], normalised[..., 1], normalised[..., 2]
    return np.maximum(np.maximum(r, g), b) - np.minimum(np.minimum(r, g), b)


def hex_hue(normalised: np.ndarray) -> np.ndarray:
    """Hue angle in degrees on the RGB colour hexagon: red 0, yellow 60, green 120, ..., magenta 300."""
    r, g, b = normalised[..., 0], normalised[..., 1], normalised[..., 2]
    return np.degrees(np.arctan2(math.sqrt(3.0) * (g - b), 2.0 * r - g - b)) % 360.0


def detect_wheels(image: np.ndarray, reduced: ReducedImage) -> list[dict[str, Any]]:
    """Every colour wheel in the image, measured at full resolution: x, y, radius, mirrored, rotation."""
    chroma = ndimage.gaussian_filter(chroma_of(reduced.normalised_reduced()), 0.7)
    wheels = []
    for blob in round_blobs(chroma > CHROMA_THRESHOLD, _MIN_WHEEL_RADIUS):
        x, y, radius = reduced.to_full(blob["x"]), reduced.to_full(blob["y"]), blob["radius"] * reduced.factor
        wheel = _measure_wheel(image, reduced, x, y, radius)
        if wheel is not None:
            wheels.append(wheel)
    if not wheels:
        raise PicamcalError("no colour wheels found in the image")
    return wheels


def round_blobs(mask: np.ndarray, min_radius: float) -> list[dict[str, float]]:
    """Connected components of ``mask`` that are round and, with their holes filled, solid discs.

    Components touching the border are skipped. Returns the centroid (x, y), the radius of the disc of
    the same area (filled) and the fraction of the filled area that is hole.
    """
    labels, _ = ndimage.label(mask)
    blobs = []
    for index, region in enumerate(ndimage.find_objects(labels), start=1):
        if region is None:
            continue
        ys, xs = region
        if ys.start == 0 or xs.start == 0 or ys.stop == mask.shape[0] or xs.stop == mask.shape[1]:
            continue
        own = labels[region] == index
        filled = ndimage.binary_fill_holes(own)
        area = float(filled.sum())
        radius = math.sqrt(area / math.pi)
        if radius < min_radius:
            continue
        py, px = np.nonzero(filled)
        cy, cx = py.mean(), px.mean()
        cov = np.cov(np.stack([px - cx, py - cy]))
        eig = np.linalg.eigvalsh(cov)
        if eig[0] <= 0 or math.sqrt(eig[1] / eig[0]) > _MAX_ELONGATION:
            continue
        # A filled ellipse has area 4 pi sqrt(det cov); anything ragged or hollow has less.
        if not 0.85 < area / (4 * math.pi * math.sqrt(eig[0] * eig[1])) < 1.15:
            continue
        blobs.append(
            {
                "x": float(cx + xs.start),
                "y": float(cy + ys.start),
                "radius": radius,
                "hole": 1.0 - float(own.sum()) / area,
            }
        )
    return blobs


def window_around(shape: tuple[int, ...], x: float, y: float, reach: float) -> tuple[int, int, int, int]:
    y0, y1 = max(0, math.floor(y - reach)), min(shape[0], math.ceil(y + reach) + 1)
    x0, x1 = max(0, math.floor(x - reach)), min(shape[1], math.ceil(x + reach) + 1)
    return y0, y1, x0, x1


def _measure_wheel(
    image: np.ndarray, reduced: ReducedImage, x: float, y: float, radius: float
) -> dict[str, Any] | None:
    """Centre, radius and orientation of the wheel roughly at (x, y, radius), or None if it is not a wheel.

    Wheels more than 120 pixels in radius are measured on block means of the image (at most 240 pixels
    across the wheel), which loses no accuracy that matters at that size and saves time on 12-megapixel
    frames; the colours are smoothed a little (Gaussian, 0.8 pixel) against noise.
    """
    step = max(1, int(radius // 120))
    y0, y1, x0, x1 = window_around(image.shape, x, y, 1.5 * radius + 3 * step)
    normalised = ndimage.gaussian_filter(reduced.normalised(image, y0, y1, x0, x1, step), (0.8, 0.8, 0))
    chroma = chroma_of(normalised)
    # Positions in the window's (reduced) pixels: u = (x - x0 + 0.5) / step - 0.5.
    shift_x, shift_y = (x0 - 0.5) / step + 0.5, (y0 - 0.5) / step + 0.5
    # Rim points: on each ray, where the chroma falls half-way from the wheel's (at 0.6-0.8 r) to the
    # background's (1.2-1.4 r), the crossing nearest the rough radius, interpolated linearly.
    angles = np.linspace(0.0, 2 * math.pi, _RAYS, endpoint=False)
    steps = np.arange(0.6 * radius, 1.4 * radius, 0.25)
    ray_x = (x + np.cos(angles)[:, None] * steps) / step - shift_x
    ray_y = (y - np.sin(angles)[:, None] * steps) / step - shift_y
    profiles = ndimage.map_coordinates(chroma, [ray_y, ray_x], order=1, mode="nearest")
    inside = np.median(profiles[:, steps <= 0.8 * radius], axis=1)
    outside = np.median(profiles[:, steps >= 1.2 * radius], axis=1)
    half = (0.5 * (inside + outside))[:, None]
    above = profiles >= half
    falls = above[:, :-1] & ~above[:, 1:]
    points = []
    for k in np.flatnonzero(inside - outside > 0.5 * CHROMA_THRESHOLD):
        crossings = np.flatnonzero(falls[k])
        if crossings.size == 0:
            continue
        i = crossings[np.argmin(np.abs(steps[crossings] - radius))]
        t = (profiles[k, i] - half[k, 0]) / (profiles[k, i] - profiles[k, i + 1])
        rho = steps[i] + t * (steps[i + 1] - steps[i])
        points.append((x + rho * math.cos(angles[k]), y - rho * math.sin(angles[k])))
    if len(points) < _RAYS // 2:
        return None
    cx, cy, r = _fit_circle(np.asarray(points))
    if not (abs(cx - x) < 0.3 * radius and abs(cy - y) < 0.3 * radius and 0.7 < r / radius < 1.3):
        return None
    rotation, mirrored = _orientation(normalised, cx / step - shift_x, cy / step - shift_y, r / step)
    if rotation is None:
        return None
    return {"x": cx, "y": cy, "radius": r, "mirrored": mirrored, "rotation_deg": rotation}


def _orientation(normalised: np.ndarray, cx: float, cy: float, radius: float) -> tuple[float | None, bool]:
    """Rotation (degrees) and mirroring of a wheel of the default segments, or None if its hues do not turn.

    The colour is sampled every 0.25 degree round a circle at 0.55 of the radius. A first estimate fits
    ``hue = s * angle + offset`` (s = 1, or -1 for a mirrored wheel) to the hue on the RGB hexagon, whose
    steps of 60 degrees are only roughly even in a desaturated corner. Each boundary between segments is
    then placed where the colour is half-way from one segment's to the next's, and the rotation is the
    circular mean of the boundaries' offsets from the unturned wheel's.
    """
    theta = np.arange(0.0, 360.0, 0.25)
    ring_x = cx + 0.55 * radius * np.cos(np.radians(theta))
    ring_y = cy - 0.55 * radius * np.sin(np.radians(theta))
    samples = np.stack(
        [ndimage.map_coordinates(normalised[..., c], [ring_y, ring_x], order=1, mode="nearest") for c in range(3)],
        axis=-1,
    )
    hue, weight = np.radians(hex_hue(samples)), chroma_of(samples)
    fits = []
    for sign in (1, -1):
        z = np.sum(weight * np.exp(1j * (hue - sign * np.radians(theta))))
        fits.append((abs(z) / max(float(weight.sum()), 1e-12), sign, math.degrees(np.angle(z))))
    quality, sign, offset = max(fits)
    if quality < _MIN_HUE_ORDER:
        return None, False
    # Segment k (hue 60 k) is centred at angle s (60 k - offset). Turned by a rotation r, the edge after it
    # is at s 60 (k + 1) + r, and its centre at s (60 k + 30) + r.
    centres = [sign * (60.0 * k - offset) for k in range(6)]
    colours = [np.median(samples[np.abs(_wrap_array(theta - c)) <= 15.0], axis=0) for c in centres]
    rotations = []
    for k in range(6):
        step = colours[(k + 1) % 6] - colours[k]
        if float(step @ step) < 1e-6:
            continue
        edge = centres[k] + 30.0 * sign
        along = sign * _wrap_array(theta - edge)
        near = np.abs(along) <= 20.0
        order = np.argsort(along[near])
        t, fraction = along[near][order], ((samples[near][order] - colours[k]) @ step) / float(step @ step)
        crossings = np.flatnonzero((fraction[:-1] < 0.5) & (fraction[1:] >= 0.5))
        if crossings.size:
            i = crossings[np.argmin(np.abs(t[crossings]))]
            found = t[i] + (0.5 - fraction[i]) / (fraction[i + 1] - fraction[i]) * (t[i + 1] - t[i])
            rotations.append(edge + sign * found - sign * 60.0 * (k + 1))
    if not rotations:
        rotations = [centres[0] - sign * 30.0]
    rotation = math.degrees(np.angle(np.mean(np.exp(1j * np.radians(rotations)))))
    return wrap_deg(rotation), sign == -1


def _fit_circle(points: np.ndarray) -> tuple[float, float, float]:
    """Least-squares circle through points (Kasa), refitted once without points off it by > 3 MADs."""
    keep = np.ones(len(points), dtype=bool)
    for _ in range(2):
        x, y = points[keep, 0], points[keep, 1]
        a = np.column_stack([x, y, np.ones_like(x)])
        (d, e, f), *_ = np.linalg.lstsq(a, x**2 + y**2, rcond=None)
        cx, cy = d / 2, e / 2
        r = math.sqrt(max(f + cx**2 + cy**2, 0.0))
        residual = np.abs(np.hypot(points[:, 0] - cx, points[:, 1] - cy) - r)
        mad = float(np.median(residual[keep]))
        keep = residual <= 3 * 1.4826 * mad + 0.05
    return float(cx), float(cy), float(r)


def _wrap_array(angle: np.ndarray) -> np.ndarray:
    return (angle + 180.0) % 360.0 - 180.0


def wrap_deg(angle: float) -> float:
    """An angle in degrees in [-180, 180)."""
    return float((angle + 180.0) % 360.0 - 180.0)


def consensus(wheels: list[dict[str, Any]]) -> tuple[float, bool]:
    """The wheels' common rotation and mirroring: the majority's mirroring and its mean rotation."""
    mirrored = sum(w["mirrored"] for w in wheels) * 2 > len(wheels)
    agreeing = [w["rotation_deg"] for w in wheels if w["mirrored"] == mirrored]
    return wrap_deg(math.degrees(np.angle(np.mean(np.exp(1j * np.radians(agreeing)))))), mirrored


def name_by_position(image: np.ndarray, wheels: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Name the wheel nearest the image centre ``"centre"`` and the others by where they lie from it."""
    h, w = image.shape[:2]
    centre = min(wheels, key=lambda wh: math.hypot(wh["x"] - (w - 1) / 2, wh["y"] - (h - 1) / 2))
    # Undo the target's tilt in the image (its rotation modulo 90 degrees), but not a turn by a multiple of
    # 90 degrees or a mirroring: names say where a wheel is in the image.
    tilt = math.radians((consensus(wheels)[0] + 45.0) % 90.0 - 45.0)
    ex = np.array([wheel["x"] - centre["x"] for wheel in wheels])
    ey = np.array([wheel["y"] - centre["y"] for wheel in wheels])
    dx, dy = ex * math.cos(tilt) - ey * math.sin(tilt), ex * math.sin(tilt) + ey * math.cos(tilt)
    # A wheel is off to a side if it lies more than half as far out as the outermost wheels, and by more
    # than two radii (so that a single row of wheels is all "middle" rows).
    reach = 2.0 * float(np.median([wheel["radius"] for wheel in wheels]))
    limit_x, limit_y = max(0.5 * np.abs(dx).max(), reach), max(0.5 * np.abs(dy).max(), reach)
    named = []
    for wheel, x, y in zip(wheels, dx, dy, strict=True):
        if wheel is centre:
            named.append((0, 0.0, {**wheel, "name": CENTRE_WHEEL}))
            continue
        col = -1 if x < -limit_x else (1 if x > limit_x else 0)
        row = -1 if y < -limit_y else (1 if y > limit_y else 0)
        order = 1 + (row + 1) * 3 + (col + 1)
        named.append((order, math.hypot(x, y), {**wheel, "name": _POSITION_NAMES[(col, row)]}))
    named.sort(key=lambda item: (item[0], item[1]))
    seen: dict[str, int] = {}
    result = []
    for _, _, wheel in named:
        count = seen[wheel["name"]] = seen.get(wheel["name"], 0) + 1
        result.append(wheel if count == 1 else {**wheel, "name": f"{wheel['name']}-{count}"})
    return result
