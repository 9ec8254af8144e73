"""Cameras behind one small interface: the Raspberry Pi camera through picamera2, and the simulator.

:class:`Camera` is what the acquisition (:mod:`picamcal.acquire.acquisition`) needs of a camera: a raw stream
in one sensor mode (the full-resolution one by default), explicit exposure time, analogue gain and colour gains (so
nothing adapts), and unpacked raw frames with their metadata. :class:`Picamera2Camera` is a thin adapter over
picamera2 (an optional extra for the Pi, imported only when used), which also gives the processed stream of any
sensor mode (what ``picamcal verify`` measures, :mod:`picamcal.acquire.verify`); :class:`SimCamera` serves frames
from :mod:`picamcal.simulate`, lit by a
:class:`~picamcal.acquire.illuminators.SimIlluminator`, so the same acquisition code runs and is tested
everywhere.
"""

from __future__ import annotations

import concurrent.futures
import json
import math
import os
import subprocess
import sys
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..errors import PicamcalError, PicamcalWarning
from ..export.tuning import TARGET_NAMES, TuningError, load_tuning, neutral_tuning, stock_tuning_path
from ..geometry import SensorMode, parse_sensor_mode
from ..raw.model import RawImage
from ..raw.picamera2 import capture_raw
from ..references import ROLES
from ..simulate import SimulatedCamera, make_camera, render
from .illuminators import REFERENCE_LIGHTS, SimIlluminator

__all__ = [
    "Camera",
    "CameraError",
    "CameraLimits",
    "Picamera2Camera",
    "SimCamera",
    "open_camera",
]


#: The coarsest analogue gain step of the sensors picamera2 drives, at any gain (the OV5647's 1/16).
GAIN_STEP = 1 / 16


class CameraError(PicamcalError):
    """The camera cannot be found, configured or read."""


@dataclass(frozen=True)
class CameraLimits:
    """The ranges of the camera's exposure controls.

    Attributes
    ----------
    exposure_time_us : (float, float)
        Shortest and longest exposure time in microseconds.
    analogue_gain : (float, float)
        Lowest and highest analogue gain.
    """

    exposure_time_us: tuple[float, float]
    analogue_gain: tuple[float, float]


class Camera(Protocol):
    """A camera the acquisition can drive: raw frames at frozen settings.

    Implementations: :class:`Picamera2Camera` (the Pi) and :class:`SimCamera` (the simulator).
    """

    def configure_raw(self) -> None:
        """Set up an unpacked raw stream at full sensor size with a neutral pipeline, and start the camera."""

    def set_controls(
        self, exposure_time_us: float, analogue_gain: float, colour_gains: tuple[float, float] | None = None
    ) -> None:
        """Fix the exposure time (µs), analogue gain and (when given) the red and blue colour gains."""

    def capture(self) -> RawImage:
        """One raw frame at the current settings (unpacked, full sensor), with its metadata."""

    def limits(self) -> CameraLimits:
        """The exposure time and gain ranges."""

    def describe(self) -> dict[str, Any]:
        """A JSON-serialisable description with at least ``kind``, ``sensor`` and ``size``."""

    def close(self) -> None:
        """Stop the camera and release it."""


