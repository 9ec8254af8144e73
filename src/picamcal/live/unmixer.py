"""The live unmixer: the per-pixel matrix field of a stream (:func:`unmixing_field`) and :class:`LiveUnmixer`, which
applies it in place to picamera2's frames and follows the stream's ScalerCrop. :mod:`picamcal.live` re-exports
both.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..calibration import Calibration
from ..correct import correct_processed
from ..errors import PicamcalError, PicamcalWarning
from ..export.isp import processed_geometry, processed_inputs
from ..geometry import Box, SensorMode, default_scaler_crop
from ..modes import Mode
from .camera import _settled_metadata, _stream_scaler_crop, _tuning_in_force, camera_sensor_mode
from .stream import (
    LiveStreamError,
    StreamFormat,
    ToneCurve,
    _check_stream_size,
    _contrast_enhancement_on,
    _numba_unmix,
    _one_step,
    _unmix_numpy,
    stream_format,
    tone_curve_tables,
)

#: Values of ``engine``.
ENGINES = ("auto", "numba", "numpy")
#: Fields a following unmixer keeps, one per ScalerCrop (36 bytes a pixel each).
_FIELDS_KEPT = 4


def unmixing_field(
    calibration: Calibration,
    size: tuple[int, int],
    mode: str | Mode = Mode.CENTRE,
    *,
    tuning: Mapping[str, Any] | None = None,
    crop: Box | None = None,
    sensor_mode: SensorMode | None = None,
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
        The sensor area the stream shows, in full-sensor pixels (picamera2's ``ScalerCrop`` metadata). Default:
        libcamera's default for a stream of this size from ``sensor_mode`` if one is given
        (:func:`~picamcal.geometry.default_scaler_crop`), else the calibration's whole area.
    sensor_mode : SensorMode, optional
        The camera's sensor mode (:func:`camera_sensor_mode`): its lens shading tables are computed for it and the
        stream is mapped through it onto the calibration's sensor area. Default: the calibration's own mode.
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
        The calibration has no unmixing, or ``mode`` has none (``flat``, ``uncorrected``); the stream shows a sensor
        area outside the calibration's (one line saying what covers it).
    PicamcalError
        A crop outside the sensor or the mode's crop, or of another aspect ratio than the stream.

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
    # Only the image's size is read: a broadcast zero costs no memory.
    image = np.broadcast_to(np.float32(0), shape)
    sensor_mode, crop = processed_geometry(calibration, image, crop=crop, sensor_mode=sensor_mode)
    inputs: dict[str, Any] = {"crop": crop, "sensor_mode": sensor_mode}
    if tuning is not None:
        inputs = dict(
            processed_inputs(
                dict(tuning), calibration, image, ct=ct, crop=crop, sensor_mode=sensor_mode, colour_gains=colour_gains
            )
        )
    field = np.empty((height, width, 3, 3), dtype=np.float32)
    for channel in range(3):
        unit = np.zeros(shape, dtype=np.float32)
        unit[..., channel] = 1.0
        field[..., channel] = correct_processed(unit, calibration, mode, **inputs)
    return field


def _named(error: PicamcalError, stream: str) -> PicamcalError:
    """The error about the stand-in image of a stream, said of the stream (another file's error as it is)."""
    if error.path != "<image>":
        return error
    return type(error)(error.problem, stream)


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
    crop : (x, y, width, height) or None
        The sensor area (ScalerCrop, full-sensor pixels) the field is for; None for an unmixer made directly.
    sensor_mode : SensorMode or None
        The camera's sensor mode the field is for.
    follow_scaler_crop : bool
        Whether :meth:`callback` re-prepares the field when a request's ``ScalerCrop`` differs from :attr:`crop`.
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
        self.crop: Box | None = None
        self.sensor_mode: SensorMode | None = None
        self.follow_scaler_crop = False
        #: The curve whose :func:`_one_step` was taken, and what it said (the kernel it picks).
        self._one_step: tuple[ToneCurve, bool] | None = None
        #: Makes the field (height, width, 9) for another ScalerCrop (set by :meth:`prepare`).
        self._field_for: Callable[[Box], np.ndarray] | None = None
        self._fields: dict[Box, np.ndarray] = {}

    @classmethod
    def prepare(
        cls,
        calibration: Calibration,
        size: tuple[int, int],
        format: str = "XBGR8888",
        *,
        tuning: Mapping[str, Any] | None = None,
        mode: str | Mode = Mode.CENTRE,
        crop: Box | None = None,
        sensor_mode: SensorMode | None = None,
        ct: float | None = None,
        colour_gains: tuple[float, float] | None = None,
        encoding: str | None = None,
        engine: str = "auto",
        parallel: bool = False,
        stream: str = "main",
        mapped_array: Callable[[Any, str], Any] | None = None,
        follow_scaler_crop: bool = False,
    ) -> LiveUnmixer:
        """Check everything about the stream and precompute its field and tables (0.6 s at 640 x 480, 2.6 s at
        1640 x 1232: three passes of :func:`~picamcal.correct.correct_processed` at the stream's size).

        :meth:`for_camera` does this from a running camera, with everything read from it.

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
            The sensor area the stream shows, in full-sensor pixels (picamera2's ``ScalerCrop`` metadata). Default:
            libcamera's default for the stream from ``sensor_mode`` if one is given, else the calibration's whole
            area (see :func:`unmixing_field`).
        sensor_mode : SensorMode, optional
            The camera's sensor mode (:func:`camera_sensor_mode`); default the calibration's own.
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
        follow_scaler_crop : bool
            Have :meth:`callback` follow the requests' ``ScalerCrop`` (digital zoom): a field for each new crop,
            made in the camera's thread on the first frame that shows it and kept for the next time (the last
            four). :meth:`for_camera` turns it on.

        Raises
        ------
        LiveStreamError
            An unknown format, or a size that is not a positive number of pixels within the limit.
        CalibrationFileError
            A calibration without an unmixing (a flat field alone); a stream that shows a sensor area outside the
            calibration's.
        PicamcalError
            A crop outside the sensor or the mode's crop, or of another aspect ratio than the stream; a bad tuning
            file.

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
            from ..kernels import numba_available

            engine = "numba" if numba_available() else "numpy"
        if tuning is not None and encoding is None and _contrast_enhancement_on(tuning):
            import warnings

            warnings.warn(
                "the tuning's rpi.contrast has adaptive contrast enhancement on (ce_enable): it bends the tone curve "
                "frame by frame, so the frames cannot be linearised exactly; set ce_enable to 0",
                PicamcalWarning,
                stacklevel=2,
            )
        stand_in = np.broadcast_to(np.float32(0), (height, width, 3))
        named = f"the {stream} stream ({width}x{height})"
        try:
            sensor_mode, crop = processed_geometry(calibration, stand_in, crop=crop, sensor_mode=sensor_mode)
        except PicamcalError as exc:
            raise _named(exc, named) from None
        chosen_mode = sensor_mode

        def field_for(area: Box) -> np.ndarray:
            try:
                field = unmixing_field(
                    calibration,
                    (width, height),
                    mode,
                    tuning=tuning,
                    crop=area,
                    sensor_mode=chosen_mode,
                    ct=ct,
                    colour_gains=colour_gains,
                )
            except PicamcalError as exc:
                raise _named(exc, named) from None
            return field.reshape(height, width, 9)

        curve = tone_curve_tables(encoding, tuning)
        unmixer = cls((width, height), fmt, field_for(crop), curve, engine, stream, mapped_array, parallel=parallel)
        unmixer.crop, unmixer.sensor_mode, unmixer.follow_scaler_crop = crop, sensor_mode, follow_scaler_crop
        unmixer._field_for = field_for
        unmixer._fields[crop] = unmixer.field
        if engine == "numba":
            _numba_unmix(parallel, unmixer._settled_in_one_step())  # compiled (or loaded from numba's cache) now
        return unmixer

    @classmethod
    def for_camera(
        cls,
        picam2: Any,
        calibration: Calibration,
        *,
        tuning: Mapping[str, Any] | None = None,
        mode: str | Mode = Mode.CENTRE,
        stream: str = "main",
        ct: float | None = None,
        colour_gains: tuple[float, float] | None = None,
        encoding: str | None = None,
        engine: str = "auto",
        parallel: bool = False,
        mapped_array: Callable[[Any, str], Any] | None = None,
    ) -> LiveUnmixer:
        """Prepare the unmixer for a running picamera2 camera's stream, from what the camera says, and have it follow
        the stream's ScalerCrop (digital zoom) from then on.

        Read from the camera: its sensor mode (:func:`camera_sensor_mode`: the configured mode's size, bit depth,
        crop and flips), the stream's size and format, and, from one request's metadata, the ScalerCrop the stream
        shows, the colour gains and the colour temperature in force (from the first frame whose metadata agrees with
        the one before: the first frames after ``start`` report the IPA's defaults). The stream is mapped through the
        mode onto the calibration's sensor area, and the ISP's lens shading is computed for the mode and sampled at the
        ScalerCrop (:func:`~picamcal.export.isp.isp_gains_for_image`), as libcamera and the ISP do. Then
        :meth:`callback` re-prepares the field when a request's ``ScalerCrop`` changes (``follow_scaler_crop``).

        Call it after ``picam2.start()``, with the white balance frozen (``AwbEnable`` off, ``ColourGains`` set):
        the gains are read once.

        Parameters
        ----------
        picam2 : picamera2.Picamera2
            The camera, configured and started.
        calibration : Calibration
            With an unmixing, covering the stream's sensor area.
        tuning : dict, optional
            The tuning file the camera runs with. Default: the file ``LIBCAMERA_RPI_TUNING_FILE`` names (picamera2
            sets it to the ``tuning`` it was opened with), else the sensor's stock file for this Pi, which libcamera
            loads when none is named.
        mode : {"centre", "pure"}
        stream : str
            The stream to unmix (``"main"``; ``"lores"`` takes the second of the Pi 5's ``ScalerCrops``).
        ct, colour_gains : optional
            Override the request's ``ColourTemperature`` and ``ColourGains``.
        encoding, engine, parallel, mapped_array
            As :meth:`prepare`.

        Raises
        ------
        LiveStreamError
            No such stream, or one that cannot be unmixed (a YUV format).
        CalibrationFileError
            The stream shows a sensor area outside the calibration's (one line saying what covers it), or the
            calibration has no unmixing.
        PicamcalError
            The tuning file the camera was opened with is gone (picamera2 deletes the file of a tuning it was given as
            a dict: give it as ``tuning``); no stock tuning for the sensor.

        Examples
        --------
        On picamcal's virtual camera (:func:`picamcal.virtualcam.install`, in a Python of its own), a 16:9 stream of
        the 2 x 2 binned mode of a small IMX219, with a calibration from the same optics:

        >>> import subprocess, sys
        >>> from pathlib import Path
        >>> _ = Path("live.py").write_text('''
        ... from picamcal.virtualcam import install
        ... install(sensor="imx219", size=(320, 240))
        ...
        ... from picamera2 import Picamera2
        ... import picamcal
        ... from picamcal.live import LiveUnmixer
        ... from picamcal.simulate import make_camera, simulate_references
        ...
        ... cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
        ... with Picamera2() as picam2:
        ...     config = {"size": (160, 90), "format": "RGB888"}
        ...     picam2.configure(picam2.create_preview_configuration(main=config, raw={"size": (160, 120)}))
        ...     picam2.start()
        ...     unmixer = LiveUnmixer.for_camera(picam2, cal, engine="numpy")
        ...     print(unmixer.sensor_mode.binning, unmixer.crop)
        ... ''')
        >>> print(subprocess.run([sys.executable, "live.py"], capture_output=True, text=True).stdout, end="")
        2 (0, 30, 320, 180)
        """
        config = picam2.camera_configuration()
        if not isinstance(config.get(stream), Mapping):
            raise LiveStreamError(f"the camera has no {stream} stream configured: configure one to unmix")
        sensor_mode = camera_sensor_mode(picam2)
        metadata = _settled_metadata(picam2)
        width, height = (int(v) for v in config[stream]["size"])
        crop = _stream_scaler_crop(metadata, stream) or default_scaler_crop(sensor_mode, (width, height))
        if colour_gains is None and metadata.get("ColourGains"):
            red, blue = metadata["ColourGains"]
            colour_gains = (float(red), float(blue))
        if ct is None and metadata.get("ColourTemperature"):
            ct = float(metadata["ColourTemperature"])
        unmixer = cls.prepare(
            calibration,
            (width, height),
            str(config[stream]["format"]),
            tuning=_tuning_in_force(picam2) if tuning is None else tuning,
            mode=mode,
            crop=crop,
            sensor_mode=sensor_mode,
            ct=ct,
            colour_gains=colour_gains,
            encoding=encoding,
            engine=engine,
            parallel=parallel,
            stream=stream,
            mapped_array=mapped_array,
            follow_scaler_crop=True,
        )
        unmixer.check_config(config)
        return unmixer

    def _settled_in_one_step(self) -> bool:
        """Whether one comparison settles each code of :attr:`curve` (:func:`_one_step`, worked out once a curve)."""
        if self._one_step is None or self._one_step[0] is not self.curve:
            self._one_step = (self.curve, _one_step(self.curve))
        return self._one_step[1]

    def _describe(self) -> str:
        return f"{self.size[0]}x{self.size[1]} {self.format.name}"

    def _follow(self, request: Any) -> None:
        """Take the field of the request's ScalerCrop (made now, or kept from before) if it is not this one."""
        crop = _stream_scaler_crop(request.get_metadata(), self.stream)
        if crop is None or crop == self.crop:
            return
        field = self._fields.get(crop)
        if field is None:
            if self._field_for is None:
                raise LiveStreamError(f"the ScalerCrop changed to {crop}, and the unmixer cannot make its field")
            try:
                field = self._field_for(crop)
            except PicamcalError as exc:
                x, y, w, h = crop
                raise LiveStreamError(
                    f"the {self.stream} stream's ScalerCrop changed to {x},{y},{w},{h}: {exc.problem}"
                ) from None
            while len(self._fields) >= _FIELDS_KEPT:
                del self._fields[next(iter(self._fields))]
            self._fields[crop] = field
        self.field, self.crop = field, crop

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
        >>> from picamcal.live import STREAM_FORMATS
        >>> field = np.zeros((480, 640, 9), np.float32)
        >>> unmixer = LiveUnmixer((640, 480), STREAM_FORMATS["RGB888"], field, tone_curve_tables("srgb"), "numpy")
        >>> unmixer.check_config({"main": {"format": "RGB888", "size": (640, 480)}})
        >>> unmixer.check_config({"format": "XBGR8888", "size": (1332, 990)})
        Traceback (most recent call last):
        ...
        picamcal.live.stream.LiveStreamError: the main stream is 1332x990 XBGR8888, but the unmixer was \
prepared for 640x480 RGB888: prepare it with size=(1332, 990), format="XBGR8888"
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
            _numba_unmix(self.parallel, self._settled_in_one_step())(
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

        The first request's stream configuration is checked (:meth:`check_config`); with
        :attr:`follow_scaler_crop`, a request whose ``ScalerCrop`` metadata differs from :attr:`crop` gets that
        crop's field (made once, in this thread, then kept); then each frame is mapped
        (``picamera2.MappedArray(request, stream)``, or the ``mapped_array`` given to :meth:`prepare`) and
        :meth:`apply` ed. ``examples/live_preview.py`` shows it on a Pi.

        It never raises: picamera2 calls it in the thread that runs its camera, where an exception would stop the
        camera or the preview's Qt. A stream that does not match, a ScalerCrop outside the calibration's area (or
        any failure) is kept in :attr:`error`, logged once (``picamcal.live``, one line) and the frames pass through
        unchanged from then on. Call
        :meth:`check_config` with ``picam2.camera_config`` before setting the callback to get that error at
        start-up instead.
        """
        if self.error is not None:
            return
        try:
            if not self._config_checked:
                self.check_config(request.config[self.stream])
                self._config_checked = True
            if self.follow_scaler_crop:
                self._follow(request)
            mapped = self._mapped_array
            if mapped is None:
                from picamera2 import MappedArray

                mapped = MappedArray
            with mapped(request, self.stream) as buffer:
                self.apply(buffer.array)
        except Exception as exc:  # in picamera2's thread: kept for the caller, never raised there
            if isinstance(exc, LiveStreamError):
                self.error = exc
            elif isinstance(exc, PicamcalError):
                self.error = LiveStreamError(str(exc))
            else:
                self.error = LiveStreamError(f"unmixing failed ({exc!r})")
            logging.getLogger(__name__).error("%s; the frames pass through unmixed", self.error)
