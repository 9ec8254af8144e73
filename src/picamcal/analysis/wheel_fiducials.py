"""Mapping a target layout onto an image through its fiducial marks: the marks, the homography, the wheels.

The target (:mod:`picamcal.colour_wheel`) has five black marks: a ring (a black disc with a white dot in its
middle) near each corner and a smaller solid disc beside the top-left ring. :func:`map_layout` finds them
in the image (dark round blobs of the background-normalised image of
:class:`picamcal.analysis.wheel_search.ReducedImage`), matches them to the layout's (the disc tells which
corner is which, and whether the image is mirrored), fits the projective transform (homography) from the
layout to the image to all of them by least squares (normalised DLT), maps the wheels through it and
checks that each mapped segment shows its colour.

Examples
--------
>>> from picamcal.colour_wheel import wheel_layout, wheel_scene
>>> from picamcal.analysis.wheel_search import ReducedImage, as_image
>>> layout = wheel_layout(320, 240)
>>> image = as_image(wheel_scene(layout))
>>> wheels, marks = map_layout(image, ReducedImage(image), layout)
>>> len(wheels), round(wheels[0]["x"], 2), round(marks["fit_rms_px"], 2)
(9, 159.5, 0.0)
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import ndimage

from ..errors import PicamcalError
from .wheel_search import CHROMA_THRESHOLD, ReducedImage, chroma_of, hex_hue, round_blobs, window_around, wrap_deg

__all__ = ["apply_homography", "find_marks", "fit_homography", "map_layout"]

_DARK_THRESHOLD = 0.5  # of 1 - max(n): black marks are ~1, the darkest segment (blue) ~0.3 in a corner
_MIN_MARK_RADIUS = 1.5  # in pixels of the reduced image


def map_layout(
    image: np.ndarray, reduced: ReducedImage, layout: Mapping[str, Any]
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Fit the homography from the layout's fiducial marks to the image's, and map the wheels through it.

    Parameters
    ----------
    image : ndarray, shape (h, w, 3)
        Linear RGB image of the target (from :func:`~picamcal.analysis.wheel_search.as_image`).
    reduced : ReducedImage
        Its reduced copy and white background.
    layout : mapping
        The target's layout, with ``fiducials`` (4 rings and 1 disc).

    Returns
    -------
    wheels : list of dict
        The layout's wheels in the image: ``name``, ``x``, ``y``, ``radius`` (mean distance of the mapped
        rim from the mapped centre), ``mirrored``, ``rotation_deg`` and their own ``segments`` (the mapped
        direction of every boundary).
    marks : dict
        ``"fiducials"`` (as found: ``name``, ``kind``, ``x``, ``y``, ``radius``), ``"homography"`` (3 x 3,
        layout to image) and ``"fit_rms_px"`` (the marks' residual).

    Raises
    ------
    PicamcalError
        ``"... the layout does not match the image"``: the marks are not found, do not fit a projective
        transform, or the mapped wheels do not show their segments' colours.
    """
    mismatch = "the layout does not match the image"
    marks = [dict(m) for m in layout["fiducials"]]
    rings_l = [m for m in marks if m.get("kind") == "ring"]
    discs_l = [m for m in marks if m.get("kind") != "ring"]
    if len(rings_l) != 4 or len(discs_l) != 1:
        raise PicamcalError(f"the layout's fiducials must be 4 rings and 1 disc, got {len(rings_l)} and {len(discs_l)}")
    found = find_marks(image, reduced)
    rings = sorted((m for m in found if m["hole"] > 0.05), key=lambda m: -m["radius"])[:8]
    discs = sorted((m for m in found if m["hole"] <= 0.05), key=lambda m: -m["radius"])[:6]
    if len(rings) < 4 or not discs:
        raise PicamcalError(
            f"found {len(rings)} ring and {len(discs)} disc fiducial marks, not the layout's 4 and 1: {mismatch}"
        )
    layout_points = np.array([[m["x"], m["y"]] for m in (*cyclic(rings_l), discs_l[0])], dtype=np.float64)
    best = None
    for four in itertools.combinations(rings, 4):
        ordered = cyclic(list(four))
        ring_radius = float(np.mean([m["radius"] for m in ordered]))
        for shift, step in itertools.product(range(4), (1, -1)):
            assigned = [ordered[(shift + step * k) % 4] for k in range(4)]
            src = layout_points[:4]
            dst = np.array([[m["x"], m["y"]] for m in assigned])
            homography = fit_homography(src, dst)
            if homography is None:
                continue
            predicted = apply_homography(homography, layout_points[4:])[0]
            for disc in discs:
                error = math.hypot(predicted[0] - disc["x"], predicted[1] - disc["y"]) / ring_radius
                if best is None or error < best[0]:
                    best = (error, assigned, disc)
    if best is None or best[0] > 0.5:
        raise PicamcalError(f"the fiducial marks do not fall where the layout puts them: {mismatch}")
    _, assigned, disc = best
    image_points = np.array([[m["x"], m["y"]] for m in (*assigned, disc)], dtype=np.float64)
    homography = fit_homography(layout_points, image_points)
    if homography is None:
        raise PicamcalError(f"the fiducial marks are degenerate: {mismatch}")
    residual = np.hypot(*(apply_homography(homography, layout_points) - image_points).T)
    ring_radius = float(np.mean([m["radius"] for m in assigned]))
    if residual.max() > 0.25 * ring_radius + 1.0:
        raise PicamcalError(
            f"the fiducial marks fit a projective transform only to {residual.max():.1f} pixels: {mismatch}"
        )
    wheels = [_map_wheel(homography, wheel, layout["segments"]) for wheel in layout["wheels"]]
    _check_wheels(image, reduced, wheels, layout["segments"], mismatch)
    names = [m.get("name", m["kind"]) for m in (*cyclic(rings_l), discs_l[0])]
    marks_found = {
        "fiducials": [
            {
                "name": str(name),
                "kind": kind,
                "x": round(m["x"], 4),
                "y": round(m["y"], 4),
                "radius": round(m["radius"], 4),
            }
            for name, kind, m in zip(names, ["ring"] * 4 + ["disc"], (*assigned, disc), strict=True)
        ],
        "homography": (homography / homography[2, 2]).tolist(),
        "fit_rms_px": float(np.sqrt(np.mean(residual**2))),
    }
    return wheels, marks_found


