"""The colour-wheel test target and the full-screen references as files to display or print: ``picamcal target``.

The target itself (nine wheels of six segments and five fiducial marks) is defined once in
:mod:`picamcal.colour_wheel`, which the simulator photographs and :mod:`picamcal.analysis.wheels` looks
for. This module lays it out on a screen or page of a printable size (:func:`target_layout`), encodes it as
8-bit sRGB (:func:`render_target`) and writes it as a PNG or PDF with its layout beside it
(:func:`save_target`), marked so that ``--overwrite`` knows a file it wrote (:func:`is_target_file`).

The full-screen references (:func:`save_screens`) are one flat colour each, ``screen_white.png``,
``screen_red.png``, ... (:data:`SCREEN_COLOURS`) and ``screen_colour_NAME.png`` for extra colours
(:func:`picamcal.references.parse_colours`): shown full-screen on a monitor and photographed through the optics,
they calibrate in the monitor's own spectra.

Coordinates are in pixels of the rendering, with pixel centres at integer coordinates, the convention of
:mod:`picamcal.analysis.metrics`; angles are ``atan2(-(y - cy), x - cx)`` in degrees, counter-clockwise from
+x as seen on screen.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, PngImagePlugin

from ._atomic import atomic_path
from .analysis.metrics import encode_srgb
from .colour_wheel import wheel_layout, wheel_scene
from .errors import OutputError, PicamcalError
from .limits import MAX_PIXELS_VARIABLE, max_pixels
from .references import colour_role, parse_colours

__all__ = [
    "SCREEN_COLOURS",
    "is_screen_file",
    "is_target_file",
    "render_target",
    "save_screens",
    "save_target",
    "screen_name",
    "target_layout",
]


_MIN_SIZE = 64  # pixels, below which the marks are too small to find
_PDF_PAGE_WIDTH_IN = 11.69  # A4 landscape: the PDF page is the target, this wide
#: What the PNG's Software text and the PDF's Creator say, so that --overwrite knows a target it wrote.
_CREATOR = "picamcal colour-wheel target"
_PDF_TAIL = 1 << 16  # matplotlib writes the document information (Creator) after the image, at the end
#: What a full-screen reference's PNG Software text says, so that --overwrite knows a screen it wrote.
_SCREEN_CREATOR = "picamcal full-screen reference"

#: The colour (8-bit sRGB code values) each reference role (:data:`picamcal.references.ROLES`) is shown in
#: full-screen: every primary at full drive for white, one primary for each colour, none for black.
SCREEN_COLOURS: dict[str, tuple[int, int, int]] = {
    "white": (255, 255, 255),
    "red": (255, 0, 0),
    "green": (0, 255, 0),
    "blue": (0, 0, 255),
    "black": (0, 0, 0),
}


def target_layout(width: int = 1920, height: int = 1080) -> dict[str, Any]:
    """The layout of the colour-wheel target on a screen or page: nine wheels and five fiducial marks.

    This is :func:`picamcal.colour_wheel.wheel_layout`, the one layout of the target (the simulator
    photographs the same one laid out on its frame), refused below the size at which its marks can be found.

    Parameters
    ----------
    width, height : int, default 1920 and 1080
        Size of the target in pixels: the screen's resolution to show it full-screen, or the printer's
        dots for a print.

    Returns
    -------
    dict
        JSON-serialisable: ``"width"``, ``"height"``, ``"units"`` (``"pixels"``), ``"segments"`` (``name``,
        ``colour`` in sRGB, ``start_deg``, ``end_deg``), ``"wheels"`` (``name``, ``x``, ``y``, ``radius``:
        ``"centre"``, ``"top-left"``, ``"top"``, ``"top-right"``, ``"left"``, ``"right"``, ``"bottom-left"``,
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
    return wheel_layout(width, height)


def render_target(layout: Mapping[str, Any], supersample: int = 4) -> np.ndarray:
    """Render a target layout as an 8-bit sRGB image: segments in their colours, fiducials black, on white.

    The linear rendering of :func:`picamcal.colour_wheel.wheel_scene` (each pixel near an edge averages
    ``supersample`` x ``supersample`` samples in linear light, so a pixel half covered by red shows half the
    red light, as a screen should), encoded by :func:`picamcal.analysis.metrics.encode_srgb`.

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
    return encode_srgb(wheel_scene(layout, supersample))


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
    >>> image_path, layout_path = save_target("wheels.png", 640, 360)
    >>> Image.open(image_path).size, layout_path.name
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
    >>> image_path, layout_path = save_target("wheels.png", 320, 240)
    >>> is_target_file(image_path), is_target_file(layout_path), is_target_file(__file__)
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


def screen_name(role: str) -> str:
    """The file name of a role's full-screen reference: ``screen_ROLE.png`` (``screen_colour_cyan.png``, ...).

    Examples
    --------
    >>> screen_name("red"), screen_name("colour_cyan")
    ('screen_red.png', 'screen_colour_cyan.png')
    """
    return f"screen_{role}.png"


def save_screens(
    folder: str | os.PathLike[str],
    width: int = 1920,
    height: int = 1080,
    colours: Mapping[str, tuple[int, int, int]] | None = None,
    *,
    overwrite: bool = False,
) -> list[Path]:
    """Write the full-screen references to show on a monitor: one flat colour each, exactly, at its size.

    ``screen_white.png``, ``screen_red.png``, ``screen_green.png``, ``screen_blue.png`` and
    ``screen_black.png`` (:data:`SCREEN_COLOURS`), then ``screen_colour_NAME.png`` for each extra colour: 8-bit
    RGB PNGs tagged sRGB, every pixel the exact code values (no dithering, no colour management). Shown
    full-screen and photographed through the optics they are the references of an in-situ calibration in the
    monitor's own spectra (``picamcal acquire --illuminator screen`` shows the same colours by itself). Each file
    is written atomically.

    Parameters
    ----------
    folder : path-like
        Created if missing.
    width, height : int, default 1920 and 1080
        The monitor's resolution in pixels (a smaller image scaled up shows the same colour, but some viewers
        leave a border).
    colours : mapping, optional
        Extra colours, name -> (R, G, B) 0-255 (:func:`picamcal.references.parse_colours`); the names are
        letters, digits and ``-``.
    overwrite : bool, default False
        Replace existing files (only those :func:`is_screen_file` recognises; anything else is refused).

    Returns
    -------
    list of Path
        The files, references first.

    Raises
    ------
    PicamcalError
        A side below one pixel, more pixels than :func:`picamcal.limits.max_pixels`, or a bad extra colour.
    OutputError
        A file exists (without ``overwrite``, or not a screen picamcal wrote), or cannot be written.

    Examples
    --------
    >>> paths = save_screens("screens", 64, 48, {"cyan": (0, 255, 255)})
    >>> [p.name for p in paths]  # doctest: +NORMALIZE_WHITESPACE
    ['screen_white.png', 'screen_red.png', 'screen_green.png', 'screen_blue.png', 'screen_black.png',
     'screen_colour_cyan.png']
    >>> image = Image.open(paths[-1])
    >>> image.size, image.getextrema(), image.info["srgb"]
    ((64, 48), ((0, 0), (255, 255), (255, 255)), 0)
    """
    width, height = int(width), int(height)
    if min(width, height) < 1:
        raise PicamcalError(f"a screen needs at least one pixel each way, got {width} x {height}")
    if width * height > max_pixels():
        raise PicamcalError(
            f"a screen of {width}x{height} pixels is over the limit of {max_pixels() // 1_000_000} MP "
            f"(set {MAX_PIXELS_VARIABLE} to write larger images)"
        )
    extra = parse_colours(f"{name}={r},{g},{b}" for name, (r, g, b) in (colours or {}).items())
    shown = {**SCREEN_COLOURS, **{colour_role(name): rgb for name, rgb in extra.items()}}
    out = Path(folder)
    paths = [out / screen_name(role) for role in shown]
    for path in paths:  # all refused before any is written
        if path.exists() and not overwrite:
            raise OutputError("exists already (use --overwrite to replace it)", path)
        if path.exists() and not is_screen_file(path):
            raise OutputError("exists and is not a screen picamcal wrote; --overwrite does not replace it", path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the folder: {exc.strerror or exc}", out) from exc
    info = PngImagePlugin.PngInfo()
    info.add_text("Software", _SCREEN_CREATOR)
    info.add(b"sRGB", b"\x00")  # the sRGB chunk, rendering intent perceptual: the code values are sRGB
    for path, rgb in zip(paths, shown.values(), strict=True):
        # Image.new fills exactly; "RGB" is 8 bits a channel, so no quantisation or dithering happens.
        with atomic_path(path, overwrite=overwrite) as tmp:
            Image.new("RGB", (width, height), rgb).save(tmp, format="PNG", pnginfo=info, optimize=True)
    return paths


def is_screen_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a full-screen reference that :func:`save_screens` wrote.

    Examples
    --------
    >>> paths = save_screens("screens", 64, 48)
    >>> is_screen_file(paths[0]), is_screen_file(__file__)
    (True, False)
    """
    path = Path(path)
    if not path.is_file() or path.suffix.lower() != ".png":  # a FIFO would block the read
        return False
    try:
        with Image.open(path) as image:
            return image.format == "PNG" and image.info.get("Software") == _SCREEN_CREATOR
    except (OSError, ValueError, Image.DecompressionBombError):
        return False
