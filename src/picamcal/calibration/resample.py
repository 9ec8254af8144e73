"""One calibration in every sensor mode: its fields taken at another mode's sensor positions.

A calibration's fields are smooth functions of the position on the sensor (the paper's flat field ``W(b)`` and
unmixing field ``U(b)``, sampled per bin). A frame from another sensor mode, a crop or a binned readout of the area
the calibration was taken in, sees the same sensor: its bins are mapped onto the calibration's sensor coordinates
(:func:`picamcal.geometry.image_to_image`: crop, binning, flips) and the fields interpolated there, bilinearly
between bin centres, as libcamera's ``resampleCalTable`` resamples its lens shading tables to a mode. Only the area
the calibration covers can be corrected: a frame reaching outside its crop is refused, never extrapolated.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np

from ..bayer import bin_centres, centre_region
from ..errors import CalibrationFileError
from ..geometry import SensorMode, image_to_image
from ..raw.model import RawImage, raw_geometry
from . import Calibration

__all__ = ["CROP_TOLERANCE", "calibration_for_raw", "resample_calibration", "site_order"]

#: Where a geometry is taken rather than told (:data:`picamcal.geometry.GEOMETRY_SOURCES`).
GUESSED_SOURCES = frozenset(("registry", "assumed", "unknown"))
#: Pixels a frame's sensor area may reach past the calibration's crop (the rounding of binned and odd-sized modes).
CROP_TOLERANCE = 2


def _weights(n_target: int, n_source: int, bin_size: int, a: float, b: float) -> np.ndarray:
    """Matrix (target bins x source bins) of bilinear weights between the source's bin centres at the target's bin
    centres, mapped by ``u_source = a u_target + b`` (continuous coordinates); clamped at the outer centres.
    ``n_target`` and ``n_source`` are the images' sizes in pixels along the axis."""
    centres = bin_centres(n_target, bin_size) + 0.5
    mapped = a * centres + b - 0.5
    source = bin_centres(n_source, bin_size)
    position = np.interp(mapped, source, np.arange(source.size, dtype=np.float64))
    lo = np.clip(np.floor(position).astype(int), 0, source.size - 1)
    hi = np.minimum(lo + 1, source.size - 1)
    frac = position - lo
    weights = np.zeros((centres.size, source.size))
    rows = np.arange(centres.size)
    weights[rows, lo] += 1 - frac
    weights[rows, hi] += frac
    return weights


def site_order(source: str, target: str) -> list[int]:
    """For each 2x2 site of Bayer order ``target``, the site of ``source`` with the same colour filter (a green by the
    colour it shares its row with, as libcamera's Gr and Gb).

    Examples
    --------
    >>> site_order("RGGB", "BGGR"), site_order("RGGB", "GRBG")
    ([3, 2, 1, 0], [1, 0, 3, 2])
    """
    order = []
    for k, colour in enumerate(target):
        partner = target[k ^ 1]
        order.append(next(j for j, c in enumerate(source) if c == colour and (c != "G" or source[j ^ 1] == partner)))
    return order


@lru_cache(maxsize=16)
def _resampled(cal: Calibration, target: SensorMode, pattern: str) -> Calibration:
    geometry = cal.geometry
    assert geometry is not None
    (ax, bx), (ay, by) = image_to_image(target, geometry)
    wy = _weights(target.height, cal.height, cal.bin_size, ay, by)
    wx = _weights(target.width, cal.width, cal.bin_size, ax, bx)

    def field(array: np.ndarray) -> np.ndarray:
        # wy along the rows, then wx along the columns, as matrix products (BLAS), whatever the trailing axes.
        out = np.tensordot(wy, array.astype(np.float64), axes=(1, 0))
        out = np.moveaxis(np.tensordot(wx, out, axes=(1, 1)), 0, 1)
        return out.astype(array.dtype) if array.dtype != bool else out > 0

    def optional(array: np.ndarray | None) -> np.ndarray | None:
        return None if array is None else field(array)

    order = site_order(cal.pattern, pattern)
    site_white = field(cal.site_white)
    responses = field(cal.site_responses.transpose(1, 2, 0, 3))
    provenance = dict(cal.provenance)
    provenance["resampled_from"] = geometry.to_record()
    return dataclasses.replace(
        cal,
        pattern=pattern,
        width=target.width,
        height=target.height,
        centre_region=centre_region(wy.shape[0], wx.shape[0]),
        geometry=target,
        provenance=provenance,
        site_responses=np.ascontiguousarray(responses.transpose(2, 0, 1, 3)[..., order]),
        site_white=np.ascontiguousarray(site_white[..., order]),
        white=field(cal.white),
        lens_shading=field(cal.lens_shading),
        crosstalk=optional(cal.crosstalk),
        unmixing=optional(cal.unmixing),
        pure_unmixing=optional(cal.pure_unmixing),
        condition_number=optional(cal.condition_number),
        ill_conditioned=optional(cal.ill_conditioned),
    )


