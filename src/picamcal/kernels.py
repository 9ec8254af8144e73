"""Fused full-resolution correction: black, flat field, demosaic and unmixing in one pass over the frame.

:func:`picamcal.correct.correct` does, per pixel (paper, section "Colour crosstalk")::

    Unmixed_ijp = sum_q U_ijpq demosaic(Cb LST (Image - black))_ijq

where the flat-field gain ``Cb LST = 1 / W`` and the matrix field ``U`` are cubic splines through
bin-resolution samples. Here both are evaluated on the fly from their local B-spline form
(:func:`picamcal.interpolate.spline_coefficients`, 4 taps along each axis), one row at a time, so no
full-resolution gain or matrix field ever exists: memory is the output plus a few rows per thread and,
for the white, its coefficients already evaluated along x (one row of each site per coefficient row,
about a 24th of a float32 output), which turns the white of a row into 4 long multiply-adds.
Demosaicing is Malvar, He and Cutler (2004), its four 5x5 linear filters with the borders of
colour-demosaicing's implementation (``scipy.ndimage.convolve``'s default ``reflect``: the frame is
mirrored about its edge, edge pixel repeated).

The output is the (H, W, 3) float32 image or its codes interleaved the same way, written row by row with no
float32 image at full resolution: uint16 ``round(value * scale)`` clipped, NaN as 0 (:func:`encode_codes`), or
the sRGB formats' codes, a 3x3 matrix then the transfer function by table (:class:`SrgbTable`, :func:`encode_table`).

Three implementations of one arithmetic: the same float32 operations in the same order, so they give
the same result to the last bit (the codes always; the float32 values on the machines measured, and
within an ulp or so where a compiler rounds one operation differently):

``c``
    :mod:`picamcal.ckernel`: ``_kernel.c``, compiled by the system's C compiler the first time it is
    needed and cached on disk, then loaded in a millisecond with ctypes; POSIX threads take blocks of
    rows one at a time. No numba: the fastest start for a command that corrects one file.
``numba``
    a parallel kernel (``prange`` over blocks of rows, handed out one block at a time so that a
    core slowed by other work takes fewer), compiled on first use and cached on disk. numba is
    optional and imported only when this kernel is first asked for (its runtime then takes about
    half a second to load the cached kernel).
``numpy``
    row blocks with array slicing, for where there is neither a C compiler nor numba (32-bit
    Raspberry Pi OS has no numba wheels).

The two parallel kernels use :func:`kernel_threads` threads (:func:`set_kernel_threads`).
"""

from __future__ import annotations

import functools
import importlib.util
import os
from numbers import Integral
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import DTypeLike

from .errors import OutputError

#: Rows per block of the numpy path: its temporaries are ~20 float32 arrays of this many rows.
NUMPY_BLOCK_ROWS = 64
#: Rows per parallel work item of the numba kernel: each recomputes 4 flat rows of its neighbours', so
#: longer blocks waste less, shorter ones share the work better between cores that other work slows.
NUMBA_BLOCK_ROWS = 64
#: Largest uint16 code.
_CODE_MAX = 65535
#: Threads of the parallel kernels, as :func:`set_kernel_threads` set it; None for :func:`available_cores`.
_threads: int | None = None

_F05, _F15, _F2, _F4, _F5, _F6, _EIGHTH = (np.float32(v) for v in (0.5, 1.5, 2.0, 4.0, 5.0, 6.0, 0.125))


class Taps(NamedTuple):
    """Where a cubic B-spline's 4 coefficients start at each position along an axis, and their weights.

    From :func:`picamcal.interpolate.spline_taps`, laid out for the kernels: the value at position
    ``i`` of a spline with coefficients ``c`` is ``sum_b weights[b, i] * c[first[i] + b]``. Leading
    axes, when present, index the Bayer site parity.

    Attributes
    ----------
    first : ndarray of int64, shape (..., m)
    weights : ndarray of float32, shape (..., 4, m)
    runs : ndarray of uint64, shape (..., r + 1)
        Start of each run of positions with the same ``first`` (between two knots), then ``m``;
        padded with ``m`` where parities have fewer runs.
    """

    first: np.ndarray
    weights: np.ndarray
    runs: np.ndarray


def make_taps(first: np.ndarray, weights: np.ndarray) -> Taps:
    """Taps from :func:`picamcal.interpolate.spline_taps` output, ``first`` (..., m) and ``weights`` (..., m, 4).

    Examples
    --------
    >>> t = make_taps(np.array([0, 0, 1, 1, 1]), np.full((5, 4), 0.25))
    >>> t.weights.shape, t.runs.tolist()
    ((4, 5), [0, 2, 5])
    """
    first = np.ascontiguousarray(first, dtype=np.int64)
    flat = first.reshape(-1, first.shape[-1])
    changes = [np.flatnonzero(np.diff(f)) + 1 for f in flat]
    runs = np.full((flat.shape[0], max(c.size for c in changes) + 2), first.shape[-1], dtype=np.uint64)
    for row, c in zip(runs, changes, strict=True):
        row[0] = 0
        row[1 : c.size + 1] = c
    return Taps(
        first,
        np.ascontiguousarray(np.swapaxes(weights, -1, -2), dtype=np.float32),
        runs.reshape(*first.shape[:-1], runs.shape[-1]),
    )


