"""The colour-wheel test target: its layout, an anti-aliased rendering, and files to display or print.

The paper tests its corrections on an image of colour wheels shown on a computer screen and imaged
through the custom optics (Figure "colour_wheels_images"), comparing the wheels away from the centre of
the frame with the one in the centre (Figure "matrix_correction_wheels_and_polar"). This target has nine
wheels, one in the centre, one near each corner and one near the middle of each edge, each of six
60-degree segments of the sRGB primaries and secondaries (red, yellow, green, cyan, blue, magenta) on
white, in the same order and at the same angles as the simulator's target
(:func:`picamcal.simulate.wheel_layout`).

Five black fiducial marks let :func:`picamcal.analysis.wheels.find_wheels` map the layout onto a
photograph of the target: a ring (a black disc with a white dot in its middle) near each corner, and a
smaller solid disc beside the top-left ring, towards the top-right one, which fixes the target's
orientation and tells a mirrored image from a true one.

Coordinates are in pixels of the rendering, with pixel centres at integer coordinates (pixel ``(i, j)``
covers ``x`` from ``j - 0.5`` to ``j + 0.5``), the convention of :mod:`picamcal.analysis.metrics`; angles are
``atan2(-(y - cy), x - cx)`` in degrees, counter-clockwise from +x as seen on screen.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, PngImagePlugin

from ._atomic import atomic_path
from .analysis.metrics import encode_srgb
from .colour_wheel import SEGMENTS
from .errors import PicamcalError
from .limits import MAX_PIXELS_VARIABLE, max_pixels

__all__ = ["is_target_file", "render_target", "save_target", "target_layout"]


# Wheel positions: (name, column, row) with columns and rows -1, 0, 1 for left/top, middle, right/bottom.
_WHEELS = (
    ("centre", 0, 0),
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
# edges (as the simulator's), but at least 0.17 m so that they keep clear of the fiducials on a square page.
_WHEEL_RADIUS = 0.10
_WHEEL_MARGIN = 0.15
_WHEEL_MARGIN_MIN = 0.17
_RING_OFFSET = 0.045  # ring centre from each edge
_RING_RADIUS = 0.025
_RING_HOLE = 0.4  # the white dot's radius, as a fraction of the ring's
_DISC_OFFSET = 0.12  # the orientation disc's centre from the left edge (its y is the top rings')
_DISC_RADIUS = 0.015
_MIN_SIZE = 64  # pixels, below which the marks are too small to find
_PDF_PAGE_WIDTH_IN = 11.69  # A4 landscape: the PDF page is the target, this wide
#: What the PNG's Software text and the PDF's Creator say, so that --overwrite knows a target it wrote.
_CREATOR = "picamcal colour-wheel target"
_PDF_TAIL = 1 << 16  # matplotlib writes the document information (Creator) after the image, at the end


def target_layout(width: int = 1920, height: int = 1080) -> dict[str, Any]:
    """The layout of the colour-wheel target: nine wheels of six segments and five fiducial marks.

    Parameters
    ----------
    width, height : int, default 1920 and 1080
        Size of the target in pixels: the screen's resolution to show it full-screen, or the printer's
        dots for a print.

    Returns
    -------
    dict
        JSON-serialisable, in the layout format of :func:`picamcal.simulate.wheel_layout` plus fiducials:
        ``"width"``, ``"height"``, ``"units"`` (``"pixels"``), ``"segments"`` (``name``, ``colour`` in
        sRGB, ``start_deg``, ``end_deg``), ``"wheels"`` (``name``, ``x``, ``y``, ``radius``: ``"centre"``,
        ``"top-left"``, ``"top"``, ``"top-right"``, ``"left"``, ``"right"``, ``"bottom-left"``,
        ``"bottom"``, ``"bottom-right"``) and ``"fiducials"`` (``name``, ``kind``, ``x``, ``y``,
        ``radius``, and ``hole_radius`` for rings): four ``"ring"`` marks named by their corner and one
        ``"disc"`` named ``"orientation"``.

    Raises
    ------
    PicamcalError
        If a side is shorter than 64 pixels, or the target has more pixels than
        :func:`picamcal.limits.max_pixels` (rendering holds a few float copies of it).

    Examples
    --------
    >>> layout = target_layout(1920, 1080)
    >>> len(layout["wheels"]), layout["wheels"][0]
    (9, {'name': 'centre', 'x': 959.5, 'y': 539.5, 'radius': 108.0})
    >>> [(f["name"], f["kind"]) for f in layout["fiducials"]][-1]
    ('orientation', 'disc')
    """
    width, height = int(width), int(height)
    if min(width, height) < _MIN_SIZE:
        raise PicamcalError(f"the target needs at least {_MIN_SIZE} x {_MIN_SIZE} pixels, got {width} x {height}")
    limit = max_pixels()
    if width * height > limit:
        raise PicamcalError(
            f"a target of {width}x{height} pixels ({width * height / 1e6:.0f} MP) is over the limit of "
            f"{limit / 1e6:.0f} MP (set {MAX_PIXELS_VARIABLE} to render larger targets)"
        )
    m = min(width, height)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    margin_x = max(_WHEEL_MARGIN * width, _WHEEL_MARGIN_MIN * m)
    margin_y = max(_WHEEL_MARGIN * height, _WHEEL_MARGIN_MIN * m)
    step_x, step_y = width / 2 - margin_x, height / 2 - margin_y
    wheels = [
        {"name": name, "x": _r(cx + col * step_x), "y": _r(cy + row * step_y), "radius": _r(_WHEEL_RADIUS * m)}
        for name, col, row in _WHEELS
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
        "segments": [
            {"name": name, "colour": list(colour), "start_deg": 60 * k, "end_deg": 60 * (k + 1)}
            for k, (name, colour) in enumerate(SEGMENTS)
        ],
        "wheels": wheels,
        "fiducials": fiducials,
    }


def render_target(layout: Mapping[str, Any], supersample: int = 4) -> np.ndarray:
    """Render a target layout as an 8-bit sRGB image: segments in their colours, fiducials black, on white.

    Each pixel near an edge averages ``supersample`` x ``supersample`` samples in linear light before
    the sRGB encoding (:func:`picamcal.analysis.metrics.encode_srgb`), so a pixel half covered by red shows half
    the red light, as a screen should; pixels away from every edge take their colour at the centre.

    Parameters
    ----------
    layout : mapping
        From :func:`target_layout` (or any layout with ``width``, ``height``, ``segments`` with
        ``colour``, ``wheels`` and optionally ``fiducials``).
    supersample : int, default 4
        Samples per pixel along each axis at the edges.

    Returns
    -------
    ndarray of uint8, shape (height, width, 3)

    Raises
    ------
    PicamcalError
        If ``supersample`` is below 1 or a segment has no colour.

    Examples
    --------
    >>> layout = target_layout(320, 240)
    >>> image = render_target(layout)
    >>> image.shape, image[0, 160].tolist(), image[115, 170].tolist()  # white margin, red segment
    ((240, 320, 3), [255, 255, 255], [255, 0, 0])
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
        edge = _near_edge(xs[None, :], ys[:, None], present)
        ey, ex = np.nonzero(edge)
        if ey.size:
            sx = xs[ex][:, None, None] + offsets[None, None, :]
            sy = ys[ey][:, None, None] + offsets[None, :, None]
            centre[ey, ex] = _paint(sx, sy, present).mean(axis=(1, 2))
        linear[y0:y1, x0:x1] = centre
    return encode_srgb(linear)


