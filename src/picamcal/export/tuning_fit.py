"""How the lens shading table is chosen: the least-squares fit of libcamera's interpolated gains to the calibration's
flat field, placed at the calibration's sensor mode on the full-sensor grid; which modes it covers; the neutral colour
gains of each mode through the exported file.

:mod:`picamcal.export.tuning` writes the files and re-exports these names.
"""

from __future__ import annotations

import dataclasses
import itertools
import warnings
from typing import Any, NamedTuple

import numpy as np

from ..bayer import bin_edges
from ..calibration import Calibration
from ..calibration.resample import CROP_TOLERANCE, resample_calibration
from ..errors import PicamcalWarning
from ..geometry import SensorMode, driver_geometry
from ..sensors import LSC_GRIDS, SENSORS, sensor_modes
from .isp import GAIN_LIMITS, TuningError, check_tuning, lens_shading_factors, mode_resampling, table_to_pixels

__all__ = [
    "MEASURED_WEIGHT",
    "SMOOTHNESS",
    "GainFit",
    "alsc_tables",
    "fit_gain_tables",
    "mode_coverage",
    "neutral_colour_gains",
    "sensor_mode_geometries",
]


def _bin_average(n_pixels: int, bin_size: int) -> np.ndarray:
    """Matrix (n_bins x n_pixels) averaging pixels into the calibration's bins."""
    edges = bin_edges(n_pixels, bin_size)
    matrix = np.zeros((edges.size - 1, n_pixels))
    for i, (a, b) in enumerate(itertools.pairwise(edges)):
        matrix[i, a:b] = 1.0 / (b - a)
    return matrix


#: Weight of the second-difference penalty (along rows and columns), relative to the mean diagonal of the normal
#: equations. It keeps a nearly square fit (a 32 x 32 table on a small frame) from turning bin noise into wild gains,
#: and changes full-size results by less than 0.01 % of flatness.
SMOOTHNESS = 1e-3


class GainFit(NamedTuple):
    """The fitted R, G, B gain tables over the full sensor, and which cells the calibration's crop measured."""

    tables: np.ndarray  # (3, rows, cols)
    measured: np.ndarray  # (rows, cols) bool: cells whose gains reach the calibration's bins


def _mode_matrices(target: str, mode: SensorMode, bin_size: int) -> tuple[np.ndarray, np.ndarray]:
    """(Fy, Fx): from a full-sensor table to the mean gain of each bin of a mode's image, per axis (libcamera's
    resampling to the mode, the IPA's and the ISP's interpolation to the pixels, the bins' average)."""
    cols, rows = LSC_GRIDS[target]
    ry, rx = mode_resampling((cols, rows), mode)
    py, px = table_to_pixels(target, mode.width, mode.height)
    return _bin_average(mode.height, bin_size) @ py @ ry, _bin_average(mode.width, bin_size) @ px @ rx


def _fitted_modes(calibration: Calibration) -> list[Calibration]:
    """The calibration in its own mode and in every other sensor mode inside its crop (:func:`mode_coverage`), at
    that mode's bins (:func:`picamcal.calibration.resample.resample_calibration`), each area once."""
    geometry = calibration.geometry
    assert geometry is not None
    if IMPORTED_KEY in calibration.provenance:
        # A table's flat field is what it gives the full sensor; fitting other modes too would trade it for theirs,
        # and a table converted (vc4 to pisp and back) would drift from itself by 1 % in places.
        return [calibration]
    fitted, areas = [calibration], {geometry.area()}
    modes = sensor_mode_geometries(calibration)
    for name in mode_coverage(calibration)["covered"]:
        mode = dataclasses.replace(modes[name], hflip=geometry.hflip, vflip=geometry.vflip)  # the camera's transform
        # A mode of too few bins (on a sensor reduced to a few hundred pixels) measures nothing the others do not.
        if mode.area() not in areas and min(mode.width, mode.height) >= MIN_FITTED_BINS * calibration.bin_size:
            areas.add(mode.area())
            fitted.append(resample_calibration(calibration, mode))
    return fitted


#: The provenance key of a calibration made from a lens shading table (:mod:`picamcal.export.tables`).
IMPORTED_KEY = "imported_table"
#: The fewest bins along each side of a mode for the fit to take it beside the calibration's own mode.
MIN_FITTED_BINS = 8


