"""Figures of a calibration, as in the paper: flat-field gains, the unmixing field, noise penalties,
normalised references with line sections, the vignetting centre and a dust map.

Every function takes a :class:`~picamcal.calibration.Calibration` and an output path, draws with
matplotlib's object-oriented API (a bare :class:`~matplotlib.figure.Figure`, rendered by Agg for PNG: no
pyplot state, safe in threads and without a display), writes the file atomically and returns its path.
The format follows the suffix (``.png``, ``.pdf``, ``.svg``). Maps are drawn on the bin grid in sensor
pixel coordinates (x right, y down, as the image); gains and noise factors use perceptually uniform
sequential colour maps, signed quantities a diverging map centred on zero.

Examples
--------
>>> from picamcal import calibrate
>>> from picamcal.simulate import make_camera, simulate_references
>>> refs = simulate_references(make_camera("imx219", size=(320, 240)), noise=False)
>>> cal = calibrate(*(refs[r] for r in ("white", "red", "green", "blue")))
>>> lens_shading_maps(cal, "lst.png").name
'lst.png'
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import QuadMesh
from matplotlib.colors import Normalize, TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from .._atomic import atomic_path
from ..bayer import bin_edges, sites_to_channels
from ..calibration import Calibration
from ..modes import Mode
from ..raw.model import CHANNELS
from ..references import COLOURS
from .diagnostics import check_dust, check_vignetting_centre, dust_residual

__all__ = [
    "dust_map",
    "lens_shading_maps",
    "noise_penalty_maps",
    "normalised_references",
    "unmixing_grid",
    "vignetting_centre_plot",
]

GAIN_CMAP = "viridis"
NOISE_CMAP = "cividis"
DIVERGING_CMAP = "RdBu_r"
_DPI = 120
_LINE_COLOURS = ("tab:red", "tab:green", "tab:blue")
_PANEL_WIDTH = 3.6  # inches per map
_PENALTY_LEVELS = (1.5, 2, 3, 4, 6, 8, 12, 16)
#: The fixed layout of :func:`_figure`, inches: room for the y ticks and label (left), the x ticks and label
#: (bottom), the suptitle, a line of panel title, the gap between panels, and a colour bar with its gap, ticks and
#: label.
_MARGINS = {"left": 0.8, "bottom": 0.55, "suptitle": 0.45, "title": 0.3, "gap": 0.3, "bar_gap": 0.15, "bar": 0.14,
            "bar_label": 0.85}  # fmt: skip


def lens_shading_maps(calibration: Calibration, path: str | os.PathLike[str], *, overwrite: bool = True) -> Path:
    """The flat-field gain per channel, ``LST = max(W) / W`` (1 at the brightest bin), as three maps.

    The three maps share one colour scale so the channels' fall-offs compare directly (red falls off
    least, paper section "Vignetting").

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> lens_shading_maps(cal, "lens_shading.png")
    PosixPath('lens_shading.png')
    """
    gains = calibration.lens_shading
    norm = Normalize(1.0, max(float(gains.max()), 1.0 + 1e-6))
    fig, axes = _figure(calibration, 1, 3)
    for c, ax in enumerate(axes[0]):
        mesh = _map(ax, calibration, gains[..., c], GAIN_CMAP, norm)
        ax.set_title(f"{CHANNELS[c]} gain (max {gains[..., c].max():.2f})")
        ax.label_outer()
    _colour_bar(fig, axes, mesh, "flat-field gain (x)", shrink=0.9)
    fig.suptitle("Lens shading: flat-field gain per channel")
    return _save(fig, path, overwrite)


def unmixing_grid(
    calibration: Calibration, path: str | os.PathLike[str], *, mode: str | Mode = Mode.CENTRE, overwrite: bool = True
) -> Path:
    """The 3 x 3 unmixing field as a grid of maps: row = output channel p, column = input channel q.

    ``out_p = sum_q U_pq in_q`` (paper, eq. for ``Unmixed``). Diagonal elements (the gain a channel keeps)
    share a sequential scale; off-diagonal elements (what is taken from the other channels, negative where
    crosstalk is removed) share a diverging scale centred on zero.

    Parameters
    ----------
    mode : {"centre", "pure"}
        The field unmixing to the sensor centre's colours (``U``, the identity there) or to pure primaries
        (``inv(M)``).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> unmixing_grid(cal, "unmixing.png", mode="pure")
    PosixPath('unmixing.png')
    """
    mode = calibration.check_mode(mode)
    matrices = calibration.matrices(mode)
    if matrices is None:
        raise ValueError(f"mode {mode.value!r} has no unmixing matrices: use 'centre' or 'pure'")
    diagonal = np.stack([matrices[..., k, k] for k in range(3)])
    off = np.stack([matrices[..., p, q] for p in range(3) for q in range(3) if p != q])
    diag_norm = Normalize(float(diagonal.min()), max(float(diagonal.max()), float(diagonal.min()) + 1e-6))
    reach = max(float(np.abs(off).max()), 1e-6)
    off_norm = TwoSlopeNorm(0.0, -reach, reach)
    fig, axes = _figure(calibration, 3, 3, bottom_bar=True)
    meshes = {}
    for p in range(3):
        for q in range(3):
            ax = axes[p, q]
            diagonal_element = p == q
            cmap, norm = (GAIN_CMAP, diag_norm) if diagonal_element else (DIVERGING_CMAP, off_norm)
            meshes[diagonal_element] = _map(ax, calibration, matrices[..., p, q], cmap, norm)
            ax.set_title(f"{CHANNELS[p]} out from {CHANNELS[q]} in", fontsize="medium")
            ax.label_outer()
    _colour_bar(fig, axes, meshes[True], "diagonal element (gain)", shrink=0.8)
    _colour_bar(fig, axes, meshes[False], "off-diagonal element", shrink=0.5, bottom=True)
    what = "to the sensor centre's colours" if mode is Mode.CENTRE else "to pure primaries"
    fig.suptitle(f"Unmixing field ({mode.value} mode: unmixing {what})")
    return _save(fig, path, overwrite)


def noise_penalty_maps(
    calibration: Calibration,
    path: str | os.PathLike[str],
    *,
    channel: str | None = None,
    overwrite: bool = True,
) -> Path:
    """Noise penalty of the vignetting correction (``flat``) and of unmixing (``centre``), side by side.

    The factor by which each correction multiplies read noise relative to the sensor centre
    (:meth:`Calibration.noise_penalty`; paper, Figure "unmixing_matrix_and_snr" (b, c)), on one scale.
    A flat-field calibration (white only) has the ``flat`` map alone.

    Parameters
    ----------
    channel : {"R", "G", "B"}, optional
        The channel to show; default the worst of the three in each bin.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> noise_penalty_maps(cal, "noise.png", channel="B")
    PosixPath('noise.png')
    """
    if channel is not None and channel not in CHANNELS:
        raise ValueError(f"channel must be one of R, G, B, got {channel!r}")
    maps = {}
    for mode in (Mode.FLAT, Mode.CENTRE) if calibration.has_unmixing else (Mode.FLAT,):
        penalty = calibration.noise_penalty(mode)
        maps[mode] = penalty.max(axis=-1) if channel is None else penalty[..., CHANNELS.index(channel)]
    norm = Normalize(1.0, max(max(float(m.max()) for m in maps.values()), 1.0 + 1e-6))
    y, x = calibration.bin_centres
    # One map alone (a flat calibration) is drawn larger, so the figure is as wide as its title.
    fig, axes = _figure(calibration, 1, len(maps), panel_width=_PANEL_WIDTH if len(maps) > 1 else 6.0)
    titles = {Mode.FLAT: "vignetting correction (flat)", Mode.CENTRE: "unmixing to the centre (centre)"}
    for ax, (mode, values) in zip(axes[0], maps.items(), strict=True):
        mesh = _map(ax, calibration, values, NOISE_CMAP, norm)
        levels = [v for v in _PENALTY_LEVELS if v < values.max()]
        if levels:
            lines = ax.contour(x, y, values, levels=levels, colors="white", linewidths=0.7)
            ax.clabel(lines, fmt="%gx", fontsize="x-small")
        ax.set_title(f"{titles[mode]}: max {values.max():.2f}x", fontsize="medium")
        ax.label_outer()
    _colour_bar(fig, axes, mesh, "noise factor (x)", shrink=0.9)
    which = "worst channel" if channel is None else f"{channel} channel"
    fig.suptitle(f"Noise penalty relative to the sensor centre ({which})")
    return _save(fig, path, overwrite)


def normalised_references(
    calibration: Calibration,
    path: str | os.PathLike[str],
    *,
    relative_to: str = "centre",
    overwrite: bool = True,
) -> Path:
    """The white, red, green and blue references (the white alone for a flat calibration) as RGB images,
    with R, G, B line sections below.

    ``relative_to="centre"`` divides every reference by the white's mean in the central ninth, per
    channel (paper, Figure "example_run": vignetting and colour both visible); ``"white"`` divides each by
    the white bin by bin (Figure "example_run_normalised": what the lens shading correction gives, with
    the desaturation towards the edges left). The line sections run along the bin row through the
    sensor centre. Images are linear, clipped to [0, 1].

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> normalised_references(cal, "references.png", relative_to="white")
    PosixPath('references.png')
    """
    if relative_to not in ("centre", "white"):
        raise ValueError(f"relative_to must be 'centre' or 'white', got {relative_to!r}")
    channels = sites_to_channels(calibration.site_responses, calibration.pattern)  # (4, nby, nbx, 3)
    white = channels[0]
    if relative_to == "centre":
        ys, xs = calibration.centre_slices
        scale = white[ys, xs].reshape(-1, 3).mean(axis=0)
    else:
        scale = white
    normalised = channels / scale
    y, x = calibration.bin_centres
    row = int(np.argmin(np.abs(y - (calibration.height - 1) / 2.0)))
    top = max(1.05, float(np.percentile(normalised[:, row], 99.9)) * 1.05)
    names = ("white", *COLOURS)[: len(channels)]  # the order of site_responses
    sep = "; " if len(names) > 1 else "\n"
    # A fixed layout, inches (as _figure's): the images over their sections, each column with its own y ticks.
    m, section, between = _MARGINS, 1.4, 0.55  # a section's height; the room for a column's y ticks
    width = max(len(names) * 3.0, 7.0)  # the white alone (a flat calibration) keeps room for its title
    panel = (width - m["left"] - m["gap"] - (len(names) - 1) * between) / len(names)
    image = panel * calibration.height / calibration.width
    head = m["suptitle"] + (0.25 if sep == "\n" else 0.0) + m["title"]  # a second line of suptitle for one column
    height = m["bottom"] + section + m["gap"] + image + head  # the images share the sections' x tick labels
    layout = {
        "left": m["left"] / width,
        "right": 1 - m["gap"] / width,
        "bottom": m["bottom"] / height,
        "top": 1 - head / height,
        "wspace": between / panel,
        "hspace": m["gap"] / ((image + section) / 2),
    }
    fig = Figure(figsize=(width, height))
    axes = fig.subplots(2, len(names), sharex=True, squeeze=False, height_ratios=(image, section), gridspec_kw=layout)
    xe, ye = _edges(calibration)
    for k, name in enumerate(names):
        ax = axes[0, k]
        ax.imshow(
            np.clip(normalised[k], 0.0, 1.0),
            extent=(xe[0], xe[-1], ye[-1], ye[0]),
            interpolation="nearest",
        )
        ax.axhline(y[row], color="white", lw=0.8, ls="--")
        ax.set_title(f"{name} reference")
        ax.set_ylabel("y (pixels)" if k == 0 else "")
        section = axes[1, k]
        for c in range(3):
            section.plot(x, normalised[k, row, :, c], color=_LINE_COLOURS[c], label=CHANNELS[c], lw=1.2)
        section.set_ylim(0, top)
        section.set_xlabel("x (pixels)")
        section.grid(alpha=0.3)
        if k == 0:
            section.set_ylabel("relative response")
            section.legend(loc="lower center", ncols=3, fontsize="small")
    basis = "the white's centre, per channel" if relative_to == "centre" else "the white, bin by bin"
    fig.suptitle(f"References normalised to {basis}{sep}sections along y = {y[row]:.0f} px")
    return _save(fig, path, overwrite)


def vignetting_centre_plot(
    calibration: Calibration,
    path: str | os.PathLike[str],
    *,
    cra_corner_deg: float | None = None,
    overwrite: bool = True,
) -> Path:
    """The green white field (relative to its peak) with the fitted vignetting centre and the sensor centre.

    The centre comes from :func:`~picamcal.analysis.diagnostics.check_vignetting_centre`; with
    ``cra_corner_deg`` the title gives the tilt it implies.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> camera = make_camera("imx219", size=(320, 240), tilt=(2.0, 0.0))  # light 2 degrees off normal
    >>> cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    >>> vignetting_centre_plot(cal, "centre.png", cra_corner_deg=26.6)
    PosixPath('centre.png')
    """
    check = check_vignetting_centre(calibration, cra_corner_deg=cra_corner_deg)
    v = check.values
    green = calibration.white[..., 1] / calibration.white[..., 1].max()
    title = (
        f"Vignetting centre ({v['x_px']:.0f}, {v['y_px']:.0f}) px: {v['offset_percent']:.1f} % of the half-diagonal off"
    )
    if v["tilt_x_deg"] is not None:
        title += f"\nimplied tilt {v['tilt_x_deg']:+.2f} deg (x), {v['tilt_y_deg']:+.2f} deg (y)"
    fig, axes = _figure(calibration, 1, 1, panel_width=6.0, title_lines=title.count("\n") + 1, suptitle=False)
    ax = axes[0, 0]
    mesh = _map(ax, calibration, green, GAIN_CMAP, Normalize(float(green.min()), 1.0))
    y, x = calibration.bin_centres
    ax.contour(x, y, green, levels=np.arange(0.1, 1.0, 0.1), colors="white", linewidths=0.5, alpha=0.6)
    ax.plot(v["sensor_centre_x_px"], v["sensor_centre_y_px"], "w+", ms=14, mew=2, label="sensor centre")
    ax.plot(v["x_px"], v["y_px"], "x", color="tab:red", ms=12, mew=2.5, label="vignetting centre")
    ax.legend(loc="upper right", fontsize="small", framealpha=0.8)
    _colour_bar(fig, axes, mesh, "green white / its peak", shrink=0.9)
    ax.set_title(title, fontsize="medium")
    return _save(fig, path, overwrite)


def dust_map(calibration: Calibration, path: str | os.PathLike[str], *, overwrite: bool = True) -> Path:
    """The white's small-scale residual (percent) with the dust specks found circled.

    The residual is :func:`~picamcal.analysis.diagnostics.dust_residual` of the sum of the four Bayer
    sites; specks are those of :func:`~picamcal.analysis.diagnostics.check_dust`, each circled with
    its region's equivalent radius and labelled with its depth.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> dust_map(cal, "dust.png")
    PosixPath('dust.png')
    """
    y, x = calibration.bin_centres
    residual = 100.0 * dust_residual(calibration.site_white.sum(axis=-1), y, x)
    check = check_dust(calibration)
    noise = check.values["noise_percent"] or 0.0  # None when the frame is too small to look for dust
    # Ten noise sigmas (at least 1 %) either way: the noise shows faintly, specks stand out saturated.
    reach = max(10.0 * noise, 1.0)
    fig, axes = _figure(calibration, 1, 1, panel_width=6.0, suptitle=False)
    ax = axes[0, 0]
    mesh = _map(ax, calibration, residual, DIVERGING_CMAP, TwoSlopeNorm(0.0, -reach, reach))
    for speck in check.values["specks"]:
        radius = max(speck["area_radius_px"], 1.5 * calibration.bin_size)
        ax.add_patch(Circle((speck["x"], speck["y"]), radius, fill=False, color="black", lw=1.5))
        ax.annotate(
            f"{speck['depth_percent']:.1f} %",
            (speck["x"], speck["y"] - radius),
            ha="center",
            va="bottom",
            fontsize="small",
        )
    _colour_bar(fig, axes, mesh, "white / smooth white - 1 (%)", shrink=0.9, extend="both")
    count = check.values["count"]
    ax.set_title(f"Dust: {count} speck{'' if count == 1 else 's'} found (bin noise {noise:.2f} %)", fontsize="medium")
    return _save(fig, path, overwrite)


# Helpers ----------------------------------------------------------------------------------------------


def _edges(calibration: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Bin edges (x, y) in sensor pixels: pixel k spans [k, k + 1), so the frame spans [0, W] x [0, H]."""
    return bin_edges(calibration.width, calibration.bin_size), bin_edges(calibration.height, calibration.bin_size)


