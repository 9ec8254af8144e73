"""The legacy firmware's lens shading table (MMAL; the picamera fork ``rwb27/picamera``, branch lens-shading).

A uint8 array of shape (4, H // 64 + 1, W // 64 + 1) from the sensor's full resolution, whatever the
mode: planes R, Gr, Gb, B; each entry is the gain at the centre of a 64 x 64-pixel cell (sensor pixel
32 + 64 k), in u3.5 fixed point (32 = 1.0, at most 255, about 7.97), interpolated bilinearly by the
firmware. It corrects the processed (ISP) output only (FORMATS.md section 5). It needs only the flat
field, so a flat-field calibration (white only) exports it as a full one does, to the same table.

Loading it with the picamera fork::

    import numpy as np
    from picamera import PiCamera

    camera = PiCamera()
    camera.lens_shading_table = np.load("lst.npy")
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from ..bayer import bin_centres
from ..calibration import Calibration
from ..errors import PicamcalError
from ..interpolate import interpolation_matrix, upsample
from ..raw.model import RawImage

CELL = 64
UNITY = 32
#: The largest gain a table entry holds: 255 / 32, about 7.97.
MAX_GAIN = 255 / UNITY


def table_shape(width: int, height: int) -> tuple[int, int, int]:
    """Shape of the legacy table for a full sensor of ``width`` x ``height``.

    Examples
    --------
    >>> table_shape(3280, 2464), table_shape(2592, 1944)
    ((4, 39, 52), (4, 31, 41))
    """
    return 4, height // CELL + 1, width // CELL + 1


def plane_sites(pattern: str) -> list[int]:
    """Bayer site (row-major in the 2x2 block) of each plane R, Gr, Gb, B; Gr is the green on the red row.

    Examples
    --------
    >>> plane_sites("BGGR")
    [3, 2, 1, 0]
    """
    red = pattern.index("R")
    blue = pattern.index("B")
    gr = red ^ 1  # the other site of red's row
    gb = blue ^ 1
    return [red, gr, gb, blue]


def _cell_interpolation(n_cells: int, n_pixels: int, site: int) -> np.ndarray:
    """Bilinear interpolation between cell centres (32 + 64 k), clamped beyond the outer ones, at one site's pixels."""
    return cell_interpolation(n_cells, np.arange(site, n_pixels, 2))


def cell_interpolation(n_cells: int, positions: np.ndarray) -> np.ndarray:
    """The firmware's interpolation of a legacy table along one axis, as a matrix (positions x cells).

    Bilinear between the cell centres (sensor pixel 32 + 64 k), clamped beyond the outer ones; ``positions`` are
    sensor pixel coordinates (pixel centres at integers), any real numbers.

    Examples
    --------
    >>> cell_interpolation(3, np.array([0.0, 64.0, 500.0])).tolist()  # before the first centre, between, past the last
    [[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.0, 0.0, 1.0]]
    """
    pixels = np.asarray(positions, dtype=np.float64)
    position = np.clip((pixels - CELL / 2) / CELL, 0, n_cells - 1)
    lo = np.minimum(np.floor(position).astype(int), n_cells - 2)
    frac = position - lo
    matrix = np.zeros((pixels.size, n_cells))
    matrix[np.arange(pixels.size), lo] = 1 - frac
    matrix[np.arange(pixels.size), lo + 1] += frac
    return matrix


#: How a tool turned gains into a table's bytes: ``nearest`` (picamcal's :func:`legacy_table`), ``floor`` (OpenFlexure's
#: ``gains.astype(np.uint8)``, 6by9's ``lens_shading`` integer division).
ROUNDINGS = ("nearest", "floor")
#: The smoother of :func:`legacy_gains`: third differences (a quadratic fall-off, the shape of vignetting, passes
#: unchanged), its weight, and the alternations with the rounding interval; chosen on simulated IMX219 whites, where
#: they bring a rounded table's residual flatness from twice to within 1.1 times the unrounded table's.
DEQUANTISE_ORDER, DEQUANTISE_WEIGHT, DEQUANTISE_ITERATIONS = 3, 10.0, 200


