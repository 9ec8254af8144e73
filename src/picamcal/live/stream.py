"""The pixels of a picamera2 RGB stream: its byte order (:data:`STREAM_FORMATS`), its tone curve as exact tables
(:func:`tone_curve_tables`), and the kernels that take a frame through the tables and a per-pixel matrix field in
place (numba, or numpy where numba is missing). :mod:`picamcal.live` re-exports the public names.

picamera2's names for the RGB formats are libcamera's (DRM fourcc) names, which give the channels from the most
significant byte of a little-endian word: ``RGB888`` holds B, G, R in memory order, ``BGR888`` R, G, B,
``XBGR8888`` R, G, B, X and ``XRGB8888`` B, G, R, X (the Picamera2 manual, Appendix A). :data:`STREAM_FORMATS`
holds the byte offsets; the padding byte of the 32-bit formats is left as it is.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ..errors import PicamcalError, closest
from ..export.isp import TuningError
from ..limits import max_pixels
from ..raw.processed import linearise

#: Entries of the table from linear values (0..1) to a first guess of the 8-bit code: its step (0.2 code at the sRGB
#: curve's steepest, 0.08 at the Pi's stock gamma curve's) leaves the guess one code low for a few values in a
#: thousand, which one comparison corrects; and 16 KB stays in a core's L1 cache.
ENCODE_TABLE_SIZE = 1 << 14
#: Rows per block of the numpy path (bounds its float32 temporaries to a few MB at 1920 pixels wide).
_NUMPY_ROWS = 64


class LiveStreamError(PicamcalError):
    """A stream the live unmixer cannot take: an unknown format, or not the size and format it was prepared for."""


@dataclass(frozen=True)
class StreamFormat:
    """Where the channels of one pixel lie in a picamera2 RGB stream's memory.

    Attributes
    ----------
    name : str
        picamera2's name (``"RGB888"``).
    bytes_per_pixel : int
        3 or 4.
    red, green, blue : int
        Byte offset of each channel within a pixel.
    """

    name: str
    bytes_per_pixel: int
    red: int
    green: int
    blue: int


#: picamera2's 8-bit RGB stream formats (the Picamera2 manual, Appendix A): memory order per pixel.
STREAM_FORMATS: dict[str, StreamFormat] = {
    "RGB888": StreamFormat("RGB888", 3, red=2, green=1, blue=0),  # B, G, R
    "BGR888": StreamFormat("BGR888", 3, red=0, green=1, blue=2),  # R, G, B
    "XBGR8888": StreamFormat("XBGR8888", 4, red=0, green=1, blue=2),  # R, G, B, X
    "XRGB8888": StreamFormat("XRGB8888", 4, red=2, green=1, blue=0),  # B, G, R, X
}


def stream_format(name: str) -> StreamFormat:
    """The :class:`StreamFormat` of a picamera2 format name (case-insensitive).

    Raises
    ------
    LiveStreamError
        Not one of :data:`STREAM_FORMATS` (YUV and raw streams have no RGB pixels to unmix).

    Examples
    --------
    >>> stream_format("RGB888")  # picamera2's RGB888 is B, G, R in memory
    StreamFormat(name='RGB888', bytes_per_pixel=3, red=2, green=1, blue=0)
    >>> stream_format("YUV420")
    Traceback (most recent call last):
    ...
    picamcal.live.stream.LiveStreamError: cannot unmix a stream of format YUV420: configure the stream as RGB888, \