def _figure(
    calibration: Calibration,
    rows: int,
    cols: int,
    *,
    panel_width: float = _PANEL_WIDTH,
    title_lines: int = 1,
    suptitle: bool = True,
    bottom_bar: bool = False,
) -> tuple[Figure, np.ndarray]:
    """A figure of map panels sized to the frame's aspect ratio, with room for a colour bar on the right (and one
    below with ``bottom_bar``: :func:`_colour_bar`), panel titles of ``title_lines`` lines and a suptitle unless
    ``suptitle=False``; axes as a 2-D array.

    The layout is fixed, in inches (:data:`_MARGINS`), not found by a layout engine: constrained layout draws each
    figure twice, which took about 40 % of a report's time. The panels share their axes: call
    :meth:`~matplotlib.axes.Axes.label_outer` on them after drawing so only the outer ones carry tick labels.
    """
    m = _MARGINS
    panel_height = panel_width * calibration.height / calibration.width
    title = m["title"] * title_lines
    bar = m["bar_gap"] + m["bar"] + m["bar_label"]
    width = m["left"] + cols * panel_width + (cols - 1) * m["gap"] + bar
    bottom = m["bottom"] + (bar if bottom_bar else 0.0)
    top = m["suptitle"] if suptitle else m["gap"]
    height = bottom + rows * (panel_height + title) + (rows - 1) * m["gap"] + top
    fig = Figure(figsize=(width, height))
    layout = {
        "left": m["left"] / width,
        "right": (width - bar) / width,
        "bottom": bottom / height,
        "top": (height - top - title) / height,
        "wspace": m["gap"] / panel_width,
        "hspace": (m["gap"] + title) / panel_height,
    }
    axes = np.asarray(fig.subplots(rows, cols, squeeze=False, sharex=True, sharey=True, gridspec_kw=layout))
    return fig, axes