def resample_calibration(calibration: Calibration, target: SensorMode, pattern: str | None = None) -> Calibration:
    """The calibration's fields at the bins of an image of another sensor mode ``target`` (Bayer order ``pattern``,
    default the calibration's).

    The result is a calibration of the target's size and mode: its per-bin fields (the white ``W``, the lens
    shading, the crosstalk ``M``, the unmixing ``U`` and ``inv(M)``, their condition numbers) interpolated at the
    target's bin centres, its per-site fields reordered for the target's Bayer order; its global values (the
    colour balance ``Cb``, ``M_centre``, ``Cx``) are the calibration's, so that a frame of any mode is corrected to
    the same white. Cached: the same calibration and mode give the same value (and the correction's cached fields).

    Raises
    ------
    CalibrationFileError
        The target is on another sensor (or the calibration's geometry is not known to be that sensor's), or reaches
        outside the calibration's crop; the message says what covers it.

    Examples
    --------
    >>> from picamcal.geometry import SensorMode
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> binned = resample_calibration(cal, SensorMode.full(320, 240, binning=2))  # a 2 x 2 binned mode
    >>> binned.width, binned.height, binned.unmixing.shape
    (160, 120, (8, 10, 3, 3))
    >>> crop = resample_calibration(cal, SensorMode(320, 240, (80, 60, 160, 120)))  # its central quarter
    >>> float(np.abs(crop.white[3, 5] - cal.white[7, 10]).max()) < 0.02 * float(cal.white.max())
    True
    """
    geometry = calibration.geometry
    assert geometry is not None  # a Calibration always has one
    if target.sensor_size != geometry.sensor_size:
        known = "" if geometry.source not in ("assumed", "unknown") else f" ({geometry.source}: it records no mode)"
        raise CalibrationFileError(
            f"size {target.width}x{target.height}, calibration is for {calibration.width}x{calibration.height}: the "
            f"image is of a {target.sensor_width}x{target.sensor_height} sensor, the calibration of a "
            f"{geometry.sensor_width}x{geometry.sensor_height} one{known}; give the image's sensor area "
            "(--sensor-crop X,Y,WIDTH,HEIGHT) or calibrate in the image's mode",
            calibration.path,
        )
    tolerance = CROP_TOLERANCE * max(target.binning, geometry.binning)
    if not geometry.contains(target.crop, tolerance):
        x, y, w, h = target.crop
        raise CalibrationFileError(
            f"the image reads the sensor area {w}x{h} at ({x}, {y}), outside the calibration's "
            f"{geometry.crop[2]}x{geometry.crop[3]} at ({geometry.crop[0]}, {geometry.crop[1]}): calibrate in a mode "
            "that covers it (a full-sensor or binned mode covers every mode)",
            calibration.path,
        )
    return _resampled(calibration, target, pattern or calibration.pattern)


def calibration_for_raw(calibration: Calibration, raw: RawImage, geometry: SensorMode | None = None) -> Calibration:
    """The calibration to correct ``raw`` with: itself for a frame of its own mode, else resampled to the frame's
    (:func:`resample_calibration`), the frame's mode ``geometry`` or :func:`picamcal.raw.model.raw_geometry`'s.

    Raises
    ------
    CalibrationFileError
        Another sensor, a mode outside the calibration's crop, or a frame whose mode is not known (the message names
        ``--sensor-crop``); naming the image.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> refs = simulate_references(camera, seed=1)
    >>> cal = picamcal.calibrate(**refs)
    >>> calibration_for_raw(cal, refs["white"]) is cal
    True
    """
    assert calibration.geometry is not None
    same_size = (raw.width, raw.height) == (calibration.width, calibration.height)
    same_frame = same_size and raw.pattern == calibration.pattern
    if geometry is None:
        if same_frame and not raw.metadata.get("sensor_crop"):
            calibration.check_compatible(raw)  # a frame that does not say its mode: taken as the calibration's
            return calibration
        geometry = raw_geometry(raw)
    guessed = GUESSED_SOURCES.intersection((geometry.source, calibration.geometry.source))
    same_area = geometry.area() == calibration.geometry.area() and raw.pattern == calibration.pattern
    if same_area or (same_frame and guessed):
        # A frame of the calibration's size and Bayer order is of its mode unless both say otherwise for certain.
        calibration.check_compatible(raw)
        return calibration
    calibration.check_compatible(raw, same_mode=False)
    try:
        return resample_calibration(calibration, geometry, raw.pattern)
    except CalibrationFileError as exc:
        raise CalibrationFileError(f"image does not match the calibration: {exc.problem}", raw.source) from None