class CorrectionFields(NamedTuple):
    """Everything the kernels need for one sensor size and mode, as float32 arrays and :class:`Taps`.

    Build it with :func:`picamcal.correct.correction_fields`. A field with B-spline coefficients
    ``C`` (:func:`picamcal.interpolate.spline_coefficients`) has at row ``y`` and column ``x`` the value
    ``sum_ab rows.weights[a, y] * C[rows.first[y] + a, cols.first[x] + b] * cols.weights[b, x]``.

    Attributes
    ----------
    black : ndarray (4,)
        Black level per site of the 2x2 Bayer block, row-major.
    channels : ndarray of int64 (4,)
        Channel (0 R, 1 G, 2 B) of each site.
    site_gains : ndarray (4,)
        Constant gain per site, used when ``white`` is None (mode ``uncorrected``).
    white : ndarray (4, ncy, W // 2) or None
        Each site's white response, its B-spline coefficients already evaluated along x at each of the site's
        columns (``x = 2 j + sx``): the white at row ``y`` is ``sum_a white_rows.weights[a, y] *
        white[site, white_rows.first[y] + a, j]``; the gain is its reciprocal.
    white_rows : Taps
        Every row, on the knots of its own site row.
    matrices : ndarray (9, ncy, ncx) or None
        B-spline coefficients of the 3x3 matrix field, row-major elements first; None for no matrix.
    matrix_rows, matrix_cols : Taps
        Every row and every column, on the knots of the bin centres.
    """

    black: np.ndarray
    channels: np.ndarray
    site_gains: np.ndarray
    white: np.ndarray | None
    white_rows: Taps
    matrices: np.ndarray | None
    matrix_rows: Taps
    matrix_cols: Taps


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity), else the machine's.

    Examples
    --------
    >>> available_cores() >= 1
    True
    """
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def set_kernel_threads(threads: int | None) -> None:
    """Set how many threads the parallel kernels (C and numba) use in this process; None for every available core.

    A process pool shares the cores among its workers this way (:mod:`picamcal.batch.executors`).

    Raises
    ------
    ValueError
        ``threads`` is not a positive whole number.

    Examples
    --------
    >>> set_kernel_threads(1)
    >>> kernel_threads()
    1
    >>> set_kernel_threads(None)
    >>> kernel_threads() == available_cores()
    True
    """
    global _threads
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, Integral) or threads < 1):
        raise ValueError(f"kernel threads must be a positive whole number or None, not {threads!r}")
    _threads = None if threads is None else int(threads)


def kernel_threads() -> int:
    """How many threads the parallel kernels use: what :func:`set_kernel_threads` set, else :func:`available_cores`.

    Examples
    --------
    >>> kernel_threads() >= 1
    True
    """
    return _threads if _threads is not None else available_cores()


@functools.cache
def numba_available() -> bool:
    """Whether numba is installed (it is optional); found without importing it, which takes about 0.2 s.

    An installed numba that then fails to import (built for another numpy) raises ImportError at the
    first ``engine="numba"`` correction; ``engine="auto"`` falls back to numpy then.

    Examples
    --------
    >>> numba_available() in (True, False)
    True
    """
    return importlib.util.find_spec("numba") is not None


class SrgbTable(NamedTuple):
    """The sRGB outputs' codes: a 3x3 matrix, then the transfer function's by table (:func:`encode_table`), as
    :func:`picamcal.output.colour.srgb_encoding` makes them.

    Attributes
    ----------
    matrix : ndarray of float32 (3, 3)
        To linear sRGB, which is clipped to 0..1.
    base : ndarray of uint8 or uint16 (cells + 1,)
        The code at the start of each of ``cells`` equal cells of 0..1 (a power of two), and at 1.
    inside : ndarray of float32 (cells + 1,)
        The value from which a cell's code is one more (at most one per cell), else infinity.
    """

    matrix: np.ndarray
    base: np.ndarray
    inside: np.ndarray


def output_array(out: np.ndarray | None, height: int, width: int, dtype: DTypeLike = np.float32) -> np.ndarray:
    """``out`` if it can take the result (else OutputError), or a new array.

    The result is the (H, W, 3) float32 image, or its uint16 or uint8 codes, interleaved the same way.

    Examples
    --------
    >>> output_array(None, 4, 6).shape, output_array(None, 4, 6, np.uint16).dtype
    ((4, 6, 3), dtype('uint16'))
    """
    kind, shape = np.dtype(dtype), _output_shape(height, width, dtype)
    if out is None:
        return np.empty(shape, dtype=kind)
    if not fits(out, height, width, dtype):
        raise OutputError(
            f"out must be a writeable C-contiguous {kind} array of shape {shape}, not {out.dtype} {out.shape}: "
            "pass one of that shape, or none"
        )
    return out


def _output_shape(height: int, width: int, dtype: DTypeLike) -> tuple[int, ...]:
    kind = np.dtype(dtype)
    if kind in (np.float32, np.uint16, np.uint8):
        return (height, width, 3)
    raise ValueError(f"the corrected image is float32, or uint16 or uint8 codes, not {kind}")


def fits(out: Any, height: int, width: int, dtype: DTypeLike = np.float32) -> bool:
    """Whether ``out`` can take the corrected image of a ``height`` x ``width`` mosaic (:func:`output_array`).

    Examples
    --------
    >>> fits(np.empty((4, 6, 3), np.float32), 4, 6), fits(np.empty((4, 6, 3), np.float32), 4, 6, np.uint16)
    (True, False)
    >>> fits(None, 4, 6)
    False
    """
    return (
        isinstance(out, np.ndarray)
        and out.shape == _output_shape(height, width, dtype)
        and out.dtype == np.dtype(dtype)
        and out.flags.c_contiguous
        and out.flags.writeable
    )


def encode_codes(rgb: np.ndarray, scale: float, out: np.ndarray) -> np.ndarray:
    """Linear RGB rows (rows, W, 3) to uint16 codes in ``out`` (rows, W, 3): ``round(value * scale)``.

    Rounded half to even, clipped to 0..65535; NaN gives 0. Computed in the input's float type (float32 rows
    need no float64 copy) and in the numba kernel in float32: the same codes bit for bit when ``scale`` is a
    power of two, as the product is then exact in either.

    Examples
    --------
    >>> encode_codes(np.array([[[1.0, np.nan, 2.5]]]), 32768, np.empty((1, 1, 3), np.uint16)).ravel()
    array([32768,     0, 65535], dtype=uint16)
    """
    rgb = np.asarray(rgb)
    values = np.nan_to_num(rgb if rgb.dtype.kind == "f" else rgb.astype(float), nan=0.0)
    with np.errstate(over="ignore"):  # the largest floats overflow to infinity, which clips to 65535 all the same
        values *= values.dtype.type(scale)
    np.clip(values, 0, _CODE_MAX, out=values)
    out[...] = np.rint(values, out=values)
    return out


def encode_table(rgb: np.ndarray, table: SrgbTable, out: np.ndarray) -> np.ndarray:
    """Linear RGB rows (rows, W, 3) to codes in ``out`` through ``table``, in float32 as the kernels do.

    ``v = clip((m0 r + m1 g) + m2 b, 0, 1)`` with a row ``m`` of the matrix, then ``code = base[c] + (v >=
    inside[c])`` in the cell ``c = floor(v * cells)``; NaN gives 0.

    Examples
    --------
    >>> from picamcal.output.colour import srgb_encoding
    >>> encode_table(np.array([[[1.0, 0.5, 2.5]]]), srgb_encoding(), np.empty((1, 1, 3), np.uint8)).ravel()
    array([231, 170, 255], dtype=uint8)
    """
    rgb, (matrix, base, inside) = np.asarray(rgb, dtype=np.float32), table
    for p in range(3):
        with np.errstate(invalid="ignore", over="ignore"):  # 0 * inf is NaN, which gives 0 all the same
            v = (matrix[p, 0] * rgb[..., 0] + matrix[p, 1] * rgb[..., 1]) + matrix[p, 2] * rgb[..., 2]
        np.fmin(np.fmax(v, np.float32(0), out=v), np.float32(1), out=v)  # fmax: NaN gives 0
        cell = (v * np.float32(base.size - 1)).astype(np.intp)  # exact: the cells are a power of two
        out[..., p] = base[cell] + (v >= inside[cell])
    return out


def _reflect(index: np.ndarray, n: int) -> np.ndarray:
    """scipy.ndimage's ``reflect`` boundary for offsets of at most n: -1 -> 0, n -> n - 1."""
    index = np.where(index < 0, -index - 1, index)
    return np.where(index >= n, 2 * n - 1 - index, index)