def _colour_bar(
    fig: Figure, axes: np.ndarray, mesh: QuadMesh, label: str, *, shrink: float, bottom: bool = False, **options
) -> None:
    """A colour bar beside the panels of :func:`_figure` (below them with ``bottom``), ``shrink`` times their extent
    and centred on it."""
    boxes = [ax.get_position() for ax in np.ravel(axes)]
    x0, x1 = min(b.x0 for b in boxes), max(b.x1 for b in boxes)
    y0, y1 = min(b.y0 for b in boxes), max(b.y1 for b in boxes)
    width, height = fig.get_size_inches()
    gap, thickness = _MARGINS["bar_gap"], _MARGINS["bar"]
    if bottom:
        span = shrink * (x1 - x0)
        lowest = (_MARGINS["bottom"] + _MARGINS["bar_gap"]) / height  # below the x ticks and label
        box = (x0 + (x1 - x0 - span) / 2, y0 - lowest, span, thickness / height)
    else:
        span = shrink * (y1 - y0)
        box = (x1 + gap / width, y0 + (y1 - y0 - span) / 2, thickness / width, span)
    orientation = "horizontal" if bottom else "vertical"
    fig.colorbar(mesh, cax=fig.add_axes(box), label=label, orientation=orientation, **options)


def _map(ax: Axes, calibration: Calibration, values: np.ndarray, cmap: str, norm: Normalize) -> QuadMesh:
    """Draw one binned map on the exact bin grid, in sensor pixels, y down."""
    xe, ye = _edges(calibration)
    mesh = ax.pcolormesh(xe, ye, values, cmap=cmap, norm=norm, shading="flat", rasterized=True)
    ax.set_xlim(xe[0], xe[-1])
    ax.set_ylim(ye[-1], ye[0])
    ax.set_aspect("equal")
    ax.set_xlabel("x (pixels)")
    ax.set_ylabel("y (pixels)")
    return mesh


def _save(fig: Figure, path: str | os.PathLike[str], overwrite: bool) -> Path:
    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"
    with atomic_path(path, overwrite=overwrite) as tmp:
        fig.savefig(tmp, format=fmt, dpi=_DPI)
    return path
