"""Find the colour wheels of the test target in a photograph, compare them, and draw the paper's figures.

The paper judges a correction by imaging a target of colour wheels and comparing the wheels away from the
centre of the frame with the centre one (Figure "matrix_correction_wheels_and_polar"): cut-outs of the
wheels (panels a-d) and polar plots of the hue (angle) and saturation (radius) of their six segments,
centre wheel solid, the others dashed (panels e-h). This module finds the wheels in an image
(:func:`find_wheels`), computes the figures of every correction mode (:func:`analyse`, on top of
:func:`picamcal.analysis.metrics.wheel_figures`) and draws both panels (:func:`wheel_crops`, :func:`polar_plot`).

The target is the one of :mod:`picamcal.colour_wheel` (what ``picamcal target`` writes and the simulator
photographs). The work is split by what it does: :mod:`picamcal.analysis.wheel_search` finds wheels by
themselves in the image divided by its own white background (so that vignetting and an unbalanced white do
not matter), :mod:`picamcal.analysis.wheel_fiducials` maps a layout onto the image through its fiducial
marks, this module reads layouts, puts the found wheels together and measures them, and
:mod:`picamcal.analysis.wheel_plots` draws the figures (re-exported here).

Coordinates are pixels of the image with pixel centres at integer coordinates; angles are
``atan2(-(y - cy), x - cx)`` in degrees, counter-clockwise from +x as seen on screen, as in
:mod:`picamcal.analysis.metrics` and :mod:`picamcal.colour_wheel`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._json import Fields, read_json
from ..colour_wheel import CENTRE_WHEEL, wheel_segments
from ..errors import PicamcalError
from .metrics import hue_saturation, segment_colours, wheel_figures
from .wheel_fiducials import map_layout
from .wheel_plots import polar_plot, wheel_crops
from .wheel_search import ReducedImage, as_image, consensus, detect_wheels, name_by_position, wrap_deg

__all__ = ["analyse", "find_wheels", "polar_plot", "read_layout", "wheel_crops"]

_MIN_MARGIN_DEG = 8.0  # metrics.segment_colours' default margin inside each segment's edges
_MAX_MARGIN_DEG = 24.0  # leaves 12 of a segment's 60 degrees to sample

#: Most wheels, segments and fiducial marks a layout may hold (picamcal's targets have 9, 6 and 5).
_MAX_LAYOUT_ITEMS = 64
#: Largest side of a target layout in pixels (a print at 1200 dpi on A3 is under 20000).
_MAX_LAYOUT_SIDE = 100_000


def read_layout(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a target layout (``TARGET.json`` from ``picamcal target``, or a simulated run's ``layout.json``).

    Everything :func:`find_wheels` and :func:`analyse` use is checked: ``width`` and ``height`` positive whole
    numbers; 1 to 64 ``segments``, each with a ``name``, finite ``start_deg`` and ``end_deg`` and optionally an
    sRGB ``colour`` of three numbers in 0..1; 2 to 64 ``wheels`` (one named ``"centre"``), each with a ``name``,
    ``x`` and ``y`` on the target and a positive ``radius``; and, if there are ``fiducials``, four ``"ring"``
    marks and one ``"disc"``, each with ``x``, ``y`` on the target and a positive ``radius`` (a ring's
    ``hole_radius`` smaller than it).

    Raises
    ------
    PicamcalError
        Not a regular file, not UTF-8 JSON, or any value of the wrong type, count or range; one line naming the
        file and the value.

    Examples
    --------
    >>> from picamcal.target import save_target
    >>> _, layout_path = save_target("wheels.png", 640, 360)
    >>> layout = read_layout(layout_path)
    >>> layout["width"], len(layout["wheels"]), len(layout["fiducials"])
    (640, 9, 5)
    """
    layout = read_json(path, PicamcalError, "a target layout")
    fields = Fields(path, PicamcalError, "a target layout", "give the TARGET.json picamcal target wrote")
    fields.mapping(layout, "the file", ("width", "height", "segments", "wheels"))
    width = fields.number(layout["width"], "width", integer=True, minimum=1, maximum=_MAX_LAYOUT_SIDE)
    height = fields.number(layout["height"], "height", integer=True, minimum=1, maximum=_MAX_LAYOUT_SIDE)
    if "units" in layout:
        fields.text(layout["units"], "units", ["pixels"])
    names = set()
    segments = fields.items(layout["segments"], "segments", minimum=1, maximum=_MAX_LAYOUT_ITEMS)
    for i, segment in enumerate(segments):
        where = f"segments[{i}]"
        fields.mapping(segment, where, ("name", "start_deg", "end_deg"))
        names.add(fields.text(segment["name"], f"{where}.name"))
        for key in ("start_deg", "end_deg"):
            fields.number(segment[key], f"{where}.{key}", minimum=-720, maximum=720)
        if "colour" in segment:
            fields.numbers(segment["colour"], f"{where}.colour", 3, minimum=0, maximum=1)
    if len(names) < len(segments):
        fields.fail("segments", "must have different names")
    wheels = fields.items(layout["wheels"], "wheels", minimum=2, maximum=_MAX_LAYOUT_ITEMS)
    names = {
        fields.text(fields.mapping(w, f"wheels[{i}]", ("name",))["name"], f"wheels[{i}].name")
        for i, w in enumerate(wheels)
    }
    if len(names) < len(wheels) or CENTRE_WHEEL not in names:
        fields.fail("wheels", f"must have different names, one of them {CENTRE_WHEEL!r}")
    marks = fields.items(layout.get("fiducials", []), "fiducials", maximum=_MAX_LAYOUT_ITEMS)
    for kind, items in (("wheels", wheels), ("fiducials", marks)):
        for i, item in enumerate(items):
            where = f"{kind}[{i}]"
            fields.mapping(item, where, ("x", "y", "radius"))
            fields.number(item["x"], f"{where}.x", minimum=-0.5, maximum=width - 0.5)
            fields.number(item["y"], f"{where}.y", minimum=-0.5, maximum=height - 0.5)
            radius = fields.number(item["radius"], f"{where}.radius", positive=True, maximum=max(width, height))
            if kind == "fiducials":
                if fields.text(item.get("kind"), f"{where}.kind", ["ring", "disc"]) == "ring":
                    fields.number(item.get("hole_radius", 0), f"{where}.hole_radius", minimum=0, maximum=radius)
                if "name" in item:
                    fields.text(item["name"], f"{where}.name")
    kinds = [m["kind"] for m in marks]
    if marks and (kinds.count("ring"), kinds.count("disc")) != (4, 1):
        fields.fail("fiducials", f"must be 4 rings and 1 disc, not {kinds.count('ring')} and {kinds.count('disc')}")
    return layout


