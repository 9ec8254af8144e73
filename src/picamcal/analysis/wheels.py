"""Find the colour wheels of the test target in a photograph, compare them, and draw the paper's figures.

The paper judges a correction by imaging a target of colour wheels and comparing the wheels away from the
centre of the frame with the centre one (Figure "matrix_correction_wheels_and_polar"): cut-outs of the
wheels (panels a-d) and polar plots of the hue (angle) and saturation (radius) of their six segments,
centre wheel solid, the others dashed (panels e-h). This module finds the wheels in an image
(:func:`find_wheels`), computes the figures of every correction mode (:func:`analyse`, on top of
:func:`picamcal.analysis.metrics.wheel_figures`) and draws both panels (:func:`wheel_crops`, :func:`polar_plot`).

Finding the wheels must work on the uncorrected image, whose corners are darker and less saturated than
its centre, and whose white need not even be balanced. Everything here therefore works on the image
divided by its own white background, ``n = rgb / background``: the background is the upper envelope of
each channel (a grey-scale morphological closing wider than a wheel, on a reduced copy of the image),
since on this target every colour is at most as bright as the white paper or screen around it in every
channel. ``n`` is about (1, 1, 1) on the white whatever the vignetting; a segment has at least one channel
near 1 and one well below it (less so in uncorrected corners), so its chroma ``max(n) - min(n)`` stands
out, and a black fiducial mark has ``max(n)`` near 0.

Coordinates are pixels of the image with pixel centres at integer coordinates; angles are
``atan2(-(y - cy), x - cx)`` in degrees, counter-clockwise from +x as seen on screen, as in
:mod:`picamcal.analysis.metrics` and :mod:`picamcal.target`.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

from .._atomic import atomic_path
from .._json import Fields, read_json
from ..colour_wheel import SEGMENTS
from ..errors import PicamcalError
from .metrics import encode_srgb, hue_saturation, segment_colours, wheel_figures

__all__ = ["analyse", "find_wheels", "polar_plot", "read_layout", "wheel_crops"]

_POSITION_NAMES = {
    (-1, -1): "top-left",
    (0, -1): "top",
    (1, -1): "top-right",
    (-1, 0): "left",
    (0, 0): "middle",
    (1, 0): "right",
    (-1, 1): "bottom-left",
    (0, 1): "bottom",
    (1, 1): "bottom-right",
}
_REFERENCE_WHEEL = "centre"

_DETECT_SIZE = 800  # long side of the reduced image the search runs on, in pixels
_BACKGROUND_SIZE = 160  # long side of the grid the white background is estimated on
_CLOSING_FRACTION = 0.35  # closing element, of the grid's short side: wider than a wheel of radius 0.15
_CHROMA_THRESHOLD = 0.2  # of max(n) - min(n): white is ~0.05 with noise, the palest corner segment ~0.45
_DARK_THRESHOLD = 0.5  # of 1 - max(n): black marks are ~1, the darkest segment (blue) ~0.3 in a corner
_MIN_WHEEL_RADIUS = 4.0  # in pixels of the reduced image
_MIN_MARK_RADIUS = 1.5
_MAX_ELONGATION = 1.35  # ratio of the principal axes of a wheel or mark in the image
_MIN_HUE_ORDER = 0.6  # resultant length of the hue-versus-angle fit that makes a blob a wheel
_RAYS = 180  # rays from the centre on which each wheel's rim is located
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
    >>> import tempfile
    >>> from picamcal.target import save_target
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     _, layout_path = save_target(Path(folder) / "wheels.png", 640, 360)
    ...     layout = read_layout(layout_path)
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
    if len(names) < len(wheels) or _REFERENCE_WHEEL not in names:
        fields.fail("wheels", f"must have different names, one of them {_REFERENCE_WHEEL!r}")
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
    segments are the six of :func:`picamcal.target.target_layout` (red, yellow, green, cyan, blue,
    magenta counter-clockwise from +x, each 60 degrees), identified by their hues.

    With a target ``layout`` that has fiducials (:func:`picamcal.target.target_layout`), the black marks
    are found (rings with a white dot and the solid orientation disc), matched to the layout's (the
    disc tells which corner is which, and whether the image is mirrored), and the projective transform
    (homography) from the layout to the image is fitted to all of them by least squares (normalised
    DLT). The wheels are mapped through it: centre, radius (mean distance of the mapped rim from the
    mapped centre) and the direction of every segment boundary. Each mapped segment is then checked to
    show the hue of its colour in the layout. A layout without fiducials (the simulator's
    ``layout.json``, with the same six segments) names the wheels found in the image after the nearest
    of its own, scaled to the image.

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
    >>> from picamcal.simulate import make_camera, simulate_target, wheel_scene
    >>> raw, truth = simulate_target(make_camera("imx219", size=(320, 240)), noise=False)
    >>> found = find_wheels(wheel_scene(truth))
    >>> [w["name"] for w in found["wheels"]]
    ['centre', 'top-left', 'top-right', 'bottom-left', 'bottom-right']
    >>> round(found["wheels"][0]["x"], 1), round(found["wheels"][0]["radius"], 1)
    (159.5, 26.4)
    """
    image = _as_image(rgb)
    reduced = _Reduced(image)
    if layout is not None and layout.get("fiducials"):
        return _find_by_fiducials(image, reduced, layout)
    wheels = _detect_wheels(image, reduced)
    if layout is not None:
        return _name_from_layout(image, wheels, layout)
    return _assemble(image, _name_by_position(image, wheels), _default_segments(), method="detected")


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
        Linear RGB images of the target, one per mode (``"balance"``, ``"flat"``, ``"centre"``,
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
        image = _as_image(rgb)
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


def polar_plot(
    analysis_for_one_mode: Mapping[str, Any], path: str | os.PathLike[str], *, title: str | None = None
) -> Path:
    """Draw the paper's polar plot of the segments' hue (angle) and saturation (radius), one line per wheel.

    As the paper's Figure "matrix_correction_wheels_and_polar" (e-h): each wheel's six segments joined in
    a closed loop, the centre wheel a solid black line and the others dashed (one colour per wheel),
    markers filled with each segment's colour. Where the correction works, the loops lie on top of each
    other; desaturated corners show as loops shrunk towards the origin.

    Parameters
    ----------
    analysis_for_one_mode : mapping
        One mode's entry of :func:`analyse` (``"segments"``, ``"wheels"`` with ``hue_deg`` and
        ``saturation``).
    path : path-like
        The PNG to write (atomically; replaced if it exists).
    title : str, optional
        Drawn above the plot; default the mode.

    Returns
    -------
    Path

    Examples
    --------
    >>> import tempfile
    >>> from PIL import Image
    >>> from picamcal.simulate import make_camera, simulate_target, wheel_scene
    >>> _, layout = simulate_target(make_camera("imx219", size=(320, 240)), noise=False)
    >>> result = analyse({"ideal": wheel_scene(layout)}, layout)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     Image.open(polar_plot(result["ideal"], Path(folder) / "polar.png")).format
    'PNG'
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    segments = list(analysis_for_one_mode["segments"])
    wheels = dict(analysis_for_one_mode["wheels"])
    if not wheels:
        raise PicamcalError("the analysis has no wheels to plot")
    names = sorted(wheels, key=lambda n: (n != _REFERENCE_WHEEL, list(wheels).index(n)))
    marker_colours = [_display_colour(s.get("colour")) for s in segments]
    figure = Figure(figsize=(6.4, 5.6), dpi=120, layout="constrained")
    axes = figure.add_subplot(projection="polar")
    cycle = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive"]
    handles = []
    for index, name in enumerate(names):
        hue = np.radians(np.asarray(wheels[name]["hue_deg"], dtype=float))
        saturation = np.asarray(wheels[name]["saturation"], dtype=float)
        centre = name == _REFERENCE_WHEEL
        colour = "black" if centre else cycle[(index - 1) % len(cycle)]
        style = "-" if centre else "--"
        axes.plot(np.append(hue, hue[:1]), np.append(saturation, saturation[:1]), style, color=colour, lw=1.4)
        axes.scatter(hue, saturation, c=marker_colours, s=46 if centre else 30, edgecolors=colour, zorder=3)
        handles.append(Line2D([], [], color=colour, ls=style, lw=1.4, label=name))
    handles += [
        Line2D([], [], ls="", marker="o", color=c, markeredgecolor="grey", label=s["name"])
        for s, c in zip(segments, marker_colours, strict=True)
    ]
    axes.set_rlabel_position(67.5)
    axes.tick_params(axis="y", labelsize=8, labelcolor="grey")
    axes.set_title(title if title is not None else str(analysis_for_one_mode.get("mode", "")), pad=14)
    axes.set_xlabel("angle: CIE hue $h_{ab}$ (degrees); radius: saturation $C^*_{ab} / L^*$", fontsize=9)
    figure.legend(handles=handles, loc="outside right center", fontsize=8, frameon=False)
    return _save_figure(figure, path)


def wheel_crops(rgb: ArrayLike, layout: Mapping[str, Any], path: str | os.PathLike[str]) -> Path:
    """Draw the wheels cut out of an image side by side, sRGB-encoded, as the paper's panels (a-d).

    Each panel is the square of 2.4 radii around a wheel (white where it runs off the image), the
    centre wheel first, labelled with a letter and the wheel's name.

    Parameters
    ----------
    rgb : array_like, shape (h, w, 3)
        Linear RGB image (white at 1), of the layout's pixels.
    layout : mapping
        Wheels in the image's pixels (:func:`find_wheels`).
    path : path-like
        The PNG to write (atomically; replaced if it exists).

    Returns
    -------
    Path

    Examples
    --------
    >>> import tempfile
    >>> from PIL import Image
    >>> from picamcal.simulate import make_camera, simulate_target, wheel_scene
    >>> _, layout = simulate_target(make_camera("imx219", size=(320, 240)), noise=False)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     Image.open(wheel_crops(wheel_scene(layout), layout, Path(folder) / "wheels.png")).format
    'PNG'
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    image = _as_image(rgb)
    wheels = sorted(layout["wheels"], key=lambda w: w["name"] != _REFERENCE_WHEEL)
    if not wheels:
        raise PicamcalError("the layout has no wheels to cut out")
    columns = min(len(wheels), 5)
    rows = math.ceil(len(wheels) / columns)
    figure = Figure(figsize=(2.2 * columns, 2.45 * rows), dpi=120, layout="constrained")
    for index, wheel in enumerate(wheels):
        axes = figure.add_subplot(rows, columns, index + 1)
        axes.imshow(encode_srgb(_crop(image, float(wheel["x"]), float(wheel["y"]), 1.2 * float(wheel["radius"]))))
        axes.set_title(f"({chr(ord('a') + index)}) {wheel['name']}", fontsize=9)
        axes.set_axis_off()
    return _save_figure(figure, path)


# --- the image and its background -------------------------------------------------------------------------


def _as_image(rgb: ArrayLike) -> np.ndarray:
    image = np.asarray(rgb)
    if image.ndim != 3 or image.shape[2] != 3 or min(image.shape[:2]) < 16:
        raise PicamcalError(f"expected an (h, w, 3) RGB image at least 16 pixels wide, got shape {image.shape}")
    if image.dtype != np.float32:
        image = image.astype(np.float32)
    return image


def _block_mean(image: np.ndarray, factor: int) -> np.ndarray:
    """Means over ``factor`` x ``factor`` blocks from the top-left; a partial last block is dropped."""
    if factor == 1:
        return image.astype(np.float32)
    h, w = image.shape[0] // factor, image.shape[1] // factor
    # Strided sums are several times faster than a reshaped mean over two axes of a 12-megapixel image.
    rows = image[0 : h * factor : factor, : w * factor].astype(np.float32)
    for i in range(1, factor):
        rows += image[i : h * factor : factor, : w * factor]
    blocks = rows[:, 0::factor].copy()
    for i in range(1, factor):
        blocks += rows[:, i::factor]
    return blocks / np.float32(factor * factor)


class _Reduced:
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


def _chroma(normalised: np.ndarray) -> np.ndarray:
    r, g, b = normalised[..., 0], normalised[..., 1], normalised[..., 2]
    return np.maximum(np.maximum(r, g), b) - np.minimum(np.minimum(r, g), b)


def _hex_hue(normalised: np.ndarray) -> np.ndarray:
    """Hue angle in degrees on the RGB colour hexagon: red 0, yellow 60, green 120, ..., magenta 300."""
    r, g, b = normalised[..., 0], normalised[..., 1], normalised[..., 2]
    return np.degrees(np.arctan2(math.sqrt(3.0) * (g - b), 2.0 * r - g - b)) % 360.0


# --- wheels without a layout ----------------------------------------------------------------------------


def _detect_wheels(image: np.ndarray, reduced: _Reduced) -> list[dict[str, Any]]:
    """Every colour wheel in the image, measured at full resolution: x, y, radius, mirrored, rotation."""
    chroma = ndimage.gaussian_filter(_chroma(reduced.normalised_reduced()), 0.7)
    wheels = []
    for blob in _round_blobs(chroma > _CHROMA_THRESHOLD, _MIN_WHEEL_RADIUS):
        x, y, radius = reduced.to_full(blob["x"]), reduced.to_full(blob["y"]), blob["radius"] * reduced.factor
        wheel = _measure_wheel(image, reduced, x, y, radius)
        if wheel is not None:
            wheels.append(wheel)
    if not wheels:
        raise PicamcalError("no colour wheels found in the image")
    return wheels


def _round_blobs(mask: np.ndarray, min_radius: float) -> list[dict[str, float]]:
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


def _window(shape: tuple[int, ...], x: float, y: float, reach: float) -> tuple[int, int, int, int]:
    y0, y1 = max(0, math.floor(y - reach)), min(shape[0], math.ceil(y + reach) + 1)
    x0, x1 = max(0, math.floor(x - reach)), min(shape[1], math.ceil(x + reach) + 1)
    return y0, y1, x0, x1


def _measure_wheel(image: np.ndarray, reduced: _Reduced, x: float, y: float, radius: float) -> dict[str, Any] | None:
    """Centre, radius and orientation of the wheel roughly at (x, y, radius), or None if it is not a wheel.

    Wheels more than 120 pixels in radius are measured on block means of the image (at most 240 pixels
    across the wheel), which loses no accuracy that matters at that size and saves time on 12-megapixel
    frames; the colours are smoothed a little (Gaussian, 0.8 pixel) against noise.
    """
    step = max(1, int(radius // 120))
    y0, y1, x0, x1 = _window(image.shape, x, y, 1.5 * radius + 3 * step)
    normalised = ndimage.gaussian_filter(reduced.normalised(image, y0, y1, x0, x1, step), (0.8, 0.8, 0))
    chroma = _chroma(normalised)
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
    for k in np.flatnonzero(inside - outside > 0.5 * _CHROMA_THRESHOLD):
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
    hue, weight = np.radians(_hex_hue(samples)), _chroma(samples)
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
    return _wrap(rotation), sign == -1


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


def _wrap(angle: float) -> float:
    """An angle in degrees in [-180, 180)."""
    return float((angle + 180.0) % 360.0 - 180.0)


def _default_segments() -> list[dict[str, Any]]:
    return [
        {"name": name, "colour": list(colour), "start_deg": 60 * k, "end_deg": 60 * (k + 1)}
        for k, (name, colour) in enumerate(SEGMENTS)
    ]


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


def _name_by_position(image: np.ndarray, wheels: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Name the wheel nearest the image centre ``"centre"`` and the others by where they lie from it."""
    h, w = image.shape[:2]
    centre = min(wheels, key=lambda wh: math.hypot(wh["x"] - (w - 1) / 2, wh["y"] - (h - 1) / 2))
    # Undo the target's tilt in the image (its rotation modulo 90 degrees), but not a turn by a multiple of
    # 90 degrees or a mirroring: names say where a wheel is in the image.
    tilt = math.radians((_consensus(wheels)[0] + 45.0) % 90.0 - 45.0)
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
            named.append((0, 0.0, {**wheel, "name": _REFERENCE_WHEEL}))
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
    rotation, mirrored = _consensus(wheels)
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


def _consensus(wheels: list[dict[str, Any]]) -> tuple[float, bool]:
    """The wheels' common rotation and mirroring: the majority's mirroring and its mean rotation."""
    mirrored = sum(w["mirrored"] for w in wheels) * 2 > len(wheels)
    agreeing = [w["rotation_deg"] for w in wheels if w["mirrored"] == mirrored]
    return _wrap(math.degrees(np.angle(np.mean(np.exp(1j * np.radians(agreeing)))))), mirrored


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
                    spread = max(spread, abs(_wrap(float(a) - b)))
    return spread


# --- wheels through the fiducials of a target layout ----------------------------------------------------


def _find_by_fiducials(image: np.ndarray, reduced: _Reduced, layout: Mapping[str, Any]) -> dict[str, Any]:
    """Fit the homography from the layout's fiducial marks to the image's, and map the wheels through it."""
    mismatch = "the layout does not match the image"
    marks = [dict(m) for m in layout["fiducials"]]
    rings_l = [m for m in marks if m.get("kind") == "ring"]
    discs_l = [m for m in marks if m.get("kind") != "ring"]
    if len(rings_l) != 4 or len(discs_l) != 1:
        raise PicamcalError(f"the layout's fiducials must be 4 rings and 1 disc, got {len(rings_l)} and {len(discs_l)}")
    found = _find_marks(image, reduced)
    rings = sorted((m for m in found if m["hole"] > 0.05), key=lambda m: -m["radius"])[:8]
    discs = sorted((m for m in found if m["hole"] <= 0.05), key=lambda m: -m["radius"])[:6]
    if len(rings) < 4 or not discs:
        raise PicamcalError(
            f"found {len(rings)} ring and {len(discs)} disc fiducial marks, not the layout's 4 and 1: {mismatch}"
        )
    layout_points = np.array([[m["x"], m["y"]] for m in (*_cyclic(rings_l), discs_l[0])], dtype=np.float64)
    best = None
    for four in itertools.combinations(rings, 4):
        ordered = _cyclic(list(four))
        ring_radius = float(np.mean([m["radius"] for m in ordered]))
        for shift, step in itertools.product(range(4), (1, -1)):
            assigned = [ordered[(shift + step * k) % 4] for k in range(4)]
            src = layout_points[:4]
            dst = np.array([[m["x"], m["y"]] for m in assigned])
            homography = _fit_homography(src, dst)
            if homography is None:
                continue
            predicted = _apply_homography(homography, layout_points[4:])[0]
            for disc in discs:
                error = math.hypot(predicted[0] - disc["x"], predicted[1] - disc["y"]) / ring_radius
                if best is None or error < best[0]:
                    best = (error, assigned, disc)
    if best is None or best[0] > 0.5:
        raise PicamcalError(f"the fiducial marks do not fall where the layout puts them: {mismatch}")
    _, assigned, disc = best
    image_points = np.array([[m["x"], m["y"]] for m in (*assigned, disc)], dtype=np.float64)
    homography = _fit_homography(layout_points, image_points)
    if homography is None:
        raise PicamcalError(f"the fiducial marks are degenerate: {mismatch}")
    residual = np.hypot(*(_apply_homography(homography, layout_points) - image_points).T)
    ring_radius = float(np.mean([m["radius"] for m in assigned]))
    if residual.max() > 0.25 * ring_radius + 1.0:
        raise PicamcalError(
            f"the fiducial marks fit a projective transform only to {residual.max():.1f} pixels: {mismatch}"
        )
    wheels = [_map_wheel(homography, wheel, layout["segments"]) for wheel in layout["wheels"]]
    _check_wheels(image, reduced, wheels, layout["segments"], mismatch)
    result = _assemble(image, wheels, [dict(s) for s in layout["segments"]], method="fiducials")
    names = [m.get("name", m["kind"]) for m in (*_cyclic(rings_l), discs_l[0])]
    result["fiducials"] = [
        {"name": str(name), "kind": kind, "x": round(m["x"], 4), "y": round(m["y"], 4), "radius": round(m["radius"], 4)}
        for name, kind, m in zip(names, ["ring"] * 4 + ["disc"], (*assigned, disc), strict=True)
    ]
    result["homography"] = (homography / homography[2, 2]).tolist()
    result["fit_rms_px"] = float(np.sqrt(np.mean(residual**2)))
    return result


def _find_marks(image: np.ndarray, reduced: _Reduced) -> list[dict[str, float]]:
    """Dark round marks: centre (darkness-weighted, at full resolution), radius and hole fraction."""
    darkness = 1.0 - reduced.normalised_reduced().max(axis=-1)
    marks = []
    for blob in _round_blobs(darkness > _DARK_THRESHOLD, _MIN_MARK_RADIUS):
        x, y, radius = reduced.to_full(blob["x"]), reduced.to_full(blob["y"]), blob["radius"] * reduced.factor
        y0, y1, x0, x1 = _window(image.shape, x, y, 1.6 * radius + 3)
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


def _cyclic(marks: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Marks ordered by angle round their centroid (counter-clockwise on screen)."""
    cx = float(np.mean([m["x"] for m in marks]))
    cy = float(np.mean([m["y"] for m in marks]))
    return sorted(marks, key=lambda m: math.atan2(-(float(m["y"]) - cy), float(m["x"]) - cx))


def _fit_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
    """The 3 x 3 H with dst ~ H src (homogeneous), by the normalised direct linear transform (Hartley)."""

    def normaliser(points: np.ndarray) -> np.ndarray:
        centre = points.mean(axis=0)
        scale = math.sqrt(2.0) / max(float(np.mean(np.hypot(*(points - centre).T))), 1e-12)
        return np.array([[scale, 0, -scale * centre[0]], [0, scale, -scale * centre[1]], [0, 0, 1]])

    ts, td = normaliser(src), normaliser(dst)
    s = _apply_homography(ts, src)
    d = _apply_homography(td, dst)
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


def _apply_homography(h: np.ndarray, points: np.ndarray) -> np.ndarray:
    p = np.column_stack([points, np.ones(len(points))]) @ np.asarray(h).T
    return p[:, :2] / p[:, 2:]


def _map_wheel(h: np.ndarray, wheel: Mapping[str, Any], segments: list[Mapping[str, Any]]) -> dict[str, Any]:
    """A layout wheel mapped into the image: centre, mean radius, and each segment boundary's direction."""
    x, y, r = float(wheel["x"]), float(wheel["y"]), float(wheel["radius"])
    (cx, cy), *_ = _apply_homography(h, np.array([[x, y]]))

    def direction(angle_deg: float, rho: float) -> np.ndarray:
        a = math.radians(angle_deg)
        return _apply_homography(h, np.array([[x + rho * math.cos(a), y - rho * math.sin(a)]]))[0]

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
        "rotation_deg": _wrap(image_angle(0.0)),
        "segments": own,
    }


def _check_wheels(
    image: np.ndarray,
    reduced: _Reduced,
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
            y0, y1, x0, x1 = _window(image.shape, px, py, half)
            colour = reduced.normalised(image, y0, y1, x0, x1).reshape(-1, 3).mean(axis=0)
            expected = np.asarray(segment.get("colour", (0, 0, 0)), dtype=np.float64)
            if _chroma(expected) == 0:
                wrong += _chroma(colour) > _CHROMA_THRESHOLD
                continue
            off = abs(_wrap(float(_hex_hue(colour)) - float(_hex_hue(expected))))
            wrong += _chroma(colour) < 0.5 * _CHROMA_THRESHOLD or off > 40.0
        if wrong:
            raise PicamcalError(
                f"{wrong} segment(s) of wheel {wheel['name']!r} do not show their colour where the layout puts them: "
                f"{mismatch}"
            )


# --- drawing --------------------------------------------------------------------------------------------


def _display_colour(colour: Any) -> tuple[float, float, float]:
    if colour is None:
        return (0.5, 0.5, 0.5)
    values = np.clip(np.asarray(colour, dtype=float)[:3], 0.0, 1.0)
    return (float(values[0]), float(values[1]), float(values[2]))


def _crop(image: np.ndarray, x: float, y: float, half: float) -> np.ndarray:
    """The square of ``2 half`` around (x, y), white beyond the image."""
    size = max(1, round(2 * half))
    x0, y0 = round(x - half), round(y - half)
    out = np.ones((size, size, 3), dtype=np.float32)
    sy0, sy1 = max(0, y0), min(image.shape[0], y0 + size)
    sx0, sx1 = max(0, x0), min(image.shape[1], x0 + size)
    if sy0 < sy1 and sx0 < sx1:
        out[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = image[sy0:sy1, sx0:sx1]
    return out


def _save_figure(figure: Any, path: str | os.PathLike[str]) -> Path:
    target = Path(path)
    with atomic_path(target) as tmp:
        figure.savefig(tmp, format="png")
    return target
