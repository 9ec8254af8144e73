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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import PicamcalError
from ..raw.model import RawImage, site_channels
from ..sensors import LSC_GRIDS, SENSORS

#: Largest gain each target's hardware can apply (exclusive).
GAIN_LIMITS = {"bcm2835": 16.0, "pisp": 8.0}


@dataclass(frozen=True)
class SensorMode:
    """Where a sensor mode's image lies on the full sensor (libcamera's ``CameraMode``).

    Attributes
    ----------
    sensor_width, sensor_height : int
        Full sensor size in pixels.
    crop : (x, y, width, height)
        The sensor area the mode reads, in full-sensor pixels.
    binning : int
        Binning or scaling factor from that area to the mode's image.
    hflip, vflip : bool
        Mirroring of the mode's image.
    """

    sensor_width: int
    sensor_height: int
    crop: tuple[int, int, int, int]
    binning: int = 1
    hflip: bool = False
    vflip: bool = False

    @classmethod
    def full(cls, width: int, height: int) -> SensorMode:
        """The full-resolution mode of a ``width`` x ``height`` sensor."""
        return cls(width, height, (0, 0, width, height))

    @property
    def width(self) -> int:
        """Image width of the mode."""
        return self.crop[2] // self.binning

    @property
    def height(self) -> int:
        """Image height of the mode."""
        return self.crop[3] // self.binning


def full_sensor_size(raw: RawImage) -> tuple[int, int]:
    """The full sensor size a raw image's lens shading refers to: the file's record, the registry's, or its own.

    Examples
    --------
    >>> full_sensor_size(picamcal.read_raw("binned.dng"))  # doctest: +SKIP
    (3280, 2464)
    """
    if raw.metadata.get("sensor_size"):
        width, height = raw.metadata["sensor_size"]
        return int(width), int(height)
    sensor = SENSORS.get(raw.sensor or "")
    return (sensor.width, sensor.height) if sensor else (raw.width, raw.height)


