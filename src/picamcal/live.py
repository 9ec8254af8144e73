"""Live unmixing on the Pi: the calibration's colour unmixing applied in place to a picamera2 stream.

A camera running with the lens shading table exported from the calibration (``picamcal export-tuning``) sends
frames that are already flat. What is left is what :func:`picamcal.correct.correct_processed` does to such an
image: divide out the residual between the exported table (as the ISP applies it) and the calibration's flat
field, with the colour gains, and unmix, all in linear camera RGB, around the colour matrix the ISP applied
(``rpi.ccm``, undone before and redone after). Every step is linear in the pixel, so per pixel they compose into
one 3 x 3 matrix

    M(y, x) = CCM · U(y, x) · diag(residual(y, x)) · CCM⁻¹

(``U`` the paper's unmixing, eq. for ``Unmixed``; ``Cx U`` in mode ``pure``). :func:`unmixing_field` computes it
once per stream size by putting three unit images through :func:`~picamcal.correct.correct_processed` itself,
so the live path and the file path cannot drift apart.

The frames are 8-bit and gamma encoded (the tuning file's ``rpi.contrast`` gamma curve), and the unmixing only
holds on linear values, so each pixel goes through a 256-entry table to linear float32, the matrix, and back to
the code that is the exact rounding of the curve (a 16384-entry table and one comparison: :func:`tone_curve_tables`).
Against ``correct_processed`` on the same frame, encoded with the exact inverse curve and rounded, the codes are
the same (``tests/test_live.py``: none differs); one could differ by a code only where the composed matrix's
float32 rounding (below 1e-6) puts a value across a code's edge. Applying the matrix to the encoded codes instead
is off by up to 169 codes on a target of saturated colours (docs/live.md).

picamera2's names for the RGB formats are libcamera's (DRM fourcc) names, which give the channels from the most
significant byte of a little-endian word: ``RGB888`` holds B, G, R in memory order, ``BGR888`` R, G, B,
``XBGR8888`` R, G, B, X and ``XRGB8888`` B, G, R, X (the Picamera2 manual, Appendix A). :data:`STREAM_FORMATS`
holds the byte offsets; the padding byte of the 32-bit formats is left as it is.

picamera2 is imported only inside :meth:`LiveUnmixer.callback`, when no other ``MappedArray`` is given.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from .calibration import Calibration
from .correct import correct_processed
from .errors import PicamcalError, PicamcalWarning, closest
from .export.isp import TuningError, processed_inputs
from .limits import max_pixels
from .modes import Mode
from .raw.processed import linearise

__all__ = [
    "ENCODE_TABLE_SIZE",
    "STREAM_FORMATS",
    "LiveStreamError",
    "LiveUnmixer",
    "StreamFormat",
    "ToneCurve",
    "stream_format",
    "tone_curve_tables",
    "unmixing_field",
]

#: Entries of the table from linear values (0..1) to a first guess of the 8-bit code: its step (0.2 code at the sRGB
#: curve's steepest, 0.08 at the Pi's stock gamma curve's) leaves the guess one code low for a few values in a
#: thousand, which one comparison corrects; and 16 KB stays in a core's L1 cache.
ENCODE_TABLE_SIZE = 1 << 14
#: Values of ``engine``.
ENGINES = ("auto", "numba", "numpy")
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
    picamcal.live.LiveStreamError: cannot unmix a stream of format YUV420: configure the stream as RGB888, BGR888, \
XBGR8888 or XRGB8888
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


def unmixing_field(
    calibration: Calibration,
    size: tuple[int, int],
    mode: str | Mode = Mode.CENTRE,
    *,
    tuning: Mapping[str, Any] | None = None,
    crop: tuple[int, int, int, int] | None = None,
    ct: float | None = None,
    colour_gains: tuple[float, float] | None = None,
) -> np.ndarray:
    """The per-pixel 3 x 3 matrix that takes a processed stream's linear RGB to the corrected one.

    ``M(y, x) = CCM · U(y, x) · diag(residual(y, x)) · CCM⁻¹``: what
    :func:`~picamcal.correct.correct_processed` does to an image of this size with
    :func:`~picamcal.export.isp.processed_inputs` from ``tuning`` (the tuning file the camera runs with: its
    lens shading, colour matrix and colour temperature); without a tuning, the unmixing alone (an ISP output
    that is already flat, and no colour matrix). Column ``c`` is ``correct_processed`` of a unit image of
    channel ``c``: it is linear in the image, so this is exact to float32 rounding.

    Parameters
    ----------
    calibration : Calibration
        A calibration with an unmixing (not a flat field alone).
    size : (width, height)
        The stream's size.
    mode : {"centre", "pure"} or Mode
    tuning : dict, optional
        The libcamera tuning file the camera runs with (:func:`picamcal.export.tuning.load_tuning`).
    crop : (x, y, width, height), optional
        The sensor area the stream shows, in sensor pixels (picamera2's ``ScalerCrop``); default the whole sensor.
    ct : float, optional
        Colour temperature of the tuning's tables; default the file's.
    colour_gains : (red, blue), optional
        The frozen white balance gains the camera applies (``ColourGains``); see ``processed_inputs``.

    Returns
    -------
    ndarray of float32, shape (height, width, 3, 3)

    Raises
    ------
    CalibrationFileError
        The calibration has no unmixing, or ``mode`` has none (``flat``, ``uncorrected``).

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> field = unmixing_field(cal, (160, 120))  # a half-size stream, already flat: U alone
    >>> field.shape, bool(np.allclose(field[60, 80], cal.unmixing[7, 10], atol=0.02))  # a bin at the centre
    ((120, 160, 3, 3), True)
    """
    calibration.require_unmixing("live unmixing")
    mode = calibration.check_mode(mode)
    if calibration.matrices(mode) is None:
        raise PicamcalError(f"mode {mode.value} has no unmixing to apply live: use centre or pure")
    width, height = _check_stream_size(size)
    shape = (height, width, 3)
    inputs: dict[str, Any] = {"crop": crop}
    if tuning is not None:
        # Only the image's size is read: a broadcast zero costs no memory.
        inputs = dict(
            processed_inputs(
                dict(tuning),
                calibration,
                np.broadcast_to(np.float32(0), shape),
                ct=ct,
                crop=crop,
                colour_gains=colour_gains,
            )
        )
    field = np.empty((height, width, 3, 3), dtype=np.float32)
    for channel in range(3):
        unit = np.zeros(shape, dtype=np.float32)
        unit[..., channel] = 1.0
        field[..., channel] = correct_processed(unit, calibration, mode, **inputs)
    return field


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


@functools.lru_cache(maxsize=2)
def _numba_unmix(parallel: bool) -> Callable[..., None]:
    """The numba kernel, compiled (or loaded from numba's cache) on first use: numba is imported only here."""
    import numba

    signature = (
        "void(uint8[:, :], int64, int64, int64, int64, int64, float32[:, :, ::1], float32[::1], uint8[::1], "
        "float32[::1])"
    )

    @numba.njit(nogil=True, cache=True)
    def encoded(value, encode, edges):
        top = encode.shape[0] - 1
        code = np.intp(encode[min(max(int(value * np.float32(top)), 0), top)])
        while value >= edges[code + 1]:
            code += 1
        return np.uint8(code)

    @numba.njit(signature, parallel=parallel, cache=True, nogil=True)
    def unmix(rows, width, step, red, green, blue, field, decode, encode, edges):
        for y in numba.prange(rows.shape[0]):
            for x in range(width):
                at = x * step
                r = decode[rows[y, at + red]]
                g = decode[rows[y, at + green]]
                b = decode[rows[y, at + blue]]
                m = field[y, x]
                out_r = m[0] * r + m[1] * g + m[2] * b
                out_g = m[3] * r + m[4] * g + m[5] * b
                out_b = m[6] * r + m[7] * g + m[8] * b
                rows[y, at + red] = encoded(out_r, encode, edges)
                rows[y, at + green] = encoded(out_g, encode, edges)
                rows[y, at + blue] = encoded(out_b, encode, edges)

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


class LiveUnmixer:
    """The calibration's unmixing for one stream size and format, applied in place to its frames.

    Make one with :meth:`prepare` (the work, once per stream); then :meth:`apply` to a frame array, or set
    :meth:`callback` as picamera2's ``pre_callback`` so that every frame is unmixed before it is shown or encoded.

    Attributes
    ----------
    size : (width, height)
    format : StreamFormat
    field : ndarray of float32, shape (height, width, 9)
        The per-pixel matrices (:func:`unmixing_field`, row-major), 36 bytes a pixel.
    curve : ToneCurve
        The tone curve's tables (:func:`tone_curve_tables`).
    engine : {"numba", "numpy"}
    parallel : bool
        Whether the numba kernel shares the rows among numba's threads.
    stream : str
        The picamera2 stream the callback unmixes.
    """

    def __init__(
        self,
        size: tuple[int, int],
        format: StreamFormat,
        field: np.ndarray,
        curve: ToneCurve,
        engine: str,
        stream: str = "main",
        mapped_array: Callable[[Any, str], Any] | None = None,
        *,
        parallel: bool = False,
    ) -> None:
        self.size = size
        self.format = format
        self.field = field
        self.curve = curve
        self.engine = engine
        self.parallel = parallel
        self.stream = stream
        self._mapped_array = mapped_array
        self._config_checked = False
        #: What stopped :meth:`callback` (None while it unmixes): a stream that does not match, or a failure.
        self.error: LiveStreamError | None = None

    @classmethod
    def prepare(
        cls,
        calibration: Calibration,
        size: tuple[int, int],
        format: str = "XBGR8888",
        *,
        tuning: Mapping[str, Any] | None = None,
        mode: str | Mode = Mode.CENTRE,
        crop: tuple[int, int, int, int] | None = None,
        ct: float | None = None,
        colour_gains: tuple[float, float] | None = None,
        encoding: str | None = None,
        engine: str = "auto",
        parallel: bool = False,
        stream: str = "main",
        mapped_array: Callable[[Any, str], Any] | None = None,
    ) -> LiveUnmixer:
        """Check everything about the stream and precompute its field and tables (2 to 6 s for an 8 MP sensor).

        Parameters
        ----------
        calibration : Calibration
            With an unmixing.
        size : (width, height)
            The stream's size (picamera2's ``config["main"]["size"]``).
        format : str
            picamera2's format name: ``XBGR8888`` (the default, as picamera2's preview and video configurations),
            ``XRGB8888``, ``RGB888`` or ``BGR888``.
        tuning : dict, optional
            The tuning file the camera runs with, the exported lens shading table in it
            (:func:`picamcal.export.tuning.load_tuning`); without one the stream is taken as flat already, with no
            colour matrix, and sRGB encoded unless ``encoding`` says otherwise. Its ``rpi.contrast`` should have
            ``ce_enable`` 0: adaptive contrast bends the tone curve frame by frame (a warning says so).
        mode : {"centre", "pure"}
        crop : (x, y, width, height), optional
            The sensor area the stream shows (picamera2's ``ScalerCrop``); default the whole sensor.
        ct : float, optional
            Colour temperature of the tuning's tables.
        colour_gains : (red, blue), optional
            The camera's frozen ``ColourGains`` (see :func:`~picamcal.export.isp.processed_inputs`).
        encoding : str, optional
            The tone curve (:func:`tone_curve_tables`); default the tuning's gamma curve, else ``srgb``.
        engine : {"auto", "numba", "numpy"}
            ``auto`` is numba when it is installed, else numpy.
        parallel : bool
            With numba, share each frame's rows among numba's threads (``NUMBA_NUM_THREADS``, every core by
            default). Off by default: one core keeps up at preview sizes (benchmarks/bench_live.py), leaves the
            others to the preview and encoder, and a frame never waits for a busy core; turn it on for large
            streams on a Pi whose other cores are idle.
        stream : str
            The stream :meth:`callback` unmixes.
        mapped_array : callable, optional
            What :meth:`callback` maps a request's buffer with; default ``picamera2.MappedArray``.

        Raises
        ------
        LiveStreamError
            An unknown format, or a size that is not a positive number of pixels within the limit.
        CalibrationFileError
            A calibration without an unmixing (a flat field alone).
        PicamcalError
            A crop outside the sensor or of another aspect ratio than the stream; a bad tuning file.

        Examples
        --------
        >>> from picamcal.simulate import make_camera, simulate_references
        >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
        >>> unmixer = LiveUnmixer.prepare(cal, size=(160, 120), format="XBGR8888", engine="numpy")
        >>> frame = np.full((120, 160, 4), 128, np.uint8)  # what MappedArray(request, "main").array gives
        >>> unmixer.apply(frame) is frame, frame.shape
        (True, (120, 160, 4))
        """
        fmt = stream_format(format)
        width, height = _check_stream_size(size)
        if engine not in ENGINES:
            raise ValueError(f"unknown engine {engine!r}: choose one of {', '.join(ENGINES)}")
        if engine == "auto":
            from .kernels import numba_available

            engine = "numba" if numba_available() else "numpy"
        if tuning is not None and encoding is None and _contrast_enhancement_on(tuning):
            import warnings

            warnings.warn(
                "the tuning's rpi.contrast has adaptive contrast enhancement on (ce_enable): it bends the tone curve "
                "frame by frame, so the frames cannot be linearised exactly; set ce_enable to 0",
                PicamcalWarning,
                stacklevel=2,
            )
        field = unmixing_field(
            calibration, (width, height), mode, tuning=tuning, crop=crop, ct=ct, colour_gains=colour_gains
        )
        curve = tone_curve_tables(encoding, tuning)
        unmixer = cls(
            (width, height),
            fmt,
            field.reshape(height, width, 9),
            curve,
            engine,
            stream,
            mapped_array,
            parallel=parallel,
        )
        if engine == "numba":
            _numba_unmix(parallel)  # compiled (or loaded from numba's cache) now, not on the first frame
        return unmixer

    def _describe(self) -> str:
        return f"{self.size[0]}x{self.size[1]} {self.format.name}"

    def check_config(self, config: Mapping[str, Any]) -> None:
        """Raise unless a picamera2 stream configuration is the prepared size and format.

        ``config`` is the stream's (``picam2.camera_config["main"]``, or a request's ``config["main"]``) or the
        whole camera configuration, from which :attr:`stream` is taken. Call it after ``configure`` and before
        ``start``; :meth:`callback` also calls it on the first frame.

        Raises
        ------
        LiveStreamError
            One line naming the stream's size and format and the prepared ones.

        Examples
        --------
        >>> field = np.zeros((480, 640, 9), np.float32)
        >>> unmixer = LiveUnmixer((640, 480), STREAM_FORMATS["RGB888"], field, tone_curve_tables("srgb"), "numpy")
        >>> unmixer.check_config({"main": {"format": "RGB888", "size": (640, 480)}})
        >>> unmixer.check_config({"format": "XBGR8888", "size": (1332, 990)})
        Traceback (most recent call last):
        ...
        picamcal.live.LiveStreamError: the main stream is 1332x990 XBGR8888, but the unmixer was prepared for \
640x480 RGB888: prepare it with size=(1332, 990), format="XBGR8888"
        """
        if self.stream in config and isinstance(config[self.stream], Mapping):
            config = config[self.stream]
        if "format" not in config or "size" not in config:
            raise LiveStreamError(f"not a picamera2 stream configuration (no format and size): {sorted(config)}")
        name = str(config["format"])
        try:
            width, height = (int(v) for v in config["size"])
        except (TypeError, ValueError):
            raise LiveStreamError(
                f"the {self.stream} stream's size {config['size']!r} is not (width, height)"
            ) from None
        if name.upper() != self.format.name or (width, height) != self.size:
            raise LiveStreamError(
                f"the {self.stream} stream is {width}x{height} {name}, but the unmixer was prepared for "
                f'{self._describe()}: prepare it with size=({width}, {height}), format="{name}"'
            )

    def _rows(self, frame: np.ndarray) -> np.ndarray:
        """The frame as (height, width * bytes per pixel) rows on the same memory, after checking it."""
        width, height = self.size
        step = self.format.bytes_per_pixel
        if not isinstance(frame, np.ndarray) or frame.dtype != np.uint8 or frame.shape != (height, width, step):
            shape = getattr(frame, "shape", None)
            dtype = getattr(frame, "dtype", type(frame).__name__)
            raise LiveStreamError(
                f"a frame of shape {shape} ({dtype}) is not a {self._describe()} frame, shape {(height, width, step)} "
                "uint8: prepare an unmixer for this stream's size and format"
            )
        if frame.strides[1:] != (step, 1) or frame.strides[0] < width * step:
            raise LiveStreamError(
                f"the {self._describe()} frame's pixels are not packed in rows (strides {frame.strides}): "
                "give the stream's own buffer, as MappedArray maps it"
            )
        if not frame.flags.writeable:
            raise LiveStreamError("the frame is read-only: map the request with MappedArray(request, stream) to write")
        return np.lib.stride_tricks.as_strided(frame, (height, width * step), (frame.strides[0], 1))

    def apply(self, frame: np.ndarray) -> np.ndarray:
        """Unmix one frame in place and return it.

        Parameters
        ----------
        frame : ndarray of uint8, shape (height, width, 3 or 4)
            The stream's pixels in its format's byte order (``MappedArray(request, "main").array``); rows may be
            padded (a row stride above the width's bytes).

        Raises
        ------
        LiveStreamError
            Not the prepared size and format (the prepared ones named), or not a writeable packed frame.

        Examples
        --------
        See :meth:`prepare`.
        """
        rows = self._rows(frame)
        fmt = self.format
        if self.engine == "numba":
            _numba_unmix(self.parallel)(
                rows,
                self.size[0],
                fmt.bytes_per_pixel,
                fmt.red,
                fmt.green,
                fmt.blue,
                self.field,
                *self.curve,
            )
        else:
            _unmix_numpy(frame, fmt, self.field, self.curve)
        return frame

    def callback(self, request: Any) -> None:
        """Unmix a picamera2 request's :attr:`stream` in place: ``picam2.pre_callback = unmixer.callback``.

        The first request's stream configuration is checked (:meth:`check_config`); then each frame is mapped
        (``picamera2.MappedArray(request, stream)``, or the ``mapped_array`` given to :meth:`prepare`) and
        :meth:`apply` ed. ``examples/live_preview.py`` shows it on a Pi.

        It never raises: picamera2 calls it in the thread that runs its camera, where an exception would stop the
        camera or the preview's Qt. A stream that does not match (or any failure) is kept in :attr:`error`, logged
        once (``picamcal.live``, one line) and the frames pass through unchanged from then on. Call
        :meth:`check_config` with ``picam2.camera_config`` before setting the callback to get that error at
        start-up instead.
        """
        if self.error is not None:
            return
        try:
            if not self._config_checked:
                self.check_config(request.config[self.stream])
                self._config_checked = True
            mapped = self._mapped_array
            if mapped is None:
                from picamera2 import MappedArray

                mapped = MappedArray
            with mapped(request, self.stream) as buffer:
                self.apply(buffer.array)
        except Exception as exc:  # in picamera2's thread: kept for the caller, never raised there
            self.error = exc if isinstance(exc, LiveStreamError) else LiveStreamError(f"unmixing failed ({exc!r})")
            logging.getLogger(__name__).error("%s; the frames pass through unmixed", self.error)