# ---------------------------------------------------------------------------------------------
# numpy path


def _flat_rows(bayer: np.ndarray, rows: np.ndarray, fields: CorrectionFields) -> np.ndarray:
    """Black-subtracted, flat-fielded mosaic rows, padded by 2 mirrored columns each side: (len(rows), W + 4)."""
    width = bayer.shape[1]
    buf = np.empty((rows.size, width + 4), dtype=np.float32)
    for sy in (0, 1):
        sel = np.flatnonzero(rows % 2 == sy)
        r = rows[sel]
        for sx in (0, 1):
            site = 2 * sy + sx
            raw = bayer[r, sx::2].astype(np.float32) - fields.black[site]
            if fields.white is None:
                buf[sel, 2 + sx : width + 2 : 2] = raw * fields.site_gains[site]
                continue
            c = fields.white[site]
            i, w = fields.white_rows.first[r], fields.white_rows.weights[:, r, None]
            white = w[0] * c[i] + w[1] * c[i + 1] + w[2] * c[i + 2] + w[3] * c[i + 3]
            buf[sel, 2 + sx : width + 2 : 2] = raw / white
    buf[:, 0] = buf[:, 3]
    buf[:, 1] = buf[:, 2]
    buf[:, width + 2] = buf[:, width + 1]
    buf[:, width + 3] = buf[:, width]
    return buf