def find_wheels(rgb: ArrayLike, *, layout: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Locate the colour wheels of the test target in an image and return their layout in its pixels.

    Without ``layout`` the wheels are found by themselves: the chroma of the background-normalised image
    (see the module docstring) is thresholded on a reduced copy, and connected, round, filled blobs whose
    hue turns once round the colour circle as one goes round them are wheels. Each is then measured at
    full resolution: its rim is located on 180 rays (where the chroma falls half-way from the segments'
    to the background's) and a circle is fitted to those points (Kasa's algebraic fit, once more without
    outliers). Whether it is mirrored, and roughly how it is turned, come from fitting
    ``hue = ±angle + offset`` to the hue sampled round a circle at 0.55 of its radius; its rotation is
    then measured at the six boundaries between its segments. The wheel nearest the image centre is named
    ``"centre"``, the others by their position relative to it (``"top-left"``, ``"top"``, ``"top-right"``,
    ``"left"``, ``"right"``, ``"bottom-left"``, ``"bottom"``, ``"bottom-right"``; off to a side if more
    than half as far out as the outermost wheel, after undoing any small tilt of the target). The
    segments are the six of :func:`picamcal.colour_wheel.wheel_segments` (red, yellow, green, cyan, blue,
    magenta counter-clockwise from +x, each 60 degrees), identified by their hues
    (:mod:`picamcal.analysis.wheel_search`).

    With a target ``layout`` that has fiducials (:func:`picamcal.colour_wheel.wheel_layout`: ``picamcal
    target``'s ``TARGET.json`` or a simulated run's ``layout.json``), the black marks
    are found (rings with a white dot and the solid orientation disc), matched to the layout's (the
    disc tells which corner is which, and whether the image is mirrored), and the projective transform
    (homography) from the layout to the image is fitted to all of them by least squares (normalised
    DLT). The wheels are mapped through it: centre, radius (mean distance of the mapped rim from the
    mapped centre) and the direction of every segment boundary. Each mapped segment is then checked to
    show the hue of its colour in the layout (:mod:`picamcal.analysis.wheel_fiducials`). A layout without
    fiducials (with the same six segments) names the wheels found in the image after the nearest of its
    own, scaled to the image.

    Parameters
    ----------
    rgb : array_like, shape (h, w, 3)
        Linear RGB image of the target at full resolution (demosaiced), uncorrected (with vignetting,
        and with or without white balance) or corrected.
    layout : mapping, optional
        The target's layout.

    Returns
    -------
    dict
        JSON-serialisable layout in the image's pixels (usable by :func:`picamcal.analysis.metrics.wheel_figures`):
        ``"width"``, ``"height"``, ``"units"`` (``"pixels"``), ``"segments"`` (``name``, ``colour``,
        ``start_deg``, ``end_deg``, turned by the wheels' mean rotation), ``"wheels"`` (``name``,
        ``x``, ``y``, ``radius``, ``rotation_deg``, ``mirrored`` and the wheel's own ``segments``), and
        ``"method"`` (``"detected"``, ``"fiducials"`` or ``"layout-names"``). ``rotation_deg`` is the
        counter-clockwise angle by which the wheel is turned from the layout's segment angles (after
        mirroring top to bottom, if ``mirrored``). With fiducials also ``"fiducials"`` (as found:
        ``name``, ``kind``, ``x``, ``y``, ``radius``), ``"homography"`` (3 x 3, layout to image) and
        ``"fit_rms_px"`` (the marks' residual).

    Raises
    ------
    PicamcalError
        ``"no colour wheels found in the image"``; ``"... the layout does not match the image"`` when
        its fiducials are not found, the fit is poor, or the mapped wheels do not show their segments;
        or a malformed image.

    Examples
    --------
    >>> from picamcal.colour_wheel import wheel_layout, wheel_scene
    >>> layout = wheel_layout(320, 240)
    >>> found = find_wheels(wheel_scene(layout))
    >>> [w["name"] for w in found["wheels"]]
    ['centre', 'top-left', 'top', 'top-right', 'left', 'right', 'bottom-left', 'bottom', 'bottom-right']
    >>> round(found["wheels"][0]["x"], 1), round(found["wheels"][0]["radius"], 1)
    (159.5, 24.0)
    >>> find_wheels(wheel_scene(layout), layout=layout)["method"]  # through the fiducial marks
    'fiducials'
    """
    image = as_image(rgb)
    reduced = ReducedImage(image)
    if layout is not None and layout.get("fiducials"):
        mapped, marks = map_layout(image, reduced, layout)
        return {**_assemble(image, mapped, [dict(s) for s in layout["segments"]], method="fiducials"), **marks}
    wheels = detect_wheels(image, reduced)
    if layout is not None:
        return _name_from_layout(image, wheels, layout)
    return _assemble(image, name_by_position(image, wheels), wheel_segments(), method="detected")


def analyse(images_by_mode: Mapping[str, ArrayLike], layout: Mapping[str, Any]) -> dict[str, Any]:
    """Compare the wheels of each correction mode's image with its centre wheel, for tables and plots.

    For each mode, the figures of :func:`picamcal.analysis.metrics.wheel_figures` (CIEDE2000 of every segment
    against the same segment of the centre wheel, hue shift, saturation ratio) and the colours behind
    them: each wheel's segment colours (linear RGB, the medians of
    :func:`picamcal.analysis.metrics.segment_colours`) and their CIE hue angle and saturation
    (:func:`picamcal.analysis.metrics.hue_saturation`). Segments are sampled 8 degrees inside their edges, plus
    however far the wheels' own segment angles (from :func:`find_wheels`) stray from the layout's
    common ones (at most 24 degrees in all).

    Parameters
    ----------
    images_by_mode : mapping of str to array_like, shape (h, w, 3)
        Linear RGB images of the target, one per mode (``"uncorrected"``, ``"flat"``, ``"centre"``,
        ``"pure"``, or any names), all of the layout's size.
    layout : mapping
        Wheels in the images' pixels, from :func:`find_wheels` (or the simulator's layout); it needs a
        wheel named ``"centre"``.

    Returns
    -------
    dict
        JSON-serialisable (NaN where a ratio is undefined), keyed by mode; each value holds ``"mode"``,
        ``"segments"`` (``name``, ``colour``), ``"wheels"`` (for every wheel including the centre:
        ``x``, ``y``, ``radius``, ``colours`` (6 x 3), ``hue_deg``, ``saturation``), ``"figures"``
        (:func:`~picamcal.analysis.metrics.wheel_figures`' per-wheel dict) and ``"summary"`` (``max_delta_e`` and
        ``mean_delta_e`` over the segments of the wheels other than the centre, ``mean_saturation_ratio``,
        ``mean_abs_hue_shift_deg``).

    Raises
    ------
    PicamcalError
        If there are no images, an image does not fit the layout, or as
        :func:`~picamcal.analysis.metrics.wheel_figures`.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_target, wheel_scene
    >>> _, layout = simulate_target(make_camera("imx219", size=(320, 240)), noise=False)
    >>> result = analyse({"ideal": wheel_scene(layout)}, layout)
    >>> result["ideal"]["summary"]["max_delta_e"]
    0.0
    >>> np.round(result["ideal"]["wheels"]["centre"]["hue_deg"][:2]).tolist()  # red, yellow
    [40.0, 103.0]
    """
    if not images_by_mode:
        raise PicamcalError("no images to analyse")
    margin = min(_MIN_MARGIN_DEG + _segment_spread(layout), _MAX_MARGIN_DEG)
    segments = [
        {"name": str(s["name"]), "colour": [float(c) for c in s.get("colour", (0.5, 0.5, 0.5))]}
        for s in layout["segments"]
    ]
    result: dict[str, Any] = {}
    for mode, rgb in images_by_mode.items():
        image = as_image(rgb)
        if (image.shape[1], image.shape[0]) != (int(layout["width"]), int(layout["height"])):
            raise PicamcalError(
                f"the {mode!r} image is {image.shape[1]} x {image.shape[0]} pixels but the layout is "
                f"{layout['width']} x {layout['height']}"
            )
        colours = segment_colours(image, layout, margin_deg=margin)
        figures = wheel_figures(image, layout, margin_deg=margin)
        wheels = {}
        for wheel in layout["wheels"]:
            name = str(wheel["name"])
            hue, saturation = hue_saturation(colours[name])
            wheels[name] = {
                "x": float(wheel["x"]),
                "y": float(wheel["y"]),
                "radius": float(wheel["radius"]),
                "colours": colours[name].tolist(),
                "hue_deg": hue.tolist(),
                "saturation": saturation.tolist(),
            }
        hue_shifts = [abs(h) for w in figures["wheels"].values() for h in w["hue_shift_deg"]]
        result[str(mode)] = {
            "mode": str(mode),
            "segments": segments,
            "wheels": wheels,
            "figures": figures["wheels"],
            "summary": {
                "max_delta_e": figures["max_delta_e"],
                "mean_delta_e": figures["mean_delta_e"],
                "mean_saturation_ratio": figures["mean_saturation_ratio"],
                "mean_abs_hue_shift_deg": float(np.mean(hue_shifts)),
            },
        }
    return result


def _name_from_layout(image: np.ndarray, wheels: list[dict[str, Any]], layout: Mapping[str, Any]) -> dict[str, Any]:
    """Name the detected wheels after the nearest wheel of a layout without fiducials, scaled to the image."""
    h, w = image.shape[:2]
    sx, sy = w / float(layout["width"]), h / float(layout["height"])
    named = []
    for expected in layout["wheels"]:
        ex, ey = (float(expected["x"]) + 0.5) * sx - 0.5, (float(expected["y"]) + 0.5) * sy - 0.5
        er = float(expected["radius"]) * math.sqrt(sx * sy)
        nearest = min(wheels, key=lambda wh: math.hypot(wh["x"] - ex, wh["y"] - ey))
        if math.hypot(nearest["x"] - ex, nearest["y"] - ey) > 0.5 * er or not 0.7 < nearest["radius"] / er < 1.3:
            raise PicamcalError(
                f"wheel {expected['name']!r} is not where the layout puts it: the layout does not match the image"
            )
        named.append({**nearest, "name": str(expected["name"])})
    return _assemble(image, named, [dict(s) for s in layout["segments"]], method="layout-names")


def _assemble(
    image: np.ndarray, wheels: list[dict[str, Any]], segments: list[dict[str, Any]], *, method: str
) -> dict[str, Any]:
    """The layout dict: per-wheel segments, and common segments turned by the wheels' consensus rotation."""
    rotation, mirrored = consensus(wheels)
    out_wheels = []
    for wheel in wheels:
        own = wheel.get("segments") or _turned_segments(segments, wheel["rotation_deg"], wheel["mirrored"])
        out_wheels.append(
            {
                "name": wheel["name"],
                "x": round(float(wheel["x"]), 4),
                "y": round(float(wheel["y"]), 4),
                "radius": round(float(wheel["radius"]), 4),
                "rotation_deg": round(float(wheel["rotation_deg"]), 3),
                "mirrored": bool(wheel["mirrored"]),
                "segments": [{k: s[k] for k in ("name", "start_deg", "end_deg")} for s in own],
            }
        )
    return {
        "width": int(image.shape[1]),
        "height": int(image.shape[0]),
        "units": "pixels",
        "method": method,
        "segments": _turned_segments(segments, rotation, mirrored),
        "wheels": out_wheels,
    }


