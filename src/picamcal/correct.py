"""Calibration + raw image -> corrected linear RGB (paper, section "Colour crosstalk", eqs. for
``Pure`` and ``Unmixed``).

The pipeline per image: subtract black; divide each Bayer site by its white response interpolated
smoothly from the bins (lens shading and colour balance, ``Cb LST = 1 / W``); demosaic (Malvar,
He and Cutler 2004, from the colour-demosaicing library); apply the interpolated 3x3 matrix field
per pixel. The modes (:class:`picamcal.modes.Mode`) are steps along it: ``uncorrected`` (colour balance
only), ``flat`` (the white becomes 1.0 everywhere), ``centre`` (then ``U``, the paper's recommended
correction) and ``pure`` (then ``Cx U``). Without a mode, the best the calibration does (:func:`choose_mode`).

Engines (the ``engine`` argument of :func:`correct`): ``c``, ``numba`` and ``numpy`` run the fused
full-resolution pass of :mod:`picamcal.kernels`, three implementations of one float32 arithmetic (no
full-resolution gain or matrix field in memory; the uint16 codes agree bit for bit, the float32 values to
the last bit or an ulp): ``c`` is compiled once per installation by the system's C compiler
(:mod:`picamcal.ckernel`) and starts fastest, ``numba`` needs numba, ``numpy`` needs neither. ``reference``
is the plain implementation above, with colour-demosaicing and dense spline matrices. All use the same
interpolant (the not-a-knot cubic spline through the bin centres, which the kernels evaluate in its local
B-spline form).
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import numpy as np
from numpy.typing import DTypeLike

from .bayer import bin_centres, bin_sites, block_mean, centre_region, sites_to_channels
from .calibration import Calibration
from .calibration.resample import CROP_TOLERANCE, calibration_for_raw
from .ckernel import correct_c, encode_image
from .errors import CalibrationFileError, KernelBuildError, PicamcalError, PicamcalWarning
from .geometry import SensorMode, image_to_image, sensor_area
from .interpolate import interpolation_matrix, spline_coefficients, spline_knots, spline_taps, upsample
from .kernels import (
    NUMPY_BLOCK_ROWS,
    CorrectionFields,
    SrgbTable,
    correct_numba,
    correct_numpy,
    encode_codes,
    make_taps,
    numba_available,
    output_array,
)
from .modes import Mode, best_mode
from .raw.model import RawImage, site_channels
from .raw.processed import ProcessedImage

#: Rows per block when applying the matrix field, to bound memory (9 float32 planes per block).
_ROW_BLOCK = 256
#: Values of :func:`correct`'s ``engine``.
ENGINES = ("auto", "c", "numba", "numpy", "reference")
#: How many (calibration, mode, size) correction fields :func:`correct` keeps.
_FIELDS_CACHE_SIZE = 4
#: A frame with more of its pixels at the white level than this fraction is warned of (:func:`warn_if_clipped`): a
#: highlight or two clip a few pixels in a thousand; beyond one in a hundred the exposure was too long for the scene.
CLIPPED_WARNING_FRACTION = 0.01
#: uint16 code of the white reference (value 1.0) in :func:`correct`'s ``dtype=np.uint16`` output and the
#: ``uint16-tiff`` files: a power of two, so code / 32768 is exact and values up to twice the white keep headroom.
UINT16_WHITE = 32768


def _site_gain_mosaic(calibration: Calibration, mode: Mode, height: int, width: int) -> np.ndarray:
    """Per-pixel gain mosaic: 1 / white per Bayer site, the white interpolated from the bins (constant uncorrected)."""
    gains = np.empty((height, width), dtype=np.float32)
    centre = calibration.centre_white
    for site in range(4):
        sy, sx = divmod(site, 2)
        if mode is Mode.UNCORRECTED:
            gains[sy::2, sx::2] = 1.0 / centre[site]
            continue
        size = calibration.bin_size
        ay = interpolation_matrix(bin_centres(height, size, sy), np.arange(sy, height, 2))
        ax = interpolation_matrix(bin_centres(width, size, sx), np.arange(sx, width, 2))
        # Interpolate the white itself, then invert: vignetting is smoother than its reciprocal.
        gains[sy::2, sx::2] = 1.0 / upsample(calibration.site_white[..., site].astype(np.float64), ay, ax)
    return gains


def demosaic(mosaic: np.ndarray, pattern: str) -> np.ndarray:
    """Demosaic a float Bayer mosaic to (H, W, 3) float32 with Malvar-He-Cutler (2004).

    Examples
    --------
    >>> rgb = demosaic(np.ones((8, 8), np.float32), "BGGR")
    >>> rgb.shape, float(rgb.min()), float(rgb.max())
    ((8, 8, 3), 1.0, 1.0)
    """
    from colour_demosaicing import demosaicing_CFA_Bayer_Malvar2004

    return np.asarray(demosaicing_CFA_Bayer_Malvar2004(mosaic, pattern), dtype=np.float32)


def malvar_demosaic(mosaic: np.ndarray, pattern: str, block_rows: int = NUMPY_BLOCK_ROWS) -> np.ndarray:
    """Demosaic a float Bayer mosaic to (H, W, 3) float32 with Malvar-He-Cutler (2004), the kernels' own arithmetic.

    The demosaic of :func:`picamcal.kernels.correct_numpy` alone (no black, flat field or unmixing), with the
    borders of :func:`demosaic`, colour-demosaicing's: equal to it exactly on integer mosaics below 2**10, and to
    float32 rounding otherwise. For what demosaics a frame without correcting it (``apply_tuning``, ``analyse``):
    colour-demosaicing, the reference, takes about 3 s to import.

    Examples
    --------
    >>> rgb = malvar_demosaic(np.ones((8, 8), np.float32), "BGGR")
    >>> rgb.shape, float(rgb.min()), float(rgb.max())
    ((8, 8, 3), 1.0, 1.0)
    """
    unused = make_taps(np.zeros(1), np.zeros((1, 4)))  # no flat field, no matrix: no taps are read
    neutral = CorrectionFields(
        black=np.zeros(4, np.float32), channels=site_channels(pattern), site_gains=np.ones(4, np.float32),
        white=None, white_rows=unused, matrices=None, matrix_rows=unused, matrix_cols=unused,
    )  # fmt: skip
    return correct_numpy(mosaic, neutral, block_rows=block_rows)


def apply_matrix_field(rgb: np.ndarray, matrices: np.ndarray, centres: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Apply a bin-resolution 3x3 matrix field to a full-resolution image, in place, block by block.

    Each pixel gets ``out = U(y, x) @ rgb`` with U interpolated by cubic splines from the bin
    centres; the full-resolution field is never held in memory at once.

    Examples
    --------
    >>> centres = (bin_centres(240, 16), bin_centres(320, 16))  # the 15 x 20 bins of a 320 x 240 image
    >>> rgb = np.tile(np.float32([0.2, 0.5, 0.8]), (240, 320, 1))
    >>> swap = np.broadcast_to(np.eye(3, dtype=np.float32)[::-1], (15, 20, 3, 3))  # red and blue swapped
    >>> out = apply_matrix_field(rgb, swap, centres)
    >>> out is rgb, out[120, 160].round(2).tolist()
    (True, [0.8, 0.5, 0.2])
    >>> ramp = np.broadcast_to((1 + centres[1] / 320)[:, None, None] * np.eye(3), (15, 20, 3, 3))  # left to right
    >>> grey = apply_matrix_field(np.full((240, 320, 3), 0.5, np.float32), ramp, centres)
    >>> grey[100, [0, 160, 319], 1].round(3).tolist()  # 0.5 (1 + x / 320) at every pixel, between the bins too
    [0.5, 0.75, 0.998]
    """
    height, width = rgb.shape[:2]
    ax = interpolation_matrix(centres[1], np.arange(width))
    ay_all = interpolation_matrix(centres[0], np.arange(height))
    for y0 in range(0, height, _ROW_BLOCK):
        y1 = min(y0 + _ROW_BLOCK, height)
        u = upsample(matrices.astype(np.float64), ay_all[y0:y1], ax).astype(np.float32)  # (rows, W, 3, 3)
        rgb[y0:y1] = np.einsum("yxpq,yxq->yxp", u, rgb[y0:y1])
    return rgb


