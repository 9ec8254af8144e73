"""The virtual camera as libcamera's Python bindings present a camera: ``CameraManager``, ``Camera``, ``Request``.

Behaviour follows the bindings (``src/py/libcamera/py_main.cpp``, ``py_camera_manager.cpp``) and libcamera
(``src/libcamera/camera.cpp``, ``request.cpp``, the Raspberry Pi pipeline handler):

- ``CameraManager.singleton()`` gives the manager while something holds it, else makes a new one, which registers
  the cameras and loads each camera's tuning file then (``pipeline_base.cpp`` ``registerCamera``); completed
  requests are collected from any thread and announced on ``event_fd`` (an eventfd), and
  ``get_ready_requests()`` hands them over;
- a camera goes Available, Acquired, Configured, Running, and refuses calls out of turn as libcamera does (the
  bindings raise ``RuntimeError`` with the ``strerror`` of the C++ error code);
- while running, the sensor delivers frames at the mode's frame duration; a frame that finds a queued request
  fills its buffers (raw and processed) and metadata and completes it; one that finds none is dropped; ``stop()``
  completes every pending request as cancelled before it returns.

Examples
--------
>>> from picamcal.virtualcam.options import Options
>>> manager = CameraManager(Options(sensor="imx219", size=(320, 240)), environ={})
>>> camera = manager.cameras[0]
>>> str(camera), camera.properties[PROPERTIES["Model"]]
("<libcamera.Camera '/base/axi/pcie@120000/rp1/i2c@88000/imx219@10'>", 'imx219')
"""

from __future__ import annotations

import errno
import os
import threading
import time
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry import SensorMode
from .buffers import FrameMetadataStatus
from .config import (
    CameraConfiguration,
    ConfigurationStatus,
    Stream,
    StreamRole,
    generate,
)
from .controls import (
    CONTROLS,
    PROPERTIES,
    ControlId,
    ControlInfo,
    as_float32,
    control_value,
    metadata_value,
    stored,
)
from .frames import Scene, VirtualSensor
from .ipa import Ipa, IpaError, load_camera_tuning
from .isp import Isp, Layout, OutputPlan, encode_raw, sample_indices
from .modes import SensorSpec, scaled_spec, sensor_spec
from .options import Options, VirtualCameraError
from .request import Request, RequestStatus, fail, log
from .timing import stage
from .values import Orientation, Point, Rectangle, Size, orientation_bits

#: What ``CameraManager.version`` says.
VERSION = "v0.7.1+picamcal-virtual"
#: Seconds a started camera goes without a request of its own before it warns that the application holds them all.
STARVED_S = 5.0
# Where each platform's device tree puts the camera's I2C bus (the camera ids of Raspberry Pi OS).
_CAMERA_PATHS = {"vc4": "/base/soc/i2c0mux/i2c@1", "pisp": "/base/axi/pcie@120000/rp1/i2c@88000"}
_I2C_ADDRESSES = {"imx477": "1a", "imx219": "10", "imx708": "1a", "ov5647": "36", "imx296": "1a", "imx500": "1a"}
# The drivers' active area origins (V4L2_SEL_TGT_CROP_DEFAULT: imx477.c, imx219.c, imx708.c, ov5647.c).
_ACTIVE_ORIGINS = {"imx477": (8, 16), "imx219": (8, 8), "imx708": (16, 24), "ov5647": (16, 6)}


class Camera:
    """One camera of the manager (the bindings' ``Camera``)."""

    def __init__(self, data: CameraData, manager: CameraManager) -> None:
        self._data = data
        self._manager = manager  # a camera keeps its manager alive (py_camera_manager.cpp keep_alive)

    @property
    def id(self) -> str:
        return self._data.id

    @property
    def _control_infos(self) -> dict[ControlId, ControlInfo]:
        return self._data.control_infos

    def _active_streams(self) -> list[Stream]:
        return self._data.active_streams

    @property
    def properties(self) -> dict[ControlId, Any]:
        return {PROPERTIES[name]: metadata_value(value) for name, value in self._data.properties.items()}

    @property
    def controls(self) -> dict[ControlId, ControlInfo]:
        return dict(self._data.control_infos)

    @property
    def streams(self) -> set[Stream]:
        return set(self._data.streams)

    def acquire(self) -> None:
        self._data.acquire()

    def release(self) -> None:
        self._data.release()

    def generate_configuration(self, roles: list[StreamRole]) -> CameraConfiguration:
        return generate(self._data, list(roles))

    def configure(self, config: CameraConfiguration) -> None:
        self._data.configure(config)

    def create_request(self, cookie: int = 0) -> Request:
        if self._data.state not in ("configured", "running"):
            raise fail("Failed to create request", errno.ENOMEM)
        return Request(self._data, cookie)

    def queue_request(self, request: Request) -> None:
        self._data.queue(request)

    def start(self, controls: dict[ControlId, Any] | None = None) -> None:
        values = {control.name: control_value(control, value) for control, value in (controls or {}).items()}
        self._data.start(values)

    def stop(self) -> None:
        self._data.stop()

    def __str__(self) -> str:
        return f"<libcamera.Camera '{self.id}'>"


