"""What the Raspberry Pi ISP does with a tuning file's lens shading, emulated on a PC.

This follows libcamera's Raspberry Pi IPA step by step (src/ipa/rpi/controller/rpi/alsc.cpp and the
vc4/pisp IPAs), so that a tuning file can be checked against a raw image without a camera:

1. ``rpi.alsc`` tables are gains at the centres of a uniform grid of cells over the full sensor
   (16 x 12 for ``bcm2835``, 32 x 32 for ``pisp``), interpolated linearly in colour temperature.
2. ``resampleCalTable`` resamples them to the sensor mode's crop, binning and flips (bilinear,
   indices clamped at the edges).
3. The final tables with ``n_iter`` 0: ``R = Cr / min(Cr) * (1 + s (L - 1))``, ``G = 1 + s (L - 1)``,
   ``B = Cb / min(Cb) * (1 + s (L - 1))`` (L = ``luminance_lut``, s = ``luminance_strength``).
4. The IPA's ``resampleTable`` turns the centre-sampled table into the hardware's corner-sampled grid:
   on ``bcm2835`` a grid of cells of 16-256 pixels (the smallest giving fewer than 64 x 49 points),
   u4.10 fixed point below 16; on ``pisp`` 33 x 33 vertices spanning the image, packed in one of four
   ranges below 8.
5. The hardware interpolates the grid bilinearly to every pixel.

libcamera's rules for the file itself, and the hardware's ranges, are :mod:`picamcal.export.tuning_rules` (their
names are importable from here too).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, TypedDict

import numpy as np

from ..bayer import central_half, sites_to_channels
from ..calibration import Calibration
from ..errors import PicamcalError
from ..geometry import (
    Box,
    SensorMode,
    check_scaler_crop,
    default_scaler_crop,
    mode_for_image,
    registry_mode,
    stream_positions,
)
from ..raw.model import RawImage, site_channels
from ..raw.processed import ProcessedImage
from ..sensors import LSC_GRIDS, SENSORS
from .tuning_rules import (  # noqa: F401 - libcamera's rules, importable from here as before
    CCM_LIMITS,
    GAIN_LIMITS,
    RECORD_KEY,
    TuningError,
    check_hardware_range,
    check_tuning,
)

#: The colour temperature (kelvin) libcamera's ALSC starts from when ``rpi.alsc`` gives no ``default_ct``.
DEFAULT_CT = 4500.0


def full_sensor_size(raw: RawImage) -> tuple[int, int]:
    """The full sensor size a raw image's lens shading refers to: the file's record, the registry's, or its own.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_target
    >>> raw, _ = simulate_target(make_camera("imx219", size=(320, 240)), seed=1)
    >>> full_sensor_size(raw)  # the simulator records its (small) sensor's size
    (320, 240)
    """
    if raw.metadata.get("sensor_size"):
        width, height = raw.metadata["sensor_size"]
        return int(width), int(height)
    sensor = SENSORS.get(raw.sensor or "")
    return (sensor.width, sensor.height) if sensor else (raw.width, raw.height)


def _resample_matrix(n_out: int, n_in: int, start: float, step: float, flip: bool = False) -> np.ndarray:
    """Bilinear resampling matrix (n_out x n_in) of libcamera's table resamplers: sample i at index
    ``start + i * step`` of the input, indices clamped to the table."""
    matrix = np.zeros((n_out, n_in))
    for i in range(n_out):
        x = start + i * step
        lo = math.floor(x)
        frac = x - lo
        hi = min(lo + 1, n_in - 1)
        lo = max(lo, 0)
        if flip:
            lo, hi = n_in - 1 - lo, n_in - 1 - hi
        matrix[i, lo] += 1 - frac
        matrix[i, hi] += frac
    return matrix


def mode_resampling(grid: tuple[int, int], mode: SensorMode) -> tuple[np.ndarray, np.ndarray]:
    """libcamera's ``resampleCalTable`` as two matrices (rows, columns): ``table_mode = Ry @ table @ Rx.T``.

    Examples
    --------
    >>> ry, rx = mode_resampling((16, 12), SensorMode(3280, 2464, crop=(820, 616, 1640, 1232)))  # a central crop
    >>> ry[0].round(2).tolist()  # its first row of cells lies between the table's rows 2 and 3
    [0.0, 0.0, 0.25, 0.75, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    """
    cols, rows = grid
    x, y, w, h = mode.crop
    scale_x, scale_y = mode.sensor_width / w, mode.sensor_height / h
    rx = _resample_matrix(cols, cols, 0.5 / scale_x + x / mode.sensor_width * cols - 0.5, 1 / scale_x, mode.hflip)
    ry = _resample_matrix(rows, rows, 0.5 / scale_y + y / mode.sensor_height * rows - 0.5, 1 / scale_y, mode.vflip)
    return ry, rx


def hardware_grid(target: str, width: int, height: int) -> tuple[tuple[int, int], tuple[float, float]]:
    """Size (columns, rows) and spacing (x, y) in pixels of the corner-sampled grid the ISP interpolates.

    Examples
    --------
    >>> hardware_grid("bcm2835", 3280, 2464)
    ((53, 40), (64.0, 64.0))
    >>> hardware_grid("pisp", 4608, 2592)
    ((33, 33), (144.0, 81.0))
    """
    if target == "bcm2835":
        for cell in (16, 32, 64, 128, 256):
            w, h = -(-width // cell), -(-height // cell)
            if w < 64 and h <= 48:
                return (w + 1, h + 1), (float(cell), float(cell))
        raise PicamcalError(f"no lens shading cell size fits a {width}x{height} image")
    cols, rows = LSC_GRIDS["pisp"]
    return (cols + 1, rows + 1), (width / cols, height / rows)


def _grid_to_pixels(n_grid: int, spacing: float, positions: int | np.ndarray) -> np.ndarray:
    """Bilinear interpolation matrix (pixels x n_grid) from grid points at ``k * spacing`` to pixel positions
    (``positions``, pixel centres at integers, or ``n`` for the pixels ``0 .. n - 1``), clamped to the grid."""
    pixels = np.arange(positions) if isinstance(positions, int) else np.asarray(positions, dtype=float)
    position = pixels / spacing
    lo = np.clip(np.floor(position).astype(int), 0, n_grid - 2)
    frac = np.clip(position - lo, 0.0, 1.0)
    rows = np.arange(pixels.size)
    matrix = np.zeros((pixels.size, n_grid))
    matrix[rows, lo] = 1 - frac
    matrix[rows, lo + 1] += frac
    return matrix


def _grid_matrices(target: str, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(Cy, Cx, Gy, Gx): the IPA's centre-to-corner resampling and the hardware's corner-to-pixel interpolation."""
    cols, rows = LSC_GRIDS[target]
    (gw, gh), (sx, sy) = hardware_grid(target, width, height)
    # The PiSP IPA divides integers here (srcW / (destW - 1)); the VC4 IPA divides doubles.
    step_x, step_y = (cols // (gw - 1), rows // (gh - 1)) if target == "pisp" else (cols / (gw - 1), rows / (gh - 1))
    cx = _resample_matrix(gw, cols, -0.5, step_x)
    cy = _resample_matrix(gh, rows, -0.5, step_y)
    return cy, cx, _grid_to_pixels(gh, sy, height), _grid_to_pixels(gw, sx, width)


def table_to_pixels(target: str, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Matrices (Py, Px) such that per-pixel gains are ``Py @ table @ Px.T`` for a centre-sampled table of the target's
    grid over the mode's image (the IPA's ``resampleTable`` and the hardware's bilinear interpolation, unrounded).

    Examples
    --------
    >>> py, px = table_to_pixels("bcm2835", 320, 240)  # a Pi 4's 16 x 12 table, gain 2 on its right half:
    >>> (py @ np.repeat([[1.0, 2.0]], 8, axis=1).repeat(12, axis=0) @ px.T)[120, [0, 160, 319]].round(2).tolist()
    [1.0, 1.5, 2.0]
    """
    cy, cx, gy, gx = _grid_matrices(target, width, height)
    return gy @ cy, gx @ cx


def _quantise(corner: np.ndarray, target: str) -> np.ndarray:
    """The hardware's fixed-point gains: u4.10 on bcm2835 (unsigned: nothing below 0); on pisp one of four ranges
    chosen per vertex."""
    if target == "bcm2835":
        return np.clip(np.floor(1024 * corner + 0.5), 0, 16383) / 1024
    lo, hi = corner.min(axis=0), corner.max(axis=0)
    scale = np.select([(lo >= 0.5) & (hi < 1.5), hi < 2.0, hi < 4.0], [1024.0, 512.0, 256.0], 128.0)
    offset = np.where(scale == 1024.0, -511.5, 0.5)
    code = np.clip(np.floor(offset + scale * corner + 0.5), 0, 1023)  # std::round: halves away from zero
    return (code - offset) / scale


def alsc_section(tuning: dict[str, Any]) -> dict[str, Any]:
    """The ``rpi.alsc`` parameters of a tuning file.

    Raises
    ------
    PicamcalError
        The file has no ``rpi.alsc`` section.

    Examples
    --------
    >>> alsc_section({"algorithms": [{"rpi.alsc": {"default_ct": 5000}}]})
    {'default_ct': 5000}
    """
    for algorithm in tuning.get("algorithms", []):
        if "rpi.alsc" in algorithm:
            return algorithm["rpi.alsc"]
    raise PicamcalError("the tuning file has no rpi.alsc section")


def default_ct(tuning: Mapping[str, Any]) -> float:
    """The colour temperature a tuning file's static tables apply at: ``rpi.alsc`` ``default_ct``, else
    :data:`DEFAULT_CT` (as libcamera's ALSC reads it).

    Examples
    --------
    >>> default_ct({"algorithms": [{"rpi.alsc": {"default_ct": 5000}}]}), default_ct({"algorithms": []})
    (5000.0, 4500.0)
    """
    for algorithm in tuning.get("algorithms", []):
        if "rpi.alsc" in algorithm:
            return float(algorithm["rpi.alsc"].get("default_ct", DEFAULT_CT))
    return DEFAULT_CT


def _table_at_ct(calibrations: list[dict[str, Any]], ct: float, size: int) -> np.ndarray:
    """libcamera's ``getCalTable``: linear interpolation in colour temperature, clamped at the ends."""
    if not calibrations:
        return np.ones(size)
    cts = [c["ct"] for c in calibrations]
    tables = np.array([c["table"] for c in calibrations], dtype=float)
    if ct <= cts[0]:
        return tables[0]
    if ct >= cts[-1]:
        return tables[-1]
    i = int(np.searchsorted(cts, ct)) - 1
    t = (ct - cts[i]) / (cts[i + 1] - cts[i])
    return tables[i] * (1 - t) + tables[i + 1] * t


def channel_tables(tuning: dict[str, Any], mode: SensorMode, ct: float | None = None) -> np.ndarray:
    """The R, G, B gain tables (3, rows, cols) libcamera's static ALSC programs for a sensor mode.

    Examples
    --------
    >>> from picamcal.export.tuning import load_tuning, stock_tuning_path
    >>> tables = channel_tables(load_tuning(stock_tuning_path("imx219", "pisp")), SensorMode.full(3280, 2464))
    >>> tables.shape, round(float(tables[1, 0, 0]), 2)  # R, G, B on a Pi 5's 32 x 32 grid; 2.6 in green's corner
    ((3, 32, 32), 2.57)
    """
    target = tuning.get("target", "bcm2835")
    cols, rows = LSC_GRIDS[target]
    alsc = alsc_section(tuning)
    ct = default_ct(tuning) if ct is None else float(ct)
    ry, rx = mode_resampling((cols, rows), mode)

    def resampled(flat: np.ndarray) -> np.ndarray:
        return ry @ flat.reshape(rows, cols) @ rx.T

    cr = resampled(_table_at_ct(alsc.get("calibrations_Cr", []), ct, cols * rows))
    cb = resampled(_table_at_ct(alsc.get("calibrations_Cb", []), ct, cols * rows))
    if "luminance_lut" not in alsc and "corner_strength" in alsc:
        raise PicamcalError("rpi.alsc has no luminance_lut (a corner_strength table is not supported)")
    # Neither table: libcamera assumes unity luminance everywhere.
    luminance = resampled(np.asarray(alsc.get("luminance_lut", np.ones(cols * rows)), dtype=float))
    strength = float(alsc.get("luminance_strength", 1.0))
    lum = 1 + strength * (luminance - 1)
    return np.stack([cr / cr.min() * lum, lum, cb / cb.min() * lum])


def _hardware_tables(tuning: dict[str, Any], mode: SensorMode, ct: float | None) -> tuple[str, np.ndarray]:
    """The target and the corner-sampled R, G, B grids (3, rows, cols) the hardware receives for a mode, in its fixed
    point."""
    target = tuning.get("target", "bcm2835")
    tables = channel_tables(tuning, mode, ct)
    cy, cx, _, _ = _grid_matrices(target, mode.width, mode.height)
    return target, _quantise(np.stack([cy @ t @ cx.T for t in tables]), target)


def lens_shading_gains(
    tuning: dict[str, Any], width: int, height: int, *, mode: SensorMode | None = None, ct: float | None = None
) -> np.ndarray:
    """Per-pixel R, G, B gains, shape (height, width, 3), that the ISP applies with this tuning's lens shading.

    Parameters
    ----------
    tuning : dict
        A version 2 tuning file.
    width, height : int
        The image size (of the mode).
    mode : SensorMode, optional
        Where the image lies on the sensor; default the full sensor at this size.
    ct : float, optional
        Colour temperature in kelvin for interpolating the tables (default the file's ``default_ct``).

    Examples
    --------
    >>> from picamcal.export.tuning import load_tuning, stock_tuning_path
    >>> gains = lens_shading_gains(load_tuning(stock_tuning_path("imx219", "pisp")), 320, 240)
    >>> gains.shape, bool(gains[120, 160, 1] < gains[0, 0, 1])  # more gain in the corners
    ((240, 320, 3), True)
    """
    gy, corners, gx = lens_shading_factors(tuning, mode or SensorMode.full(width, height), ct=ct)
    return np.stack([gy @ c @ gx.T for c in corners], axis=-1).astype(np.float32)


def lens_shading_factors(
    tuning: dict[str, Any], mode: SensorMode, *, ct: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`lens_shading_gains` in separable form ``(Gy, corners, Gx)``: channel ``c``'s gain at pixel ``(y, x)``
    of the mode's image is ``(Gy @ corners[c] @ Gx.T)[y, x]``.

    ``corners`` (3, rows, cols) are the corner-sampled grids the hardware receives for the mode, in its fixed point;
    ``Gy`` (height, rows) and ``Gx`` (width, cols) its bilinear interpolation to the pixels. Sums and averages of the
    gains over areas then cost a few small matrix products, never the whole (height, width, 3) image.

    Examples
    --------
    >>> from picamcal.export.tuning import load_tuning, stock_tuning_path
    >>> tuning = load_tuning(stock_tuning_path("imx219", "pisp"))
    >>> gy, corners, gx = lens_shading_factors(tuning, SensorMode.full(320, 240))
    >>> gy.shape, corners.shape, gx.shape
    ((240, 33), (3, 33, 33), (320, 33))
    >>> bool(np.allclose(gy @ corners[1] @ gx.T, lens_shading_gains(tuning, 320, 240)[..., 1]))
    True
    """
    target, corners = _hardware_tables(tuning, mode, ct)
    _, _, gy, gx = _grid_matrices(target, mode.width, mode.height)
    return gy, corners, gx


def lens_shading_gains_at(
    tuning: dict[str, Any], mode: SensorMode, rows: np.ndarray, cols: np.ndarray, *, ct: float | None = None
) -> np.ndarray:
    """The R, G, B gains (3, len(rows), len(cols)) the ISP applies at some positions of a mode's image.

    :func:`lens_shading_gains` at chosen rows and columns only (pixel centres at integers, any real positions,
    clamped to the image): the tables libcamera computes for the mode, quantised as the hardware holds them and
    interpolated bilinearly from its grid, without making the whole (height, width, 3) image.

    Examples
    --------
    >>> from picamcal.export.tuning import load_tuning, stock_tuning_path
    >>> tuning = load_tuning(stock_tuning_path("imx219", "pisp"))
    >>> at = lens_shading_gains_at(tuning, SensorMode.full(320, 240), np.array([0.0, 120.0]), np.array([0.0, 160.0]))
    >>> bool(np.allclose(at[:, 1, 1], lens_shading_gains(tuning, 320, 240)[120, 160]))
    True
    """
    target, corners = _hardware_tables(tuning, mode, ct)
    (gw, gh), (spacing_x, spacing_y) = hardware_grid(target, mode.width, mode.height)
    gy = _grid_to_pixels(gh, spacing_y, np.clip(np.asarray(rows, dtype=float), 0, mode.height - 1))
    gx = _grid_to_pixels(gw, spacing_x, np.clip(np.asarray(cols, dtype=float), 0, mode.width - 1))
    return np.stack([gy @ c @ gx.T for c in corners])


def isp_gains_for_image(
    tuning: dict[str, Any],
    mode: SensorMode | tuple[int, int],
    image_size: tuple[int, int],
    *,
    scaler_crop: Box | None = None,
    ct: float | None = None,
) -> np.ndarray:
    """Lens shading gains at the pixels of a processed stream, shape (height, width, 3).

    libcamera computes the lens shading tables for the sensor mode (its crop, binning and flips: ``resampleCalTable``
    in ``src/ipa/rpi/controller/rpi/alsc.cpp``), the ISP applies them to the mode's image, and only then crops it to
    the ScalerCrop and scales it to the stream's size. So the gains at a stream's pixels are the mode's gains
    (:func:`lens_shading_gains`, as the hardware interpolates its grid) taken where each pixel lies in the mode's
    image (:func:`stream_positions`); the gains are smooth, so a pixel takes the grid's value at its centre.

    Parameters
    ----------
    tuning : dict
        A version 2 tuning file (the one the camera runs with).
    mode : SensorMode or (width, height)
        The camera's sensor mode (picamera2's configured sensor mode; :func:`picamcal.geometry.named_mode`); a
        (width, height) is a sensor of that size read whole, unbinned.
    image_size : (width, height)
        The stream's size.
    scaler_crop : (x, y, width, height), optional
        The sensor area the stream shows, in full-sensor pixels (picamera2's ``ScalerCrop`` metadata); default the
        mode's whole crop.
    ct : float, optional
        Colour temperature of the tables (default the file's ``default_ct``).

    Raises
    ------
    PicamcalError
        A ScalerCrop outside the mode's crop (:func:`check_scaler_crop`); a tuning without ``rpi.alsc``.

    Examples
    --------
    >>> from picamcal.export.tuning import load_tuning, stock_tuning_path
    >>> tuning = load_tuning(stock_tuning_path("imx219", "pisp"))
    >>> binned = SensorMode.full(3280, 2464, binning=2)
    >>> isp_gains_for_image(tuning, binned, (320, 240)).shape  # a small output of the 2 x 2 binned mode
    (240, 320, 3)
    >>> whole = isp_gains_for_image(tuning, binned, (320, 240))
    >>> zoom = isp_gains_for_image(tuning, binned, (320, 240), scaler_crop=(820, 616, 1640, 1232))  # 2x zoom
    >>> bool(abs(zoom[0, 0, 1] - whole[60, 80, 1]) < 0.01)  # the zoom's corner is the whole field's quarter point
    True
    """
    if not isinstance(mode, SensorMode):
        mode = SensorMode.full(int(mode[0]), int(mode[1]))
    target, corners = _hardware_tables(tuning, mode, ct)
    (gw, gh), (spacing_x, spacing_y) = hardware_grid(target, mode.width, mode.height)
    rows, cols = stream_positions(mode, image_size, scaler_crop)
    # The hardware's grid holds for the mode's pixels 0 .. n - 1: a position beyond them takes the edge pixel's gain.
    gy = _grid_to_pixels(gh, spacing_y, np.clip(rows, 0, mode.height - 1))
    gx = _grid_to_pixels(gw, spacing_x, np.clip(cols, 0, mode.width - 1))
    return np.stack([gy @ c @ gx.T for c in corners], axis=-1).astype(np.float32)


def tuning_black_level(tuning: dict[str, Any], bit_depth: int) -> float | None:
    """``rpi.black_level`` at ``bit_depth`` bits (the file stores it on a 16-bit scale), or None.

    A section without ``black_level`` means libcamera's default, 4096 (64 at 10 bits).

    Examples
    --------
    >>> tuning_black_level({"algorithms": [{"rpi.black_level": {"black_level": 4096}}]}, 10)
    64.0
    """
    for algorithm in tuning.get("algorithms", []):
        if "rpi.black_level" in algorithm:
            return float(algorithm["rpi.black_level"].get("black_level", 4096)) * 2.0 ** (bit_depth - 16)
    return None


def tuning_ccm(tuning: dict[str, Any], ct: float) -> np.ndarray | None:
    """The ``rpi.ccm`` matrix at colour temperature ``ct`` (linear in ct between entries), or None.

    Examples
    --------
    >>> ccms = [{"ct": 3000, "ccm": [2, -1, 0, 0, 1, 0, 0, 0, 1]}, {"ct": 6000, "ccm": [1, 0, 0, 0, 1, 0, 0, 0, 1]}]
    >>> tuning_ccm({"algorithms": [{"rpi.ccm": {"ccms": ccms}}]}, 4500)[0]
    array([ 1.5, -0.5,  0. ])
    """
    for algorithm in tuning.get("algorithms", []):
        if "rpi.ccm" in algorithm:
            entries = algorithm["rpi.ccm"].get("ccms", [])
            if not entries:
                return None
            return _table_at_ct([{"ct": e["ct"], "table": e["ccm"]} for e in entries], ct, 9).reshape(3, 3)
    return None


def applied_colour_gains(
    raw: RawImage, colour_gains: tuple[float, float] | None = None, tuning: Mapping[str, Any] | None = None
) -> tuple[float, float]:
    """The white balance gains (red, blue) to apply: ``colour_gains``, else (given a ``tuning``) those the tuning file
    records as making its calibration's white neutral (``picamcal export-tuning`` writes them; ``apply-tuning``'s
    default), else the raw's ``metadata["colour_gains"]`` (the gains the camera froze), else 1.

    What an ``apply_tuning`` output should record (as ``colour_gains``) so that :func:`processed_inputs` divides
    out the very gains it applied.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_target
    >>> raw, _ = simulate_target(make_camera("imx219", size=(320, 240)), seed=1)
    >>> applied_colour_gains(raw), applied_colour_gains(raw, (1.5, 1.2))
    ((2.0023, 1.0316), (1.5, 1.2))
    >>> applied_colour_gains(raw, tuning={"picamcal": {"colour_gains": [1.9, 1.4]}})
    (1.9, 1.4)
    """
    recorded = (tuning or {}).get(RECORD_KEY, {}).get("colour_gains")
    red, blue = colour_gains or recorded or raw.metadata.get("colour_gains") or (1.0, 1.0)
    return float(red), float(blue)


def apply_tuning(
    raw: RawImage,
    tuning: dict[str, Any],
    *,
    colour_gains: tuple[float, float] | None = None,
    ccm: bool = False,
    mode: SensorMode | None = None,
    sensor_size: tuple[int, int] | None = None,
    ct: float | None = None,
) -> np.ndarray:
    """Apply a tuning file's black level, static lens shading, colour gains and optionally CCM to a raw image.

    What the camera's ISP would do with the same raw frame, up to demosaicing (picamcal's), denoise and
    the tone curve (not applied): the output is linear RGB scaled so that the white level is 1.

    Parameters
    ----------
    raw : RawImage
    tuning : dict
        A version 2 tuning file (``load_tuning``).
    colour_gains : (red, blue), optional
        White balance gains; default the raw's metadata ``colour_gains`` (the camera's frozen ones), else 1.
        ``applied_colour_gains(raw, None, tuning)`` gives those an exported file records (``apply-tuning``'s default).
    ccm : bool
        Apply the tuning's ``rpi.ccm`` at ``ct``.
    mode : SensorMode, optional
        Where the image lies on the sensor; default from ``sensor_size`` and the image size.
    sensor_size : (width, height), optional
        The full sensor size; default :func:`full_sensor_size` (the file's record, the registry's size for
        its sensor, or the image size).
    ct : float, optional
        Colour temperature for the tables (default the file's ``default_ct``, or 4500).

    Returns
    -------
    ndarray of float32, shape (H, W, 3)

    Examples
    --------
    >>> from picamcal.export.tuning import load_tuning, stock_tuning_path
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
    >>> rgb = apply_tuning(white, load_tuning(stock_tuning_path("imx219", "pisp")), ccm=True)
    >>> rgb.shape, rgb.dtype
    ((240, 320, 3), dtype('float32'))
    """
    from ..correct import malvar_demosaic

    if mode is None:
        mode = mode_for_image(sensor_size or full_sensor_size(raw), (raw.width, raw.height))
    black = tuning_black_level(tuning, raw.bit_depth)
    levels = np.asarray(raw.black_level if black is None else (black,) * 4, dtype=np.float32)
    gains = lens_shading_gains(tuning, raw.width, raw.height, mode=mode, ct=ct)
    red, blue = applied_colour_gains(raw, colour_gains)
    balance = np.array([red, 1.0, blue], dtype=np.float32)
    mosaic = raw.bayer.astype(np.float32)
    for site, channel in enumerate(site_channels(raw.pattern)):
        sy, sx = divmod(site, 2)
        plane = mosaic[sy::2, sx::2]
        plane -= levels[site]
        plane *= gains[sy::2, sx::2, channel] * balance[channel] / (raw.white_level - levels[site])
    rgb = malvar_demosaic(mosaic, raw.pattern)
    if ccm:
        matrix = tuning_ccm(tuning, default_ct(tuning) if ct is None else ct)
        if matrix is None:
            raise PicamcalError("the tuning file has no rpi.ccm to apply")
        rgb = np.einsum("pq,yxq->yxp", matrix.astype(np.float32), rgb)
    return rgb


class ProcessedInputs(TypedDict):
    """What the ISP did to a processed image: the keyword arguments of :func:`picamcal.correct.correct_processed`."""

    ccm: np.ndarray | None
    isp_gains: np.ndarray
    colour_gains: tuple[float, float] | None
    crop: Box | None
    sensor_mode: SensorMode | None


def calibration_colour_gains(calibration: Calibration) -> tuple[float, float]:
    """The white balance of a camera frozen on the calibration's white reference: (green / red, green / blue).

    The white's bins over the central half of the frame (:func:`picamcal.bayer.central_half`), before any lens
    shading table:
    the region where ``picamcal acquire`` measures the ``ColourGains`` it freezes for the references (and where
    the simulator measures its ``colour_gains``), and the paper's procedure freezes the camera's.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), noise=False)
    >>> gains = calibration_colour_gains(picamcal.calibrate(**refs))
    >>> [round(g, 3) for g in gains], refs["white"].metadata["colour_gains"]  # the camera's own
    ([2.007, 1.031], [2.0023, 1.0316])
    """
    half_rows, half_cols = central_half(calibration.height, calibration.width)
    centre_y, centre_x = calibration.bin_centres
    rows = (centre_y >= half_rows.start) & (centre_y < half_rows.stop)
    cols = (centre_x >= half_cols.start) & (centre_x < half_cols.stop)
    sites = calibration.site_white[rows][:, cols].reshape(-1, 4).mean(axis=0, dtype=np.float64)
    red, green, blue = sites_to_channels(sites, calibration.pattern)
    return float(green / red), float(green / blue)


def _recorded_geometry(metadata: Mapping[str, Any], source: str) -> tuple[SensorMode | None, Box | None]:
    """The sensor mode and ScalerCrop a processed image's metadata records (picamcal's record first, as
    ``apply-tuning`` writes it), or None for each it does not."""
    record = metadata.get("picamcal")
    record = record if isinstance(record, Mapping) else {}
    mode_record = record.get("sensor_mode", metadata.get("sensor_mode"))
    crop = record.get("scaler_crop", metadata.get("scaler_crop"))
    mode = None
    if mode_record is not None:
        try:
            mode = SensorMode.from_record(mode_record)
        except (KeyError, TypeError, ValueError, PicamcalError) as exc:
            problem = exc.problem if isinstance(exc, PicamcalError) else f"{type(exc).__name__}: {exc}"
            raise PicamcalError(f"its recorded sensor_mode is not a sensor mode ({problem})", source) from None
    if crop is not None:
        if not isinstance(crop, (list, tuple)) or len(crop) != 4 or not all(isinstance(v, int) for v in crop):
            raise PicamcalError(f"its recorded scaler_crop {crop!r} is not X,Y,WIDTH,HEIGHT in whole pixels", source)
        crop = (crop[0], crop[1], crop[2], crop[3])
    return mode, crop


def _refuse_a_cropped_modes_size(
    calibration: Calibration, mode: SensorMode, size: tuple[int, int], source: str
) -> None:
    """An image that nothing places, of the very size of a cropped mode of the calibration's sensor (imx219's
    640x480, imx477's 1332x990) other than the calibration's own: it may show that mode's area or the whole
    calibration's, scaled, and taking the wrong one is silently wrong (corners at 0.44 of the centre). Refused."""
    candidate = registry_mode(calibration.sensor, *size)
    if candidate is None or candidate.is_full or candidate.sensor_size != mode.sensor_size:
        return
    if candidate.area() == mode.area():
        return
    x, y, w, h = candidate.crop
    raise PicamcalError(
        f"a {size[0]}x{size[1]} image may come from the {calibration.sensor}'s {size[0]}x{size[1]} mode (the {w}x{h} "
        f"area at ({x}, {y})) or show the calibration's whole area, scaled: say which with --sensor-mode "
        f"{size[0]}x{size[1]}, or --sensor-crop X,Y,WIDTH,HEIGHT (the sensor area it shows: picamera2's ScalerCrop)",
        source,
    )


def processed_geometry(
    calibration: Calibration,
    image: ProcessedImage | np.ndarray,
    *,
    crop: Box | None = None,
    sensor_mode: SensorMode | None = None,
) -> tuple[SensorMode, Box]:
    """The camera's sensor mode and the sensor area (ScalerCrop) a processed image shows.

    A processed image is the ISP's output: the sensor mode's image, lens-shaded for the mode, cropped to the
    ScalerCrop and scaled to the stream's size (:func:`isp_gains_for_image`). Its size says neither, so they come from,
    in this order:

    1. ``sensor_mode`` and ``crop``, the user's word (``correct --processed --sensor-mode``, ``--sensor-crop``);
    2. the image's record (``metadata["picamcal"]`` ``sensor_mode`` and ``scaler_crop``: what ``picamcal
       apply-tuning`` writes in its TIFF; or the same keys in ``metadata``);
    3. the mode: the calibration's own (its :attr:`~picamcal.calibration.Calibration.geometry`); the area: for a
       mode given or recorded, the ScalerCrop libcamera gives a stream of the image's size
       (:func:`~picamcal.geometry.default_scaler_crop`, the mode's whole crop when the aspect ratios agree), else the
       mode's whole crop (an image of another aspect ratio is then refused by
       :func:`picamcal.correct.correct_processed`, naming the options).

    Raises
    ------
    PicamcalError
        A crop outside the sensor or the mode's crop (:func:`check_scaler_crop`), or a damaged record; naming the image.

    Examples
    --------
    >>> from picamcal.geometry import named_mode
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> processed_geometry(cal, np.zeros((120, 160, 3)))[1]  # nothing says: the calibration's whole area
    (0, 0, 320, 240)
    >>> mode, crop = processed_geometry(cal, np.zeros((90, 160, 3)), sensor_mode=SensorMode.full(320, 240))
    >>> crop  # a 16:9 stream of a 4:3 mode: libcamera's default crop, centred
    (0, 30, 320, 180)
    """
    metadata = image.metadata if isinstance(image, ProcessedImage) else {}
    source = str(metadata.get("path", "<image>"))
    height, width = image.rgb.shape[:2] if isinstance(image, ProcessedImage) else np.shape(image)[:2]
    recorded_mode, recorded_crop = _recorded_geometry(metadata, source)
    what = "--sensor-crop" if crop is not None else "the recorded scaler_crop" if recorded_crop else "the ScalerCrop"
    said = sensor_mode or recorded_mode
    mode = said or calibration.geometry or SensorMode.full(calibration.width, calibration.height)
    area = crop or recorded_crop
    if said is None and area is None:
        _refuse_a_cropped_modes_size(calibration, mode, (int(width), int(height)), source)
    if area is None:
        area = default_scaler_crop(mode, (int(width), int(height))) if said is not None else mode.crop
    try:
        return mode, check_scaler_crop(mode, area, what)
    except PicamcalError as exc:
        raise PicamcalError(exc.problem, source) from None


def processed_inputs(
    tuning: dict[str, Any],
    calibration: Calibration,
    image: ProcessedImage | np.ndarray,
    *,
    ct: float | None = None,
    crop: Box | None = None,
    sensor_mode: SensorMode | None = None,
    colour_gains: tuple[float, float] | None = None,
) -> ProcessedInputs:
    """What the camera's ISP did to a processed image, from the tuning file it ran with, for ``correct_processed``.

    The ISP applied the tuning file's static lens shading (``rpi.alsc``) for the camera's sensor mode, cropped and
    scaled its image to the stream (:func:`isp_gains_for_image` gives the gains at the stream's pixels), the camera's
    colour gains and then its colour matrix (``rpi.ccm``), the tables at the colour temperature ``ct``.
    :func:`picamcal.correct.correct_processed` maps the stream onto the calibration's sensor area, divides out the
    lens shading and colour gains with the calibration's flat field (so the white is neutral where the unmixing
    acts, as on the raw path), and undoes and re-applies the matrix around the unmixing:
    ``correct_processed(image, cal, mode, **processed_inputs(tuning, cal, image))``, what
    ``picamcal correct --processed --tuning FILE`` does for each image.

    The colour gains matter: the table's gains at the centre are not neutral (libcamera scales the colour
    tables to 1 at their smallest cell, not at the centre; (1.67, 1.03, 1.05) for an IMX219 table exported from
    the simulator), so the white is neutral in the image only if the camera's white balance was frozen on the
    white with this tuning loaded (its auto white balance measures after the lens shading). Gains frozen
    otherwise (before the table was loaded, as ``picamcal acquire`` records them) must be given.

    Parameters
    ----------
    tuning : dict
        The libcamera tuning file the camera ran with (:func:`picamcal.export.tuning.load_tuning`).
    calibration : Calibration
        The calibration the image is corrected with.
    image : ProcessedImage or ndarray (H, W, 3)
        The processed image (its size and its record are used: the ISP scales its output).
    ct : float, optional
        Colour temperature in kelvin; default the tuning file's (:func:`default_ct`).
    crop : (x, y, width, height), optional
        The sensor area the image shows, in full-sensor pixels: picamera2's ``ScalerCrop`` metadata of the capture.
        Default: the image's record, else as :func:`processed_geometry` says.
    sensor_mode : SensorMode, optional
        The camera's sensor mode (its crop, binning and flips; :func:`picamcal.geometry.named_mode` gives a sensor's
        mode by its size): libcamera computes the lens shading tables for it. Default: the image's record, else the
        calibration's own mode.
    colour_gains : (red, blue), optional
        The white balance gains the camera applied (Picamera2's ``ColourGains`` metadata). Default: the image's
        ``metadata["colour_gains"]`` if it has them (``picamcal apply-tuning`` records those it applied); else, for
        an apply-tuning output that records none (it applied the raw's frozen gains, those a calibration run
        freezes on its white), :func:`calibration_colour_gains`;
        else None: the camera's auto white balance ran on the white with this tuning loaded and was then frozen,
        so the image's white is neutral at the centre (:func:`picamcal.correct.correct_processed` keeps its
        balance there).

    Returns
    -------
    ProcessedInputs
        ``ccm`` (3 x 3; None if the file has no ``rpi.ccm``, or if the image is ``picamcal apply-tuning``'s
        output made without ``--ccm``, as its ``metadata["picamcal"]["ccm"]`` records), ``isp_gains``
        (H, W, 3), ``colour_gains``, ``crop`` and ``sensor_mode`` (those of :func:`processed_geometry`).

    Raises
    ------
    PicamcalError
        The tuning file has no ``rpi.alsc`` section; a crop outside the sensor or the mode's crop.

    Examples
    --------
    >>> from picamcal.correct import correct_processed
    >>> from picamcal.export.tuning import load_tuning, stock_tuning_path
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal = picamcal.calibrate(**refs)
    >>> tuning = load_tuning(stock_tuning_path("imx219", "pisp"))
    >>> image = np.full((120, 160, 3), 0.25, np.float32)  # a half-size ISP output
    >>> inputs = processed_inputs(tuning, cal, image)
    >>> inputs["isp_gains"].shape, inputs["ccm"].shape, inputs["crop"]
    ((120, 160, 3), (3, 3), (0, 0, 320, 240))
    >>> correct_processed(image, cal, "centre", **inputs).shape
    (120, 160, 3)
    """
    height, width = image.rgb.shape[:2] if isinstance(image, ProcessedImage) else np.shape(image)[:2]
    ct = default_ct(tuning) if ct is None else float(ct)
    mode, area = processed_geometry(calibration, image, crop=crop, sensor_mode=sensor_mode)
    gains = isp_gains_for_image(tuning, mode, (int(width), int(height)), scaler_crop=area, ct=ct)
    metadata = image.metadata if isinstance(image, ProcessedImage) else {}
    record = metadata.get("picamcal", {})  # apply-tuning's output says what the emulated ISP did
    if colour_gains is None and metadata.get("colour_gains"):
        colour_gains = metadata["colour_gains"]
    if colour_gains is None and "tuning" in record:
        colour_gains = calibration_colour_gains(calibration)
    # The camera's ISP always applies its CCM; apply-tuning only with --ccm, which its record keeps.
    applied_ccm = record.get("ccm", True) is not False
    return {
        "ccm": tuning_ccm(tuning, ct) if applied_ccm else None,
        "isp_gains": gains,
        "colour_gains": None if colour_gains is None else (float(colour_gains[0]), float(colour_gains[1])),
        "crop": area,
        "sensor_mode": mode,
    }