def find_marks(image: np.ndarray, reduced: ReducedImage) -> list[dict[str, float]]:
    """Dark round marks: centre (darkness-weighted, at full resolution), radius and hole fraction."""
    darkness = 1.0 - reduced.normalised_reduced().max(axis=-1)
    marks = []
    for blob in round_blobs(darkness > _DARK_THRESHOLD, _MIN_MARK_RADIUS):
        x, y, radius = reduced.to_full(blob["x"]), reduced.to_full(blob["y"]), blob["radius"] * reduced.factor
        y0, y1, x0, x1 = window_around(image.shape, x, y, 1.6 * radius + 3)
        dark = np.clip(1.0 - reduced.normalised(image, y0, y1, x0, x1).max(axis=-1), 0.0, 1.0)
        mask = dark > _DARK_THRESHOLD
        labels, count = ndimage.label(ndimage.binary_fill_holes(mask))
        if count == 0:
            continue
        chosen = labels[min(max(round(y) - y0, 0), y1 - y0 - 1), min(max(round(x) - x0, 0), x1 - x0 - 1)]
        if chosen == 0:
            chosen = 1 + int(np.argmax(ndimage.sum_labels(mask, labels, range(1, count + 1))))
        filled = labels == chosen
        own = filled & mask
        region = ndimage.binary_dilation(filled, iterations=2)
        weights = np.where(region, dark, 0.0)
        weights[filled & ~own] = 0.0
        total = float(weights.sum())
        if total <= 0:
            continue
        py, px = np.mgrid[y0:y1, x0:x1]
        area = float(filled.sum())
        marks.append(
            {
                "x": float((weights * px).sum() / total),
                "y": float((weights * py).sum() / total),
                "radius": math.sqrt(area / math.pi),
                "hole": 1.0 - float(own.sum()) / area,
            }
        )
    return marks


