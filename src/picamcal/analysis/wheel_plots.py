"""The paper's figures of a wheel analysis: polar plots of hue and saturation, and cut-outs of the wheels.

As the paper's Figure "matrix_correction_wheels_and_polar": cut-outs of the wheels (panels a-d,
:func:`wheel_crops`) and polar plots of the hue (angle) and saturation (radius) of their six segments,
centre wheel solid, the others dashed (panels e-h, :func:`polar_plot`), from
:func:`picamcal.analysis.wheels.analyse`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike

from .._atomic import atomic_path
from ..colour_wheel import CENTRE_WHEEL
from ..errors import PicamcalError
from .metrics import encode_srgb
from .wheel_search import as_image

__all__ = ["polar_plot", "wheel_crops"]


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
    >>> from PIL import Image
    >>> from picamcal.analysis.wheels import analyse
    >>> from picamcal.colour_wheel import wheel_layout, wheel_scene
    >>> layout = wheel_layout(320, 240)
    >>> result = analyse({"ideal": wheel_scene(layout)}, layout)
    >>> Image.open(polar_plot(result["ideal"], "polar.png")).format
    'PNG'
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.projections.polar import PolarAxes

    segments = list(analysis_for_one_mode["segments"])
    wheels = dict(analysis_for_one_mode["wheels"])
    if not wheels:
        raise PicamcalError("the analysis has no wheels to plot")
    names = sorted(wheels, key=lambda n: (n != CENTRE_WHEEL, list(wheels).index(n)))
    marker_colours = [_display_colour(s.get("colour")) for s in segments]
    # A fixed layout, inches: the wheel on the left under its title, its angle labels, then the legend in the 1.6
    # inches on the right (no layout engine: constrained layout drew the figure twice, for the same places).
    width, height, left, bottom, top, labels, legend = 6.4, 5.6, 0.45, 0.6, 0.65, 0.4, 1.6
    figure = Figure(figsize=(width, height), dpi=120)
    box = (left / width, bottom / height, (width - left - labels - legend) / width, (height - bottom - top) / height)
    # The stubs type add_axes as plain Axes whatever the projection.
    axes = cast(PolarAxes, figure.add_axes(box, projection="polar"))
    cycle = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive"]
    handles = []
    for index, name in enumerate(names):
        hue = np.radians(np.asarray(wheels[name]["hue_deg"], dtype=float))
        saturation = np.asarray(wheels[name]["saturation"], dtype=float)
        centre = name == CENTRE_WHEEL
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
    beside = (1 - legend / width, 0.5)
    figure.legend(handles=handles, loc="center left", bbox_to_anchor=beside, fontsize=8, frameon=False)
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
    >>> from PIL import Image
    >>> from picamcal.colour_wheel import wheel_layout, wheel_scene
    >>> layout = wheel_layout(320, 240)
    >>> Image.open(wheel_crops(wheel_scene(layout), layout, "wheels.png")).format
    'PNG'
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    image = as_image(rgb)
    wheels = sorted(layout["wheels"], key=lambda w: w["name"] != CENTRE_WHEEL)
    if not wheels:
        raise PicamcalError("the layout has no wheels to cut out")
    columns = min(len(wheels), 5)
    rows = math.ceil(len(wheels) / columns)
    # A fixed grid of 2.2 x 2.45 inch cells, each a square crop under its title (no layout engine: constrained layout
    # drew the figure twice, for the same places).
    cell_width, cell_height, title, pad = 2.2, 2.45, 0.3, 0.08
    width, height = cell_width * columns, cell_height * rows
    figure = Figure(figsize=(width, height), dpi=120)
    for index, wheel in enumerate(wheels):
        row, column = divmod(index, columns)
        x, y = column * cell_width + pad, (rows - 1 - row) * cell_height + pad
        box = (x / width, y / height, (cell_width - 2 * pad) / width, (cell_height - title - pad) / height)
        axes = figure.add_axes(box)
        axes.imshow(encode_srgb(_crop(image, float(wheel["x"]), float(wheel["y"]), 1.2 * float(wheel["radius"]))))
        axes.set_title(f"({chr(ord('a') + index)}) {wheel['name']}", fontsize=9)
        axes.set_axis_off()
    return _save_figure(figure, path)


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