class SimCamera:
    """A simulated camera that renders raw frames of the light a :class:`SimIlluminator` gives.

    The signal is linear in the light, the exposure time and the analogue gain, and clips at the white
    level, so auto-exposure works as on a real camera. At exposure time ``t`` µs and gain ``g`` the frame is
    ``render(make_camera(sensor, size=size, tilt=tilt, exposure=f), light)`` with the exposure fraction
    ``f = brightness * t / 10000 * g`` (:meth:`exposure_fraction`; above 1 the scale is extrapolated and the
    white clips). Each frame's noise comes from a random stream keyed by what the camera sees: stream ``i``
    of ``seed`` for reference ``ROLES[i]`` (:data:`picamcal.references.ROLES`) and the colour-wheel target's
    stream for a placed target, as :func:`~picamcal.simulate.simulate_references` and
    :func:`~picamcal.simulate.simulate_target` draw them.
    So the frames of an acquisition are bit for bit those of the simulator at the same exposure fraction.

    Parameters
    ----------
    sensor : str
        A sensor of the registry.
    size : (int, int), optional
        Frame (width, height); default the full sensor.
    seed : int
        Seed of the noise.
    light : SimIlluminator, optional
        The light the camera sees; a new one (off) by default, at :attr:`light`.
    brightness : float
        Exposure fraction of the brightest noiseless white pixel at the starting 10 ms and gain 1. The
        default 2 clips the white, so the acquisition has to find the exposure itself.
    exposure_limits_us : (float, float)
        Shortest and longest exposure time.
    gain_limits : (float, float)
        Lowest and highest analogue gain.
    noise : bool
        Shot and read noise.
    tilt : (float, float)
        Angle of incidence in degrees, as :func:`~picamcal.simulate.make_camera`.

    Examples
    --------
    >>> camera = SimCamera("imx219", size=(320, 240))
    >>> camera.configure_raw()
    >>> camera.light.set_rgb(255, 255, 255)
    >>> raw = camera.capture()
    >>> raw.bayer.shape, int(raw.bayer.max()) == raw.white_level  # 10 ms is too long for this light
    ((240, 320), True)
    >>> camera.set_controls(4000, 1.0)
    >>> camera.exposure_fraction(4000, 1.0)
    0.8
    """

    REFERENCE_EXPOSURE_US = 10_000.0

    def __init__(
        self,
        sensor: str = "imx219",
        size: tuple[int, int] | None = None,
        seed: int = 0,
        *,
        light: SimIlluminator | None = None,
        brightness: float = 2.0,
        exposure_limits_us: tuple[float, float] = (100.0, 1_000_000.0),
        gain_limits: tuple[float, float] = (1.0, 16.0),
        noise: bool = True,
        tilt: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        if not brightness > 0:
            raise PicamcalError(f"the simulated light's brightness must be positive, got {brightness}")
        self._unit = make_camera(sensor, size=size, tilt=tilt, exposure=1.0)
        self.seed = int(seed)
        self.light = SimIlluminator() if light is None else light
        self.brightness = float(brightness)
        self._limits = CameraLimits(
            (float(exposure_limits_us[0]), float(exposure_limits_us[1])),
            (float(gain_limits[0]), float(gain_limits[1])),
        )
        self.noise = bool(noise)
        self.exposure_time_us = int(self.REFERENCE_EXPOSURE_US)
        self.analogue_gain = 1.0
        self.colour_gains: tuple[float, float] | None = None
        self.placed: tuple[str, np.ndarray] | None = None
        self._configured = False
        self._cameras: dict[float, SimulatedCamera] = {}

    def configure_raw(self) -> None:
        """Nothing to configure: the simulator's frames are the full (simulated) sensor, unpacked."""
        self._configured = True

    def set_controls(
        self, exposure_time_us: float, analogue_gain: float, colour_gains: tuple[float, float] | None = None
    ) -> None:
        """Set the exposure time (rounded to whole µs, as the Pi does), gain and colour gains, within the limits."""
        (t_min, t_max), (g_min, g_max) = self._limits.exposure_time_us, self._limits.analogue_gain
        if not (t_min <= exposure_time_us <= t_max and g_min <= analogue_gain <= g_max):
            raise CameraError(
                f"exposure {exposure_time_us} µs at gain {analogue_gain} is outside the camera's range "
                f"({t_min:g}-{t_max:g} µs, gain {g_min:g}-{g_max:g})"
            )
        self.exposure_time_us = round(exposure_time_us)
        self.analogue_gain = float(analogue_gain)
        if colour_gains is not None:
            self.colour_gains = (float(colour_gains[0]), float(colour_gains[1]))

    def exposure_fraction(self, exposure_time_us: float, analogue_gain: float) -> float:
        """The :func:`~picamcal.simulate.make_camera` exposure these settings give under white light.

        Examples
        --------
        >>> SimCamera(size=(64, 48), brightness=2.0).exposure_fraction(5000, 1.5)
        1.5
        """
        return self.brightness * exposure_time_us / self.REFERENCE_EXPOSURE_US * analogue_gain

    def simulated_camera(self) -> SimulatedCamera:
        """The simulator's camera at the current settings (what :func:`~picamcal.simulate.render` is given)."""
        fraction = self.exposure_fraction(self.exposure_time_us, self.analogue_gain)
        if fraction not in self._cameras:
            unit = self._unit
            if fraction <= 1:
                camera = make_camera(unit.sensor, size=(unit.width, unit.height), tilt=unit.tilt, exposure=fraction)
            else:
                camera = replace(unit, scale=unit.scale * fraction)
            self._cameras = {fraction: camera}  # settings rarely go back: keep the last one only
        return self._cameras[fraction]

    def place(self, scene: np.ndarray | None, name: str = "target") -> None:
        """Put a transmission target (H, W, 3 per primary, 0-1) in the light path, or take it away (None)."""
        if scene is None:
            self.placed = None
            return
        scene = np.asarray(scene, dtype=np.float32)
        if scene.shape != (self._unit.height, self._unit.width, 3):
            raise PicamcalError(
                f"a target must have shape ({self._unit.height}, {self._unit.width}, 3), got {scene.shape}"
            )
        self.placed = (name, scene)

    def capture(self) -> RawImage:
        """Render one frame of the current light (and placed target) at the current settings."""
        if not self._configured:
            raise CameraError("the camera is not configured: call configure_raw() first")
        camera = self.simulated_camera()
        amounts, role = self.light.amounts, _ROLE_OF_LIGHT.get(self.light.rgb)
        if self.placed is None:
            scene: Any = amounts
            key: tuple[int, ...] = (ROLES.index(role),) if role else (_OTHER_STREAM, *self.light.rgb)
        else:
            scene = self.placed[1] * amounts
            key = (_TARGET_STREAM,) if role == "white" else (_OTHER_STREAM, *self.light.rgb)
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=key))
        raw = render(camera, scene, noise=self.noise, rng=rng)
        if self.placed is not None:
            raw.metadata["scene"] = self.placed[0]
        raw.metadata.update(exposure_time_s=self.exposure_time_us * 1e-6, analogue_gain=self.analogue_gain)
        if self.colour_gains is not None:
            raw.metadata["colour_gains"] = list(self.colour_gains)
        return raw

    def limits(self) -> CameraLimits:
        """The simulated exposure and gain ranges."""
        return self._limits

    def describe(self) -> dict[str, Any]:
        """Kind ``sim``, sensor, size, pattern, seed, brightness, noise and tilt."""
        unit = self._unit
        return {
            "kind": "sim",
            "sensor": unit.sensor,
            "size": [unit.width, unit.height],
            "pattern": unit.pattern,
            "seed": self.seed,
            "brightness": self.brightness,
            "noise": self.noise,
            "tilt": list(unit.tilt),
        }

    def close(self) -> None:
        """Nothing to release."""
        self._configured = False