BGR888, XBGR8888 or XRGB8888
    """
    key = str(name).strip().upper()
    if key in STREAM_FORMATS:
        return STREAM_FORMATS[key]
    near = closest(key, STREAM_FORMATS)
    hint = f" (did you mean {near}?)" if near else ""
    names = list(STREAM_FORMATS)
    raise LiveStreamError(
        f"cannot unmix a stream of format {str(name)[:40]}{hint}: configure the stream as "
        f"{', '.join(names[:-1])} or {names[-1]}"
    )


def _check_stream_size(size: tuple[int, int]) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in size)
    except (TypeError, ValueError):
        raise LiveStreamError(f"stream size {size!r} is not (width, height) in pixels") from None
    if width < 1 or height < 1 or (width, height) != tuple(size):
        raise LiveStreamError(f"stream size {size!r} is not two positive whole numbers of pixels")
    if width * height > max_pixels():
        raise LiveStreamError(f"a {width}x{height} stream is over the limit of {max_pixels()} pixels")
    return width, height


def _gamma_curve(tuning: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """The ``rpi.contrast`` ``gamma_curve`` of a tuning as (linear, encoded) on 0..1, or None if it has none."""
    for algorithm in tuning.get("algorithms", []):
        section = algorithm.get("rpi.contrast") if isinstance(algorithm, dict) else None
        if isinstance(section, dict) and "gamma_curve" in section:
            curve = np.asarray(section["gamma_curve"], dtype=np.float64)
            linear, encoded = curve[0::2] / 65535.0, curve[1::2] / 65535.0
            if curve.size < 4 or curve.size % 2 or np.any(np.diff(linear) <= 0) or np.any(np.diff(encoded) < 0):
                raise TuningError("rpi.contrast gamma_curve is not increasing (input, output) pairs: cannot undo it")
            return linear, encoded
    return None


def _contrast_enhancement_on(tuning: Mapping[str, Any]) -> bool:
    """Whether libcamera's adaptive contrast enhancement bends the gamma curve frame by frame (``ce_enable``,
    on unless the file says 0)."""
    for algorithm in tuning.get("algorithms", []):
        section = algorithm.get("rpi.contrast") if isinstance(algorithm, dict) else None
        if isinstance(section, dict):
            return bool(section.get("ce_enable", 1))
    return False


class ToneCurve(NamedTuple):
    """A tone curve as the tables the kernel reads (:func:`tone_curve_tables`).

    Attributes
    ----------
    decode : ndarray of float32, shape (256,)
        The linear value of each 8-bit code.
    encode : ndarray of uint8, shape (16384,)
        A first guess, never too high, of the code of a linear value ``v``: ``encode[floor(v * 16383)]``
        (:data:`ENCODE_TABLE_SIZE`).
    edges : ndarray of float32, shape (257,)
        ``edges[c]`` is the smallest float32 at or above the linear value where code ``c`` begins (the decoding of
        ``(c - 0.5) / 255``; ``-inf`` and ``inf`` at the ends): the guess goes up while ``v >= edges[c + 1]``.
    """

    decode: np.ndarray
    encode: np.ndarray
    edges: np.ndarray


def tone_curve_tables(encoding: str | None = None, tuning: Mapping[str, Any] | None = None) -> ToneCurve:
    """The tables that take 8-bit codes to linear values and back, exactly.

    ``decode[code]`` is what :func:`picamcal.raw.processed.read_processed` makes of a code (the same
    :func:`~picamcal.raw.processed.linearise`, or the tuning's curve interpolated as it does). A float32 linear
    value ``v`` goes back to ``round(255 * curve(v))``, the code whose interval of the decoded curve holds it:
    ``encode[floor(v * 16383)]`` (clipped to the table) gives it, or one code below where an interval's edge lies
    within the table's step (one value in a few hundred on the Pi's gamma curve), and a comparison with ``edges``
    settles those. The result is the exact rounding, not an approximation: the edges are float32 numbers
    rounded up, so ``v >= edges[c]`` holds exactly when ``v`` is at or above the true edge.

    Parameters
    ----------
    encoding : str, optional
        ``srgb``, ``linear``, ``gamma:G`` or ``tuning:FILE`` (as :func:`~picamcal.raw.processed.linearise`);
        default the ``rpi.contrast`` gamma curve of ``tuning`` if it has one, else ``srgb``.
    tuning : dict, optional
        The tuning file the camera runs with.

    Examples
    --------
    >>> curve = tone_curve_tables("srgb")
    >>> round(float(curve.decode[188]), 3), int(curve.encode[int(0.5 * 16383)])  # sRGB 188 is linear 0.5, and back
    (0.503, 188)
    """
    points = _gamma_curve(tuning) if tuning is not None and encoding is None else None
    if points is not None:
        linear_points, encoded_points = points

        def decode(values: np.ndarray) -> np.ndarray:
            return np.interp(values, encoded_points, linear_points)

    else:
        spelled = "srgb" if encoding is None else encoding

        def decode(values: np.ndarray) -> np.ndarray:
            return linearise(values, spelled)

    table = np.asarray(decode(np.arange(256, dtype=np.float32) / 255.0), dtype=np.float32)
    inner = np.maximum.accumulate(np.asarray(decode((np.arange(255) + 0.5) / 255.0), dtype=np.float64))
    edges = np.concatenate([[-np.inf], inner, [np.inf]])
    rounded = edges.astype(np.float32)
    rounded = np.where(rounded < edges, np.nextafter(rounded, np.float32(np.inf)), rounded)
    # The float32 product v * 16383 may round up to the next index: guess from a little below each step's start.
    steps = np.arange(ENCODE_TABLE_SIZE) / (ENCODE_TABLE_SIZE - 1) - 1e-6
    guess = np.clip(np.searchsorted(edges, steps, side="right") - 1, 0, 255).astype(np.uint8)
    return ToneCurve(table, guess, rounded.astype(np.float32))


def _one_step(curve: ToneCurve) -> bool:
    """Whether one comparison with ``edges`` settles every first guess of the curve's ``encode`` table: no table step
    holds more than one code's edge past its guess (so on the sRGB curve and the Pi's gamma curves, not where a curve
    is steeper than a code a step, as ``gamma:2.2`` is near black).

    The values that take table entry ``i`` lie below ``(i + 1) / top`` (the float32 product ``v * top`` is below
    ``i + 1`` only if ``v`` is), so the highest code they reach is that of the last edge below that bound.
    """
    top = curve.encode.shape[0] - 1
    bounds = np.arange(1, top + 2, dtype=np.float64) / top
    highest = np.searchsorted(curve.edges.astype(np.float64), bounds, side="left") - 1
    return bool((np.minimum(highest, 255) - curve.encode.astype(np.int64)).max() <= 1)


@functools.lru_cache(maxsize=4)
def _numba_unmix(parallel: bool, one_step: bool = False) -> Callable[..., None]:
    """The numba kernel, compiled (or loaded from numba's cache) on first use: numba is imported only here.

    With ``one_step`` (a curve :func:`_one_step` allows) each code is its guess plus one comparison, without a branch
    (a fifth of the kernel's time); else the guess goes up while the value is at or above the next edge. Indices are
    unsigned, which spares numba's test for negative ones.
    """
    import numba

    signature = (
        "void(uint8[:, :], int64, int64, int64, int64, int64, float32[:, :, ::1], float32[::1], uint8[::1], "
        "float32[::1])"
    )

    @numba.njit(nogil=True, cache=True, inline="always")
    def stepped(value, encode, edges):
        top = np.float32(encode.shape[0] - 1)
        code = np.uint64(encode[np.uint64(min(max(value * top, np.float32(0.0)), top))])
        while value >= edges[code + np.uint64(1)]:
            code += np.uint64(1)
        return np.uint8(code)

    @numba.njit(nogil=True, cache=True, inline="always")
    def once(value, encode, edges):
        top = np.float32(encode.shape[0] - 1)
        code = np.uint64(encode[np.uint64(min(max(value * top, np.float32(0.0)), top))])
        return np.uint8(code + np.uint64(value >= edges[code + np.uint64(1)]))

    encoded = once if one_step else stepped

    @numba.njit(signature, parallel=parallel, cache=True, nogil=True)
    def unmix(rows, width, step, red, green, blue, field, decode, encode, edges):
        red_at, green_at, blue_at = np.uint64(red), np.uint64(green), np.uint64(blue)
        for y in numba.prange(rows.shape[0]):
            row, matrices = rows[y], field[y]
            for x in range(width):
                at = np.uint64(x) * np.uint64(step)
                r = decode[row[at + red_at]]
                g = decode[row[at + green_at]]
                b = decode[row[at + blue_at]]
                m = matrices[np.uint64(x)]
                out_r = m[0] * r + m[1] * g + m[2] * b
                out_g = m[3] * r + m[4] * g + m[5] * b
                out_b = m[6] * r + m[7] * g + m[8] * b
                row[at + red_at] = encoded(out_r, encode, edges)
                row[at + green_at] = encoded(out_g, encode, edges)
                row[at + blue_at] = encoded(out_b, encode, edges)

    return unmix


def _encode_numpy(value: np.ndarray, curve: ToneCurve) -> np.ndarray:
    top = curve.encode.shape[0] - 1
    code = curve.encode[np.clip(value * np.float32(top), 0, top).astype(np.intp)].astype(np.intp)
    while True:
        up = value >= curve.edges[code + 1]
        if not up.any():
            return code.astype(np.uint8)
        code += up


def _unmix_numpy(frame: np.ndarray, fmt: StreamFormat, field: np.ndarray, curve: ToneCurve) -> None:
    """The numba kernel's arithmetic in numpy, block by block (the same float32 operations in the same order)."""
    offsets = (fmt.red, fmt.green, fmt.blue)
    for y0 in range(0, frame.shape[0], _NUMPY_ROWS):
        block = frame[y0 : y0 + _NUMPY_ROWS]
        m = field[y0 : y0 + _NUMPY_ROWS]
        r, g, b = (curve.decode[block[..., offset]] for offset in offsets)
        for p, offset in enumerate(offsets):
            block[..., offset] = _encode_numpy(m[..., 3 * p] * r + m[..., 3 * p + 1] * g + m[..., 3 * p + 2] * b, curve)