def save_target(
    path: str | os.PathLike[str], width: int = 1920, height: int = 1080, *, overwrite: bool = True
) -> tuple[Path, Path]:
    """Write the target as a PNG (to show full-screen) or PDF (to print), and its layout beside it.

    The image is :func:`render_target` of :func:`target_layout`; a PDF is one page that the image fills
    exactly, pixel for pixel and losslessly, 11.69 inches (A4 landscape) wide and as high as the image's
    proportions make it, so printing it "fit to page" keeps the layout's proportions. The layout goes to
    the same name with the suffix ``.json`` (``TARGET.png`` and ``TARGET.json``). Both are written
    atomically.

    To test a correction as the paper did, show the PNG full-screen on a monitor of exactly
    ``width`` x ``height`` pixels (no scaling) and photograph it through the optics, filling as much of
    the frame as possible with all five fiducials in view.

    Parameters
    ----------
    path : path-like
        ``.png`` or ``.pdf``.
    width, height : int, default 1920 and 1080
        Pixels of the target (the screen's resolution, or the print's dots).
    overwrite : bool, default True
        Replace existing files; otherwise raise if either exists (``picamcal target --overwrite`` replaces only
        files :func:`is_target_file` recognises).

    Returns
    -------
    (Path, Path)
        The image and the layout JSON.

    Raises
    ------
    PicamcalError
        If the suffix is neither ``.png`` nor ``.pdf``, or as :func:`target_layout`; OutputError if a file
        cannot be written or exists and ``overwrite`` is False.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     image_path, layout_path = save_target(Path(folder) / "wheels.png", 640, 360)
    ...     Image.open(image_path).size, layout_path.name
    ((640, 360), 'wheels.json')
    """
    image_path = Path(path)
    suffix = image_path.suffix.lower()
    if suffix not in (".png", ".pdf"):
        raise PicamcalError("the target can be written as .png or .pdf", image_path)
    layout_path = image_path.with_suffix(".json")
    layout = target_layout(width, height)
    pixels = render_target(layout)
    with atomic_path(image_path, overwrite=overwrite) as tmp:
        if suffix == ".png":
            info = PngImagePlugin.PngInfo()
            info.add_text("Software", _CREATOR)
            Image.fromarray(pixels).save(tmp, format="PNG", pnginfo=info)
        else:
            _save_pdf(tmp, pixels)
    with atomic_path(layout_path, overwrite=overwrite) as tmp:
        tmp.write_text(json.dumps(layout, indent=2) + "\n", encoding="utf-8")
    return image_path, layout_path