def _segment_spread(layout: Mapping[str, Any]) -> float:
    """Largest angle by which a wheel's own segment edges stray from the layout's common ones, in degrees."""
    common = {str(s["name"]): float(s["start_deg"]) for s in layout["segments"]}
    common_end = {str(s["name"]): float(s["end_deg"]) for s in layout["segments"]}
    spread = 0.0
    for wheel in layout["wheels"]:
        for own in wheel.get("segments", []):
            name = str(own["name"])
            if name in common:
                for a, b in ((own["start_deg"], common[name]), (own["end_deg"], common_end[name])):
                    spread = max(spread, abs(wrap_deg(float(a) - b)))
    return spread


def _turned_segments(segments: list[dict[str, Any]], rotation: float, mirrored: bool) -> list[dict[str, Any]]:
    """Segments mirrored top to bottom (if ``mirrored``) and then turned counter-clockwise by ``rotation``."""
    turned = []
    for segment in segments:
        start, end = float(segment["start_deg"]), float(segment["end_deg"])
        if mirrored:
            start, end = -end, -start
        span = (end - start) % 360.0 or 360.0
        start = (start + rotation) % 360.0
        end = start + span
        turned.append({**segment, "start_deg": round(start, 4), "end_deg": round(end, 4)})
    return turned