def _taps(centres: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return spline_taps(spline_knots(centres), positions)


def _site_taps(n_pixels: int, bin_size: int) -> tuple[np.ndarray, np.ndarray]:
    """Taps of every pixel along an axis on the bin centres of its own Bayer site (its parity)."""
    first, weights = np.empty(n_pixels, dtype=np.int64), np.empty((n_pixels, 4))
    for site in (0, 1):
        first[site::2], weights[site::2] = _taps(bin_centres(n_pixels, bin_size, site), np.arange(site, n_pixels, 2))
    return first, weights


def correction_fields(calibration: Calibration, mode: str | Mode, height: int, width: int) -> CorrectionFields:
    """The coarse fields of a correction mode in local spline form, for the kernels of :mod:`picamcal.kernels`.

    Solves for the B-spline coefficients of the per-site white and of the matrix field on the bin
    grid, evaluates the white's along x at each of its site's columns, and tabulates each row's and
    column's 4 taps (tens of milliseconds at 12 megapixels, so
    :func:`correct` keeps the last few). The interpolant is that of :func:`interpolation_matrix`,
    so the result matches ``engine="reference"`` up to rounding.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> fields = correction_fields(cal, "centre", cal.height, cal.width)
    >>> fields.matrices.shape  # 9 elements on the 15 x 20 bins' spline
    (9, 15, 20)
    >>> fields.white.shape  # 4 sites, the 15 coefficient rows evaluated at each site's 160 columns
    (4, 15, 160)
    """
    mode = calibration.check_mode(mode)
    size = calibration.bin_size
    white = None
    if mode is not Mode.UNCORRECTED:
        white = np.stack([_white_along_x(calibration, site, height, width) for site in range(4)])
    centres_y, centres_x = bin_centres(height, size), bin_centres(width, size)
    matrices = calibration.matrices(mode)
    if matrices is not None:
        matrices = spline_coefficients(matrices.reshape(*matrices.shape[:2], 9), centres_y, centres_x)
        matrices = np.ascontiguousarray(np.moveaxis(matrices, -1, 0), dtype=np.float32)
    return CorrectionFields(
        black=np.zeros(4, dtype=np.float32),
        channels=site_channels(calibration.pattern).astype(np.int64),
        site_gains=(1.0 / calibration.centre_white).astype(np.float32),
        white=white,
        white_rows=make_taps(*_site_taps(height, size)),
        matrices=matrices,
        matrix_rows=make_taps(*_taps(centres_y, np.arange(height))),
        matrix_cols=make_taps(*_taps(centres_x, np.arange(width))),
    )


def _white_along_x(calibration: Calibration, site: int, height: int, width: int) -> np.ndarray:
    """A site's white B-spline coefficients evaluated at each of its columns: (ncy, W // 2) float32.

    Evaluated in float64 and rounded once; a row of the white is then 4 multiply-adds per pixel on long rows.
    """
    size = calibration.bin_size
    sy, sx = divmod(site, 2)
    coefficients = spline_coefficients(
        calibration.site_white[..., site], bin_centres(height, size, sy), bin_centres(width, size, sx)
    )
    first, weights = _taps(bin_centres(width, size, sx), np.arange(sx, width, 2))
    along_x = sum(weights[:, b] * coefficients[:, first + b] for b in range(4))
    return np.ascontiguousarray(along_x, dtype=np.float32)


@functools.lru_cache(maxsize=_FIELDS_CACHE_SIZE)
def _cached_fields(calibration: Calibration, mode: Mode, height: int, width: int) -> CorrectionFields:
    """:func:`correction_fields`, kept for the last few calibrations (by identity: a Calibration is immutable).

    Solving for the coefficients costs tens of milliseconds at 12 megapixels, a large part of a frame's correction.
    """
    return correction_fields(calibration, mode, height, width)


def with_known_black_level(raw: RawImage, calibration: Calibration) -> RawImage:
    """``raw`` itself if its black level is known, else ``raw`` with the calibration's black level, said in a warning.

    A raw image whose black level is unknown (NaN: a headless dump of a sensor picamcal does not know) is of the
    calibration's sensor, whose black level the calibration holds: measured from its dark frame, or its references'
    (given with ``--black-level`` when they were dumps too), scaled to the image's bit depth. The image must then be
    taken at the calibration's settings, which the warning says. The warning does not name the file: every frame of
    a batch gives the same one, shown once.

    Examples
    --------
    >>> import dataclasses, warnings
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal = picamcal.calibrate(**refs)  # with a dark frame
    >>> dump = dataclasses.replace(refs["white"], black_level=(np.nan,) * 4)  # a headless dump: level unknown
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     print([round(level) for level in with_known_black_level(dump, cal).black_level])
    [64, 64, 64, 64]
    >>> print(caught[0].message)
    frames that give no black level are corrected with the calibration's, 64 DN (from its dark frame): right if ...
    """
    if np.all(np.isfinite(raw.black_level)):
        return raw
    black = np.asarray(calibration.black_level, dtype=float)
    if calibration.bit_depth and calibration.bit_depth != raw.bit_depth:
        black = black * 2.0 ** (raw.bit_depth - calibration.bit_depth)
    each = [f"{v:.3g}" for v in black]  # to 0.1 DN or better: a dark frame's per-site medians differ by less
    levels = each[0] if len(set(each)) == 1 else ",".join(each)
    source = "its dark frame" if calibration.black_level_source == "dark frame" else "its references"
    warnings.warn(
        f"frames that give no black level are corrected with the calibration's, {levels} DN (from {source}): right "
        "if they were taken at its settings; else give --black-level",
        PicamcalWarning,
        stacklevel=2,
    )
    return dataclasses.replace(raw, black_level=(float(black[0]), float(black[1]), float(black[2]), float(black[3])))


def warn_if_clipped(raw: RawImage) -> float:
    """Warn, naming the file, when more than :data:`CLIPPED_WARNING_FRACTION` of ``raw``'s pixels are at its white
    level; return that fraction.

    A clipped pixel's value is a lower bound: neither the flat field nor the unmixing can give its true value and
    colour, and its neighbours' demosaiced colours inherit the error.

    Examples
    --------
    >>> import warnings
    >>> bayer = np.full((4, 4), 1023, np.uint16)
    >>> bayer[:2] = 500  # half the frame clipped
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     fraction = warn_if_clipped(RawImage(bayer, "BGGR", 64, 1023, 10, None, {"path": "scan.dng"}))
    >>> fraction, str(caught[0].message)
    (0.5, 'scan.dng: 50 % of its pixels are at the white level (1023): clipped, they cannot be corrected; ...')
    """
    fraction = int(np.count_nonzero(raw.bayer >= raw.white_level)) / raw.bayer.size
    _warn_clipped(raw, fraction, stacklevel=4)
    return fraction


def _warn_clipped(raw: RawImage, fraction: float, stacklevel: int) -> None:
    """:func:`warn_if_clipped`'s warning, for a ``fraction`` of clipped pixels counted already (by the C kernel)."""
    if fraction > CLIPPED_WARNING_FRACTION:
        warnings.warn(
            f"{raw.source}: {100 * fraction:.3g} % of its pixels are at the white level ({raw.white_level}): clipped, "
            "they cannot be corrected; reduce the exposure",
            PicamcalWarning,
            stacklevel=stacklevel,
        )


def choose_mode(calibration: Calibration, mode: str | Mode | None = None) -> Mode:
    """The mode a correction with ``calibration`` takes: ``mode`` if the calibration does it, else an error; without
    one, the best it does (:func:`picamcal.modes.best_mode`: ``centre``, or ``flat`` for a white-only calibration).

    Raises
    ------
    CalibrationFileError
        ``centre`` or ``pure`` asked of a white-only calibration (the message names ``--mode flat``).
    ValueError
        An unknown mode.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> choose_mode(picamcal.calibrate(refs["white"])), choose_mode(picamcal.calibrate(**refs))
    (<Mode.FLAT: 'flat'>, <Mode.CENTRE: 'centre'>)
    >>> choose_mode(picamcal.calibrate(**refs), "pure")
    <Mode.PURE: 'pure'>
    """
    return best_mode(calibration.has_unmixing) if mode is None else calibration.check_mode(mode)


def correct(
    raw: RawImage,
    calibration: Calibration,
    mode: str | Mode | None = None,
    binned: bool = False,
    *,
    engine: str = "auto",
    out: np.ndarray | None = None,
    dtype: DTypeLike | None = None,
    encoding: SrgbTable | None = None,
    geometry: SensorMode | None = None,
) -> np.ndarray:
    """Correct a raw image's vignetting and colour crosstalk.

    Parameters
    ----------
    raw : RawImage
        The image, from the calibration's sensor: of its sensor mode, or of any mode inside the calibration's crop
        (binned, cropped, flipped: the calibration's fields are taken at the frame's sensor positions,
        :func:`picamcal.calibration.resample.calibration_for_raw`). An unknown (NaN) black level takes the
        calibration's (:func:`with_known_black_level`).
    calibration : Calibration
        From :func:`picamcal.calibrate` or :func:`picamcal.load_calibration`.
    mode : {"centre", "flat", "pure", "uncorrected"} or Mode, optional
        See :mod:`picamcal.modes`; ``centre`` is the paper's recommended correction. A flat calibration
        (white only) does ``uncorrected`` and ``flat``; the others raise CalibrationFileError. The old name
        ``balance`` is ``uncorrected``, with a warning. Default: the best the calibration does (:func:`choose_mode`:
        ``centre``, or ``flat`` for a white-only calibration).
    binned : bool
        Return the bin-resolution image (one value per bin and channel, no demosaicing) instead of
        the full-resolution one.
    engine : {"auto", "c", "numba", "numpy", "reference"}
        How to compute the full-resolution image (see the module docstring): ``auto`` is ``c`` when the C
        kernel is compiled or can be (a C compiler is installed), else ``numba`` when numba is installed,
        else ``numpy``; all three give the same result. Ignored when ``binned``.
    out : ndarray, optional
        Write the full-resolution result here (C-contiguous, of the returned shape and type) instead of
        into a new array: when correcting many frames, reusing one buffer saves the cost of touching fresh
        memory (about a fifth of the time of a 12-megapixel frame with the numba kernel). Not with ``binned``.
    dtype : {np.float32, np.uint16, np.uint8}, optional
        ``np.uint16`` returns the ``uint16-tiff`` codes instead, (H, W, 3) as the image: ``round(value *``
        :data:`UINT16_WHITE` ``)`` clipped to 0..65535, NaN as 0, bit for bit those of
        :func:`picamcal.output.tiff.encode_uint16` of the float32 result, but computed row by row with no
        float32 image at full resolution (half the memory). Not with ``binned``. Default float32, or with
        ``encoding`` its codes' type (uint8 or uint16; ``dtype`` may say it again).
    encoding : SrgbTable, optional
        Return the codes of this encoding instead, written by the kernel row by row with no float32 image:
        the sRGB formats' from :func:`picamcal.output.colour.srgb_encoding` (8 or 16 bit), bit for bit
        :func:`picamcal.output.colour.encode_srgb` of the float32 result. Not with ``binned``.
    geometry : SensorMode, optional
        The frame's sensor mode (``--sensor-crop``, ``--sensor-mode``: :func:`picamcal.raw.model.raw_geometry`);
        by default what its file says, else the registry's mode of its size.

    Returns
    -------
    ndarray of float32, shape (H, W, 3) or (nby, nbx, 3); or of uint16, shape (H, W, 3)
        Linear RGB in which the calibration's white reference is 1.0 (``flat``, ``centre`` and ``pure``),
        or its uint16 codes.

    Raises
    ------
    CalibrationFileError
        A mode the calibration cannot do (:func:`choose_mode`), or an image it does not fit.
    OutputError
        ``out`` is not an array of the result's shape and type.
    KernelBuildError
        ``engine="c"`` on a machine where the C kernel cannot be compiled (the message says what to do).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references, simulate_target
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    >>> target, layout = simulate_target(camera, seed=2)
    >>> rgb = picamcal.correct(target, cal, mode="centre")
    >>> rgb.shape, rgb.dtype
    ((240, 320, 3), dtype('float32'))
    >>> same = picamcal.correct(target, cal, engine="numpy", out=rgb)  # into the same buffer
    >>> same is rgb, picamcal.correct(target, cal, "flat", binned=True).shape
    (True, (15, 20, 3))
    >>> codes = picamcal.correct(target, cal, dtype=np.uint16)  # uint16-tiff codes, the white at 32768
    >>> codes.shape, codes.dtype
    ((240, 320, 3), dtype('uint16'))
    >>> from picamcal.output.colour import camera_to_srgb, srgb_encoding
    >>> srgb = srgb_encoding(camera_to_srgb(target.metadata), bits=8)  # the srgb-jpeg and srgb-png codes
    >>> picamcal.correct(target, cal, dtype=np.uint8, encoding=srgb).dtype
    dtype('uint8')
    """
    mode = choose_mode(calibration, mode)
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}: choose one of {', '.join(ENGINES)}")
    kind = _output_type(dtype, encoding)
    to_codes = kind == np.uint16 and encoding is None
    calibration = calibration_for_raw(calibration, raw, geometry)
    matrices = calibration.matrices(mode)
    raw = with_known_black_level(raw, calibration)
    if binned or engine not in ("auto", "c"):  # the C kernel counts the clipped pixels as it reads them
        warn_if_clipped(raw)
    if binned:
        if out is not None or kind != np.float32:
            raise ValueError("out, dtype and encoding take a full-resolution image; binned=True returns float32")
        sites = bin_sites(raw.black_subtracted(), calibration.bin_size)
        white = (
            np.broadcast_to(calibration.centre_white, sites.shape)
            if mode is Mode.UNCORRECTED
            else calibration.site_white
        )
        rgb = sites_to_channels(sites / white, raw.pattern)
        if matrices is not None:
            rgb = np.einsum("yxpq,yxq->yxp", matrices.astype(np.float64), rgb)
        return rgb.astype(np.float32)
    if engine == "reference":
        rgb = _correct_reference(raw, calibration, mode)
        if encoding is not None:
            return encode_image(rgb, output_array(out, raw.height, raw.width, kind), table=encoding)
        if to_codes:
            return encode_codes(rgb, UINT16_WHITE, output_array(out, raw.height, raw.width, np.uint16))
        if out is None:
            return rgb
        np.copyto(output_array(out, raw.height, raw.width), rgb)
        return out
    fields = _cached_fields(calibration, mode, raw.height, raw.width)._replace(
        black=np.asarray(raw.black_level, dtype=np.float32)
    )
    scale = UINT16_WHITE if to_codes else None
    if engine in ("auto", "c"):
        try:
            clipped = np.zeros(1, np.int64)
            result = correct_c(
                raw.bayer, fields, out, code_scale=scale, table=encoding, clipped=(raw.white_level, clipped)
            )
            _warn_clipped(raw, int(clipped[0]) / raw.bayer.size, stacklevel=3)
            return result
        except KernelBuildError:
            if engine == "c":
                raise
            # No C compiler, or it failed (remembered, not tried again): numba's or numpy's path gives the same.
            warn_if_clipped(raw)
    if engine == "numba" or (engine == "auto" and numba_available()):
        try:
            return correct_numba(raw.bayer, fields, out, code_scale=scale, table=encoding)
        except ImportError:
            if engine == "numba":
                raise
            # numba is installed but does not import (built for another numpy): numpy's path gives the same.
    return correct_numpy(raw.bayer, fields, out, code_scale=scale, table=encoding)