def _fit(calibration: Calibration, target: str) -> GainFit:
    """:func:`fit_gain_tables` with the cells the calibration measured; the others take the nearest measured cell's."""
    cols, rows = LSC_GRIDS[target]
    n = rows * cols
    scale = (1.0 / calibration.white.astype(np.float64)).min(axis=(0, 1))  # one normalisation for every mode
    normal, rhs = np.zeros((n, n)), np.zeros((3, n))
    seen_y = seen_x = np.zeros(0)
    for fitted in _fitted_modes(calibration):
        assert fitted.geometry is not None
        fy, fx = _mode_matrices(target, fitted.geometry, fitted.bin_size)
        if fitted is calibration:  # a cell is measured when the ISP carries it into the bins with some weight
            seen_y, seen_x = fy.sum(axis=0) > MEASURED_WEIGHT, fx.sum(axis=0) > MEASURED_WEIGHT
        gains = 1.0 / (fitted.white.astype(np.float64) * scale)
        weight = 1.0 / gains[..., 0].size  # each mode's mean square error counts alike
        # vec(Fy T Fx') = (Fx kron Fy) vec(T), vec column-major: the normal equations of all modes at once.
        normal += weight * np.kron(fx.T @ fx, fy.T @ fy)
        rhs += weight * np.stack([(fy.T @ gains[..., c] @ fx).ravel(order="F") for c in range(3)])
    dy, dx = np.diff(np.eye(rows), 2, axis=0), np.diff(np.eye(cols), 2, axis=0)
    penalty = np.kron(np.eye(cols), dy.T @ dy) + np.kron(dx.T @ dx, np.eye(rows))
    solution = np.linalg.solve(normal + SMOOTHNESS * np.trace(normal) / n * penalty, rhs.T)
    tables = np.stack([solution[:, c].reshape((rows, cols), order="F") for c in range(3)])
    measured = np.outer(seen_y, seen_x)
    if not measured.all():
        # Outside the crop nothing is measured: each cell takes the nearest measured cell's gains, the table extended
        # by its edge values as libcamera's resampling clamps at a table's edges (continuous, and never beyond the
        # gains the crop needed, which the fit's smoothness penalty alone does not promise).
        ys, xs = np.flatnonzero(seen_y), np.flatnonzero(seen_x)
        iy = np.clip(np.arange(rows), ys.min(), ys.max())
        ix = np.clip(np.arange(cols), xs.min(), xs.max())
        tables = tables[:, iy][:, :, ix]
    return GainFit(tables, measured)


#: A table cell whose interpolation weight summed over the calibration's bins exceeds this (in bins) is measured.
MEASURED_WEIGHT = 0.05


def fit_gain_tables(calibration: Calibration, target: str) -> np.ndarray:
    """Least-squares R, G, B gain tables (3, rows, cols) over the full sensor whose ISP-interpolated gains flatten
    the white in the calibration's sensor mode and in every mode inside its crop.

    libcamera's tables cover the full sensor; for a mode it resamples them to the mode's crop (``resampleCalTable``,
    :func:`picamcal.export.isp.mode_resampling`, ``R``), then the IPA and the ISP interpolate them to the pixels
    (:func:`picamcal.export.isp.table_to_pixels`, ``P``). The per-pixel gains in a mode are ``Py Ry T Rx' Px'``,
    averaged over each bin, ``Fy T Fx'`` with ``F = bin average @ P @ R``; the target in each bin is the reciprocal of
    the white there, ``1 / W_c(b)`` (paper: ``Cb LST = 1 / W``), with the white taken at the mode's bins
    (:func:`picamcal.calibration.resample.resample_calibration`). The table is the least-squares solution over the
    calibration's mode and every sensor mode inside its crop (:func:`mode_coverage`), each mode's mean square
    error counting alike, with a small second-difference penalty (:data:`SMOOTHNESS`); libcamera resamples a table
    coarsely to a cropped mode (most on a Pi 4's 16 x 12 grid), so a table fitted to one mode alone can miss
    another by several per cent (a calibration made from a lens shading table, :mod:`picamcal.export.tables`, is
    fitted in the full sensor mode alone: the field a table describes is the one it gives there). A calibration of the
    whole sensor (binned or not) measures every cell; one from a
    cropped mode measures the cells over its crop, and the table is extended beyond it by its edge values: every
    mode inside the crop comes out flat, the others are extrapolated.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> fit_gain_tables(cal, "bcm2835").shape, fit_gain_tables(cal, "pisp").shape  # the Pi 4's and the Pi 5's grid
    ((3, 12, 16), (3, 32, 32))
    >>> red, green, blue = fit_gain_tables(cal, "pisp")
    >>> bool(green[0, 0] > 1.5 * green[16, 16])  # the corners, darker, get more gain
    True
    """
    return _fit(calibration, target).tables