def _demosaic_block(buf: np.ndarray, y0: int, channels: np.ndarray, rgb: np.ndarray) -> None:
    """Malvar-He-Cutler on padded flat rows ``buf`` (rows y0 - 2 ... ) into ``rgb`` (rows, W, 3)."""
    n_rows, width = rgb.shape[:2]
    for ry in range(min(2, n_rows)):  # local row parity
        sy = (y0 + ry) % 2
        ny = (n_rows - ry + 1) // 2
        c_even, c_odd = channels[2 * sy], channels[2 * sy + 1]
        colour, green_x = (c_odd, 0) if c_even == 1 else (c_even, 1)
        other = 2 - colour
        for px, is_green in ((1 - green_x, False), (green_x, True)):
            nx = (width - px + 1) // 2

            def tap(dy: int, dx: int, ry: int = ry, px: int = px, ny: int = ny, nx: int = nx) -> np.ndarray:
                r0, c0 = 2 + ry + dy, 2 + px + dx
                return buf[r0 : r0 + 2 * ny - 1 : 2, c0 : c0 + 2 * nx - 1 : 2]

            v = tap(0, 0)
            out = rgb[ry::2, px::2]
            if not is_green:
                cross = (tap(-1, 0) + tap(1, 0) + tap(0, -1)) + tap(0, 1)
                axial2 = (tap(-2, 0) + tap(2, 0) + tap(0, -2)) + tap(0, 2)
                diagonal = (tap(-1, -1) + tap(-1, 1) + tap(1, -1)) + tap(1, 1)
                out[..., colour] = v
                out[..., 1] = (_F4 * v + _F2 * cross - axial2) * _EIGHTH
                out[..., other] = (_F6 * v + _F2 * diagonal - _F15 * axial2) * _EIGHTH
            else:
                diagonal = (tap(-1, -1) + tap(-1, 1) + tap(1, -1)) + tap(1, 1)
                horizontal1 = tap(0, -1) + tap(0, 1)
                horizontal2 = tap(0, -2) + tap(0, 2)
                vertical1 = tap(-1, 0) + tap(1, 0)
                vertical2 = tap(-2, 0) + tap(2, 0)
                out[..., 1] = v
                out[..., colour] = (_F5 * v + _F4 * horizontal1 - horizontal2 - diagonal + _F05 * vertical2) * _EIGHTH
                out[..., other] = (_F5 * v + _F4 * vertical1 - vertical2 - diagonal + _F05 * horizontal2) * _EIGHTH


def _unmix_block(rgb: np.ndarray, y0: int, fields: CorrectionFields, matrices: np.ndarray) -> None:
    """Apply the interpolated matrix field to rows y0 ... of the image, in place on ``rgb`` (rows, W, 3)."""
    c = matrices
    rows = slice(y0, y0 + rgb.shape[0])
    i, w = fields.matrix_rows.first[rows], fields.matrix_rows.weights[:, rows, None]
    along_y = w[0] * c[:, i] + w[1] * c[:, i + 1] + w[2] * c[:, i + 2] + w[3] * c[:, i + 3]  # (9, rows, ncx)
    j, u = fields.matrix_cols.first, fields.matrix_cols.weights
    r, g, b = rgb[..., 0].copy(), rgb[..., 1].copy(), rgb[..., 2].copy()
    for p in range(3):
        m = []
        for a in along_y[3 * p : 3 * p + 3]:
            element = u[0] * a[:, j] + u[1] * a[:, j + 1] + u[2] * a[:, j + 2]
            element += u[3] * a[:, j + 3]
            m.append(element)
        rgb[..., p] = m[0] * r + m[1] * g + m[2] * b