def _output_type(dtype: DTypeLike | None, encoding: SrgbTable | None) -> np.dtype:
    """What :func:`correct` returns: float32, uint16 codes, or the codes of ``encoding`` (``dtype`` may repeat it)."""
    if encoding is not None:
        kind = np.dtype(encoding.base.dtype)
        if dtype is not None and np.dtype(dtype) != kind:
            raise ValueError(f"this encoding's codes are {kind}, not {np.dtype(dtype)}: give its dtype, or none")
        return kind
    kind = np.dtype(np.float32 if dtype is None else dtype)
    if kind not in (np.float32, np.uint16):
        hint = ", or uint8 with an encoding (picamcal.output.colour.srgb_encoding)" if kind == np.uint8 else ""
        raise ValueError(f"dtype must be numpy.float32 or numpy.uint16{hint}, not {kind}")
    return kind


def _correct_reference(raw: RawImage, calibration: Calibration, mode: Mode) -> np.ndarray:
    """The plain full-resolution pipeline: whole-frame gain mosaic, colour-demosaicing, blocks of the matrix field."""
    mosaic = raw.black_subtracted()
    mosaic *= _site_gain_mosaic(calibration, mode, raw.height, raw.width)
    rgb = demosaic(mosaic, raw.pattern)
    del mosaic
    matrices = calibration.matrices(mode)
    if matrices is not None:
        apply_matrix_field(rgb, matrices, calibration.bin_centres)
    return rgb