def legacy_gains(table: np.ndarray, rounding: str = "nearest") -> np.ndarray:
    """The gains (4, rows, cols) a legacy table stands for: the smoothest consistent with its bytes.

    A u3.5 byte holds a gain to 1/32 (3 % at unity), coarser than the flat field it was made from; taken as they
    are, the steps leave about twice the residual of the unrounded gains. So each plane is dequantised by alternating
    projections: a third-difference smoother along rows and columns (:data:`DEQUANTISE_ORDER`), then back into the
    interval the byte was rounded from (``nearest``: within half a step; ``floor``: up to a step above; a byte of 32
    or 255 may have been clipped there, so its interval is open on that side). The result rounds back to the table.

    Examples
    --------
    >>> rows = np.round(32 * (1 + 0.5 * np.linspace(-1, 1, 12) ** 2))  # a quadratic fall-off, rounded
    >>> table = np.broadcast_to(rows[None, :, None], (4, 12, 8)).astype(np.uint8)
    >>> gains = legacy_gains(table)
    >>> bool(np.array_equal(np.round(32 * gains), table))  # consistent with the bytes
    True
    >>> truth = 1 + 0.5 * np.linspace(-1, 1, 12) ** 2
    >>> bool(np.abs(gains[0, :, 0] - truth).max() < np.abs(table[0, :, 0] / 32 - truth).max())  # nearer the truth
    True
    """
    if rounding not in ROUNDINGS:
        raise PicamcalError(f"unknown rounding {rounding!r} (expected {' or '.join(ROUNDINGS)})")
    steps = np.asarray(table, dtype=np.float64)
    lo, hi = (steps - 0.5, steps + 0.5) if rounding == "nearest" else (steps, steps + 1.0)
    hi = np.where(steps >= 255, np.inf, hi)
    _, rows, cols = steps.shape
    sy, sx = _smoother(rows), _smoother(cols)
    gains = steps.copy()
    for _ in range(DEQUANTISE_ITERATIONS):
        gains = np.clip(sy @ gains @ sx.T, lo, hi)
    return gains / UNITY


def _smoother(n: int) -> np.ndarray:
    """Whittaker's smoother along one axis: ``inv(I + w D'D)``, D the differences of :data:`DEQUANTISE_ORDER`."""
    order = min(DEQUANTISE_ORDER, n - 1)
    d = np.diff(np.eye(n), order, axis=0)
    return np.linalg.inv(np.eye(n) + DEQUANTISE_WEIGHT * d.T @ d)


def legacy_table(calibration: Calibration, rounding: str = "nearest") -> np.ndarray:
    """The legacy lens shading table of a calibration: uint8 (4, H // 64 + 1, W // 64 + 1), planes R, Gr, Gb, B.

    Each plane's target gain is its white's maximum over the white (1 at the brightest point, so the
    table does not change the colour balance, as the firmware expects); the table values are chosen by
    least squares so that the firmware's bilinear interpolation fits the target at every pixel row and
    column of the sensor, then rounded to u3.5 (``rounding``: ``nearest``, or ``floor`` as OpenFlexure's and 6by9's
    tools do) and clipped to 32..255.

    Raises
    ------
    PicamcalError
        A gain above 255/32 would be needed: refused, never clipped or wrapped round (a table full of 255 gives
        black images, a reported failure).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> table = legacy_table(cal)
    >>> table.shape, table.dtype, int(table.min())  # gain 1.0 (32) at the brightest point
    ((4, 4, 6), dtype('uint8'), 32)
    """
    _, rows, cols = table_shape(calibration.width, calibration.height)
    planes = []
    for site in plane_sites(calibration.pattern):
        sy, sx = divmod(site, 2)
        ys, xs = np.arange(sy, calibration.height, 2), np.arange(sx, calibration.width, 2)
        white = upsample(
            calibration.site_white[..., site].astype(np.float64),
            interpolation_matrix(bin_centres(calibration.height, calibration.bin_size, sy), ys),
            interpolation_matrix(bin_centres(calibration.width, calibration.bin_size, sx), xs),
        )
        gain = white.max() / white
        ay = _cell_interpolation(rows, calibration.height, sy)
        ax = _cell_interpolation(cols, calibration.width, sx)
        planes.append(np.linalg.pinv(ay) @ gain @ np.linalg.pinv(ax).T)
    gains = np.stack(planes)
    if not np.all(np.isfinite(gains)):
        raise PicamcalError("the legacy table's gains are not finite: the calibration's white is not usable")
    if gains.max() > MAX_GAIN:
        raise PicamcalError(
            f"the legacy table would need gains up to {gains.max():.2f}, above its maximum of {MAX_GAIN:.2f} "
            "(u3.5 in a byte): the legacy firmware cannot correct this much vignetting; use export-tuning for "
            "libcamera (gains up to 8 on a Pi 5, 16 on a Pi 4)"
        )
    if rounding not in ROUNDINGS:
        raise PicamcalError(f"unknown rounding {rounding!r} (expected {' or '.join(ROUNDINGS)})")
    steps = np.round(gains * UNITY) if rounding == "nearest" else np.floor(gains * UNITY)
    return np.clip(steps, UNITY, 255).astype(np.uint8)