def correct_numpy(
    bayer: np.ndarray,
    fields: CorrectionFields,
    out: np.ndarray | None = None,
    block_rows: int = NUMPY_BLOCK_ROWS,
    *,
    code_scale: float | None = None,
    table: SrgbTable | None = None,
) -> np.ndarray:
    """The fused correction with numpy, block of rows by block of rows (same arithmetic as :func:`correct_numba`).

    Parameters
    ----------
    bayer : ndarray of uint16, shape (H, W)
        The raw mosaic (even H and W).
    fields : CorrectionFields
        From :func:`picamcal.correct.correction_fields`, with the image's black level.
    out : ndarray, optional
        Where to write the result (C-contiguous, of the returned shape and type); a new array by default.
    block_rows : int
        Rows per block: temporaries scale with it.
    code_scale, table : float or SrgbTable, optional
        Return codes instead of float32, each block encoded as soon as it is corrected: uint16 ``round(value *
        code_scale)`` (:func:`encode_codes`; a power of two), or those of ``table`` (:func:`encode_table`).

    Returns
    -------
    ndarray of float32, or of the codes' type, shape (H, W, 3)

    Examples
    --------
    >>> from picamcal.correct import correction_fields
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal, raw = picamcal.calibrate(**refs), refs["white"]
    >>> black = np.asarray(raw.black_level, dtype=np.float32)
    >>> fields = correction_fields(cal, "centre", raw.height, raw.width)._replace(black=black)
    >>> rgb = correct_numpy(raw.bayer, fields)
    >>> rgb.shape, round(float(rgb.mean()), 2)  # the calibration's own white comes out 1.0
    ((240, 320, 3), 1.0)
    >>> codes = correct_numpy(raw.bayer, fields, code_scale=32768)
    >>> codes.shape, round(float(codes.mean()) / 32768, 2)  # the white at code 32768
    ((240, 320, 3), 1.0)
    """
    height, width = bayer.shape
    out = output_array(out, height, width, _code_type(code_scale, table))
    block = None if out.dtype == np.float32 else np.empty((min(block_rows, height), width, 3), dtype=np.float32)
    for y0 in range(0, height, block_rows):
        y1 = min(y0 + block_rows, height)
        rgb = out[y0:y1] if block is None else block[: y1 - y0]
        buf = _flat_rows(bayer, _reflect(np.arange(y0 - 2, y1 + 2), height), fields)
        _demosaic_block(buf, y0, fields.channels, rgb)
        if fields.matrices is not None:
            _unmix_block(rgb, y0, fields, fields.matrices)
        if table is not None:
            encode_table(rgb, table, out[y0:y1])
        elif code_scale is not None:
            encode_codes(rgb, code_scale, out[y0:y1])
    return out


def _code_type(code_scale: float | None, table: SrgbTable | None) -> np.dtype:
    """The output's type: float32, uint16 for ``code_scale``, the table's codes' (one of them at most)."""
    if table is not None and code_scale is not None:
        raise ValueError("codes are either scaled (code_scale) or from a table, not both")
    return np.dtype(np.float32 if code_scale is None else np.uint16) if table is None else table.base.dtype


# ---------------------------------------------------------------------------------------------
# numba path
#
# Written for LLVM's loop vectoriser, which gives up on a loop for reasons that are easy to miss:
# - an index numba cannot prove non-negative gets a wrap-around test: inner loops count from 0, or
#   over unsigned run bounds;
# - numba's default error model tests every float division for zero: error_model="numpy" (IEEE, as numpy);
# - stores at stride 2: the mosaic is kept as two planes per row (even and odd columns), the demosaic
#   writes 6 half-row planes and only then merges them into full rows;
# - gathers: the matrix field is evaluated run by run (a run is the pixels between two knots, where the
#   4 coefficients are constants), the white from its coefficients evaluated along x beforehand (its runs,
#   of a site's columns, are too short for a vector loop).
# - no fastmath: the uint16 codes test for NaN, and even "contract" alone (a multiply and an add in one
#   rounding) moves the result of mode pure by over 1e-6 from numpy's, for no measurable gain.
# Each thread works in its own 5-row ring of flat-fielded mosaic rows and a few planar rows, and
# writes the output row last, interleaved: float32, or uint16 codes.