class CameraData:
    """The pipeline behind one camera: its sensor, IPA and ISP, its state, and the thread that runs it."""

    def __init__(self, options: Options, spec: SensorSpec, ipa: Ipa, manager: CameraManager) -> None:
        self.options, self.spec, self.ipa = options, spec, ipa
        self.platform = options.platform
        self.manager_ref = weakref.ref(manager)
        address = _I2C_ADDRESSES.get(spec.name, "1a")
        self.id = f"{_CAMERA_PATHS[self.platform]}/{spec.name}@{address}"
        self.sensor = VirtualSensor(spec, Scene(options.scene), options.seed, options.brightness)
        rotation = {0: Orientation.Rotate0, 180: Orientation.Rotate180}.get(spec.rotation, Orientation.Rotate0)
        self.mounting_bits = orientation_bits(rotation)
        raw_name = "CFE Output0" if self.platform == "pisp" else "Unicam Image"
        self.streams = [Stream(raw_name), Stream("ISP Output0"), Stream("ISP Output1")]
        self.state = "available"
        self.lock = threading.Condition()
        self.queue_: list[Request] = []
        self.threads: list[threading.Thread] = []
        #: Requests the sensor has taken, oldest first, and the frames handed to the ISP stage (same order).
        self.in_flight: list[Request] = []
        self.developing: list[_Frame] = []
        self.stopping = False
        self.active_streams: list[Stream] = []
        self.configured: CameraConfiguration | None = None
        self.properties = self._properties()
        self.control_infos = self._ipa_controls()
        self.plans: list[tuple[Stream, Any]] = []
        self.isp: Isp | None = None
        self.crops: list[Rectangle] = []

    # -- registration -------------------------------------------------------------------------------------------
    def _properties(self) -> dict[str, Any]:
        spec = self.spec
        origin = _ACTIVE_ORIGINS.get(spec.name, (0, 0)) if not self.options.size else (0, 0)
        cell = spec.unit_cell_nm
        return {
            "Location": 2,
            "Rotation": spec.rotation,
            "Model": spec.name,
            "UnitCellSize": Size(cell, cell),
            "PixelArraySize": Size(spec.width, spec.height),
            "PixelArrayActiveAreas": (Rectangle(origin[0], origin[1], spec.width, spec.height),),
            "ScalerCropMaximum": Rectangle(),
            "ColorFilterArrangement": "RGGB GRBG GBRG BGGR".split().index(spec.native_order),
            "SystemDevices": (20754, 20753, 20752, 20755) if self.platform == "pisp" else (20749, 20737, 20738),
            "PipelineHandler": f"rpi/{self.platform}",
        }

    def _ipa_controls(self, platform_controls: bool = True) -> dict[ControlId, ControlInfo]:
        """The controls the Raspberry Pi IPA handles (``ipa_base.cpp`` ``ipaControls``, the colour ones, and at
        ``init`` only the platform's), with the ranges it gives before a mode is chosen."""
        rect_max = Rectangle(65535, 65535, 65535, 65535)
        infos = {
            "AeEnable": ControlInfo(False, True, True),
            "ExposureTimeMode": ControlInfo.of_values([0, 1], 0),
            "ExposureTime": ControlInfo(1, 66666, 20000),
            "AnalogueGainMode": ControlInfo.of_values([0, 1], 0),
            "AnalogueGain": ControlInfo(1.0, 16.0, 1.0),
            "AeMeteringMode": ControlInfo.of_values([0, 1, 2, 3]),
            "AeConstraintMode": ControlInfo.of_values([0, 1, 2, 3]),
            "AeExposureMode": ControlInfo.of_values([0, 1, 2, 3]),
            "ExposureValue": ControlInfo(-8.0, 8.0, 0.0),
            "AeFlickerMode": ControlInfo.of_values([0, 1], 0),
            "AeFlickerPeriod": ControlInfo(100, 1000000),
            "Brightness": ControlInfo(-1.0, 1.0, 0.0),
            "Contrast": ControlInfo(0.0, 32.0, 1.0),
            "HdrMode": ControlInfo.of_values([0, 1, 2, 3, 4]),
            "Sharpness": ControlInfo(0.0, 16.0, 1.0),
            "ScalerCrop": ControlInfo(Rectangle(), rect_max, Rectangle()),
            "FrameDurationLimits": ControlInfo(33333, 250000000, (33333, 33333)),
            "NoiseReductionMode": ControlInfo.of_values([0, 1, 2, 3, 4]),
            "StatsOutputEnable": ControlInfo(False, True, False),
            "CnnEnableInputTensor": ControlInfo(False, True, False),
            "SyncMode": ControlInfo.of_values([0, 2], 0),
            "SyncFrames": ControlInfo(100, 100000, 1000),
            "AwbEnable": ControlInfo(False, True),
            "AwbMode": ControlInfo.of_values(list(range(8))),
            "ColourGains": ControlInfo(0.0, 32.0),
            "ColourCorrectionMatrix": ControlInfo(0.0, 8.0),
            "ColourTemperature": ControlInfo(100, 100000),
            "Saturation": ControlInfo(0.0, 32.0, 1.0),
        }
        if self.platform == "pisp" and platform_controls:
            infos["ScalerCrops"] = ControlInfo(Rectangle(), rect_max, Rectangle())
        return {CONTROLS[name]: info for name, info in infos.items()}

    def order_for(self, transform_bits: int) -> str:
        """The Bayer order of frames read with the sensor transform ``transform_bits`` (flips)."""
        return self.sensor.order(bool(transform_bits & 1), bool(transform_bits & 2))

    # -- state ----------------------------------------------------------------------------------------------------
    def acquire(self) -> None:
        with self.lock:
            if self.state != "available":
                raise fail("Failed to acquire camera", errno.EBUSY)
            self.state = "acquired"

    def release(self) -> None:
        self.join()
        with self.lock:
            if self.state == "running":
                raise fail("Failed to release camera", errno.EBUSY)
            self.state = "available"
            self.active_streams = []

    def configure(self, config: CameraConfiguration) -> None:
        self.join()
        if self.state not in ("acquired", "configured"):
            raise fail("Failed to configure camera", errno.EACCES)
        if not isinstance(config, CameraConfiguration) or config._data is not self:
            raise fail("Failed to configure camera", errno.EINVAL)
        for cfg in config:
            cfg._stream = None
        if config.validate() != ConfigurationStatus.Valid:
            log("ERROR", "Camera", "camera.cpp", "Can't configure camera with invalid configuration")
            raise fail("Failed to configure camera", errno.EINVAL)
        mode = config.sensor_mode
        assert mode is not None
        streams = []
        outputs = []
        for cfg in config:
            info = cfg.pixel_format.info
            if info is not None and info.kind == "raw":
                stream = self.streams[0]
            else:
                outputs.append(cfg)
                continue
            cfg._stream = stream
            streams.append(stream)
        outputs_by_size = sorted(outputs, key=lambda c: c.size.width * c.size.height, reverse=True)
        for i, cfg in enumerate(outputs_by_size):
            cfg._stream = self.streams[1 + i]
            streams.append(cfg._stream)
        for cfg in config:
            assert cfg._stream is not None
            cfg._stream._configuration = cfg.copy()
        self.configured = config
        self.active_streams = streams
        self._configure_pipeline(config, outputs)
        self.ipa.configure(mode)
        self._configure_controls()
        self._prepare(config)
        self.state = "configured"
        log(
            "INFO",
            "Camera",
            "camera.cpp",
            "configuring streams: " + " ".join(f"({i}) {c}" for i, c in enumerate(config)),
        )

    def _configure_pipeline(self, config: CameraConfiguration, outputs: list[Any]) -> None:
        """The sensor mode, the ISP's lens shading for it, and each output's crop (``platformConfigure``)."""
        mode = config.sensor_mode
        assert mode is not None
        bits = config.transform_bits
        user = orientation_bits(config.orientation)
        binning = mode.binning
        x, y = mode.crop[:2]
        lsc_mode = SensorMode(
            self.spec.width, self.spec.height, (x, y, mode.width * binning, mode.height * binning), binning,
            bool(user & 1), bool(user & 2),
        )  # fmt: skip
        tuning = self.ipa.tuning
        self.isp = Isp(tuning.data, lsc_mode, self.order_for(bits), mode.bit_depth, tuning.black_level, tuning.gamma)
        self.sensor_flips = (bool(bits & 1), bool(bits & 2))
        mode_size = Size(mode.width, mode.height)
        self.analog_crop = Rectangle(*mode.crop)
        largest = max((c.size for c in outputs), key=lambda s: s.width * s.height, default=mode_size)
        self.crops, self.min_crops, self.plans = [], [], []
        for cfg in outputs:
            ratio = largest if self.platform == "vc4" else cfg.size
            crop = mode_size.bounded_to_aspect_ratio(ratio).centered_to(Rectangle(mode_size).center)
            self.crops.append(crop)
            minimum = Size(16, 16) if self.platform == "vc4" else Size(32, 32)
            if self.platform == "pisp":
                scaling = cfg.size.shrunk_by(Size(1, 1)) / 16
                minimum = minimum.expanded_to(scaling.grown_by(Size(2, 2)))
            self.min_crops.append(minimum)
        self.outputs = outputs
        self._plan_outputs()

    def _plan_outputs(self) -> None:
        """Each output's sampling of the mode for the current crops."""
        mode = self.configured.sensor_mode if self.configured else None
        assert mode is not None
        self.plans = []
        for i, cfg in enumerate(self.outputs):
            crop = self.crops[0 if self.platform == "vc4" else i]
            layout = Layout(str(cfg.pixel_format), cfg.size.width, cfg.size.height, cfg.stride, cfg.frame_size)
            rows, cols = sample_indices(
                (crop.x, crop.y, crop.width, crop.height), cfg.size.width, cfg.size.height,
                (mode.width // 2, mode.height // 2),
            )  # fmt: skip
            self.plans.append((cfg._stream, OutputPlan(layout, cfg.color_space, rows, cols)))

    def _prepare(self, config: CameraConfiguration) -> None:
        """Do now what the first frame would otherwise wait for (the mode's optics, the lens shading tables, the
        compressor's compilation), so that frames come at the mode's rate from the start, as on a Pi."""
        mode = config.sensor_mode
        assert mode is not None and self.isp is not None
        frame = self.sensor.capture(mode, 1000.0, 1.0, 0, *self.sensor_flips, noise=False)  # the response as read out
        self.isp.lens_shading(self.ipa.ct)
        # One frame through each configured stream into scratch buffers: every kernel compiled for the exact types
        # and layouts the frames will use (numba compiles anew for each), and for no others (one to three seconds
        # each, the first time after an install), not while the first frame is awaited.
        raw = self.streams[0]._configuration if self.streams[0] in self.active_streams else None
        if raw is not None:
            layout = Layout(str(raw.pixel_format), raw.size.width, raw.size.height, raw.stride, raw.frame_size)
            scratch = np.zeros(raw.frame_size, np.uint8).reshape(layout.height, -1)
            encode_raw(frame, layout, mode.bit_depth, scratch)
        for _, plan in self.plans:
            scratch = np.zeros(plan.layout.frame_size, np.uint8)
            self.isp.render(frame, self.ipa.ct, plan, self.ipa.colour_gains(), 1.0, self.ipa.ccm(), scratch)

    def _native_crop(self, crop: Rectangle) -> Rectangle:
        """``scaleIspCrop``: an ISP crop in sensor coordinates."""
        mode = self.configured.sensor_mode if self.configured else None
        assert mode is not None
        native = crop.scaled_by(self.analog_crop.size, Size(mode.width, mode.height))
        return native.translated_by(self.analog_crop.topLeft)

    def _configure_controls(self) -> None:
        """The controls' ranges for the mode (``IpaBase::configure``, ``PipelineHandlerBase::configure``)."""
        infos = self._ipa_controls(platform_controls=False)
        limits = self.ipa.control_limits()
        for name, (low, high, default) in limits.items():
            if name == "AnalogueGain":
                low, high, default = as_float32(low), as_float32(high), as_float32(default)
            infos[CONTROLS[name]] = ControlInfo(low, high, default)
        if self.crops:
            minimum = self._native_crop(Rectangle(self.min_crops[0]))
            default = self._native_crop(self.crops[0])
            infos[CONTROLS["ScalerCrop"]] = ControlInfo(minimum, self.analog_crop, default)
            if self.platform == "pisp" and len(self.crops) == 2:
                infos[CONTROLS["ScalerCrops"]] = ControlInfo(
                    self._native_crop(self.crops[0]), self._native_crop(self.crops[1]), default
                )
        self.control_infos = infos
        self.properties["ScalerCropMaximum"] = Rectangle(
            self.analog_crop.x, self.analog_crop.y, self.analog_crop.width, self.analog_crop.height
        )

    def apply_scaler_crop(self, controls: dict[str, Any]) -> None:
        """``applyScalerCrop``: ScalerCrops (per output) or ScalerCrop (all outputs), kept within the mode."""
        mode = self.configured.sensor_mode if self.configured else None
        if mode is None or not self.crops:
            return
        crops = controls.get("ScalerCrops")
        single = controls.get("ScalerCrop")
        if crops is None and single is None:
            return
        changed = False
        for i in range(len(self.crops) if self.platform == "pisp" else 1):
            native = crops[i] if crops is not None and i < len(crops) else single
            if native is None:
                continue
            if not native.width or not native.height:
                native = Rectangle(0, 0, 1, 1)
            crop = native.translated_by(Point(-self.analog_crop.x, -self.analog_crop.y))
            crop = crop.scaled_by(Size(mode.width, mode.height), self.analog_crop.size)
            minimum = self.min_crops[i].expanded_to_aspect_ratio(native.size)
            size = crop.size.expanded_to(minimum)
            crop = size.centered_to(crop.center).enclosed_in(Rectangle(Size(mode.width, mode.height)))
            if crop != self.crops[i]:
                self.crops[i], changed = crop, True
        if changed:
            self._plan_outputs()

    def start(self, controls: dict[str, Any]) -> None:
        self.join()
        with self.lock:
            if self.state != "configured":
                raise fail("Failed to start camera", errno.EACCES)
            manager = self.manager_ref()
            if manager is None:
                raise fail("Failed to start camera", errno.ENODEV)
            self.apply_scaler_crop(controls)
            if "AeEnable" in controls:
                on = bool(controls["AeEnable"])
                controls = {"ExposureTimeMode": int(not on), "AnalogueGainMode": int(not on), **controls}
            self.startup, self.invalid = self.ipa.start(controls)
            self.sequence = 0
            self.request_sequence = 0
            self.queue_ = []
            self.stopping = False
            self.state = "running"
            name = f"virtual camera {self.spec.name}"
            self.threads = [
                threading.Thread(target=self._run, name=name, daemon=True),
                threading.Thread(target=self._run_isp, name=f"{name} ISP", daemon=True),
            ]
            for thread in self.threads:
                thread.start()

    def queue(self, request: Request) -> None:
        with self.lock:
            if self.state != "running":
                raise fail("Failed to queue request", errno.EACCES)
            if request._owner is not self:
                raise fail("Failed to queue request", errno.EXDEV)
            if request._status != RequestStatus.Pending or not request._buffers:
                raise fail("Failed to queue request", errno.EINVAL)
            if any(stream not in self.active_streams for stream in request._buffers):
                raise fail("Failed to queue request", errno.EINVAL)
            if "AeEnable" in request._controls:  # camera.cpp patchControlList
                on = bool(request._controls["AeEnable"])
                request._controls.setdefault("AnalogueGainMode", int(not on))
                request._controls.setdefault("ExposureTimeMode", int(not on))
            request._sequence = self.request_sequence
            self.request_sequence += 1
            self.queue_.append(request)
            self.lock.notify_all()

    def stop(self) -> None:
        """Stop at once: the queued requests, and those whose frames are being made, complete as cancelled now (the
        frames under way are dropped when they are done)."""
        with self.lock:
            if self.state != "running":
                return
            self.stopping = True
            pending = [*self.in_flight, *self.queue_]
            self.queue_, self.in_flight, self.developing = [], [], []
            self.state = "configured"
            self.lock.notify_all()
            manager = self.manager_ref()
            for request in pending:
                for buffer in request._buffers.values():
                    buffer.metadata._set(FrameMetadataStatus.Cancelled, 0, 0, [])
                request._status, request._pending = RequestStatus.Cancelled, 0
                if manager is not None:
                    manager._complete(request)

    def join(self) -> None:
        """Wait for the frame threads of an earlier start to end (before the camera changes under them)."""
        for thread in self.threads:
            if thread is not threading.current_thread():
                thread.join()
        self.threads = []

    # -- frames ---------------------------------------------------------------------------------------------------
    # Two stages, as on a Pi: the sensor's (the receiver writes the raw frame into the oldest queued request at the
    # frame clock, and the IPA sees its statistics) and the ISP's (processed outputs, then completion, in order). A
    # frame is processed while the next is read out, so a frame that takes a little longer to process does not cost
    # the next one; requests bound how far the ISP may fall behind.
    def _run(self) -> None:
        """The sensor's frame clock: each frame goes to the oldest queued request, or is dropped.

        A camera left with no request of its own (none queued, none being filled or processed: the application holds
        them all) delivers nothing, as on a Pi; after :data:`STARVED_S` of that, one warning says why, once a stall.
        """
        next_frame = time.monotonic_ns()
        starved_since: int | None = None
        while True:
            settings = self.ipa.settings_for(self.sequence)
            frame_us = self.ipa.exposure_of(settings)[2]
            next_frame += int(frame_us * 1000)
            with self.lock:
                while not self.stopping:
                    delay = (next_frame - time.monotonic_ns()) / 1e9
                    if delay <= 0:
                        break
                    self.lock.wait(delay)
                if self.stopping:
                    return
                request = self.queue_.pop(0) if self.queue_ else None
                if request is not None:
                    self.in_flight.append(request)
                    starved_since = None
                elif not self.in_flight and not self.developing:
                    starved_since = self._starved(starved_since, next_frame)
            if request is not None:
                try:
                    with stage("sensor stage: controls, IPA, metadata"):
                        self._receive(request, settings, next_frame)
                except Exception as exc:  # a bug here must not leave picamera2 waiting for ever
                    self._fail_request(request, self.sequence, exc)
            self.sequence += 1
            late = time.monotonic_ns() - next_frame - int(frame_us * 1000)
            if late > 0:  # the frames the sensor delivered meanwhile went by without a request
                missed = late // max(int(frame_us * 1000), 1) + 1
                self.sequence += int(missed)
                next_frame += int(missed * frame_us * 1000)
                for seq in range(self.sequence - int(missed), self.sequence):
                    self.ipa.settings_for(seq)

    def _run_isp(self) -> None:
        """The ISP: the frames the sensor stage hands over, processed and completed in order."""
        while True:
            with self.lock:
                while not self.stopping and not self.developing:
                    self.lock.wait()
                if self.stopping:
                    return
                frame = self.developing.pop(0)
            try:
                with stage("ISP stage: completion"):
                    self._develop(frame)
            except Exception as exc:  # as in _run
                self._fail_request(frame.request, frame.sequence, exc)

    @staticmethod
    def _starved(since: int | None, now: int) -> int | None:
        """When the camera's stall without requests began (``now`` if it begins now); warns once, after STARVED_S."""
        if since is None:
            return now
        if since >= 0 and now - since >= STARVED_S * 1e9:  # -1: warned already
            log(
                "WARN",
                "VirtualCamera",
                "camera.py",
                f"no request queued for {STARVED_S:g} s: the application holds every request of the camera (one not "
                "released, as after a failed picamera2 capture job, keeps its buffers); no frame comes until a "
                "request is queued again, or the camera is stopped and started, as on a Raspberry Pi",
            )
            return -1  # warned: not again until a request comes
        return since

    def _fail_request(self, request: Request, sequence: int, exc: Exception) -> None:
        """Complete a request whose frame could not be made, as a frame in error."""
        log("ERROR", "RPI", "virtualcam", f"frame {sequence} failed: {exc!r}")
        self._complete(request, FrameMetadataStatus.Error, sequence, 0, {}, filled=False)

    def _complete(
        self,
        request: Request,
        status: FrameMetadataStatus,
        sequence: int,
        timestamp: int,
        metadata: dict[str, Any],
        filled: bool = True,
    ) -> None:
        """Complete a request of the frame threads (``filled``: its buffers hold a frame), unless :meth:`stop`
        cancelled it meanwhile: its buffers' and its own metadata set and its completion signalled at once, under the
        camera's lock. So no request completes after ``stop()`` returns, as libcamera promises (``Camera::stop``) and
        picamera2 relies on: it flushes the completed requests right after stopping, and one signalled later would
        come back to it as a frame of the next configuration (its event loop then fails on it, and every request
        stays held)."""
        with self.lock:
            if request not in self.in_flight:
                return
            self.in_flight.remove(request)
            for stream, buffer in request._buffers.items():
                assert stream._configuration is not None
                buffer.metadata._set(status, sequence, timestamp, [stream._configuration.frame_size] if filled else [])
            request._metadata = {k: stored(CONTROLS[k], v) for k, v in metadata.items() if k in CONTROLS}
            request._status, request._pending = RequestStatus.Complete, 0
            manager = self.manager_ref()
            if manager is not None:
                manager._complete(request)

    def _receive(self, request: Request, settings: Any, timestamp: int) -> None:
        """The sensor's stage of frame ``self.sequence``: the request's controls applied, the raw frame read out
        (into the raw stream's buffer), the IPA run on its statistics; the rest handed to the ISP stage."""
        isp = self.isp
        mode = self.configured.sensor_mode if self.configured else None
        assert isp is not None and mode is not None
        controls = request._controls
        self.apply_scaler_crop(controls)
        self.ipa.apply_controls(controls)
        exposure_us, gain, _ = self.ipa.exposure_of(settings)
        hflip, vflip = self.sensor_flips
        with stage("readout"):
            frame = self.sensor.capture(mode, exposure_us, gain, self.sequence, hflip, vflip)
        ct = self.ipa.ct
        with stage("statistics"):
            means = isp.statistics(frame, ct)
        raw = self.streams[0]
        if raw in request._buffers:
            config = raw._configuration
            assert config is not None
            layout = Layout(str(config.pixel_format), config.size.width, config.size.height, config.stride,
                            config.frame_size)  # fmt: skip
            with stage("raw stream"):
                encode_raw(frame, layout, mode.bit_depth, self._buffer_bytes(request, raw).reshape(layout.height, -1))
        metadata = self.ipa.metadata(settings, means)
        metadata["SensorTimestamp"] = int(timestamp)
        metadata["FrameWallClock"] = time.time_ns() - (time.monotonic_ns() - int(timestamp))
        if self.crops:
            native = [self._native_crop(c) for c in self.crops]
            metadata["ScalerCrop"] = native[0]
            if len(native) > 1 and self.platform == "pisp":
                metadata["ScalerCrops"] = tuple(native)
        developed = _Frame(
            request, self.sequence, int(timestamp), frame, ct, self.plans, self.ipa.colour_gains(),
            settings.digital_gain, self.ipa.ccm(), metadata, self._status(),
        )  # fmt: skip
        self.ipa.process(self.sequence, settings, means)
        with self.lock:
            if request in self.in_flight:  # not cancelled by stop() meanwhile
                self.developing.append(developed)
                self.lock.notify_all()

    def _status(self) -> FrameMetadataStatus:
        """The next frame's status: the IPA's invalid frames, then its start-up frames, then success."""
        if self.invalid:
            self.invalid -= 1
            return FrameMetadataStatus.Error
        if self.startup:
            self.startup -= 1
            return FrameMetadataStatus.Startup_
        return FrameMetadataStatus.Success

    @staticmethod
    def _buffer_bytes(request: Request, stream: Stream) -> np.ndarray:
        """The bytes of a request's buffer for ``stream`` (uint8, the stream's frame size)."""
        buffer = request._buffers[stream]
        config = stream._configuration
        assert config is not None
        return np.frombuffer(buffer.mapping(), np.uint8, count=config.frame_size, offset=buffer._planes[0].offset)

    def _develop(self, frame: _Frame) -> None:
        """The ISP's stage of one frame: its processed outputs, then its request completed."""
        isp = self.isp
        assert isp is not None
        request = frame.request
        for stream, plan in frame.plans:
            if stream in request._buffers:
                dest = self._buffer_bytes(request, stream)
                with stage("ISP render"):
                    isp.render(frame.raw, frame.ct, plan, frame.gains, frame.digital_gain, frame.ccm, dest)
                del dest  # the mapping's export, before the next
        self._complete(request, frame.status, frame.sequence, frame.timestamp, frame.metadata)


@dataclass(frozen=True)
class _Frame:
    """A frame between the sensor's stage and the ISP's: the raw frame and what the IPA had in force for it."""

    request: Request
    sequence: int
    timestamp: int
    raw: np.ndarray
    ct: float
    plans: list[tuple[Stream, OutputPlan]]
    gains: tuple[float, float]
    digital_gain: float
    ccm: np.ndarray
    metadata: dict[str, Any]
    status: FrameMetadataStatus


class CameraManager:
    """The camera manager of the bindings (one per process while it is held): the virtual camera registered.

    Parameters
    ----------
    options : Options, optional
        The virtual camera's settings; default from the environment (:meth:`Options.from_environment`).
    environ : mapping, optional
        Where ``LIBCAMERA_RPI_TUNING_FILE`` is read; default ``os.environ``.
    """

    _instance: weakref.ref[CameraManager] | None = None
    _lock = threading.Lock()

    def __init__(self, options: Options | None = None, environ: dict[str, str] | None = None) -> None:
        self._options = options or Options.from_environment()
        self._event_fd = os.eventfd(0, os.EFD_CLOEXEC | os.EFD_NONBLOCK)
        weakref.finalize(self, os.close, self._event_fd)
        self._completed: list[Request] = []
        self._completed_lock = threading.Lock()
        self._camera_data: list[CameraData] = []
        self._wrappers: weakref.WeakValueDictionary[int, Camera] = weakref.WeakValueDictionary()
        spec = scaled_spec(sensor_spec(self._options.sensor), self._options.size)
        try:
            tuning = load_camera_tuning(spec, self._options.platform, environ)
        except IpaError as exc:
            # A camera whose IPA fails to start is not registered (pipeline_base.cpp registerCamera).
            log("ERROR", "IPARPI", "ipa_base.cpp", str(exc))
            log("ERROR", "RPI", "pipeline_base.cpp", "Failed to load a suitable IPA library")
            return
        self._camera_data.append(CameraData(self._options, spec, Ipa(spec, tuning), self))

    @staticmethod
    def singleton() -> CameraManager:
        with CameraManager._lock:
            manager = CameraManager._instance() if CameraManager._instance else None
            if manager is None:
                manager = CameraManager()
                CameraManager._instance = weakref.ref(manager)
            return manager

    @property
    def version(self) -> str:
        return VERSION

    @property
    def cameras(self) -> list[Camera]:
        return [self._wrap(i) for i in range(len(self._camera_data))]

    def _wrap(self, index: int) -> Camera:
        camera = self._wrappers.get(index)
        if camera is None:
            camera = Camera(self._camera_data[index], self)
            self._wrappers[index] = camera
        return camera

    def get(self, camera_id: str) -> Camera | None:
        for i, data in enumerate(self._camera_data):
            if data.id == camera_id:
                return self._wrap(i)
        return None

    @property
    def event_fd(self) -> int:
        return self._event_fd

    def get_ready_requests(self) -> list[Request]:
        try:
            os.read(self._event_fd, 8)
        except BlockingIOError:
            return []
        with self._completed_lock:
            ready, self._completed = self._completed, []
        return ready

    def _complete(self, request: Request) -> None:
        """``handleRequestCompleted``: keep the request and signal the event fd (from the camera's thread)."""
        with self._completed_lock:
            self._completed.append(request)
        os.eventfd_write(self._event_fd, 1)


def set_light(light: tuple[float, float, float]) -> None:
    """Light the scene of the virtual cameras of this process: the light of a virtual rig.

    The illuminator of ``picamcal acquire --camera picamera2 --illuminator virtual``
    (:class:`picamcal.acquire.illuminators.VirtualIlluminator`); the frames after the change see it.

    Parameters
    ----------
    light : (float, float, float)
        Amounts of the light's red, green and blue primaries (1, 1, 1 is the white light; 0, 0, 0 is dark).

    Raises
    ------
    VirtualCameraError
        No virtual camera runs in this process (none has been opened through picamera2).

    Examples
    --------
    >>> manager = CameraManager.singleton()  # as picamera2 starts it, inside the virtual camera
    >>> set_light((1.0, 0.0, 0.0))
    >>> [data.sensor.scene.light for data in manager._camera_data]
    [(1.0, 0.0, 0.0)]
    """
    manager = CameraManager._instance() if CameraManager._instance else None
    if manager is None:
        raise VirtualCameraError(
            "no virtual camera runs in this process: the virtual light needs picamera2 on the virtual camera "
            "(picamcal virtual-camera -- COMMAND)"
        )
    for data in manager._camera_data:
        data.sensor.scene.set_light(light)