# Random streams of SimCamera frames; the first len(ROLES) + 2 are those of simulate_references (one per
# reference, in ROLES order) and simulate_target (after the dust stream), the others are keyed by the LED setting.
_TARGET_STREAM = len(ROLES) + 1
_OTHER_STREAM = len(ROLES) + 2
_ROLE_OF_LIGHT = {rgb: role for role, rgb in REFERENCE_LIGHTS.items()}


def _import_picamera2() -> Any:
    try:
        import picamera2
    except ImportError:
        raise CameraError(
            "picamera2 is not installed: on a Raspberry Pi install picamcal[pi] (or apt install python3-picamera2)"
        ) from None
    return picamera2


class _Flushed:
    """A Picamera2 whose ``capture_request`` waits, at most ``timeout`` s, for a frame begun after the call."""

    def __init__(self, picam2: Any, timeout: float) -> None:
        self._picam2 = picam2
        self._timeout = timeout
        self.camera_properties = picam2.camera_properties

    def camera_configuration(self) -> Any:
        return self._picam2.camera_configuration()

    def capture_request(self) -> Any:
        job = self._picam2.capture_request(flush=True, wait=False)
        try:
            return self._picam2.wait(job, timeout=self._timeout)
        # picamera2's job is a concurrent.futures.Future: its timeout is not the built-in TimeoutError before 3.11.
        except (TimeoutError, concurrent.futures.TimeoutError):
            raise CameraError(f"the camera sent no frame within {self._timeout:.0f} s: it stopped answering") from None


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
    On a Raspberry Pi 5 with the HQ camera (docs/virtual-camera.md runs it on the virtual camera):

    >>> [camera["Model"] for camera in list_cameras()]  # doctest: +SKIP
    ['imx477']
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
    picamcal.acquire.cameras.CameraError: tuning.json is for a Raspberry Pi 5 (target pisp), but this is a \
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