@functools.cache
def _numba_kernel():
    """Compile (or load from numba's cache) the parallel kernel and image encoder; numba is imported here only.

    The helpers become module globals rather than closure variables of the kernel: numba keys its
    disk cache of a closure on a pickle of the closure's variables, and a pickled dispatcher differs
    from one process to the next, so a kernel that closed over its helpers would never be reused.
    """
    global _nb_flat_row, _nb_demosaic_pairs, _nb_merge, _nb_demosaic_row, _nb_unmix_row, _nb_code, _nb_write_row
    import numba

    f05, f15, f2, f4, f5, f6, eighth = _F05, _F15, _F2, _F4, _F5, _F6, _EIGHTH
    zero, one, code_max = np.float32(0.0), np.float32(1.0), np.float32(_CODE_MAX)
    options = {"cache": True, "nogil": True, "error_model": "numpy"}

    @numba.njit(**options)
    def _nb_flat_row(bayer, y, black, site_gains, flat, white, iy, wy, dst):
        half = bayer.shape[1] // 2
        sy = y & 1
        raw = bayer[y]
        even, odd = dst[0, 1 : half + 1], dst[1, 1 : half + 1]
        level0, level1 = black[2 * sy], black[2 * sy + 1]
        if flat:
            i = iy[y]
            w0, w1, w2, w3 = wy[0, y], wy[1, y], wy[2, y], wy[3, y]
            even_white, odd_white = white[2 * sy], white[2 * sy + 1]
            e0, e1, e2, e3 = even_white[i], even_white[i + 1], even_white[i + 2], even_white[i + 3]
            o0, o1, o2, o3 = odd_white[i], odd_white[i + 1], odd_white[i + 2], odd_white[i + 3]
            for j in range(half):
                even[j] = (np.float32(raw[2 * j]) - level0) / (w0 * e0[j] + w1 * e1[j] + w2 * e2[j] + w3 * e3[j])
                odd[j] = (np.float32(raw[2 * j + 1]) - level1) / (w0 * o0[j] + w1 * o1[j] + w2 * o2[j] + w3 * o3[j])
        else:
            gain0, gain1 = site_gains[2 * sy], site_gains[2 * sy + 1]
            for j in range(half):
                even[j] = (np.float32(raw[2 * j]) - level0) * gain0
                odd[j] = (np.float32(raw[2 * j + 1]) - level1) * gain1
        dst[0, 0] = dst[1, 1]
        dst[1, 0] = dst[0, 1]
        dst[0, half + 1] = dst[1, half]
        dst[1, half + 1] = dst[0, half]

    @numba.njit(inline="always", error_model="numpy")
    def _nb_demosaic_pairs(r0, r1, r2, r3, r4, gx, half_rows):
        # Pixel 2j + gx is green, 2j + 1 - gx the row's red or blue (its colour c; o is the other of the two).
        # Mosaic planes are padded by one column; results go to 6 planes of half rows (green-pixel G, c, o,
        # then other-pixel c, G, o), as stride-2 stores would keep the loop from vectorising.
        nx = 1 - gx
        g0, g1, g2, g3, g4 = r0[gx], r1[gx], r2[gx], r3[gx], r4[gx]
        n0, n1, n2, n3, n4 = r0[nx], r1[nx], r2[nx], r3[nx], r4[nx]
        green_g, green_c, green_o = half_rows[0], half_rows[1], half_rows[2]
        other_c, other_g, other_o = half_rows[3], half_rows[4], half_rows[5]
        for j in range(green_g.shape[0]):
            v = g2[j + 1]
            diagonal = (n1[j + gx] + n1[j + gx + 1] + n3[j + gx]) + n3[j + gx + 1]
            horizontal1 = n2[j + gx] + n2[j + gx + 1]
            horizontal2 = g2[j] + g2[j + 2]
            vertical1 = g1[j + 1] + g3[j + 1]
            vertical2 = g0[j + 1] + g4[j + 1]
            green_g[j] = v
            green_c[j] = (f5 * v + f4 * horizontal1 - horizontal2 - diagonal + f05 * vertical2) * eighth
            green_o[j] = (f5 * v + f4 * vertical1 - vertical2 - diagonal + f05 * horizontal2) * eighth
            v = n2[j + 1]
            cross = (n1[j + 1] + n3[j + 1] + g2[j + nx]) + g2[j + nx + 1]
            axial2 = (n0[j + 1] + n4[j + 1] + n2[j]) + n2[j + 2]
            diagonal = (g1[j + nx] + g1[j + nx + 1] + g3[j + nx]) + g3[j + nx + 1]
            other_c[j] = v
            other_g[j] = (f4 * v + f2 * cross - axial2) * eighth
            other_o[j] = (f6 * v + f2 * diagonal - f15 * axial2) * eighth

    @numba.njit(**options)
    def _nb_merge(even, odd, dst):
        for j in range(even.shape[0]):
            dst[2 * j] = even[j]
            dst[2 * j + 1] = odd[j]

    @numba.njit(**options)
    def _nb_demosaic_row(r0, r1, r2, r3, r4, y, channels, half_rows, rgb):
        sy = y & 1
        c_even, c_odd = channels[2 * sy], channels[2 * sy + 1]
        colour = c_odd if c_even == 1 else c_even
        if c_even == 1:
            _nb_demosaic_pairs(r0, r1, r2, r3, r4, 0, half_rows)
            _nb_merge(half_rows[0], half_rows[4], rgb[1])
            _nb_merge(half_rows[1], half_rows[3], rgb[colour])
            _nb_merge(half_rows[2], half_rows[5], rgb[2 - colour])
        else:
            _nb_demosaic_pairs(r0, r1, r2, r3, r4, 1, half_rows)
            _nb_merge(half_rows[4], half_rows[0], rgb[1])
            _nb_merge(half_rows[3], half_rows[1], rgb[colour])
            _nb_merge(half_rows[5], half_rows[2], rgb[2 - colour])

    @numba.njit(**options)
    def _nb_unmix_row(y, matrices, iy, wy, first, weights, runs, along_y, rgb, mixed):
        i = iy[y]
        w0, w1, w2, w3 = wy[0, y], wy[1, y], wy[2, y], wy[3, y]
        for k in range(9):
            c0, c1, c2, c3 = matrices[k, i], matrices[k, i + 1], matrices[k, i + 2], matrices[k, i + 3]
            a = along_y[k]
            for j in range(a.shape[0]):
                a[j] = w0 * c0[j] + w1 * c1[j] + w2 * c2[j] + w3 * c3[j]
        u0, u1, u2, u3 = weights[0], weights[1], weights[2], weights[3]
        red, green, blue = rgb[0], rgb[1], rgb[2]
        # Runs outside, channels inside: a run's pixels stay in L1 for its 3 channels (5 % faster than the other way
        # round); all 9 elements in one loop keep too many constants for the registers (50 % slower).
        for r in range(runs.shape[0] - 1):
            x0, x1 = runs[r], runs[r + 1]
            k = first[x0]
            for p in range(3):
                ap0, ap1, ap2 = along_y[3 * p], along_y[3 * p + 1], along_y[3 * p + 2]
                d = mixed[p]
                a00, a10, a20, a30 = ap0[k], ap0[k + 1], ap0[k + 2], ap0[k + 3]
                a01, a11, a21, a31 = ap1[k], ap1[k + 1], ap1[k + 2], ap1[k + 3]
                a02, a12, a22, a32 = ap2[k], ap2[k + 1], ap2[k + 2], ap2[k + 3]
                for x in range(x0, x1):
                    m0 = u0[x] * a00 + u1[x] * a10 + u2[x] * a20
                    m0 += u3[x] * a30
                    m1 = u0[x] * a01 + u1[x] * a11 + u2[x] * a21
                    m1 += u3[x] * a31
                    m2 = u0[x] * a02 + u1[x] * a12 + u2[x] * a22
                    m2 += u3[x] * a32
                    d[x] = m0 * red[x] + m1 * green[x] + m2 * blue[x]

    @numba.njit(inline="always", error_model="numpy")
    def _nb_code(value, scale, top):
        # As encode_codes and encode_table: NaN and negatives fail "> 0" and give 0.
        v = value * scale
        v = v if v > zero else zero
        return v if v < top else top

    @numba.njit(**options)
    def _nb_write_row(red, green, blue, floats, scale, codes, matrix, base, inside, y):
        # Row y of the output, interleaved: float32, scaled codes or a table's (NaN fails "> 0": 0, as encode_table).
        if base.shape[0] > 0:
            row, cells = codes[y], np.float32(base.shape[0] - 1)
            for x in range(red.shape[0]):
                r, g, b = red[x], green[x], blue[x]
                for p in range(3):
                    v = _nb_code(matrix[p, 0] * r + matrix[p, 1] * g + matrix[p, 2] * b, one, one)
                    c = np.intp(v * cells)
                    row[3 * x + p] = base[c] + (v >= inside[c])
        elif scale > 0:  # rint rounds half to even, as numpy's
            row = codes[y]
            for x in range(red.shape[0]):
                row[3 * x] = np.uint16(np.rint(_nb_code(red[x], scale, code_max)))
                row[3 * x + 1] = np.uint16(np.rint(_nb_code(green[x], scale, code_max)))
                row[3 * x + 2] = np.uint16(np.rint(_nb_code(blue[x], scale, code_max)))
        else:
            row = floats[y]
            for x in range(red.shape[0]):
                row[3 * x] = red[x]
                row[3 * x + 1] = green[x]
                row[3 * x + 2] = blue[x]

    @numba.njit(parallel=True, **options)
    def kernel(bayer, sites, white_field, matrix_field, block_rows, scratch, output):
        height, (black, channels, site_gains) = bayer.shape[0], sites
        flat, white, (wiy, wwy) = white_field
        unmix, matrices, (miy, mwy), (mfirst, mweights, mruns) = matrix_field
        ring, half_rows, rgb, mixed, matrix_along = scratch
        floats, scale, codes, (matrix, base, inside) = output  # flat arrays: a tuple inside prange cannot be passed
        n_blocks = (height + block_rows - 1) // block_rows
        for block in numba.prange(n_blocks):
            t = numba.get_thread_id()
            rows, planar, unmixed = ring[t], rgb[t], mixed[t]
            y0 = block * block_rows
            y1 = min(y0 + block_rows, height)
            # Flat-field row r into the 5-row ring (rows beyond the image mirrored), then demosaic the row two
            # behind it, once its neighbours r - 4 .. r are all in the ring.
            for r in range(y0 - 2, y1 + 2):
                source = -r - 1 if r < 0 else (2 * height - 1 - r if r >= height else r)
                _nb_flat_row(bayer, source, black, site_gains, flat, white, wiy, wwy, rows[(r + 5) % 5])
                y = r - 2
                if y < y0:
                    continue
                r0, r1, r2 = rows[(y + 3) % 5], rows[(y + 4) % 5], rows[y % 5]
                _nb_demosaic_row(r0, r1, r2, rows[(y + 1) % 5], rows[(y + 2) % 5], y, channels, half_rows[t], planar)
                result = planar
                if unmix:
                    _nb_unmix_row(y, matrices, miy, mwy, mfirst, mweights, mruns, matrix_along[t], planar, unmixed)
                    result = unmixed
                _nb_write_row(result[0], result[1], result[2], floats, scale, codes, matrix, base, inside, y)

    @numba.njit(parallel=True, **options)
    def encoder(rgb, output):
        floats, scale, codes, (matrix, base, inside) = output
        for y in numba.prange(rgb.shape[0]):
            _nb_write_row(rgb[y, :, 0], rgb[y, :, 1], rgb[y, :, 2], floats, scale, codes, matrix, base, inside, y)

    return kernel, encoder