def _save_pdf(path: Path, pixels: np.ndarray) -> None:
    """One page exactly the image's size at 11.69 inches wide, the image embedded losslessly (Flate).

    Matplotlib rather than Pillow, whose PDF writer stores RGB as JPEG and would blur the segments' edges.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    height, width = pixels.shape[:2]
    dpi = width / _PDF_PAGE_WIDTH_IN
    figure = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    figure.figimage(pixels, resize=False)
    figure.savefig(path, format="pdf", dpi=dpi, metadata={"Creator": _CREATOR})


def is_target_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a target image (PNG or PDF) or layout that :func:`save_target` wrote.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     image_path, layout_path = save_target(Path(folder) / "wheels.png", 320, 240)
    ...     is_target_file(image_path), is_target_file(layout_path), is_target_file(__file__)
    (True, True, False)
    """
    path = Path(path)
    if not path.is_file():  # a FIFO would block the read
        return False
    suffix = path.suffix.lower()
    if suffix == ".json":
        try:
            layout = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):
            return False
        return isinstance(layout, dict) and layout.get("units") == "pixels" and "fiducials" in layout
    if suffix == ".png":
        try:
            with Image.open(path) as image:
                return image.format == "PNG" and image.info.get("Software") == _CREATOR
        except (OSError, ValueError, Image.DecompressionBombError):
            return False
    if suffix == ".pdf":
        try:
            with open(path, "rb") as f:
                f.seek(max(0, f.seek(0, os.SEEK_END) - _PDF_TAIL))
                return f"/Creator ({_CREATOR})".encode() in f.read()
        except OSError:
            return False
    return False


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
    """Pixels centred at (x, y) that an edge may cross (within 0.75 pixel, beyond half the diagonal)."""
    near = 0.75
    x, y = np.broadcast_arrays(x, y)
    edge = np.zeros(x.shape, dtype=bool)
    for shape in shapes:
        dx, dy = x - shape["x"], y - shape["y"]
        rho = np.hypot(dx, dy)
        edge |= np.abs(rho - shape["radius"]) < near
        if shape["kind"] == "wheel":
            for start, _, _ in shape["segments"]:
                b = math.radians(start)
                along = dx * math.cos(b) - dy * math.sin(b)
                across = np.abs(dx * math.sin(b) + dy * math.cos(b))
                edge |= (np.where(along > 0, across, rho) < near) & (rho < shape["radius"] + near)
        elif shape["hole"] > 0:
            edge |= np.abs(rho - shape["hole"]) < near
    return edge