class Picamera2Camera:
    """A Raspberry Pi camera through picamera2, with a neutral pipeline and frozen settings.

    Opening it loads the sensor's stock tuning made neutral (:func:`picamcal.export.tuning.neutral_tuning`,
    as editing tuning files is the exporter's business) unless given a tuning, and picks the full-sensor mode
    of the highest bit depth; :meth:`configure_raw` asks for that mode's unpacked raw format (the Pi 5 grants
    ``S<order>16``; its lossy ``PISP_COMP1`` is refused). Each capture waits for a
    frame that began exposing after the call and carries the requested exposure and gain; a camera that
    sends no frame for 5 s plus three exposures has stopped answering.

    Parameters
    ----------
    camera_num : int
        Which camera (``Picamera2.global_camera_info()`` order).
    tuning : dict, optional
        The libcamera tuning to open the camera with, as given (``picamcal.export.tuning.load_tuning(path)``);
        by default the sensor's stock tuning, made neutral.

    Raises
    ------
    CameraError
        picamera2 is not installed, there is no camera, or it cannot be opened.

    Examples
    --------
    >>> camera = Picamera2Camera()  # doctest: +SKIP
    >>> camera.configure_raw()  # doctest: +SKIP
    >>> camera.set_controls(4000, 1.0, (1.8, 1.6))  # doctest: +SKIP
    >>> raw = camera.capture()  # doctest: +SKIP
    """

    #: Frames to wait for new controls to reach the sensor before giving up.
    MAX_SETTLE_FRAMES = 12

    def __init__(self, camera_num: int = 0, *, tuning: dict[str, Any] | None = None) -> None:
        module = _import_picamera2()
        if tuning is None:
            cameras = list_cameras()
            if not cameras:
                raise CameraError(
                    "no camera found: check the ribbon cable and that rpicam-hello --list-cameras lists the camera"
                )
            if not 0 <= camera_num < len(cameras):
                raise CameraError(f"no camera {camera_num}: {len(cameras)} found (numbered from 0)")
            model = cameras[camera_num].get("Model", "unknown")
            try:  # the file picamera2 finds (Picamera2.load_tuning_file), read by libcamera's rules
                tuning = neutral_tuning(load_tuning(stock_tuning_path(model, picamera2_target(module))))
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
        modes = raw_sensor_modes(list(self._picam2.sensor_modes))
        if not modes:
            self._picam2.close()
            raise CameraError(f"the {self.model} reports no raw sensor mode that picamera2 describes")
        self._mode = max(modes, key=lambda m: (m["size"][0] * m["size"][1], m["bit_depth"]))
        self._raw_format: str | None = None
        self._requested: tuple[int, float] = (10_000, 1.0)
        self._pending = False

    def configure_raw(self) -> None:
        """Configure the full-sensor unpacked raw stream and start the camera."""
        picam2, mode = self._picam2, self._mode
        size = tuple(mode["size"])
        try:
            config = picam2.create_still_configuration(
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
        self._raw_format = str(granted["format"])
        try:
            picam2.start()
        except RuntimeError as exc:
            raise CameraError(f"cannot start the {self.model} ({exc})") from exc

    def set_controls(
        self, exposure_time_us: float, analogue_gain: float, colour_gains: tuple[float, float] | None = None
    ) -> None:
        """Turn off auto-exposure and auto white balance and set the exposure, gain and colour gains."""
        controls: dict[str, Any] = {
            "AeEnable": False,
            "AwbEnable": False,
            "ExposureTime": round(exposure_time_us),
            "AnalogueGain": float(analogue_gain),
        }
        if colour_gains is not None:
            controls["ColourGains"] = (float(colour_gains[0]), float(colour_gains[1]))
        try:
            self._picam2.set_controls(controls)
        except (RuntimeError, ValueError) as exc:
            raise CameraError(f"the camera refused the controls {controls} ({exc})") from exc
        self._requested = (controls["ExposureTime"], controls["AnalogueGain"])
        self._pending = True

    def _applied(self, raw: RawImage) -> bool:
        """True when a frame carries the requested exposure and gain (within the sensor's quantisation)."""
        exposure_us, gain = self._requested
        actual_us = 1e6 * float(raw.metadata.get("exposure_time_s", 0.0))
        actual_gain = float(raw.metadata.get("analogue_gain", 0.0))
        # Exposure is whole sensor lines (tens of µs) and gain a register code: a few % at high gain, and steps of
        # 1/16 on the OV5647, whose code is floor(16 g) (libcamera cam_helper_ov5647.cpp): 1.06 is applied as 1.0.
        return abs(actual_us - exposure_us) <= max(100.0, 0.02 * exposure_us) and math.isclose(
            actual_gain, gain, rel_tol=0.05, abs_tol=GAIN_STEP
        )

    def capture(self) -> RawImage:
        """One raw frame exposed after the call, at the requested settings."""
        if self._raw_format is None:
            raise CameraError("the camera is not configured: call configure_raw() first")
        camera = _Flushed(self._picam2, timeout=5.0 + 3e-6 * self._requested[0])
        try:
            raw = capture_raw(camera)
            frames = 1
            while self._pending and not self._applied(raw):
                if frames >= self.MAX_SETTLE_FRAMES:
                    raise CameraError(
                        f"the camera did not apply exposure {self._requested[0]} µs at gain {self._requested[1]} "
                        f"within {frames} frames (it reports {raw.metadata.get('exposure_time_s')} s, gain "
                        f"{raw.metadata.get('analogue_gain')})"
                    )
                raw = capture_raw(camera)
                frames += 1
        except RuntimeError as exc:
            raise CameraError(f"the camera stopped answering ({exc})") from exc
        self._pending = False
        return raw

    def limits(self) -> CameraLimits:
        """Exposure and gain ranges from picamera2's ``camera_controls``."""
        controls = self._picam2.camera_controls
        exposure, gain = controls["ExposureTime"], controls["AnalogueGain"]
        return CameraLimits((float(exposure[0]), float(exposure[1])), (float(gain[0]), float(gain[1])))

    def describe(self) -> dict[str, Any]:
        """Kind ``picamera2``, the sensor model, camera number, raw format, size and bit depth."""
        return {
            "kind": "picamera2",
            "sensor": self.model,
            "camera_num": self.camera_num,
            "size": list(self._mode["size"]),
            "raw_format": self._raw_format or str(self._mode["unpacked"]),
            "bit_depth": int(self._mode["bit_depth"]),
            "tuning": self._tuning_description,
        }

    def close(self) -> None:
        """Stop and close the camera."""
        try:
            self._picam2.stop()
        finally:
            self._picam2.close()


def open_camera(spec: str, *, sensor: str = "imx219", size: tuple[int, int] | None = None, seed: int = 0) -> Camera:
    """Open a camera named on the command line: ``picamera2`` (or ``picamera2:N``) or ``sim``.

    Parameters
    ----------
    spec : str
        ``picamera2[:N]`` for camera N of the Pi (default 0), ``sim`` for the simulator.
    sensor, size, seed
        For ``sim`` only: as :class:`SimCamera`.

    Raises
    ------
    PicamcalError
        An unknown kind; :class:`CameraError` when the camera cannot be opened.

    Examples
    --------
    >>> open_camera("sim", size=(64, 48)).describe()["size"]
    [64, 48]
    """
    kind, _, argument = spec.partition(":")
    kind = kind.strip().lower()
    if kind == "sim" and not argument:
        return SimCamera(sensor, size=size, seed=seed)
    if kind == "picamera2":
        if argument and not argument.isdigit():
            raise PicamcalError(f"camera number {argument!r} is not a whole number (picamera2:0, picamera2:1)")
        return Picamera2Camera(int(argument or 0))
    raise PicamcalError(f"unknown camera {spec!r} (expected picamera2, picamera2:N or sim)")