def _numba_output(out: np.ndarray | None, shape: tuple[int, ...], code_scale: float | None, table: SrgbTable | None):
    """``out`` (:func:`output_array`) and the numba kernels' output: float32 rows, scale, code rows, the table."""
    out = output_array(out, shape[0], shape[1], _code_type(code_scale, table))
    rows, none = out.reshape(shape[0], -1), np.empty((0, 0), np.float32)
    table = table or SrgbTable(np.zeros((3, 3), np.float32), np.empty(0, np.uint16), np.empty(0, np.float32))
    floats, codes = (rows, np.empty((0, 0), np.uint16)) if out.dtype == np.float32 else (none, rows)
    return out, (floats, np.float32(code_scale or 0.0), codes, tuple(table))


def _numba_threads() -> int:
    """Set numba's threads for this call (:func:`kernel_threads`, at most those numba has started): how many."""
    import numba

    # numba's own runtime setting, not NUMBA_NUM_THREADS (numba re-reads its environment when it compiles and refuses
    # a value that differs from the threads it has started); it holds for the calling thread only, so set it here.
    # numba.config's attributes are set at import from the environment: not in its stubs.
    threads = min(kernel_threads(), int(getattr(numba.config, "NUMBA_NUM_THREADS")))  # noqa: B009
    numba.set_num_threads(threads)
    return threads


