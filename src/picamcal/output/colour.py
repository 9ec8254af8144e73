"""Colour for the sRGB outputs: the 3x3 matrix from a corrected image's RGB to linear sRGB, and the encoding.

:func:`camera_to_srgb` picks the best matrix known for a raw image (a tuning file's, the image's own, a DNG's);
:func:`srgb_encoding` makes of it the correction kernels' encoding to sRGB codes (the matrix, the white reference
at :data:`SRGB_WHITE_LEVEL`, the sRGB transfer function of IEC 61966-2-1 by a table), with which
``picamcal.correct(..., encoding=...)`` writes the codes straight from the raw frame; :func:`encode_srgb` applies
the same compiled code to a corrected float image.
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..ckernel import encode_image
from ..errors import PicamcalError, PicamcalWarning
from ..kernels import SrgbTable

#: Linear sRGB level of the white reference in the sRGB formats: 25 % headroom above it before clipping.
SRGB_WHITE_LEVEL = 0.8
#: Linear sRGB (D65) to CIE XYZ, IEC 61966-2-1:1999 section 5.2 (the standard's 4-digit matrix).
SRGB_TO_XYZ_D65 = np.array(
    [
        [0.4124, 0.3576, 0.1805],
        [0.2126, 0.7152, 0.0722],
        [0.0193, 0.1192, 0.9505],
    ]
)
#: CIE XYZ relative to D50 to linear sRGB (D65), Bradford chromatic adaptation: Bruce Lindbloom, "RGB/XYZ
#: Matrices" (http://www.brucelindbloom.com/Eqn_RGB_XYZ_Matrix.html, sRGB with reference white D50).
#: tests/test_output.py checks it against colour-science.
XYZ_D50_TO_SRGB = np.array(
    [
        [3.1338561, -1.6168667, -0.4906146],
        [-0.9787684, 1.9161415, 0.0334540],
        [0.0719453, -0.2289914, 1.4052427],
    ]
)
#: What an identity colour matrix means when nothing better is known.
NO_MATRIX = "none known: the camera's primaries are taken as sRGB's (identity)"

_STRIP_PIXELS = 1 << 20  # rows are encoded in strips of about this many pixels: bounded temporaries


@dataclass(frozen=True, eq=False)
class ColourMatrix:
    """A 3x3 matrix from a corrected image's RGB to linear sRGB, and where it came from.

    The matrix is normalised on construction so that white (1, 1, 1) maps to white (each row divided by its
    sum): the calibration's white reference stays neutral, at the stated level.

    Attributes
    ----------
    matrix : ndarray (3, 3)
        ``srgb = matrix @ rgb``, rows summing to 1.
    source : str
        Where it came from, in words (recorded in the outputs' metadata).

    Examples
    --------
    >>> ColourMatrix([[2.0, -0.5, -0.5], [-0.25, 1.5, -0.25], [0.0, -0.5, 1.5]], "my chart fit").matrix[0]
    array([ 2. , -0.5, -0.5])
    """

    matrix: np.ndarray
    source: str

    def __post_init__(self) -> None:
        matrix = np.asarray(self.matrix, dtype=float)
        if matrix.shape != (3, 3) or not np.isfinite(matrix).all():
            raise ValueError(f"a colour matrix is 3x3 and finite, not {matrix.tolist()}")
        white = matrix.sum(axis=1)
        if (white <= 1e-6).any():
            raise ValueError(f"this colour matrix takes white to {white.round(4).tolist()}: it cannot be normalised")
        object.__setattr__(self, "matrix", matrix / white[:, None])


def forward_matrix_to_srgb(forward_matrix: Any) -> np.ndarray:
    """White-balanced camera RGB to linear sRGB from a DNG ForwardMatrix (camera to XYZ D50), not normalised.

    The DNG specification (1.4, chapter 6, "Camera to XYZ (D50) transform") defines ForwardMatrix as mapping
    white-balanced camera colours to XYZ relative to D50; :data:`XYZ_D50_TO_SRGB` takes those to sRGB.

    Examples
    --------
    >>> np.allclose(forward_matrix_to_srgb(np.linalg.inv(XYZ_D50_TO_SRGB)), np.eye(3))  # sRGB primaries
    True
    """
    return XYZ_D50_TO_SRGB @ np.asarray(forward_matrix, dtype=float).reshape(3, 3)


def color_matrix_to_srgb(color_matrix: Any) -> np.ndarray:
    """White-balanced camera RGB to linear sRGB from a DNG ColorMatrix (XYZ to camera), white to white.

    As dcraw does it: ``camera_from_srgb = ColorMatrix @ SRGB_TO_XYZ_D65``, each row scaled so that sRGB
    white gives camera (1, 1, 1) (the white balance: the scene's white is taken as D65), then inverted.

    Raises
    ------
    ValueError
        The matrix is singular.

    Examples
    --------
    >>> np.allclose(color_matrix_to_srgb(np.linalg.inv(SRGB_TO_XYZ_D65)), np.eye(3))  # sRGB primaries
    True
    """
    camera_from_srgb = np.asarray(color_matrix, dtype=float).reshape(3, 3) @ SRGB_TO_XYZ_D65
    white = camera_from_srgb.sum(axis=1)
    if np.linalg.cond(camera_from_srgb) > 1e8 or (np.abs(white) < 1e-9).any():
        raise ValueError("the ColorMatrix is singular")
    return np.linalg.inv(camera_from_srgb / white[:, None])


def camera_to_srgb(
    metadata: Mapping[str, Any] | None = None,
    tuning: Mapping[str, Any] | None = None,
    *,
    tuning_path: str | os.PathLike[str] | None = None,
) -> ColourMatrix:
    """The colour matrix for the sRGB outputs of a raw image, from the best source known.

    In this order: the ``tuning`` file's ``rpi.ccm`` (libcamera's CCM maps white-balanced camera RGB to
    linear sRGB), at the image's colour temperature (``metadata["colour_temperature"]``, from picamera2),
    else the tuning file's default (:func:`picamcal.export.isp.default_ct`); the image's own libcamera CCM
    (``metadata["colour_correction_matrix"]``, picamera2's ``ColourCorrectionMatrix``); a DNG's
    ForwardMatrix1 (:func:`forward_matrix_to_srgb`); a DNG's ColorMatrix1 (:func:`color_matrix_to_srgb`);
    else the identity (:data:`NO_MATRIX`). An identity matrix in a file is a placeholder (picamcal's own
    DNGs carried one), not a measurement, and is passed over. The image's matrices are the camera's
    own: for the corrected image they are right in ``uncorrected``, ``flat`` and ``centre`` modes, whose
    output is white-balanced camera RGB.

    Parameters
    ----------
    metadata : mapping, optional
        The raw image's metadata (:attr:`picamcal.RawImage.metadata`).
    tuning : mapping, optional
        A libcamera tuning file (:func:`picamcal.export.tuning.load_tuning`).
    tuning_path : path-like, optional
        Where ``tuning`` came from: named in the matrix's source and in errors.

    Returns
    -------
    ColourMatrix

    Raises
    ------
    PicamcalError
        The tuning file has no ``rpi.ccm``.

    Examples
    --------
    >>> camera_to_srgb({"colour_correction_matrix": [1.8, -0.6, -0.2, -0.3, 1.6, -0.3, 0.0, -0.7, 1.7]}).source
    "the image's ColourCorrectionMatrix (libcamera's CCM at capture)"
    >>> camera_to_srgb({}).source == NO_MATRIX
    True
    """
    metadata = metadata or {}
    if tuning is not None:
        from ..export.isp import default_ct, tuning_ccm

        ct = float(metadata.get("colour_temperature") or default_ct(dict(tuning)))
        ccm = tuning_ccm(dict(tuning), ct)
        if ccm is None:
            raise PicamcalError("has no rpi.ccm colour matrix: give the camera's own tuning file", tuning_path)
        name = Path(tuning_path).name if tuning_path is not None else "the tuning file"
        return ColourMatrix(ccm, f"{name} rpi.ccm at {ct:.0f} K")
    where = metadata.get("path", "the image")
    candidates = (
        ("colour_correction_matrix", "the image's ColourCorrectionMatrix (libcamera's CCM at capture)", np.asarray),
        ("forward_matrix1", "the DNG's ForwardMatrix1, then XYZ D50 to sRGB (Bradford)", forward_matrix_to_srgb),
        ("color_matrix1", "the DNG's ColorMatrix1, inverted (scene white taken as D65)", color_matrix_to_srgb),
    )
    for key, source, to_srgb in candidates:
        values = metadata.get(key)
        if values is None:
            continue
        matrix = np.asarray(values, dtype=float)
        if matrix.size != 9 or np.allclose(matrix.reshape(3, 3), np.eye(3)):
            continue
        try:
            return ColourMatrix(to_srgb(matrix.reshape(3, 3)), source)
        except ValueError as exc:
            warnings.warn(f"{where}: its {key} is not usable ({exc}); trying the next source", PicamcalWarning, 2)
    return ColourMatrix(np.eye(3), NO_MATRIX)


def srgb_transfer(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1:1999, the encoding): linear 0-1 to non-linear 0-1.

    Examples
    --------
    >>> float(srgb_transfer(np.array(SRGB_WHITE_LEVEL)) * 255)
    231.11459710273513
    """
    linear = np.asarray(linear, dtype=float)
    return np.where(
        linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(np.maximum(linear, 0.0031308), 1 / 2.4) - 0.055
    )


def srgb_encoding(
    colour_matrix: ColourMatrix | None = None, *, white_level: float = SRGB_WHITE_LEVEL, bits: int = 8
) -> SrgbTable:
    """The sRGB formats' encoding, for the correction kernels: matrix, white level, clip, transfer function, round.

    ``code = round((2**bits - 1) * srgb_transfer(clip(white_level * matrix @ rgb, 0, 1)))``, NaN as 0, with the
    matrix product in float32 (as the kernels compute, in the order ``(m0 r + m1 g) + m2 b``) and the rest exact:
    the transfer function and its rounding by a table (the code at the start of each of 4096 cells of 0..1 for
    8 bits, 2**20 for 16, and the one threshold inside each). Give it to ``picamcal.correct(..., encoding=)``
    (the codes straight from the raw frame) or :func:`picamcal.ckernel.encode_image` (a float image's).

    Parameters
    ----------
    colour_matrix : ColourMatrix, optional
        To linear sRGB (:func:`camera_to_srgb`); default the identity.
    white_level : float
        The linear sRGB level of the white reference (1.0 in the corrected image).
    bits : {8, 16}
        uint8 codes (``srgb-png``, ``srgb-jpeg``) or uint16 (``srgb-png16``).

    Returns
    -------
    SrgbTable
        The matrix ``white_level * colour_matrix`` in float32, and the tables (made once per process).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal = picamcal.calibrate(**refs)
    >>> codes = picamcal.correct(refs["white"], cal, "flat", encoding=srgb_encoding(bits=8))
    >>> codes.dtype, int(np.median(codes))  # the white reference at its code, 231
    (dtype('uint8'), 231)
    """
    if bits not in (8, 16):
        raise ValueError("bits is 8 or 16")
    matrix = np.eye(3) if colour_matrix is None else colour_matrix.matrix
    return SrgbTable(np.asarray(white_level * matrix, dtype=np.float32), *_float32_table(bits))


def encode_srgb(
    rgb: np.ndarray,
    colour_matrix: ColourMatrix | None = None,
    *,
    white_level: float = SRGB_WHITE_LEVEL,
    bits: int = 8,
) -> np.ndarray:
    """Linear RGB (white reference 1.0) to sRGB code values: matrix, white level, clip, transfer function.

    ``code = round((2**bits - 1) * srgb_transfer(clip(white_level * matrix @ rgb, 0, 1)))``; NaN gives 0. A
    float32 image (what :func:`picamcal.correct` returns) goes through the correction kernel's own compiled code
    (:func:`picamcal.ckernel.encode_image` with :func:`srgb_encoding`), the matrix product in float32: its codes are
    those the kernel writes, bit for bit. Another type keeps the product in float64 (numpy, a strip of rows at a
    time); the two differ by one code at most, where a value lies within float32's rounding of a code's threshold.

    Parameters
    ----------
    rgb : ndarray (H, W, 3)
        Corrected linear RGB.
    colour_matrix : ColourMatrix, optional
        To linear sRGB (:func:`camera_to_srgb`); default the identity.
    white_level : float
        The linear sRGB level of the white reference (1.0 in ``rgb``).
    bits : {8, 16}

    Returns
    -------
    ndarray of uint8 or uint16, shape (H, W, 3)

    Examples
    --------
    >>> encode_srgb(np.ones((1, 1, 3), np.float32))
    array([[[231, 231, 231]]], dtype=uint8)
    """
    encoding, rgb = srgb_encoding(colour_matrix, white_level=white_level, bits=bits), check_rgb(rgb)
    if rgb.dtype == np.float32:
        return encode_image(rgb, table=encoding)
    to_linear = (white_level * (np.eye(3) if colour_matrix is None else colour_matrix.matrix)).T
    out = np.empty(rgb.shape, dtype=encoding.base.dtype)
    base, inside = _code_table(bits)
    for rows in strips(rgb.shape):
        linear = rgb[rows].astype(float) @ to_linear
        # fmax and fmin take the number where the other is NaN: NaN gives 0, and +-inf clip as any value
        np.fmin(np.fmax(linear, 0.0, out=linear), 1.0, out=linear)
        cell = (linear * (len(base) - 1)).astype(np.intp)  # exact: the cells are a power of two
        out[rows] = base[cell] + (linear >= inside[cell])
    return out


@functools.cache
def _code_table(bits: int) -> tuple[np.ndarray, np.ndarray]:
    """``round(top * srgb_transfer(x))`` for x in [0, 1] as a table lookup, exactly (``top = 2**bits - 1``).

    [0, 1] is cut into ``cells`` equal cells (a power of two, narrower than the distance between two codes'
    thresholds, so that at most one threshold falls inside a cell); ``base[c]`` is the code at the start of cell
    c and ``inside[c]`` the threshold inside it (inf if none), so that the code of x in cell c is
    ``base[c] + (x >= inside[c])``. A threshold is the smallest float64 x whose code reaches k, found by bisection
    over the float64 values (ordered as their bit patterns): the same arithmetic as the formula, so the same codes.
    """
    top = 2**bits - 1
    # The steepest part of the curve is its linear segment (slope 12.92): thresholds there are 1 / (12.92 * top)
    # apart, more than a cell of 2**-12 (8 bits) or 2**-20 (16 bits).
    cells = 2**12 if bits == 8 else 2**20

    def codes(x: np.ndarray) -> np.ndarray:
        return np.rint(top * srgb_transfer(x))

    wanted = np.arange(1, top + 1)
    low = np.zeros(top, np.int64)  # bit patterns of 0.0, whose code 0 is below every k
    high = np.full(top, np.float64(1.0).view(np.int64))  # and of 1.0, whose code top reaches every k
    while np.any(high - low > 1):
        middle = low + (high - low) // 2
        reached = codes(middle.view(np.float64)) >= wanted
        high, low = np.where(reached, middle, high), np.where(reached, low, middle)
    thresholds = high.view(np.float64)
    base = codes(np.arange(cells + 1) / cells).astype(np.uint8 if bits == 8 else np.uint16)
    cell = (thresholds * cells).astype(np.intp)
    within = thresholds > cell / cells  # a threshold at a cell's start is in its base already
    inside = np.full(cells + 1, np.inf)
    inside[cell[within]] = thresholds[within]
    return base, inside


@functools.cache
def _float32_table(bits: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_code_table` for float32 values, read-only: each threshold rounded up to a float32, the smallest that
    reaches it, so that ``v >= inside`` holds for a float32 ``v`` exactly when it does in float64."""
    base, inside = _code_table(bits)
    inside32 = inside.astype(np.float32)
    low = inside32 < inside
    inside32[low] = np.nextafter(inside32[low], np.float32(np.inf))
    for table in (base, inside32):
        table.flags.writeable = False
    return base, inside32


def check_rgb(rgb: np.ndarray) -> np.ndarray:
    """``rgb`` as an array, refused (ValueError) unless it is a corrected image, (H, W, 3).

    Examples
    --------
    >>> check_rgb(np.zeros((2, 4, 3))).shape
    (2, 4, 3)
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"a corrected image is (H, W, 3), not {rgb.shape}")
    return rgb


def strips(shape: tuple[int, ...]) -> list[slice]:
    """Slices of rows of about a megapixel each: an image is encoded strip by strip, with bounded temporaries.

    Examples
    --------
    >>> len(strips((3040, 4056, 3)))
    12
    """
    step = max(1, _STRIP_PIXELS // max(1, shape[1]))
    return [slice(y, y + step) for y in range(0, shape[0], step)]


__all__ = [
    "NO_MATRIX",
    "SRGB_TO_XYZ_D65",
    "SRGB_WHITE_LEVEL",
    "XYZ_D50_TO_SRGB",
    "ColourMatrix",
    "camera_to_srgb",
    "check_rgb",
    "color_matrix_to_srgb",
    "encode_srgb",
    "forward_matrix_to_srgb",
    "srgb_encoding",
    "srgb_transfer",
    "strips",
]
