"""The Raspberry Pi camera through picamera2: the acquisition's :class:`Picamera2Camera` and what it needs.

picamera2 (an optional extra for the Pi) is imported only when a camera is opened. :class:`Picamera2Camera` is a
thin adapter: raw frames of one sensor mode (the full-resolution one by default) at frozen settings for the
acquisition, and the processed stream of any mode for ``picamcal verify`` (:mod:`picamcal.acquire.verify`). The
functions around it list the cameras in another process (so that the tuning a camera is opened with is the one in
force), name and choose picamera2's sensor modes, and refuse a tuning for the other Raspberry Pi.
:mod:`picamcal.acquire.cameras` re-exports them all.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import math
import os
import subprocess
import sys
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PicamcalError, PicamcalWarning
from ..export.tuning import TARGET_NAMES, TuningError, load_tuning, neutral_tuning, stock_tuning_path
from ..geometry import SensorMode, mode_from_crop, parse_sensor_mode
from ..raw.model import RawImage
from ..raw.picamera2 import capture_raw
from ..raw.picamera2.metadata import active_area_size
from .base import CameraError, CameraLimits

__all__ = [
    "GAIN_STEP",
    "Picamera2Camera",
    "camera_model",
    "check_tuning_target",
    "choose_mode",
    "import_picamera2",
    "is_cropped",
    "list_cameras",
    "mode_geometry",
    "mode_name",
    "picamera2_number",
    "picamera2_target",
    "raw_sensor_modes",
    "stock_tuning_file",
]


#: The coarsest analogue gain step of the sensors picamera2 drives, at any gain (the OV5647's 1/16).
GAIN_STEP = 1 / 16


def import_picamera2() -> Any:
    """picamera2, imported; CameraError saying how to install it when it is not."""
    try:
        import picamera2
    except ImportError as exc:
        if exc.name == "picamera2":
            raise CameraError(
                "picamera2 is not installed: on a Raspberry Pi install picamcal[pi] (or apt install python3-picamera2)"
            ) from None
        raise CameraError(
            f"picamera2 cannot be imported (no module named {exc.name!r}): it needs libcamera, which a Raspberry Pi "
            "has; on a PC run the command under picamcal virtual-camera"
        ) from None
    return picamera2


class _Flushed:
    """A Picamera2 whose ``capture_request`` waits for a frame begun after the call as long as the camera answers: it
    gives up only when no frame at all (``Picamera2.frames``, the frames picamera2 has received) came for ``timeout``
    s. A camera slow to deliver a fresh frame, as a virtual one on a busy machine, has its frames in flight finish."""

    def __init__(self, picam2: Any, timeout: float) -> None:
        self._picam2 = picam2
        self._timeout = timeout
        self.camera_properties = picam2.camera_properties

    @property
    def camera_controls(self) -> Any:
        """The configured mode's controls (its ``ScalerCrop`` limits place the mode on the sensor)."""
        return self._picam2.camera_controls

    def camera_configuration(self) -> Any:
        return self._picam2.camera_configuration()

    def capture_request(self) -> Any:
        job = self._picam2.capture_request(flush=True, wait=False)
        frames = self._picam2.frames
        while True:
            try:
                return self._picam2.wait(job, timeout=self._timeout)
            # picamera2's job is a concurrent.futures.Future: its timeout is not the built-in TimeoutError before 3.11.
            except (TimeoutError, concurrent.futures.TimeoutError):
                if self._picam2.frames == frames:
                    raise CameraError(
                        f"the camera sent no frame within {self._timeout:.2g} s: it stopped answering"
                    ) from None
                frames = self._picam2.frames


#: Lists the cameras as ``Picamera2.global_camera_info()`` does, in a process of its own (:func:`list_cameras`).
_LIST_CAMERAS = """
import json
from picamera2 import Picamera2
print(json.dumps([{str(k): str(v) for k, v in camera.items()} for camera in Picamera2.global_camera_info()]))
"""


