"""The colour-wheel test target, defined once: its layout (wheels, segments, fiducial marks) and its rendering.

The paper tests its corrections on an image of colour wheels shown on a computer screen and imaged
through the custom optics (Figure "colour_wheels_images"), comparing the wheels away from the centre of
the frame with the one in the centre (Figure "matrix_correction_wheels_and_polar"). The target has nine
wheels, one in the centre, one near each corner and one near the middle of each edge, each of six
60-degree segments of the primaries and secondaries (red, yellow, green, cyan, blue, magenta) on white.
Five black fiducial marks let :func:`picamcal.analysis.wheels.find_wheels` map the layout onto a
photograph of the target: a ring (a black disc with a white dot in its middle) near each corner, and a
smaller solid disc beside the top-left ring, towards the top-right one, which fixes the target's
orientation and tells a mirrored image from a true one.

Everything that shows or looks for the target uses this one definition:

- ``picamcal target`` (:mod:`picamcal.target`) writes :func:`wheel_scene` of :func:`wheel_layout`,
  sRGB-encoded, as a PNG to show full-screen or a PDF to print;
- the simulator (:func:`picamcal.simulate.simulate_target`) photographs the same target laid out on the
  frame (``wheel_layout(width, height)`` of the simulated sensor), in amounts of its LED primaries;
- :mod:`picamcal.analysis.wheels` finds its wheels and fiducial marks in an image.

Coordinates are in pixels of the rendering, with pixel centres at integer coordinates (pixel ``(i, j)``
covers ``x`` from ``j - 0.5`` to ``j + 0.5``); angles are ``atan2(-(y - cy), x - cx)`` in degrees,
counter-clockwise from +x as seen on screen (y grows downwards).

Examples
--------
>>> layout = wheel_layout(320, 240)
>>> len(layout["wheels"]), len(layout["fiducials"]), wheel_scene(layout).shape
(9, 5, (240, 320, 3))
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from .errors import PicamcalError
from .limits import MAX_PIXELS_VARIABLE, max_pixels

__all__ = ["CENTRE_WHEEL", "SEGMENTS", "WHEEL_POSITIONS", "wheel_layout", "wheel_scene", "wheel_segments"]

#: Segment names and colours (in the primaries: sRGB on screen, LED amounts in the simulator), counter-clockwise
#: from +x as seen on screen, 60 degrees each.
SEGMENTS: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("red", (1, 0, 0)),
    ("yellow", (1, 1, 0)),
    ("green", (0, 1, 0)),
    ("cyan", (0, 1, 1)),
    ("blue", (0, 0, 1)),
    ("magenta", (1, 0, 1)),
)

#: The wheel every other wheel is compared with.
CENTRE_WHEEL = "centre"

#: Wheel names and positions: (name, column, row), columns and rows -1, 0, 1 for left/top, middle, right/bottom.
WHEEL_POSITIONS: tuple[tuple[str, int, int], ...] = (
    (CENTRE_WHEEL, 0, 0),
    ("top-left", -1, -1),
    ("top", 0, -1),
    ("top-right", 1, -1),
    ("left", -1, 0),
    ("right", 1, 0),
    ("bottom-left", -1, 1),
    ("bottom", 0, 1),
    ("bottom-right", 1, 1),
)

# Sizes as fractions of m = min(width, height). The outer wheels sit 15 % of the width or height from the
# edges, but at least 0.17 m so that they keep clear of the fiducials on a square page.
_WHEEL_RADIUS = 0.10
_WHEEL_MARGIN = 0.15
_WHEEL_MARGIN_MIN = 0.17
_RING_OFFSET = 0.045  # ring centre from each edge
_RING_RADIUS = 0.025
_RING_HOLE = 0.4  # the white dot's radius, as a fraction of the ring's
_DISC_OFFSET = 0.12  # the orientation disc's centre from the left edge (its y is the top rings')
_DISC_RADIUS = 0.015
_NEAR_EDGE = 0.75  # pixels: beyond half a pixel's diagonal (0.71) an edge cannot cross the pixel


def wheel_segments() -> list[dict[str, Any]]:
    """The six segments of every wheel, as a layout lists them.

    Returns
    -------
    list of dict
        ``{"name", "colour", "start_deg", "end_deg"}`` per segment of :data:`SEGMENTS`, segment ``k`` covering
        ``[60 k, 60 k + 60)`` degrees.

    Examples
    --------
    >>> wheel_segments()[1]
    {'name': 'yellow', 'colour': [1, 1, 0], 'start_deg': 60, 'end_deg': 120}
    """
    return [
        {"name": name, "colour": list(colour), "start_deg": 60 * k, "end_deg": 60 * (k + 1)}
        for k, (name, colour) in enumerate(SEGMENTS)
    ]


def wheel_layout(width: int, height: int) -> dict[str, Any]:
    """The layout of the colour-wheel target on a page, screen or frame of ``width`` x ``height`` pixels.

    Nine wheels of radius ``0.10 m`` (``m = min(width, height)``) at the positions of
    :data:`WHEEL_POSITIONS`: the centre wheel at the middle of the frame, the outer ones ``max(0.15 W,
    0.17 m)`` from the left and right edges and ``max(0.15 H, 0.17 m)`` from the top and bottom; four rings
    of radius ``0.025 m`` (a white dot of 0.4 of that in the middle) centred ``0.045 m`` from the edges at
    the corners; and the orientation disc of radius ``0.015 m``, ``0.12 m`` from the left edge at the
    height of the top rings. :func:`picamcal.target.target_layout` is this layout with a printable
    minimum size.

    Parameters
    ----------
    width, height : int
        Size in pixels (at least one each).

    Returns
    -------
    dict
        JSON-serialisable: ``"width"``, ``"height"``, ``"units"`` (``"pixels"``), ``"segments"``
        (:func:`wheel_segments`), ``"wheels"`` (``name``, ``x``, ``y``, ``radius``) and ``"fiducials"``
        (``name``, ``kind``, ``x``, ``y``, ``radius``, and ``hole_radius`` for rings): four ``"ring"`` marks
        named by their corner and one ``"disc"`` named ``"orientation"``.

    Raises
    ------
    PicamcalError
        A side below one pixel, or more pixels than :func:`picamcal.limits.max_pixels` (a rendering holds a
        few float copies of the target).

    Examples
    --------
    >>> layout = wheel_layout(640, 480)
    >>> layout["wheels"][0], layout["wheels"][1]["name"]
    ({'name': 'centre', 'x': 319.5, 'y': 239.5, 'radius': 48.0}, 'top-left')
    >>> [(f["name"], f["kind"]) for f in layout["fiducials"]][-1]
    ('orientation', 'disc')
    """
    width, height = int(width), int(height)
    if min(width, height) < 1:
        raise PicamcalError(f"a target needs at least one pixel each way, got {width} x {height}")
    limit = max_pixels()
    if width * height > limit:
        raise PicamcalError(
            f"a target of {width}x{height} pixels ({width * height / 1e6:.0f} MP) is over the limit of "
            f"{limit / 1e6:.0f} MP (set {MAX_PIXELS_VARIABLE} to render larger targets)"
        )
    m = min(width, height)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    step_x = width / 2 - max(_WHEEL_MARGIN * width, _WHEEL_MARGIN_MIN * m)
    step_y = height / 2 - max(_WHEEL_MARGIN * height, _WHEEL_MARGIN_MIN * m)
    wheels = [
        {"name": name, "x": _r(cx + col * step_x), "y": _r(cy + row * step_y), "radius": _r(_WHEEL_RADIUS * m)}
        for name, col, row in WHEEL_POSITIONS
    ]
    near, far_x, far_y = _RING_OFFSET * m - 0.5, width - 0.5 - _RING_OFFSET * m, height - 0.5 - _RING_OFFSET * m
    ring = {"kind": "ring", "radius": _r(_RING_RADIUS * m), "hole_radius": _r(_RING_HOLE * _RING_RADIUS * m)}
    fiducials = [
        {"name": "top-left", "x": _r(near), "y": _r(near), **ring},
        {"name": "top-right", "x": _r(far_x), "y": _r(near), **ring},
        {"name": "bottom-left", "x": _r(near), "y": _r(far_y), **ring},
        {"name": "bottom-right", "x": _r(far_x), "y": _r(far_y), **ring},
        {
            "name": "orientation",
            "kind": "disc",
            "x": _r(_DISC_OFFSET * m - 0.5),
            "y": _r(near),
            "radius": _r(_DISC_RADIUS * m),
        },
    ]
    return {
        "width": width,
        "height": height,
        "units": "pixels",
        "segments": wheel_segments(),
        "wheels": wheels,
        "fiducials": fiducials,
    }


def wheel_scene(layout: Mapping[str, Any], supersample: int = 4) -> np.ndarray:
    """Render a target layout in linear light: segments in their colours, fiducials black, on white (1).

    Each pixel an edge may cross averages ``supersample`` x ``supersample`` samples (anti-aliasing), so a
    pixel half covered by red shows half the red light; pixels away from every edge take the colour at
    their centre. The values are amounts of the three primaries: linear sRGB for a screen or print
    (:func:`picamcal.target.render_target` encodes them), LED amounts for the simulator.

    Parameters
    ----------
    layout : mapping
        From :func:`wheel_layout` (or any layout with ``width``, ``height``, ``segments`` with
        ``colour``, ``wheels`` and optionally ``fiducials``).
    supersample : int, default 4
        Samples per pixel along each axis at the edges.

    Returns
    -------
    ndarray of float32, shape (height, width, 3)

    Raises
    ------
    PicamcalError
        If ``supersample`` is below 1 or a segment has no colour.

    Examples
    --------
    >>> scene = wheel_scene(wheel_layout(320, 240))
    >>> scene[115, 170].tolist(), scene[0, 0].tolist()  # a red segment, the white margin
    ([1.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    """
    supersample = int(supersample)
    if supersample < 1:
        raise PicamcalError(f"supersample must be at least 1, got {supersample}")
    width, height = int(layout["width"]), int(layout["height"])
    shapes = _shapes(layout)
    linear = np.ones((height, width, 3), dtype=np.float32)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    for bbox in {shape["bbox"] for shape in shapes}:
        x0, x1 = max(0, bbox[0]), min(width, bbox[1])
        y0, y1 = max(0, bbox[2]), min(height, bbox[3])
        if x0 >= x1 or y0 >= y1:
            continue
        present = [s for s in shapes if _overlaps(s["bbox"], (x0, x1, y0, y1))]
        xs = np.arange(x0, x1, dtype=np.float64)
        ys = np.arange(y0, y1, dtype=np.float64)
        # Sample at pixel centres first; supersample only the pixels where an edge passes.
        centre = _paint(xs[None, :], ys[:, None], present)
        ey, ex = np.nonzero(_near_edge(xs[None, :], ys[:, None], present))
        if ey.size:
            sx = xs[ex][:, None, None] + offsets[None, None, :]
            sy = ys[ey][:, None, None] + offsets[None, :, None]
            centre[ey, ex] = _paint(sx, sy, present).mean(axis=(1, 2))
        linear[y0:y1, x0:x1] = centre
    return linear


def _r(value: float) -> float:
    return round(float(value), 6)


def _shapes(layout: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Wheels and fiducials as drawable shapes, each with its pixel bounding box (x0, x1, y0, y1)."""
    segments = []
    for segment in layout["segments"]:
        if "colour" not in segment:
            raise PicamcalError(f"segment {segment.get('name')!r} of the layout has no colour to render")
        start = float(segment["start_deg"]) % 360.0
        span = (float(segment["end_deg"]) - float(segment["start_deg"])) % 360.0 or 360.0
        segments.append((start, span, np.asarray(segment["colour"], dtype=np.float32)))
    shapes = []
    for wheel in layout["wheels"]:
        shapes.append({"kind": "wheel", "segments": segments, **_circle(wheel)})
    for mark in layout.get("fiducials", []):
        shape = {"kind": str(mark.get("kind", "disc")), "hole": float(mark.get("hole_radius", 0.0)), **_circle(mark)}
        shapes.append(shape)
    return shapes


def _overlaps(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]


def _circle(item: Mapping[str, Any]) -> dict[str, Any]:
    x, y, radius = float(item["x"]), float(item["y"]), float(item["radius"])
    reach = radius + 1.0
    bbox = (math.floor(x - reach), math.ceil(x + reach) + 1, math.floor(y - reach), math.ceil(y + reach) + 1)
    return {"x": x, "y": y, "radius": radius, "bbox": bbox}


def _paint(x: np.ndarray, y: np.ndarray, shapes: list[dict[str, Any]]) -> np.ndarray:
    """Linear RGB of the target at points (x, y) (broadcast together): white, then each shape over it."""
    x, y = np.broadcast_arrays(x, y)
    out = np.ones((*x.shape, 3), dtype=np.float32)
    for shape in shapes:
        dx, dy = x - shape["x"], y - shape["y"]
        rho = np.hypot(dx, dy)
        inside = rho <= shape["radius"]
        if shape["kind"] == "wheel":
            angle = np.degrees(np.arctan2(-dy, dx)) % 360.0
            for start, span, colour in shape["segments"]:
                out[inside & ((angle - start) % 360.0 < span)] = colour
        else:
            out[inside & (rho > shape["hole"])] = 0.0
    return out


def _near_edge(x: np.ndarray, y: np.ndarray, shapes: list[dict[str, Any]]) -> np.ndarray:
    """Pixels centred at (x, y) that an edge (a rim, a segment boundary, a ring's hole) may cross."""
    x, y = np.broadcast_arrays(x, y)
    edge = np.zeros(x.shape, dtype=bool)
    for shape in shapes:
        dx, dy = x - shape["x"], y - shape["y"]
        rho = np.hypot(dx, dy)
        edge |= np.abs(rho - shape["radius"]) < _NEAR_EDGE
        if shape["kind"] == "wheel":
            for start, _, _ in shape["segments"]:
                # Distance to the boundary ray at this angle (on screen, y down): perpendicular where the point
                # projects onto the ray, else the distance to the wheel centre.
                b = math.radians(start)
                along = dx * math.cos(b) - dy * math.sin(b)
                across = np.abs(dx * math.sin(b) + dy * math.cos(b))
                edge |= (np.where(along > 0, across, rho) < _NEAR_EDGE) & (rho < shape["radius"] + _NEAR_EDGE)
        elif shape["hole"] > 0:
            edge |= np.abs(rho - shape["hole"]) < _NEAR_EDGE
    return edge