def mode_coverage(calibration: Calibration) -> dict[str, list[str]]:
    """Which of the sensor's modes (:func:`picamcal.sensors.sensor_modes`) lie inside the calibration's crop
    (``"covered"``: an exported table makes them flat) and which reach outside it (``"extrapolated"``), named
    ``WIDTHxHEIGHT:BITS`` (:func:`sensor_mode_geometries`).

    Examples
    --------
    >>> from picamcal.geometry import SensorMode
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> mode_coverage(cal)["extrapolated"]
    []
    """
    geometry = calibration.geometry
    assert geometry is not None
    coverage: dict[str, list[str]] = {"covered": [], "extrapolated": []}
    for name, mode in sensor_mode_geometries(calibration).items():
        inside = geometry.contains(mode.crop, CROP_TOLERANCE * max(mode.binning, geometry.binning))
        coverage["covered" if inside else "extrapolated"].append(name)
    return coverage


def sensor_mode_geometries(calibration: Calibration) -> dict[str, SensorMode]:
    """The sensor's modes by name (``WIDTHxHEIGHT:BITS``) on the calibration's sensor: the registry's
    (:func:`picamcal.sensors.sensor_modes`, reduced with the sensor where the calibration's is a reduced one, as the
    simulator's and the virtual camera's ``--size`` make them); for a sensor outside the registry, or a calibration
    whose sensor is only assumed to be of its own size, the whole sensor and the calibration's own mode.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"])
    >>> list(sensor_mode_geometries(cal))  # the IMX219's modes on a sensor reduced to 320 x 240
    ['62x46:8', '160x120:8', '188x106:8', '320x240:8', '62x46:10', '160x120:10', '188x106:10', '320x240:10']
    """
    geometry = calibration.geometry
    assert geometry is not None
    sensor = SENSORS.get(calibration.sensor or "")
    size = geometry.sensor_size
    if sensor is not None and (size == sensor.size or geometry.source not in ("assumed", "unknown")):
        return {
            f"{m.width}x{m.height}:{m.bit_depth}": driver_geometry(size, m) for m in sensor_modes(sensor.name, size)
        }
    bits = geometry.bit_depth or calibration.bit_depth
    full = SensorMode.full(*geometry.sensor_size, bit_depth=bits, source="assumed")
    return {f"{m.width}x{m.height}:{bits}": m for m in (full, geometry)}


def _describe_cells(mask: np.ndarray) -> str:
    rows, cols = mask.shape
    names = []
    for r, c in zip(*np.nonzero(mask), strict=True):
        vertical = "top" if r < rows / 3 else "bottom" if r >= 2 * rows / 3 else "middle"
        horizontal = "left" if c < cols / 3 else "right" if c >= 2 * cols / 3 else "centre"
        names.append(f"{vertical}-{horizontal}")
    return ", ".join(sorted(set(names)))


def alsc_tables(
    calibration: Calibration, target: str, *, luminance_strength: float = 1.0, clip_gains: bool = False
) -> dict[str, np.ndarray]:
    """The ``luminance_lut``, ``Cr`` and ``Cb`` tables (rows, cols) of a static lens shading table.

    ``L`` is normalised to 1 at its brightest cell, ``Cr = G/R`` and ``Cb = G/B`` gains to 1 at their
    smallest (libcamera uses only their shape), so the gains libcamera applies are
    ``R = Cr (1 + s (L - 1))``, ``G = 1 + s (L - 1)``, ``B = Cb (1 + s (L - 1))``.

    Raises
    ------
    TuningError
        A gain would reach the hardware limit (8 on pisp, 16 on bcm2835) and ``clip_gains`` is False; the
        message names the calibration's file.

    Warns
    -----
    PicamcalWarning
        With ``clip_gains``, which cells were clipped and by how much.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> tables = alsc_tables(cal, "pisp")
    >>> {name: (table.shape, round(float(table.min()), 3)) for name, table in tables.items()}
    {'luminance_lut': ((32, 32), 1.0), 'Cr': ((32, 32), 1.0), 'Cb': ((32, 32), 1.0)}
    >>> round(float(tables["luminance_lut"].max()), 1)  # the darkest corner's gain
    1.9
    """
    fit = _fit(calibration, target)
    t_r, t_g, t_b = fit.tables
    if np.any(fit.tables[:, fit.measured] <= 0):
        raise TuningError(
            "the fitted lens shading table has gains <= 0: the white reference is too uneven", calibration.path
        )
    lum = t_g / t_g[fit.measured].min()
    cr, cb = t_r / t_g, t_b / t_g
    cr, cb = cr / cr[fit.measured].min(), cb / cb[fit.measured].min()
    s = luminance_strength
    green = 1 + s * (lum - 1)
    final = {"red": cr * green, "green": green, "blue": cb * green}
    limit = GAIN_LIMITS[target]
    ceiling = np.nextafter(limit, 0) - 1e-3
    over = {name: g > ceiling for name, g in final.items()}
    if any(m.any() for m in over.values()):
        worst = max(float(g.max()) for g in final.values())
        where = _describe_cells(np.logical_or.reduce(list(over.values())))
        message = (
            f"the lens shading table needs gains up to {worst:.2f}, above the {target} hardware limit of {limit:g}, "
            f"in {sum(int(m.sum()) for m in over.values())} cells ({where})"
        )
        if not clip_gains:
            raise TuningError(
                f"{message}; pass --clip-gains to clip them (those areas then stay darker)", calibration.path
            )
        warnings.warn(
            f"{message}: clipped, so those cells stay up to {100 * (1 - ceiling / worst):.0f} % darker",
            PicamcalWarning,
            stacklevel=2,
        )
        final = {name: np.minimum(g, ceiling) for name, g in final.items()}
        green = final["green"]
        lum = 1 + (green - 1) / s if s > 0 else lum
        cr, cb = final["red"] / green, final["blue"] / green
    return {"luminance_lut": lum, "Cr": cr, "Cb": cb}