def list_cameras(timeout: float = 120.0) -> list[dict[str, str]]:
    """The cameras picamera2 sees (``Picamera2.global_camera_info()``: Model, Id, Num, ...), listed by another process.

    Not in this one: listing the cameras starts libcamera's camera manager, whose Raspberry Pi pipeline reads the
    tuning file (``LIBCAMERA_RPI_TUNING_FILE``, else the stock file) when it registers each camera, and picamera2
    keeps that manager while it lives, so a tuning given to ``Picamera2(tuning=...)`` afterwards in the same
    process would be silently ignored (libcamera ``pipeline_base.cpp``; picamera2 ``Picamera2.__init__``).

    Raises
    ------
    CameraError
        The listing fails (picamera2 or libcamera cannot start) or takes longer than ``timeout`` seconds.

    Examples
    --------
    On a Raspberry Pi 5 with the HQ camera (docs/virtual-camera.md runs it on the virtual camera)::

        [camera["Model"] for camera in list_cameras()]  # ['imx477']
    """
    try:
        result = subprocess.run(
            [sys.executable, "-c", _LIST_CAMERAS], capture_output=True, text=True, timeout=timeout, env=os.environ
        )
    except subprocess.TimeoutExpired:
        raise CameraError(f"libcamera did not list the cameras within {timeout:.0f} s") from None
    if result.returncode != 0:
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        raise CameraError(f"libcamera cannot list the cameras ({lines[-1] if lines else result.returncode})")
    try:
        cameras = json.loads(result.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        raise CameraError(f"libcamera cannot list the cameras (it printed {result.stdout[-200:]!r})") from None
    return [dict(camera) for camera in cameras]


def picamera2_target(module: Any) -> str:
    """The tuning target of the Pi that picamera2 (the imported ``module``) runs on: ``"pisp"`` (Pi 5) or
    ``"bcm2835"`` (Pi 4 and earlier), from ``Picamera2.platform``."""
    return "bcm2835" if "VC4" in str(getattr(module.Picamera2, "platform", "")).upper() else "pisp"


def check_tuning_target(tuning: dict[str, Any], module: Any, name: str = "the tuning") -> None:
    """Refuse a tuning for the other Raspberry Pi before picamera2 opens the camera with it.

    libcamera registers no camera with a tuning file for the other platform (a Pi 5's ``pisp`` file on a Pi 4), and
    picamera2 then fails with a bare IndexError.

    Parameters
    ----------
    tuning : dict
        The tuning (:func:`picamcal.export.tuning.load_tuning`).
    module : module
        picamera2, imported (``Picamera2.platform`` says which Pi this is).
    name : str
        The tuning's name for the message (its file).

    Raises
    ------
    CameraError
        The tuning's target is not this Pi's.

    Examples
    --------
    >>> import types
    >>> pi4 = types.SimpleNamespace(Picamera2=types.SimpleNamespace(platform="Platform.VC4"))
    >>> check_tuning_target({"target": "pisp"}, pi4, "tuning.json")
    Traceback (most recent call last):
    ...
    picamcal.acquire.base.CameraError: tuning.json is for a Raspberry Pi 5 (target pisp), but this is a \
Raspberry Pi 4 or earlier (vc4, target bcm2835): export the tuning again with --target vc4
    """
    target, given = picamera2_target(module), str(tuning.get("target", ""))
    if given == target:
        return
    names = {"pisp": "a Raspberry Pi 5", "bcm2835": "a Raspberry Pi 4 or earlier"}
    label = {value: key for key, value in TARGET_NAMES.items()}[target]
    raise CameraError(
        f"{name} is for {names.get(given, 'no Raspberry Pi')} (target {given or 'missing'}), but this is "
        f"{names[target]} ({label}, target {target}): export the tuning again with --target {label}"
    )


def raw_sensor_modes(modes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The sensor modes of picamera2's ``sensor_modes`` that it describes in full (a size and a bit depth).

    picamera2 gives a raw format it does not list (a 14-bit one, ``formats.BAYER_FORMATS``) by its name alone.

    Examples
    --------
    >>> full = {"format": "SRGGB12", "unpacked": "SRGGB12", "bit_depth": 12, "size": (4056, 3040)}
    >>> [mode["format"] for mode in raw_sensor_modes([{"format": "SRGGB14"}, full])]
    ['SRGGB12']
    """
    return [mode for mode in modes if {"size", "bit_depth", "unpacked"} <= mode.keys()]


def mode_name(mode: Mapping[str, Any]) -> str:
    """A picamera2 sensor mode's name, ``WIDTHxHEIGHT:BITS``, as ``--sensor-mode`` takes it and as the exported
    tuning's ``colour_gains_by_mode`` is keyed.

    Examples
    --------
    >>> mode_name({"size": (1920, 1080), "bit_depth": 10})
    '1920x1080:10'
    """
    width, height = mode["size"]
    return f"{int(width)}x{int(height)}:{int(mode['bit_depth'])}"


def choose_mode(modes: Sequence[Mapping[str, Any]], sensor_mode: str | None, model: str = "camera") -> dict[str, Any]:
    """The mode of picamera2's ``sensor_modes`` (:func:`raw_sensor_modes`) that ``--sensor-mode WxH[:BITS]`` names.

    Without ``sensor_mode``, the full-resolution mode; without ``:BITS``, the named size's highest bit depth.

    Raises
    ------
    CameraError
        The sensor has no such mode (the message lists those picamera2 reports), or no mode at all.

    Examples
    --------
    >>> modes = [{"size": (1920, 1080), "bit_depth": 10, "unpacked": "SRGGB10"},
    ...          {"size": (3280, 2464), "bit_depth": 10, "unpacked": "SRGGB10"}]
    >>> mode_name(choose_mode(modes, None)), mode_name(choose_mode(modes, "1920x1080"))
    ('3280x2464:10', '1920x1080:10')
    >>> choose_mode(modes, "1920x1080:12", "imx219")
    Traceback (most recent call last):
    ...
    picamcal.acquire.base.CameraError: --sensor-mode 1920x1080:12: the imx219 has no such mode (picamera2 \
reports 1920x1080:10, 3280x2464:10)
    """
    if not modes:
        raise CameraError(f"the {model} reports no raw sensor mode that picamera2 describes")
    by_size = sorted(modes, key=lambda m: (m["size"][0] * m["size"][1], m["bit_depth"]))
    if sensor_mode is None:
        return dict(by_size[-1])
    try:
        parsed = parse_sensor_mode(sensor_mode)
    except PicamcalError as exc:
        raise CameraError(exc.problem) from None
    assert parsed is not None
    width, height, bits = parsed
    matches = [m for m in by_size if tuple(m["size"]) == (width, height) and bits in (None, m["bit_depth"])]
    if not matches:
        names = ", ".join(mode_name(m) for m in by_size)
        raise CameraError(f"--sensor-mode {sensor_mode}: the {model} has no such mode (picamera2 reports {names})")
    return dict(matches[-1])


def mode_geometry(mode: Mapping[str, Any], pixel_array: Sequence[int]) -> SensorMode:
    """Where a picamera2 sensor mode lies on the sensor: its ``crop_limits`` on the sensor's active area
    (:func:`picamcal.geometry.mode_from_crop`).

    Examples
    --------
    >>> geometry = mode_geometry({"size": (1640, 1232), "bit_depth": 10, "crop_limits": (0, 0, 3280, 2464)},
    ...                          (3280, 2464))
    >>> geometry.binning, geometry.is_full
    (2, True)
    """
    width, height = (int(v) for v in pixel_array)
    crop = tuple(int(v) for v in mode.get("crop_limits", (0, 0, width, height)))
    size = (int(mode["size"][0]), int(mode["size"][1]))
    geometry = mode_from_crop((width, height), size, crop, what="the mode's crop limits")  # type: ignore[arg-type]
    return dataclasses.replace(geometry, bit_depth=int(mode["bit_depth"]), source="camera")


def is_cropped(geometry: SensorMode) -> bool:
    """Whether a mode reads only part of the sensor: its crop misses more than a few pixels of the array at an
    edge (a binned mode's crop may leave off the array's odd last pixels: the HQ camera's 4056 columns binned to
    2028 are whole, a reduced virtual sensor's 1014 binned to 506 leave two).

    Examples
    --------
    >>> is_cropped(SensorMode(3280, 2464, (680, 692, 1920, 1080)))
    True
    >>> is_cropped(SensorMode(1014, 760, (0, 0, 1012, 760), binning=2))
    False
    """
    return not geometry.contains((0, 0, geometry.sensor_width, geometry.sensor_height), 2 * geometry.binning)


def camera_model(camera_num: int = 0) -> str:
    """The model of camera ``camera_num`` (``imx219``, ``imx708_wide``), as picamera2 lists it in another process
    (:func:`list_cameras`: listing in this one would fix the tuning before the camera is opened with one).

    Raises
    ------
    CameraError
        No camera, or no camera of that number.

    Examples
    --------
    On a Raspberry Pi with the HQ camera::

        camera_model(0)  # 'imx477'
    """
    cameras = list_cameras()
    if not cameras:
        raise CameraError(
            "no camera found: check the ribbon cable and that rpicam-hello --list-cameras lists the camera"
        )
    if not 0 <= camera_num < len(cameras):
        raise CameraError(f"no camera {camera_num}: {len(cameras)} found (numbered from 0)")
    return cameras[camera_num].get("Model", "unknown")


def stock_tuning_file(model: str, module: Any) -> Path:
    """The tuning file the camera of ``model`` loads when none is given: picamera2's stock file for this Pi.

    Raises
    ------
    CameraError
        There is none.

    Examples
    --------
    On a Raspberry Pi 5::

        stock_tuning_file("imx219", import_picamera2())  # /usr/share/libcamera/ipa/rpi/pisp/imx219.json
    """
    try:
        return stock_tuning_path(model, picamera2_target(module))
    except TuningError as exc:
        raise CameraError(f"no stock libcamera tuning file for the {model} ({exc})") from exc


class Picamera2Camera:
    """A Raspberry Pi camera through picamera2, with a neutral pipeline and frozen settings.

    Opening it loads the sensor's stock tuning made neutral (:func:`picamcal.export.tuning.neutral_tuning`,
    as editing tuning files is the exporter's business) unless given a tuning, and picks the sensor mode
    ``sensor_mode`` names, by default the full-resolution mode of the highest bit depth; :meth:`configure_raw`
    asks for that mode's unpacked raw format (the Pi 5 grants ``S<order>16``; its lossy ``PISP_COMP1`` is
    refused). A cropped mode (one that reads part of the sensor) is warned about: a calibration from it, and the
    lens shading table exported from it, cover that crop only. Each capture waits for a frame that began exposing
    after the call and carries the requested exposure and gain; a camera that sends no frame for 5 s plus three
    exposures has stopped answering.

    :meth:`configure_processed` and :meth:`capture_processed` give instead the camera's own processed RGB stream in
    any of its modes, through the tuning in force (what :func:`picamcal.acquire.verify.verify_modes` measures).

    Parameters
    ----------
    camera_num : int
        Which camera (``Picamera2.global_camera_info()`` order).
    tuning : dict, optional
        The libcamera tuning to open the camera with, as given (``picamcal.export.tuning.load_tuning(path)``);
        by default the sensor's stock tuning, made neutral.
    sensor_mode : str, optional
        ``WIDTHxHEIGHT[:BITS]``: the sensor mode to acquire in (:func:`choose_mode`); by default the full-resolution
        one.

    Raises
    ------
    CameraError
        picamera2 is not installed, there is no camera, it cannot be opened, or it has no such mode (the message
        lists the modes picamera2 reports).

    Warns
    -----
    PicamcalWarning
        ``sensor_mode`` names a cropped mode.

    Examples
    --------
    On a Raspberry Pi (``tests/test_virtualcam_pi_path.py`` runs it on the virtual camera)::

        camera = Picamera2Camera(sensor_mode="1920x1080")  # warns: a cropped mode
        camera.configure_raw()
        camera.set_controls(4000, 1.0, (1.8, 1.6))
        raw = camera.capture()  # raw.metadata["sensor_crop"] == [680, 692, 1920, 1080]
    """

    #: Frames to wait for new controls to reach the sensor before giving up.
    MAX_SETTLE_FRAMES = 12
    #: Frames without the requested settings after which the controls are sent again: picamera2 attaches them to
    #: the next request it recycles, and a ``set_controls`` that lands while another thread recycles a request is
    #: lost (``CompletedRequest.release`` reads the pending controls, then replaces them with an empty set). Sending
    #: the same values again is harmless; 4 frames is the sensor's delay of 2 and a request in flight, and more.
    RESEND_FRAMES = 4

    def __init__(
        self, camera_num: int = 0, *, tuning: dict[str, Any] | None = None, sensor_mode: str | None = None
    ) -> None:
        module = import_picamera2()
        if tuning is None:
            model = camera_model(camera_num)
            try:  # the file picamera2 finds (Picamera2.load_tuning_file), read by libcamera's rules
                tuning = neutral_tuning(load_tuning(stock_tuning_file(model, module)))
            except TuningError as exc:
                raise CameraError(f"no stock libcamera tuning file for the {model} ({exc})") from exc
            self._tuning_description = "stock with static unity rpi.alsc (n_iter 0)"
        else:
            check_tuning_target(tuning, module)
            self._tuning_description = "as given"
        try:
            self._picam2 = module.Picamera2(camera_num, tuning=tuning)
        except IndexError:  # picamera2 found no such camera
            raise CameraError(f"no camera {camera_num}: libcamera registered none with this tuning") from None
        except RuntimeError as exc:
            raise CameraError(f"cannot open camera {camera_num} ({exc}); is another program using it?") from exc
        self.camera_num = camera_num
        self.model = str(self._picam2.camera_properties.get("Model", "unknown"))
        try:
            self._modes = raw_sensor_modes(list(self._picam2.sensor_modes))
            self._mode = choose_mode(self._modes, sensor_mode, self.model)
        except CameraError:
            self._picam2.close()
            raise
        self._pixel_array = tuple(active_area_size(self._picam2.camera_properties) or self._mode["size"])
        geometry = self.geometry()
        if sensor_mode is not None and is_cropped(geometry):
            x, y, w, h = geometry.crop
            warnings.warn(
                f"the {self.model}'s {mode_name(self._mode)} mode reads only the {w}x{h} area at ({x}, {y}) of its "
                f"{geometry.sensor_width}x{geometry.sensor_height} sensor: the calibration, and the lens shading "
                "table exported from it, will cover only that crop (acquire in the full-resolution or a binned "
                "mode to cover every mode)",
                PicamcalWarning,
                stacklevel=2,
            )
        self._raw_format: str | None = None
        self._processed: dict[str, Any] | None = None
        self._controls: dict[str, Any] = {"ExposureTime": 10_000, "AnalogueGain": 1.0}  # the last requested
        self._scaler_crop: list[int] | None = None
        self._pending = False

    @property
    def sensor_modes(self) -> list[dict[str, Any]]:
        """The sensor modes picamera2 reports and describes in full (:func:`raw_sensor_modes`), in its order."""
        return [dict(mode) for mode in self._modes]

    @property
    def mode(self) -> dict[str, Any]:
        """The sensor mode the acquisition uses (picamera2's description of it)."""
        return dict(self._mode)

    def geometry(self, mode: Mapping[str, Any] | None = None) -> SensorMode:
        """Where a mode (default the acquisition's) lies on the sensor (:func:`mode_geometry`)."""
        return mode_geometry(self._mode if mode is None else mode, self._pixel_array)

    def configure_raw(self) -> None:
        """Configure the chosen mode's unpacked raw stream and start the camera."""
        picam2, mode = self._picam2, self._mode
        size = tuple(mode["size"])
        try:
            if picam2.started:
                picam2.stop()
            # The main stream at the mode's size: its ScalerCrop (recorded with each frame) is then the whole mode.
            config = picam2.create_still_configuration(
                main={"size": size},
                raw={"format": str(mode["unpacked"]), "size": size},
                sensor={"output_size": size, "bit_depth": mode["bit_depth"]},
                buffer_count=2,
            )
            picam2.configure(config)
            granted = picam2.camera_configuration()["raw"]
        except (RuntimeError, KeyError, ValueError) as exc:
            raise CameraError(f"cannot configure a {size[0]}x{size[1]} raw stream on the {self.model} ({exc})") from exc
        if "PISP_COMP1" in str(granted["format"]):
            raise CameraError(
                f"the camera gave the lossy {granted['format']} raw format instead of {mode['unpacked']}; "
                "update picamera2 and libcamera"
            )
        self._raw_format, self._processed = str(granted["format"]), None
        self._start()

    def configure_processed(self, mode: Mapping[str, Any], size: tuple[int, int]) -> None:
        """Configure a processed RGB stream (``BGR888``: R, G, B in memory) of ``size`` from the sensor mode ``mode``
        (one of :attr:`sensor_modes`), through the tuning in force, and start the camera."""
        picam2 = self._picam2
        try:
            if picam2.started:
                picam2.stop()
            config = picam2.create_still_configuration(
                main={"format": "BGR888", "size": tuple(size)},
                sensor={"output_size": tuple(mode["size"]), "bit_depth": mode["bit_depth"]},
                buffer_count=2,
            )
            picam2.configure(config)
            granted = picam2.camera_configuration()
        except (RuntimeError, KeyError, ValueError) as exc:
            raise CameraError(f"cannot configure the {mode_name(mode)} mode on the {self.model} ({exc})") from exc
        sensor = granted.get("sensor") or {}
        if tuple(sensor.get("output_size", mode["size"])) != tuple(mode["size"]):
            raise CameraError(
                f"the {self.model} was asked for its {mode_name(mode)} mode but runs {sensor.get('output_size')}"
            )
        self._raw_format, self._processed = None, dict(mode)
        self._start()

    def _start(self) -> None:
        try:
            self._picam2.start()
        except RuntimeError as exc:
            raise CameraError(f"cannot start the {self.model} ({exc})") from exc

    def set_controls(
        self,
        exposure_time_us: float,
        analogue_gain: float,
        colour_gains: tuple[float, float] | None = None,
        *,
        auto_white_balance: bool = False,
    ) -> None:
        """Turn off auto-exposure and set the exposure, gain and colour gains; auto white balance stays off unless
        ``auto_white_balance`` (then the colour gains must not be given)."""
        controls: dict[str, Any] = {
            "AeEnable": False,
            "AwbEnable": bool(auto_white_balance),
            "ExposureTime": round(exposure_time_us),
            "AnalogueGain": float(analogue_gain),
        }
        if colour_gains is not None:
            if auto_white_balance:
                raise CameraError("colour gains are the auto white balance's to choose: give one or the other")
            controls["ColourGains"] = (float(colour_gains[0]), float(colour_gains[1]))
        self._send(controls)
        self._controls = controls
        self._pending = True

    def _send(self, controls: dict[str, Any]) -> None:
        try:
            self._picam2.set_controls(controls)
        except (RuntimeError, ValueError) as exc:
            raise CameraError(f"the camera refused the controls {controls} ({exc})") from exc

    def _settling(self, frames: int, exposure_s: Any, gain: Any) -> None:
        """After ``frames`` frames without the requested settings (the last one at ``exposure_s`` and ``gain``):
        give up at :attr:`MAX_SETTLE_FRAMES`, and send the controls again every :attr:`RESEND_FRAMES`."""
        if frames >= self.MAX_SETTLE_FRAMES:
            raise CameraError(
                f"the camera did not apply exposure {self._controls['ExposureTime']} µs at gain "
                f"{self._controls['AnalogueGain']} within {frames} frames (it reports {exposure_s} s, gain {gain})"
            )
        if frames % self.RESEND_FRAMES == 0:
            self._send(self._controls)

    def _applied(self, exposure_time_s: Any, analogue_gain: Any, colour_gains: Any = None) -> bool:
        """True when a frame carries the requested exposure and gain (within the sensor's quantisation), and the
        requested colour gains when ``colour_gains`` (a frame's ``ColourGains``) is given."""
        exposure_us, gain = self._controls["ExposureTime"], self._controls["AnalogueGain"]
        requested_gains = self._controls.get("ColourGains")
        actual_us = 1e6 * float(exposure_time_s or 0.0)
        actual_gain = float(analogue_gain or 0.0)
        # Exposure is whole sensor lines (tens of µs) and gain a register code: a few % at high gain, and steps of
        # 1/16 on the OV5647, whose code is floor(16 g) (libcamera cam_helper_ov5647.cpp): 1.06 is applied as 1.0.
        applied = abs(actual_us - exposure_us) <= max(100.0, 0.02 * exposure_us) and math.isclose(
            actual_gain, gain, rel_tol=0.05, abs_tol=GAIN_STEP
        )
        if applied and colour_gains is not None and requested_gains is not None:
            # The metadata's gains pass through a C++ float (libcamera's control values).
            red, blue = (float(g) for g in colour_gains)
            applied = math.isclose(red, requested_gains[0], rel_tol=1e-3) and math.isclose(
                blue, requested_gains[1], rel_tol=1e-3
            )
        return applied

    def _timeout(self) -> float:
        return 5.0 + 3e-6 * self._controls["ExposureTime"]

    def capture(self) -> RawImage:
        """One raw frame exposed after the call, at the requested settings."""
        if self._raw_format is None:
            raise CameraError("the camera is not configured: call configure_raw() first")
        camera = _Flushed(self._picam2, timeout=self._timeout())
        try:
            raw = capture_raw(camera)
            frames = 1
            while self._pending and not self._applied(
                raw.metadata.get("exposure_time_s"), raw.metadata.get("analogue_gain")
            ):
                self._settling(frames, raw.metadata.get("exposure_time_s"), raw.metadata.get("analogue_gain"))
                raw = capture_raw(camera)
                frames += 1
        except RuntimeError as exc:
            raise CameraError(f"the camera stopped answering ({exc})") from exc
        self._pending = False
        self._scaler_crop = raw.metadata.get("scaler_crop", self._scaler_crop)
        return raw

    def capture_processed(self) -> tuple[np.ndarray, dict[str, Any]]:
        """One frame of the processed stream (:meth:`configure_processed`) exposed after the call at the requested
        settings (colour gains included): its R, G, B array (height, width, 3, uint8) and the request's metadata."""
        if self._processed is None:
            raise CameraError("the camera is not configured: call configure_processed() first")
        camera = _Flushed(self._picam2, timeout=self._timeout())
        frames = 0
        while True:
            try:
                request = camera.capture_request()
                try:
                    rgb, metadata = request.make_array("main")[..., :3].copy(), dict(request.get_metadata())
                finally:
                    request.release()
            except RuntimeError as exc:
                raise CameraError(f"the camera stopped answering ({exc})") from exc
            exposure_s = 1e-6 * float(metadata.get("ExposureTime", 0))
            if not self._pending or self._applied(
                exposure_s, metadata.get("AnalogueGain"), metadata.get("ColourGains")
            ):
                self._pending = False
                return rgb, metadata
            frames += 1
            self._settling(frames, exposure_s, metadata.get("AnalogueGain"))

    def limits(self) -> CameraLimits:
        """Exposure and gain ranges from picamera2's ``camera_controls`` (those of the configured mode)."""
        controls = self._picam2.camera_controls
        exposure, gain = controls["ExposureTime"], controls["AnalogueGain"]
        return CameraLimits((float(exposure[0]), float(exposure[1])), (float(gain[0]), float(gain[1])))

    def describe(self) -> dict[str, Any]:
        """Kind ``picamera2``, the sensor model, camera number, raw format, size and bit depth, the sensor mode
        (``WxH:BITS``), the sensor's size and the mode's crop on it, and the ``ScalerCrop`` of the last frame."""
        geometry = self.geometry()
        record = {
            "kind": "picamera2",
            "sensor": self.model,
            "camera_num": self.camera_num,
            "size": list(self._mode["size"]),
            "raw_format": self._raw_format or str(self._mode["unpacked"]),
            "bit_depth": int(self._mode["bit_depth"]),
            "sensor_mode": mode_name(self._mode),
            "sensor_size": list(geometry.sensor_size),
            "crop": list(geometry.crop),
            "tuning": self._tuning_description,
        }
        if self._scaler_crop is not None:
            record["scaler_crop"] = list(self._scaler_crop)
        return record

    def close(self) -> None:
        """Stop and close the camera."""
        try:
            self._picam2.stop()
        finally:
            self._picam2.close()


def picamera2_number(spec: str) -> int | None:
    """The camera number of ``picamera2`` (0) or ``picamera2:N`` named on the command line; None for another kind.

    Raises
    ------
    PicamcalError
        ``N`` is not a whole number.

    Examples
    --------
    >>> picamera2_number("picamera2"), picamera2_number("picamera2:1"), picamera2_number("sim")
    (0, 1, None)
    """
    kind, _, argument = spec.partition(":")
    if kind.strip().lower() != "picamera2":
        return None
    if argument and not argument.isdigit():
        raise PicamcalError(f"camera number {argument!r} is not a whole number (picamera2:0, picamera2:1)")
    return int(argument or 0)