def check_legacy_table(table: np.ndarray) -> None:
    """Raise PicamcalError unless ``table`` is what the firmware reads: uint8 of shape (4, rows, columns).

    Gains are u3.5 (32 = 1.0): any other dtype is refused rather than converted, so no gain wraps round.

    Examples
    --------
    >>> check_legacy_table(np.full((4, 39, 52), 32, np.uint8))
    >>> check_legacy_table(np.full((4, 39, 52), 8.5))
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: a legacy table must be uint8 (u3.5 gains, 32 = 1.0), not float64: make it \
with legacy_table()
    """
    if not isinstance(table, np.ndarray) or table.dtype != np.uint8:
        dtype = table.dtype if isinstance(table, np.ndarray) else type(table).__name__
        raise PicamcalError(
            f"a legacy table must be uint8 (u3.5 gains, 32 = 1.0), not {dtype}: make it with legacy_table()"
        )
    if table.ndim != 3 or table.shape[0] != 4 or min(table.shape) < 2:
        raise PicamcalError(f"a legacy table has shape (4, rows, columns), not {table.shape}")


def apply_legacy_table(raw: RawImage, table: np.ndarray) -> np.ndarray:
    """Apply a legacy table to a raw mosaic the way the firmware does: black-subtracted mosaic times gains.

    Returns the float32 mosaic (H, W) with each site multiplied by its plane's gains, interpolated
    bilinearly between cell centres. For checking a table on a PC; the camera applies it to its ISP output.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> white = refs["white"]
    >>> flat = apply_legacy_table(white, legacy_table(picamcal.calibrate(**refs)))
    >>> def spread(mosaic):  # of one of the two green sites, relative to its mean
    ...     green = mosaic[1::2, 0::2]
    ...     return float(green.std() / green.mean())
    >>> spread(flat) < 0.05 < spread(white.black_subtracted())
    True
    """
    expected = table_shape(raw.width, raw.height)
    if table.shape != expected:
        raise PicamcalError(
            f"a legacy table for a {raw.width}x{raw.height} sensor has shape {expected}, not {table.shape}"
        )
    mosaic = raw.black_subtracted()
    for plane, site in zip(table, plane_sites(raw.pattern), strict=True):
        sy, sx = divmod(site, 2)
        ay = _cell_interpolation(expected[1], raw.height, sy)
        ax = _cell_interpolation(expected[2], raw.width, sx)
        mosaic[sy::2, sx::2] *= (ay @ (plane.astype(np.float64) / UNITY) @ ax.T).astype(np.float32)
    return mosaic


def save_legacy_table(path: str | os.PathLike[str], table: np.ndarray, overwrite: bool = False) -> Path:
    """Save a legacy table as ``.npy`` (what ``numpy.load`` gives back to the picamera fork), atomically.

    Raises
    ------
    PicamcalError
        Not a table the firmware reads (:func:`check_legacy_table`); nothing is written.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> save_legacy_table("lens_shading.npy", legacy_table(cal))
    PosixPath('lens_shading.npy')
    >>> np.load("lens_shading.npy").shape  # what the picamera fork's camera.lens_shading_table takes
    (4, 4, 6)
    >>> save_legacy_table("lens_shading.npy", legacy_table(cal))
    Traceback (most recent call last):
    ...
    picamcal.errors.OutputError: lens_shading.npy: exists already (use --overwrite to replace it)
    """
    check_legacy_table(table)
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        np.save(f, table)
    return path


def is_legacy_table(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is a legacy lens shading table (``.npy`` of uint8, shape (4, rows, columns)).

    Examples
    --------
    >>> save_legacy_table("lens_shading.npy", np.full((4, 4, 6), 32, np.uint8))
    PosixPath('lens_shading.npy')
    >>> is_legacy_table("lens_shading.npy"), is_legacy_table("missing.npy")
    (True, False)
    """
    if not os.path.isfile(path):  # a FIFO would block np.load
        return False
    try:
        table = np.load(path, mmap_mode="r", allow_pickle=False)
    except Exception:  # numpy's header parser raises many types (tokenize.TokenError among them): not a table
        return False
    return table.dtype == np.uint8 and table.ndim == 3 and table.shape[0] == 4