def neutral_colour_gains(
    calibration: Calibration, tuning: dict[str, Any], mode: SensorMode | None = None
) -> tuple[float, float]:
    """The colour gains (red, blue) that make the calibration's white neutral through a tuning file's lens shading,
    in a sensor mode (default the calibration's own).

    libcamera's ``ColourGains`` (rpicam-apps ``--awbgains R,B``): the white's mean red, green and blue over the
    mode's frame after the per-pixel gains the ISP applies with this file's static ``rpi.alsc`` tables in that mode
    (:func:`picamcal.export.isp.lens_shading_gains`: resampled to the mode, interpolated as the IPA and the hardware
    do), then green / red and green / blue. libcamera scales each mode's colour tables to 1 at their smallest cell
    over the mode's crop, so the gains differ between modes, and between the vc4 and pisp files of one
    calibration. A mode reaching outside the calibration's crop is measured over the part inside it.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> from picamcal.export.tuning import export_tuning, load_tuning, stock_tuning_path
    >>> neutral_colour_gains(cal, export_tuning(cal, load_tuning(stock_tuning_path("imx219", "bcm2835"))))
    (1.2514, 1.0028)
    """
    check_tuning(tuning)
    geometry = calibration.geometry
    assert geometry is not None
    mode = mode or geometry
    gy, corners, gx = lens_shading_factors(tuning, mode)
    area = _overlap(mode, geometry)
    if area is None:
        raise TuningError(f"the {mode.describe()} mode does not overlap the calibration's crop", calibration.path)
    x0, y0, x1, y1 = area
    crop = (*_sensor_xy(mode, x0, y0), (x1 - x0) * mode.binning, (y1 - y0) * mode.binning)
    inside = resample_calibration(calibration, dataclasses.replace(mode, crop=crop))
    if mode.hflip:  # the window in the mirrored image
        x0, x1 = mode.width - x1, mode.width - x0
    if mode.vflip:
        y0, y1 = mode.height - y1, mode.height - y0
    size = inside.bin_size
    # The gains averaged over each bin of the window, in the separable form (never the whole per-pixel image).
    rows, cols = _bin_average(y1 - y0, size) @ gy[y0:y1], _bin_average(x1 - x0, size) @ gx[x0:x1]
    binned = np.stack([rows @ corner @ cols.T for corner in corners], axis=-1)
    red, green, blue = (binned * inside.white).reshape(-1, 3).mean(axis=0)
    return round(float(green / red), 4), round(float(green / blue), 4)


def _sensor_xy(mode: SensorMode, x: int, y: int) -> tuple[int, int]:
    """The sensor position of the top left of pixel (x, y) of an unflipped mode."""
    return mode.crop[0] + x * mode.binning, mode.crop[1] + y * mode.binning


def _overlap(mode: SensorMode, geometry: SensorMode) -> tuple[int, int, int, int] | None:
    """The pixels (x0, y0, x1, y1) of the mode's image, as if unflipped, whose sensor area lies inside the
    calibration's crop, or None."""
    gx, gy, gw, gh = geometry.crop
    mx, my, _, _ = mode.crop
    b = mode.binning
    x0, y0 = max(0, -(-(gx - mx) // b)), max(0, -(-(gy - my) // b))
    x1, y1 = min(mode.width, (gx + gw - mx) // b), min(mode.height, (gy + gh - my) // b)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    return x0, y0, x1, y1