def correct_numba(
    bayer: np.ndarray,
    fields: CorrectionFields,
    out: np.ndarray | None = None,
    block_rows: int = NUMBA_BLOCK_ROWS,
    *,
    code_scale: float | None = None,
    table: SrgbTable | None = None,
) -> np.ndarray:
    """The fused correction as one parallel numba kernel (same arithmetic as :func:`correct_numpy`).

    The first call in a process imports numba and loads the compiled kernel from numba's disk cache (a
    fraction of a second), or compiles it (about 10 s) when there is none; later calls run at full speed.
    It runs on :func:`kernel_threads` threads. Each thread works in 5 mosaic rows, a few RGB rows and one
    row of spline coefficients, allocated here; nothing else is allocated besides ``out``.

    Parameters
    ----------
    bayer : ndarray of uint16, shape (H, W)
    fields : CorrectionFields
    out : ndarray, optional
        float32 (H, W, 3), or of the codes' type with ``code_scale`` or ``table``.
    block_rows : int
        Rows per parallel work item.
    code_scale, table : float or SrgbTable, optional
        Return codes instead of float32: uint16 ``round(value * code_scale)`` (:func:`encode_codes`; a power of
        two, for the codes to be those of numpy bit for bit), or those of ``table`` (:func:`encode_table`).

    Returns
    -------
    ndarray of float32, or of the codes' type, shape (H, W, 3)

    Raises
    ------
    ImportError
        numba is not installed.

    Examples
    --------
    >>> from picamcal.correct import correction_fields
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> refs = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)
    >>> cal, raw = picamcal.calibrate(**refs), refs["white"]
    >>> black = np.asarray(raw.black_level, dtype=np.float32)
    >>> fields = correction_fields(cal, "centre", raw.height, raw.width)._replace(black=black)
    >>> bool(np.allclose(correct_numba(raw.bayer, fields), correct_numpy(raw.bayer, fields), atol=1e-5))
    True
    >>> codes = correct_numba(raw.bayer, fields, code_scale=32768)
    >>> bool(np.array_equal(codes, correct_numpy(raw.bayer, fields, code_scale=32768)))
    True
    """
    import numba

    kernel, _ = _numba_kernel()
    out, output = _numba_output(out, bayer.shape, code_scale, table)
    threads, width = _numba_threads(), bayer.shape[1]
    half = width // 2
    white = np.zeros((4, 4, 4), np.float32) if fields.white is None else fields.white
    matrices = np.zeros((9, 4, 4), np.float32) if fields.matrices is None else fields.matrices
    scratch = tuple(
        np.empty((threads, *shape), dtype=np.float32)
        for shape in ((5, 2, half + 2), (6, half), (3, width), (3, width), (9, matrices.shape[2]))
    )
    # One block at a time to whichever thread is free: a core busy with other work then takes fewer blocks.
    with numba.parallel_chunksize(1):
        kernel(
            np.ascontiguousarray(bayer, dtype=np.uint16),
            (fields.black, fields.channels, fields.site_gains),
            (fields.white is not None, white, tuple(fields.white_rows[:2])),
            (fields.matrices is not None, matrices, tuple(fields.matrix_rows[:2]), tuple(fields.matrix_cols)),
            block_rows,
            scratch,
            output,
        )
    return out


def encode_numba(
    rgb: np.ndarray, out: np.ndarray | None = None, *, code_scale: float | None = None, table: SrgbTable | None = None
) -> np.ndarray:
    """A float32 (H, W, 3) image's codes (:func:`encode_codes` or :func:`encode_table`) by a parallel numba loop.

    Examples
    --------
    >>> rgb = np.array([[[1.0, 0.5, 2.5]]], np.float32)
    >>> encode_numba(rgb, code_scale=32768).ravel()
    array([32768, 16384, 65535], dtype=uint16)
    """
    _, encoder = _numba_kernel()
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    out, output = _numba_output(out, rgb.shape, code_scale, table)
    _numba_threads()
    encoder(rgb, output)
    return out