def _stream_on_calibration(
    calibration: Calibration,
    size: tuple[int, int],
    crop: tuple[int, int, int, int] | None,
    sensor_mode: SensorMode | None,
    source: str,
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The affine map (per axis, x then y) ``u_cal = a u + b`` from a processed image's continuous coordinates to
    the calibration image's, through the camera's sensor mode: the ISP cropped the mode's image to the ScalerCrop
    ``crop`` (libcamera's ``ispCrop``, in the mode's unflipped pixels) and scaled it to ``size``; the mode lies on
    the sensor as its crop, binning and flips say, as does the calibration
    (:func:`picamcal.geometry.image_to_image`)."""
    geometry = calibration.geometry or SensorMode.full(calibration.width, calibration.height)
    mode = sensor_mode or geometry
    if mode.sensor_size != geometry.sensor_size:
        raise CalibrationFileError(
            f"image does not match the calibration: the camera's sensor mode is of a "
            f"{mode.sensor_width}x{mode.sensor_height} sensor, the calibration of a "
            f"{geometry.sensor_width}x{geometry.sensor_height} one",
            source,
        )
    try:
        x, y, w, h = SensorMode(*mode.sensor_size, crop or mode.crop).crop
    except PicamcalError as exc:
        raise PicamcalError(exc.problem, source) from None
    width, height = size
    if abs((w / width) / (h / height) - 1) > 0.02:
        raise PicamcalError(
            f"image is {width}x{height} but shows a {w}x{h} sensor area: the aspect ratios differ; give the sensor "
            "area it shows (--sensor-crop X,Y,WIDTH,HEIGHT in full-sensor pixels: picamera2's ScalerCrop) or the "
            "camera's sensor mode (--sensor-mode WIDTHxHEIGHT)",
            source,
        )
    mode_x, mode_y, mode_w, mode_h = mode.crop
    sx, sy = mode.width / mode_w, mode.height / mode_h
    box = ((x - mode_x) * sx, (y - mode_y) * sy, w * sx, h * sy)  # the ISP's crop, in the mode's image
    area = sensor_area(mode, box)
    if not geometry.contains(area, CROP_TOLERANCE * max(mode.binning, geometry.binning)):
        gx, gy, gw, gh = geometry.crop
        raise CalibrationFileError(
            f"image does not match the calibration: it shows the sensor area {area[2]}x{area[3]} at "
            f"({area[0]}, {area[1]}), outside the calibration's {gw}x{gh} at ({gx}, {gy}): calibrate in a mode that "
            "covers it (a full-sensor or binned mode covers every mode)",
            source,
        )
    (ax, bx), (ay, by) = image_to_image(mode, geometry)
    return (ax * box[2] / width, ax * box[0] + bx), (ay * box[3] / height, ay * box[1] + by)


def _image_centres(centres: np.ndarray, a: float, b: float) -> tuple[np.ndarray, bool]:
    """The calibration's bin centres (pixel centres at integers) in the image's pixels by ``u_cal = a u + b``, in
    increasing order, and whether that reversed them (the image mirrored against the calibration)."""
    positions = (centres + 0.5 - b) / a - 0.5
    return (positions[::-1], True) if a < 0 else (positions, False)


def correct_processed(
    image: ProcessedImage | np.ndarray,
    calibration: Calibration,
    mode: str | Mode | None = None,
    *,
    white: ProcessedImage | np.ndarray | None = None,
    ccm: np.ndarray | None = None,
    crop: tuple[int, int, int, int] | None = None,
    sensor_mode: SensorMode | None = None,
    isp_gains: np.ndarray | None = None,
    colour_gains: tuple[float, float] | np.ndarray | None = None,
) -> np.ndarray:
    """Correct a processed (ISP output) image: apply only what the camera's pipeline did not.

    The ISP has already subtracted black, applied its lens shading table and colour gains, and
    demosaiced. If the table loaded into the camera came from this calibration (``picamcal
    export-tuning``) the image is already flat; what remains is the unmixing ``U`` (``centre``) or
    ``Cx U`` (``pure``), applied per pixel in the camera's colour space. Otherwise give a processed
    ``white`` reference taken through the same pipeline, and the remaining flat field is measured from
    it and divided out first (then its white maps to 1.0). A colour correction matrix that the ISP
    applied after the gains (``ccm``, as in the tuning file's ``rpi.ccm``) is undone before unmixing
    and re-applied after it.

    The image may come from any sensor mode, crop and zoom inside the calibration's sensor area: the ISP cropped the
    sensor mode's image to the ScalerCrop (``crop``) and scaled it to the image's size, so each image pixel is mapped
    to the sensor through the mode (its crop, binning and flips) and from there into the calibration's image (its
    :attr:`~picamcal.calibration.Calibration.geometry`), where the fields are interpolated.

    Parameters
    ----------
    image : ProcessedImage or ndarray (H, W, 3)
        Linear RGB (see :func:`picamcal.raw.processed.read_processed` for undoing the tone curve).
    calibration : Calibration
    mode : {"centre", "pure", "flat", "uncorrected"} or Mode, optional
        ``flat`` and ``uncorrected`` apply only the residual flat field (nothing without ``white``). Default: the
        best the calibration does (:func:`choose_mode`).
    white : ProcessedImage or ndarray (H, W, 3), optional
        A processed image of the white reference, at the same size and settings.
    ccm : ndarray (3, 3), optional
        The colour matrix the ISP applied (camera RGB -> output RGB).
    crop : (x, y, width, height), optional
        The sensor area the image shows, in full-sensor pixels: picamera2's ``ScalerCrop`` metadata (libcamera's
        ``ScalerCrop``, in the sensor mode's unflipped coordinates). Default: the sensor mode's whole crop. The image
        may be scaled (the ISP's output usually is), but not stretched: its aspect ratio must be the area's.
    sensor_mode : SensorMode, optional
        The camera's sensor mode when the image was taken (:func:`picamcal.geometry.named_mode` gives a sensor's mode
        by its size). Default: the calibration's own (:attr:`~picamcal.calibration.Calibration.geometry`).
    isp_gains : ndarray (H, W, 3), optional
        The lens shading gains the ISP applied, per image pixel (from a tuning file:
        :func:`picamcal.export.isp.isp_gains_for_image`). The residual between them and this
        calibration's flat field is divided out, normalised at the centre so that the image keeps its
        brightness there, and without ``colour_gains`` its colour balance there too. Not used with ``white``,
        which went through the same gains (dividing by it removes them).
    colour_gains : (red, blue), optional
        Used with ``isp_gains`` only: the white balance gains the ISP applied after its lens shading (the camera's
        frozen ``ColourGains``). They are divided out with the ISP's gains and the calibration's white, so
        the white reference becomes neutral everywhere and the unmixing acts on the channels as on the raw
        path (:func:`correct`). Without them the ISP's colour balance at the centre is kept, which is right
        only if the white was neutral there (white balance frozen on the white with the same tuning loaded);
        any other balance tints the white by the ISP's gains at the centre and the unmixing, which acts on
        white-normalised channels, then mixes the wrong amounts (:func:`picamcal.export.isp.processed_inputs`
        gives them).

    Returns
    -------
    ndarray of float32, shape (H, W, 3)

    Raises
    ------
    PicamcalError
        Not an RGB image; a crop outside the sensor, or of another aspect ratio than the image (the message names
        ``--sensor-crop`` and ``--sensor-mode``).
    CalibrationFileError
        The image shows a sensor area outside the calibration's (the message says what covers it), or the sensor
        mode is of another sensor; naming the image.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references, simulate_target
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    >>> target, _ = simulate_target(camera, seed=2)
    >>> isp_output = correct(target, cal, "flat")  # stands for a camera whose lens shading came from ``cal``
    >>> correct_processed(isp_output[::2, ::2], cal, "centre").shape  # a scaled output: only U is left to do
    (120, 160, 3)
    >>> zoom = correct_processed(isp_output[60:180, 80:240], cal, "centre", crop=(80, 60, 160, 120))  # a 2x zoom
    >>> bool(np.allclose(zoom, correct_processed(isp_output, cal, "centre")[60:180, 80:240], atol=1e-4))
    True
    """
    mode = choose_mode(calibration, mode)
    rgb = np.array(image.rgb if isinstance(image, ProcessedImage) else image, dtype=np.float32)
    source = image.metadata.get("path", "<image>") if isinstance(image, ProcessedImage) else "<image>"
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise PicamcalError(f"expected an RGB image, got shape {rgb.shape}", source)
    height, width = rgb.shape[:2]
    (ax, bx), (ay, by) = _stream_on_calibration(calibration, (width, height), crop, sensor_mode, source)
    if ccm is not None:
        ccm = np.asarray(ccm, dtype=np.float64).reshape(3, 3)
        rgb = np.einsum("pq,yxq->yxp", np.linalg.inv(ccm).astype(np.float32), rgb)
    if white is not None:
        w = np.asarray(white.rgb if isinstance(white, ProcessedImage) else white, dtype=np.float32)
        if w.shape != rgb.shape:
            raise PicamcalError(f"white reference is {w.shape[1]}x{w.shape[0]}, the image {width}x{height}", source)
        if ccm is not None:
            w = np.einsum("pq,yxq->yxp", np.linalg.inv(ccm).astype(np.float32), w)
        block = max(2, round(calibration.bin_size / abs(ax)))
        means = block_mean(w, block)
        centres = bin_centres(height, block), bin_centres(width, block)
        if np.any(means <= 0):
            raise PicamcalError("the processed white reference has blocks with no light", source)
        white_y = interpolation_matrix(centres[0], np.arange(height))
        white_x = interpolation_matrix(centres[1], np.arange(width))
        rgb /= upsample(means, white_y, white_x).astype(np.float32)
    cy, cx = calibration.bin_centres
    (centres_y, flip_y), (centres_x, flip_x) = _image_centres(cy, ay, by), _image_centres(cx, ax, bx)
    image_centres = (centres_y, centres_x)

    def oriented(field: np.ndarray) -> np.ndarray:
        """A per-bin field in the image's orientation (mirrored where the image is against the calibration)."""
        field = field[::-1] if flip_y else field
        return field[:, ::-1] if flip_x else field

    if isp_gains is not None and isp_gains.shape != rgb.shape:
        raise PicamcalError(f"ISP gains of shape {isp_gains.shape} do not match the {width}x{height} image", source)
    # A processed white went through the same lens shading and colour gains: dividing by it removed them already.
    if isp_gains is not None and white is None:
        residual_y = interpolation_matrix(image_centres[0], np.arange(height))
        residual_x = interpolation_matrix(image_centres[1], np.arange(width))
        residual = 1.0 / (upsample(oriented(calibration.white).astype(np.float64), residual_y, residual_x) * isp_gains)
        top, bottom, left, right = centre_region(height, width)  # the central ninth, in image pixels
        centre = residual[top:bottom, left:right].mean(axis=(0, 1))
        if colour_gains is not None:
            red, blue = np.asarray(colour_gains, dtype=np.float64).reshape(2)
            if not (red > 0 and blue > 0 and np.isfinite(red + blue)):
                raise PicamcalError(f"colour gains must be two positive numbers, not {red:g}, {blue:g}", source)
            # One scale for all three channels: the white comes out neutral, as the raw path's does.
            residual /= np.array([red, 1.0, blue])
            centre = np.full(3, centre[1])
        rgb *= (residual / centre).astype(np.float32)
    matrices = calibration.matrices(mode)
    if matrices is not None:
        apply_matrix_field(rgb, oriented(matrices), image_centres)
    if ccm is not None:
        rgb = np.einsum("pq,yxq->yxp", ccm.astype(np.float32), rgb)
    return rgb