def cyclic(marks: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Marks ordered by angle round their centroid (counter-clockwise on screen)."""
    cx = float(np.mean([m["x"] for m in marks]))
    cy = float(np.mean([m["y"] for m in marks]))
    return sorted(marks, key=lambda m: math.atan2(-(float(m["y"]) - cy), float(m["x"]) - cx))


def fit_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
    """The 3 x 3 H with dst ~ H src (homogeneous), by the normalised direct linear transform (Hartley)."""

    def normaliser(points: np.ndarray) -> np.ndarray:
        centre = points.mean(axis=0)
        scale = math.sqrt(2.0) / max(float(np.mean(np.hypot(*(points - centre).T))), 1e-12)
        return np.array([[scale, 0, -scale * centre[0]], [0, scale, -scale * centre[1]], [0, 0, 1]])

    ts, td = normaliser(src), normaliser(dst)
    s = apply_homography(ts, src)
    d = apply_homography(td, dst)
    rows = []
    for (x, y), (u, v) in zip(s, d, strict=True):
        rows.append([-x, -y, -1, 0, 0, 0, u * x, u * y, u])
        rows.append([0, 0, 0, -x, -y, -1, v * x, v * y, v])
    _, singular, vt = np.linalg.svd(np.asarray(rows))
    # Three collinear points leave more than one solution: the eighth singular value vanishes too.
    if singular[7] < 1e-8 * singular[0]:
        return None
    h = np.linalg.inv(td) @ vt[-1].reshape(3, 3) @ ts
    return None if abs(h[2, 2]) < 1e-12 * np.abs(h).max() else h / h[2, 2]


def apply_homography(h: np.ndarray, points: np.ndarray) -> np.ndarray:
    p = np.column_stack([points, np.ones(len(points))]) @ np.asarray(h).T
    return p[:, :2] / p[:, 2:]


def _map_wheel(h: np.ndarray, wheel: Mapping[str, Any], segments: list[Mapping[str, Any]]) -> dict[str, Any]:
    """A layout wheel mapped into the image: centre, mean radius, and each segment boundary's direction."""
    x, y, r = float(wheel["x"]), float(wheel["y"]), float(wheel["radius"])
    (cx, cy), *_ = apply_homography(h, np.array([[x, y]]))

    def direction(angle_deg: float, rho: float) -> np.ndarray:
        a = math.radians(angle_deg)
        return apply_homography(h, np.array([[x + rho * math.cos(a), y - rho * math.sin(a)]]))[0]

    rim = np.array([direction(a, r) for a in range(0, 360, 5)])
    radius = float(np.mean(np.hypot(rim[:, 0] - cx, rim[:, 1] - cy)))

    def image_angle(angle_deg: float) -> float:
        px, py = direction(angle_deg, 0.6 * r)
        return math.degrees(math.atan2(-(py - cy), px - cx)) % 360.0

    jacobian = np.column_stack([direction(0, 1.0) - (cx, cy), direction(90, 1.0) - (cx, cy)])
    # Layout (1, 0) and (0, 1 up) map to these columns; in on-screen coordinates (y down) a proper rotation
    # keeps the sign of the determinant of [[1, 0], [0, -1]].
    mirrored = bool(np.linalg.det(jacobian) > 0)
    own = []
    for segment in segments:
        start, end = image_angle(float(segment["start_deg"])), image_angle(float(segment["end_deg"]))
        if mirrored:
            start, end = end, start
        span = (end - start) % 360.0 or 360.0
        own.append({"name": str(segment["name"]), "start_deg": round(start, 4), "end_deg": round(start + span, 4)})
    return {
        "name": str(wheel["name"]),
        "x": float(cx),
        "y": float(cy),
        "radius": radius,
        "mirrored": mirrored,
        "rotation_deg": wrap_deg(image_angle(0.0)),
        "segments": own,
    }


def _check_wheels(
    image: np.ndarray,
    reduced: ReducedImage,
    wheels: list[dict[str, Any]],
    segments: list[Mapping[str, Any]],
    mismatch: str,
) -> None:
    """Check every mapped wheel lies in the image and shows each segment's hue in the middle of its sector."""
    h, w = image.shape[:2]
    for wheel in wheels:
        x, y, r = wheel["x"], wheel["y"], wheel["radius"]
        if x - r < 0 or y - r < 0 or x + r > w - 1 or y + r > h - 1:
            raise PicamcalError(f"wheel {wheel['name']!r} would fall outside the image: {mismatch}")
        half = max(1, round(0.05 * r))
        wrong = 0
        for own, segment in zip(wheel["segments"], segments, strict=True):
            mid = math.radians(own["start_deg"] + 0.5 * ((own["end_deg"] - own["start_deg"]) % 360.0))
            px, py = x + 0.55 * r * math.cos(mid), y - 0.55 * r * math.sin(mid)
            y0, y1, x0, x1 = window_around(image.shape, px, py, half)
            colour = reduced.normalised(image, y0, y1, x0, x1).reshape(-1, 3).mean(axis=0)
            expected = np.asarray(segment.get("colour", (0, 0, 0)), dtype=np.float64)
            if chroma_of(expected) == 0:
                wrong += bool(chroma_of(colour) > CHROMA_THRESHOLD)
                continue
            off = abs(wrap_deg(float(hex_hue(colour)) - float(hex_hue(expected))))
            wrong += bool(chroma_of(colour) < 0.5 * CHROMA_THRESHOLD or off > 40.0)
        if wrong:
            raise PicamcalError(
                f"{wrong} segment(s) of wheel {wheel['name']!r} do not show their colour where the layout puts them: "
                f"{mismatch}"
            )