def mode_for_image(
    sensor_size: tuple[int, int], image_size: tuple[int, int], crop: tuple[int, int, int, int] | None = None
) -> SensorMode:
    """The sensor mode an image of ``image_size`` comes from: full size, a binned full field, or an explicit crop.

    Raises
    ------
    PicamcalError
        The image is neither the full sensor nor an integer binning of it, and no crop is given.

    Examples
    --------
    >>> mode_for_image((3280, 2464), (1640, 1232)).binning
    2
    """
    (sw, sh), (w, h) = sensor_size, image_size
    if crop is None:
        for binning in (1, 2, 3, 4):
            if (sw // binning, sh // binning) == (w, h) or (-(-sw // binning), -(-sh // binning)) == (w, h):
                return SensorMode(sw, sh, (0, 0, sw, sh), binning)
        raise PicamcalError(
            f"a {w}x{h} image is not the full {sw}x{sh} sensor or a binned copy of it: give the sensor crop of its "
            "mode (--sensor-crop X,Y,WIDTH,HEIGHT in full-sensor pixels)"
        )
    x, y, cw, ch = crop
    if x < 0 or y < 0 or x + cw > sw or y + ch > sh:
        raise PicamcalError(f"sensor crop {crop} lies outside the {sw}x{sh} sensor")
    binning = round(cw / w)
    if binning < 1 or abs(cw / binning - w) > 1 or abs(ch / binning - h) > 1:
        raise PicamcalError(f"a {w}x{h} image cannot come from the {cw}x{ch} sensor crop {crop}")
    return SensorMode(sw, sh, (x, y, cw, ch), binning)


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
    """libcamera's ``resampleCalTable`` as two matrices (rows, columns): ``table_mode = Ry @ table @ Rx.T``."""
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


def _grid_to_pixels(n_grid: int, spacing: float, n_pixels: int) -> np.ndarray:
    """Bilinear interpolation matrix (n_pixels x n_grid) from grid points at ``k * spacing`` to pixels."""
    position = np.arange(n_pixels) / spacing
    lo = np.clip(np.floor(position).astype(int), 0, n_grid - 2)
    frac = np.clip(position - lo, 0.0, 1.0)
    matrix = np.zeros((n_pixels, n_grid))
    matrix[np.arange(n_pixels), lo] = 1 - frac
    matrix[np.arange(n_pixels), lo + 1] += frac
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
    """Matrices (Py, Px) such that per-pixel gains are ``Py @ table @ Px.T`` for a centre-sampled table
    of the target's grid over the mode's image (the IPA's ``resampleTable`` and the hardware's bilinear
    interpolation, without the fixed-point rounding)."""
    cy, cx, gy, gx = _grid_matrices(target, width, height)
    return gy @ cy, gx @ cx


def _quantise(corner: np.ndarray, target: str) -> np.ndarray:
    """The hardware's fixed-point gains: u4.10 on bcm2835; on pisp one of four ranges chosen per vertex."""
    if target == "bcm2835":
        return np.minimum(np.floor(1024 * corner + 0.5), 16383) / 1024
    lo, hi = corner.min(axis=0), corner.max(axis=0)
    scale = np.select([(lo >= 0.5) & (hi < 1.5), hi < 2.0, hi < 4.0], [1024.0, 512.0, 256.0], 128.0)
    offset = np.where(scale == 1024.0, -511.5, 0.5)
    code = np.clip(np.floor(offset + scale * corner + 0.5), 0, 1023)  # std::round: halves away from zero
    return (code - offset) / scale


def alsc_section(tuning: dict[str, Any]) -> dict[str, Any]:
    """The ``rpi.alsc`` parameters of a tuning file."""
    for algorithm in tuning.get("algorithms", []):
        if "rpi.alsc" in algorithm:
            return algorithm["rpi.alsc"]
    raise PicamcalError("the tuning file has no rpi.alsc section")


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
    """The R, G, B gain tables (3, rows, cols) libcamera's static ALSC programs for a sensor mode."""
    target = tuning.get("target", "bcm2835")
    cols, rows = LSC_GRIDS[target]
    alsc = alsc_section(tuning)
    ct = float(alsc.get("default_ct", 4500) if ct is None else ct)
    ry, rx = mode_resampling((cols, rows), mode)

    def resampled(flat: np.ndarray) -> np.ndarray:
        return ry @ flat.reshape(rows, cols) @ rx.T

    cr = resampled(_table_at_ct(alsc.get("calibrations_Cr", []), ct, cols * rows))
    cb = resampled(_table_at_ct(alsc.get("calibrations_Cb", []), ct, cols * rows))
    if "luminance_lut" not in alsc:
        raise PicamcalError("rpi.alsc has no luminance_lut (a corner_strength table is not supported)")
    luminance = resampled(np.asarray(alsc["luminance_lut"], dtype=float))
    strength = float(alsc.get("luminance_strength", 1.0))
    lum = 1 + strength * (luminance - 1)
    return np.stack([cr / cr.min() * lum, lum, cb / cb.min() * lum])


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
    >>> gains = lens_shading_gains(tuning, 3280, 2464)  # doctest: +SKIP
    """
    target = tuning.get("target", "bcm2835")
    mode = mode or SensorMode.full(width, height)
    tables = channel_tables(tuning, mode, ct)
    cy, cx, gy, gx = _grid_matrices(target, width, height)
    # The hardware receives the corner-sampled grid in fixed point.
    corners = _quantise(np.stack([cy @ t @ cx.T for t in tables]), target)
    return np.stack([gy @ c @ gx.T for c in corners], axis=-1).astype(np.float32)


def isp_gains_for_image(
    tuning: dict[str, Any],
    sensor_size: tuple[int, int],
    image_size: tuple[int, int],
    *,
    crop: tuple[int, int, int, int] | None = None,
    ct: float | None = None,
) -> np.ndarray:
    """Lens shading gains at the pixels of a processed image, shape (height, width, 3).

    The ISP applies the gains at the sensor mode's resolution and then scales its output; the gains
    are smooth, so they are computed for the mode (the full sensor, or ``crop``) and resampled to the image.
    """
    mode = SensorMode(*sensor_size, crop or (0, 0, *sensor_size))
    gains = lens_shading_gains(tuning, mode.width, mode.height, mode=mode, ct=ct)
    width, height = image_size
    ys = np.clip(np.round((np.arange(height) + 0.5) * mode.height / height - 0.5).astype(int), 0, mode.height - 1)
    xs = np.clip(np.round((np.arange(width) + 0.5) * mode.width / width - 0.5).astype(int), 0, mode.width - 1)
    return gains[ys][:, xs]


def tuning_black_level(tuning: dict[str, Any], bit_depth: int) -> float | None:
    """``rpi.black_level`` at ``bit_depth`` bits (the file stores it on a 16-bit scale), or None."""
    for algorithm in tuning.get("algorithms", []):
        if "rpi.black_level" in algorithm:
            return float(algorithm["rpi.black_level"]["black_level"]) * 2.0 ** (bit_depth - 16)
    return None


def tuning_ccm(tuning: dict[str, Any], ct: float) -> np.ndarray | None:
    """The ``rpi.ccm`` matrix at colour temperature ``ct`` (linear in ct between entries), or None."""
    for algorithm in tuning.get("algorithms", []):
        if "rpi.ccm" in algorithm:
            entries = algorithm["rpi.ccm"].get("ccms", [])
            if not entries:
                return None
            return _table_at_ct([{"ct": e["ct"], "table": e["ccm"]} for e in entries], ct, 9).reshape(3, 3)
    return None


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
        White balance gains; default the raw's metadata ``colour_gains``, else 1.
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
    >>> rgb = apply_tuning(picamcal.read_raw("white.dng"), load_tuning("imx219.json"))  # doctest: +SKIP
    """
    from ..correct import demosaic

    if mode is None:
        mode = mode_for_image(sensor_size or full_sensor_size(raw), (raw.width, raw.height))
    black = tuning_black_level(tuning, raw.bit_depth)
    levels = np.asarray(raw.black_level if black is None else (black,) * 4, dtype=np.float32)
    gains = lens_shading_gains(tuning, raw.width, raw.height, mode=mode, ct=ct)
    if colour_gains is None:
        colour_gains = tuple(raw.metadata.get("colour_gains") or (1.0, 1.0))  # type: ignore[assignment]
    balance = np.array([colour_gains[0], 1.0, colour_gains[1]], dtype=np.float32)
    mosaic = raw.bayer.astype(np.float32)
    for site, channel in enumerate(site_channels(raw.pattern)):
        sy, sx = divmod(site, 2)
        plane = mosaic[sy::2, sx::2]
        plane -= levels[site]
        plane *= gains[sy::2, sx::2, channel] * balance[channel] / (raw.white_level - levels[site])
    rgb = demosaic(mosaic, raw.pattern)
    if ccm:
        alsc_ct = float(alsc_section(tuning).get("default_ct", 4500) if ct is None else ct)
        matrix = tuning_ccm(tuning, alsc_ct)
        if matrix is None:
            raise PicamcalError("the tuning file has no rpi.ccm to apply")
        rgb = np.einsum("pq,yxq->yxp", matrix.astype(np.float32), rgb)
    return rgb
