"""The Raspberry Pi IPA of the virtual camera: the tuning file, auto exposure and white balance, delayed sensor
controls, and each frame's metadata.

It follows libcamera's Raspberry Pi IPA (``src/ipa/rpi/common/ipa_base.cpp``) in what a program sees:

- the tuning file is read once, when the camera is registered (``init``): ``LIBCAMERA_RPI_TUNING_FILE`` if set,
  else the stock file of the sensor for the platform (``src/libcamera/ipa_proxy.cpp`` ``configurationFile``); a
  file of the other platform is refused (``vc4.cpp``/``pisp.cpp`` ``platformInit``);
- ``ExposureTimeMode``/``AnalogueGainMode`` (``AeEnable`` turned into both, ``src/libcamera/camera.cpp``
  ``patchControlList``) fix the exposure time and gain; ``AwbEnable`` and ``ColourGains`` (non-zero gains mean
  manual) the white balance (``applyControls``); each control applied is echoed in that frame's metadata;
- exposure and gain reach the sensor ``delays`` frames after the IPA decides them (``delayed_controls.cpp``), and
  the metadata reports what the sensor applied, quantised to whole lines and gain codes (``fillDeviceStatus``,
  ``applyAGC``); frame durations follow ``FrameDurationLimits`` clamped to the mode (``applyFrameDurations``);
- the first frames after a cold start are marked "startup" (AGC convergence frames + the helper's mistrusted
  frames), which picamera2 drops (``IpaBase::start``).

The algorithms themselves are simpler than libcamera's: the AGC brings the frame's mean luminance to the tuning's
``y_target`` and divides the exposure along the ``normal`` exposure mode (``rpi.agc``); the AWB makes the frame's
mean grey and reads its colour temperature off ``rpi.awb``'s ``ct_curve``; ``rpi.lux`` gives the lux. Metering and
constraint modes, flicker, HDR and autofocus are not emulated.

Examples
--------
>>> from picamcal.virtualcam.modes import sensor_spec
>>> tuning = load_camera_tuning(sensor_spec("imx477"), "pisp", environ={})
>>> tuning.path.name, tuning.black_level, round(tuning.y_target, 2)
('imx477.json', 4096.0, 0.16)
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PicamcalError
from ..export.isp import default_ct, tuning_ccm
from ..export.tuning import BUNDLED_TUNING_DIR, load_tuning
from .modes import ModeSpec, SensorSpec

#: The IPA's directories and the target each platform's tuning files name (``ipa_proxy.cpp``, ``platformInit``).
PLATFORM_TARGETS = {"vc4": "bcm2835", "pisp": "pisp"}
TUNING_VARIABLE = "LIBCAMERA_RPI_TUNING_FILE"
# ipa_base.cpp: the sensor's initial settings and the frame duration limits before any control.
DEFAULT_EXPOSURE_US = 20000.0
DEFAULT_MIN_FRAME_US = 1e6 / 30.0
DEFAULT_MAX_FRAME_US = 250e6


class IpaError(PicamcalError):
    """The IPA cannot start: its tuning file is missing, unreadable or for the other platform."""


@dataclass
class CameraTuning:
    """What the IPA reads from a tuning file at registration.

    Attributes
    ----------
    path : Path
    data : dict
        The whole file (for :mod:`picamcal.export.isp`'s lens shading).
    black_level : float
        ``rpi.black_level`` on the 16-bit scale (4096 when the section gives none).
    y_target : float
        The AGC's target mean luminance (``rpi.agc`` ``y_target`` at low lux).
    shutter, gain : list of float
        The ``normal`` exposure mode's stages.
    agc_speed, awb_speed : float
        How far each frame moves towards the new exposure and white balance after the start-up frames.
    startup_frames, agc_convergence_frames, awb_convergence_frames : int
    ct_curve : ndarray, shape (n, 3)
        ``rpi.awb`` ``ct_curve`` as (ct, r/g, b/g) rows, or empty.
    lux : (shutter, gain, lux, Y) or None
        ``rpi.lux``'s reference.
    gamma : (x, y) arrays on 0..1, or None
        ``rpi.contrast`` ``gamma_curve``.
    """

    path: Path
    data: dict[str, Any]
    black_level: float = 4096.0
    y_target: float = 0.16
    shutter: list[float] = field(default_factory=lambda: [100.0, 10000.0, 30000.0, 60000.0, 66666.0])
    gain: list[float] = field(default_factory=lambda: [1.0, 2.0, 4.0, 6.0, 8.0])
    agc_speed: float = 0.2
    awb_speed: float = 0.05
    startup_frames: int = 10
    agc_convergence_frames: int = 6
    awb_convergence_frames: int = 3
    ct_curve: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    lux: tuple[float, float, float, float] | None = None
    gamma: tuple[np.ndarray, np.ndarray] | None = None

    def section(self, name: str) -> dict[str, Any] | None:
        """An algorithm's parameters, or None."""
        for algorithm in self.data.get("algorithms", []):
            if name in algorithm:
                return algorithm[name]
        return None


def tuning_path(spec: SensorSpec, platform: str, environ: Mapping[str, str] | None = None) -> Path:
    """The tuning file libcamera loads for the sensor: ``LIBCAMERA_RPI_TUNING_FILE``, else the stock file.

    Examples
    --------
    >>> from picamcal.virtualcam.modes import sensor_spec
    >>> tuning_path(sensor_spec("imx219"), "vc4", environ={}).parts[-2:]
    ('vc4', 'imx219.json')
    >>> str(tuning_path(sensor_spec("imx219"), "vc4", environ={"LIBCAMERA_RPI_TUNING_FILE": "/tmp/t.json"}))
    '/tmp/t.json'
    """
    environ = os.environ if environ is None else environ
    given = environ.get(TUNING_VARIABLE, "")
    if given:
        return Path(given)
    return BUNDLED_TUNING_DIR / platform / f"{spec.name}.json"


def load_camera_tuning(spec: SensorSpec, platform: str, environ: Mapping[str, str] | None = None) -> CameraTuning:
    """Read the tuning file for a camera as the IPA does when the camera is registered.

    Raises
    ------
    IpaError
        The file is missing or not a tuning file libcamera reads (the reason, as :func:`load_tuning` gives it),
        or names the other platform's target (libcamera's own message).
    """
    path = tuning_path(spec, platform, environ)
    if not path.exists() and TUNING_VARIABLE not in (os.environ if environ is None else environ):
        raise IpaError(f"Configuration file '{spec.name}.json' not found for IPA module 'rpi/{platform}'")
    try:
        data = load_tuning(path)
    except PicamcalError as exc:
        raise IpaError(f"Failed to load tuning data file {path} ({exc.problem})") from None
    target = PLATFORM_TARGETS[platform]
    if data.get("target") != target:
        raise IpaError(f'Tuning data file target returned "{data.get("target")}", expected "{target}"')
    tuning = CameraTuning(path, data)
    _read_sections(tuning)
    return tuning


def _pairs(values: Any) -> tuple[np.ndarray, np.ndarray] | None:
    array = np.asarray(values, dtype=np.float64).ravel()
    if array.size < 2 or array.size % 2:
        return None
    return array[0::2], array[1::2]


def _read_sections(tuning: CameraTuning) -> None:
    """Fill the algorithm parameters from the file's sections (libcamera's defaults where a key is absent)."""
    black = tuning.section("rpi.black_level")
    if black is not None:
        tuning.black_level = float(black.get("black_level", 4096))
    agc = tuning.section("rpi.agc")
    if agc is not None:
        channel = agc["channels"][0] if isinstance(agc.get("channels"), list) and agc["channels"] else agc
        target = _pairs(channel.get("y_target", []))
        if target is not None:
            tuning.y_target = float(target[1][0])
        normal = channel.get("exposure_modes", {}).get("normal", {})
        if normal.get("shutter") and normal.get("gain"):
            tuning.shutter = [float(v) for v in normal["shutter"]]
            tuning.gain = [float(v) for v in normal["gain"]]
        tuning.agc_speed = float(channel.get("speed", 0.2))
        tuning.startup_frames = int(channel.get("startup_frames", 10))
        tuning.agc_convergence_frames = int(channel.get("convergence_frames", 6))
    awb = tuning.section("rpi.awb")
    if awb is not None:
        curve = np.asarray(awb.get("ct_curve", []), dtype=np.float64).ravel()
        if curve.size >= 6 and curve.size % 3 == 0:
            tuning.ct_curve = curve.reshape(-1, 3)
        tuning.awb_speed = float(awb.get("speed", 0.05))
        tuning.awb_convergence_frames = int(awb.get("convergence_frames", 3))
    lux = tuning.section("rpi.lux")
    if lux is not None and all(k in lux for k in ("reference_shutter_speed", "reference_gain", "reference_Y")):
        tuning.lux = (
            float(lux["reference_shutter_speed"]),
            float(lux["reference_gain"]),
            float(lux.get("reference_lux", 1000)),
            float(lux["reference_Y"]),
        )
    contrast = tuning.section("rpi.contrast")
    if contrast is not None and "gamma_curve" in contrast:
        gamma = _pairs(contrast["gamma_curve"])
        if gamma is not None:
            tuning.gamma = (gamma[0] / 65535.0, gamma[1] / 65535.0)


@dataclass
class FrameSettings:
    """What the sensor applied to one frame: exposure lines, gain code and frame length in lines."""

    exposure_lines: int
    gain_code: int
    frame_lines: int
    digital_gain: float = 1.0


@dataclass
class ModeTiming:
    """A configured mode's timing limits (``IpaBase::setMode``)."""

    mode: ModeSpec
    spec: SensorSpec

    @property
    def line_us(self) -> float:
        return self.mode.line_time_us

    @property
    def min_frame_us(self) -> float:
        return self.mode.min_frame_lines * self.line_us

    @property
    def max_frame_us(self) -> float:
        return self.spec.max_frame_lines * self.line_us

    @property
    def min_exposure_us(self) -> float:
        return self.spec.exposure_min_lines * self.line_us

    @property
    def max_exposure_us(self) -> float:
        return (self.spec.max_frame_lines - self.spec.integration_diff) * self.line_us


class Ipa:
    """One camera's IPA: the algorithms' state between frames, and the sensor's delayed controls.

    Parameters
    ----------
    spec : SensorSpec
    tuning : CameraTuning
    """

    def __init__(self, spec: SensorSpec, tuning: CameraTuning) -> None:
        self.spec, self.tuning = spec, tuning
        self.timing: ModeTiming | None = None
        self.first_start = True
        self.fixed_exposure_us = 0.0
        self.fixed_gain = 0.0
        self.auto_exposure = self.auto_gain = True
        self.ev = 1.0
        self.awb_auto = True
        self.manual_gains = (0.0, 0.0)
        self.ccm_override: np.ndarray | None = None
        self.saturation = 1.0
        self.frame_limits_us = (DEFAULT_MIN_FRAME_US, DEFAULT_MAX_FRAME_US)
        self.total_exposure = 0.0
        self.exposure_us, self.gain, self.digital_gain = DEFAULT_EXPOSURE_US, 1.0, 1.0
        self.awb_gains = (1.0, 1.0)
        self.ct = default_ct(tuning.data)
        self.locked = False
        self.frame_count = 0
        self.pending: list[tuple[int, str, float]] = []  # (first frame, control, value)
        self.sensor = FrameSettings(0, 0, 0)
        self.echo: dict[str, Any] = {}
        sync = tuning.section("rpi.sync")
        self.sync_available = sync is not None
        self.sync_ready_frame = int((sync or {}).get("ready_frame", 100))  # sync.cpp kDefaultReadyFrame
        self.sync_mode, self.sync_count = 0, 0

    # -- configuration ------------------------------------------------------------------------------------------
    def configure(self, mode: ModeSpec) -> None:
        """Take a mode (``IpaBase::configure``): the limits, and the default settings on the very first one."""
        self.timing = ModeTiming(mode, self.spec)
        if self.first_start:
            self._apply_frame_durations(*self.frame_limits_us)
        settings = self._sensor_settings(self.exposure_us, self.gain)
        self.sensor = settings

    def control_limits(self) -> dict[str, tuple[Any, Any, Any]]:
        """The (min, max, default) the IPA gives the mode's exposure, gain and frame duration controls."""
        timing = self._timing()
        gains = self.spec.gain_range
        return {
            "ExposureTime": (int(timing.min_exposure_us), int(timing.max_exposure_us), int(DEFAULT_EXPOSURE_US)),
            "AnalogueGain": (gains[0], gains[1], 1.0),
            "FrameDurationLimits": (
                int(timing.min_frame_us),
                int(timing.max_frame_us),
                (int(DEFAULT_MIN_FRAME_US), int(DEFAULT_MIN_FRAME_US)),
            ),
        }

    def _timing(self) -> ModeTiming:
        if self.timing is None:
            raise RuntimeError("the IPA has no sensor mode: configure the camera first")
        return self.timing

    # -- controls -----------------------------------------------------------------------------------------------
    def apply_controls(self, controls: Mapping[str, Any]) -> None:
        """``applyControls``: the request's controls, echoed in this frame's metadata."""
        self.echo = {}
        if "AeEnable" in controls:
            on = bool(controls["AeEnable"])
            controls = {"ExposureTimeMode": int(not on), "AnalogueGainMode": int(not on), **controls}
        # Turning an algorithm off freezes what it last chose (agc_channel.cpp disableAuto*, awb.cpp disableAuto).
        if "ExposureTimeMode" in controls:
            self.auto_exposure = int(controls["ExposureTimeMode"]) == 0
            self.fixed_exposure_us = 0.0 if self.auto_exposure else self.exposure_us
            self.echo["ExposureTimeMode"] = int(controls["ExposureTimeMode"])
        if "AnalogueGainMode" in controls:
            self.auto_gain = int(controls["AnalogueGainMode"]) == 0
            self.fixed_gain = 0.0 if self.auto_gain else self.gain
            self.echo["AnalogueGainMode"] = int(controls["AnalogueGainMode"])
        if "AwbEnable" in controls:
            self.awb_auto = bool(controls["AwbEnable"])
            if not self.awb_auto:
                self.manual_gains = self.awb_gains
            self.echo["AwbEnable"] = self.awb_auto
        if "ColourGains" in controls:
            red, blue = (float(v) for v in controls["ColourGains"])
            self.manual_gains = (red, blue)
            if red and blue:
                self.awb_auto = False
                self.echo["ColourGains"] = (red, blue)
            else:
                self.awb_auto = True
        if "ExposureTime" in controls and not self.auto_exposure:
            self.fixed_exposure_us = float(controls["ExposureTime"])
            self.echo["ExposureTime"] = int(controls["ExposureTime"])
        if "AnalogueGain" in controls and not self.auto_gain:
            self.fixed_gain = float(controls["AnalogueGain"])
            self.echo["AnalogueGain"] = float(controls["AnalogueGain"])
        if "ExposureValue" in controls:
            self.ev = 2.0 ** float(controls["ExposureValue"])
            self.echo["ExposureValue"] = float(controls["ExposureValue"])
        if "ColourCorrectionMatrix" in controls and not self.awb_auto:
            self.ccm_override = np.asarray(controls["ColourCorrectionMatrix"], dtype=np.float64).reshape(3, 3)
        if "Saturation" in controls:
            self.saturation = float(controls["Saturation"])
        if "FrameDurationLimits" in controls:
            low, high = (float(v) for v in controls["FrameDurationLimits"])
            self._apply_frame_durations(low, high)
        if "SyncMode" in controls and self.sync_available:
            self.sync_mode, self.sync_count = int(controls["SyncMode"]), 0
        if "SyncFrames" in controls and int(controls["SyncFrames"]) > 0:
            self.sync_ready_frame = int(controls["SyncFrames"])
        if self.awb_auto:
            self.ccm_override = None

    def _apply_frame_durations(self, low: float, high: float) -> None:
        """``applyFrameDurations``: clamped to the mode, echoed."""
        timing = self._timing() if self.timing else None
        low = low or DEFAULT_MIN_FRAME_US
        high = high or DEFAULT_MAX_FRAME_US
        if timing is not None:
            low = min(max(low, timing.min_frame_us), timing.max_frame_us)
            high = min(max(high, timing.min_frame_us), timing.max_frame_us)
        high = max(high, low)
        self.frame_limits_us = (low, high)
        self.echo["FrameDurationLimits"] = (int(low), int(high))

    # -- start ----------------------------------------------------------------------------------------------------
    def start(self, controls: Mapping[str, Any]) -> tuple[int, int]:
        """``IpaBase::start``: apply the start controls, set the sensor now; return (startup frames, invalid frames)."""
        if controls:
            self.apply_controls(controls)
        self.frame_count = 0
        self.pending = []
        if self.fixed_exposure_us and not self.auto_exposure:
            self.exposure_us = self.fixed_exposure_us
        if self.fixed_gain and not self.auto_gain:
            self.gain = self.fixed_gain
        self.total_exposure = self.exposure_us * self.gain
        self.sensor = self._sensor_settings(self.exposure_us, self.gain)
        startup = invalid = 0
        if self.first_start:
            invalid = self.spec.hide_frames_startup
            mistrust = self.spec.mistrust_frames_startup
            agc = 0 if (not self.auto_exposure and not self.auto_gain) else self.tuning.agc_convergence_frames
            awb = self.tuning.awb_convergence_frames if self.awb_auto else 0
            startup = max(agc + mistrust if agc else 0, awb + mistrust if awb else 0)
        self.first_start = False
        return startup, invalid

    def _sensor_settings(self, exposure_us: float, gain: float) -> FrameSettings:
        """``applyAGC`` and ``getBlanking``: whole lines within the frame length limits, a gain code in range."""
        timing = self._timing()
        spec = self.spec
        low, high = self.frame_limits_us
        min_lines = max(math.floor(low / timing.line_us), timing.mode.min_frame_lines)
        max_lines = min(max(math.floor(high / timing.line_us), min_lines), spec.max_frame_lines)
        lines = max(int(exposure_us / timing.line_us), spec.exposure_min_lines)
        frame = min(max(lines + spec.integration_diff, min_lines), max_lines)
        lines = min(lines, frame - spec.integration_diff)
        code = min(max(spec.gain_code(max(gain, 1e-6)), spec.gain_codes[0]), spec.gain_codes[1])
        return FrameSettings(lines, code, frame)

    # -- per frame ------------------------------------------------------------------------------------------------
    def settings_for(self, sequence: int) -> FrameSettings:
        """The sensor's settings for frame ``sequence``: every pending write whose frame has come is applied."""
        due = [p for p in self.pending if p[0] <= sequence]
        self.pending = [p for p in self.pending if p[0] > sequence]
        for _, name, value in due:
            setattr(self.sensor, name, value if name == "digital_gain" else int(value))
        return FrameSettings(self.sensor.exposure_lines, self.sensor.gain_code, self.sensor.frame_lines)

    def exposure_of(self, settings: FrameSettings) -> tuple[float, float, float]:
        """Exposure time (µs), analogue gain and frame duration (µs) of applied settings."""
        line = self._timing().line_us
        return settings.exposure_lines * line, self.spec.gain(settings.gain_code), settings.frame_lines * line

    def colour_gains(self) -> tuple[float, float]:
        """The white balance gains the ISP applies now."""
        return self.awb_gains if self.awb_auto else self.manual_gains

    def ccm(self) -> np.ndarray:
        """The colour matrix at the current colour temperature, with the saturation applied (``rpi.ccm``)."""
        if self.ccm_override is not None:
            matrix = self.ccm_override
        else:
            found = tuning_ccm(self.tuning.data, self.ct)
            matrix = np.eye(3) if found is None else found
        if self.saturation != 1.0:
            to_ycc = np.array([[0.299, 0.587, 0.114], [-0.169, -0.331, 0.5], [0.5, -0.419, -0.081]])
            matrix = np.linalg.inv(to_ycc) @ np.diag([1.0, self.saturation, self.saturation]) @ to_ycc @ matrix
        return matrix

    def sync_status(self, frame_us: float) -> dict[str, Any]:
        """The software sync algorithm's metadata (``rpi.sync``, ``sync.cpp``): a server alone is ready at its
        ready frame; a client never hears a server here, so it is never ready."""
        if not self.sync_mode:
            return {}
        if self.sync_mode == 1:
            self.sync_count += 1
            remaining = self.sync_ready_frame - self.sync_count
            return {"SyncReady": remaining <= 0, "SyncTimer": int(remaining * frame_us)}
        return {"SyncReady": False}

    def process(self, sequence: int, settings: FrameSettings, means: tuple[float, float, float]) -> None:
        """``processStats``: the AWB and AGC on one frame's statistics, then the sensor writes they ask for.

        ``means`` are the frame's mean red, green and blue (linear, black subtracted, lens shading applied, before
        the white balance), on 0..1.
        """
        self.frame_count += 1
        startup = self.frame_count <= self.tuning.startup_frames
        red, green, blue = (max(float(m), 1e-6) for m in means)
        if self.awb_auto:
            target = (green / red, green / blue)
            speed = 1.0 if startup else self.tuning.awb_speed
            self.awb_gains = tuple(  # type: ignore[assignment]
                old + speed * (new - old) for old, new in zip(self.awb_gains, target, strict=True)
            )
        gain_r, gain_b = self.colour_gains()
        self.ct = self._colour_temperature(gain_r, gain_b)
        exposure_us, gain, _ = self.exposure_of(settings)
        luminance = luminance_of(means, (gain_r, gain_b))
        target_y = self.tuning.y_target * self.ev
        current = exposure_us * gain * settings.digital_gain
        wanted = current * target_y / max(luminance * settings.digital_gain, 1e-6)
        speed = 1.0 if startup else self.tuning.agc_speed
        self.total_exposure = (self.total_exposure or current) + speed * (wanted - (self.total_exposure or current))
        self.locked = abs(luminance * settings.digital_gain / target_y - 1) < 0.05
        exposure_us, gain = self._divide(self.total_exposure)
        self.exposure_us, self.gain = exposure_us, gain
        new = self._sensor_settings(exposure_us, gain)
        applied = new.exposure_lines * self._timing().line_us * self.spec.gain(new.gain_code)
        self.digital_gain = max(1.0, self.total_exposure / applied) if self.auto_exposure or self.auto_gain else 1.0
        delays = self.spec.delays
        for name, value, delay in (
            ("exposure_lines", new.exposure_lines, delays[0]),
            ("gain_code", new.gain_code, delays[1]),
            ("frame_lines", new.frame_lines, delays[2]),
            ("digital_gain", self.digital_gain, delays[0]),
        ):
            self.pending.append((sequence + 1 + delay, name, value))

    def _divide(self, total: float) -> tuple[float, float]:
        """Split a total exposure (µs x gain) into exposure time and analogue gain along the exposure mode's stages
        (libcamera's ``AgcChannel::divideUpExposure``), honouring fixed values and the limits."""
        timing = self._timing()
        low_gain, high_gain = self.spec.gain_range
        max_exposure = min(
            timing.max_exposure_us, self.frame_limits_us[1] - self.spec.integration_diff * timing.line_us
        )
        fixed_exposure = None if self.auto_exposure else (self.fixed_exposure_us or self.exposure_us)
        fixed_gain = None if self.auto_gain else (self.fixed_gain or self.gain)
        if fixed_exposure is not None and fixed_gain is not None:
            return fixed_exposure, fixed_gain
        if fixed_exposure is not None:
            return fixed_exposure, min(max(total / fixed_exposure, low_gain), high_gain)
        if fixed_gain is not None:
            return min(max(total / fixed_gain, timing.min_exposure_us), max_exposure), fixed_gain
        shutter, gains = self.tuning.shutter, self.tuning.gain
        exposure, gain = shutter[0], gains[0]
        if total > shutter[0] * gains[0]:
            for stage in range(1, len(shutter)):
                if total <= shutter[stage] * gains[stage - 1]:
                    exposure, gain = total / gains[stage - 1], gains[stage - 1]
                    break
                exposure = shutter[stage]
                if total <= shutter[stage] * gains[stage]:
                    gain = total / shutter[stage]
                    break
                gain = gains[stage]
            else:
                gain = total / exposure
        else:
            exposure = total / gain
        exposure = min(max(exposure, timing.min_exposure_us), max_exposure)
        gain = min(max(total / exposure, low_gain), high_gain)
        return exposure, gain

    def _colour_temperature(self, gain_r: float, gain_b: float) -> float:
        """The ``ct_curve`` point nearest the white's (r/g, b/g) = (1/gain_r, 1/gain_b)."""
        curve = self.tuning.ct_curve
        if len(curve) < 2:
            return default_ct(self.tuning.data)
        cts = np.linspace(curve[0, 0], curve[-1, 0], 256)
        r = np.interp(cts, curve[:, 0], curve[:, 1])
        b = np.interp(cts, curve[:, 0], curve[:, 2])
        index = int(np.argmin((r - 1 / gain_r) ** 2 + (b - 1 / gain_b) ** 2))
        return float(cts[index])

    def metadata(self, settings: FrameSettings, means: tuple[float, float, float]) -> dict[str, Any]:
        """``reportMetadata``: what the frame's request carries back (names of libcamera's controls)."""
        exposure_us, gain, frame_us = self.exposure_of(settings)
        gain_r, gain_b = self.colour_gains()
        black = round(self.tuning.black_level)
        metadata: dict[str, Any] = {
            **self.echo,
            **self.sync_status(frame_us),
            "ExposureTime": int(exposure_us),
            "AnalogueGain": gain,
            "FrameDuration": int(frame_us),
            "DigitalGain": settings.digital_gain,
            "ColourGains": (gain_r, gain_b),
            "ColourTemperature": int(self.ct),
            "SensorBlackLevels": (black, black, black, black),
            "ColourCorrectionMatrix": tuple(float(v) for v in self.ccm().ravel()),
            "AeState": 0 if not (self.auto_exposure or self.auto_gain) else (2 if self.locked else 1),
        }
        if self.tuning.lux is not None:
            # rpi.lux: lux scales with the frame's luminance (on a 16-bit scale) over the exposure.
            shutter, ref_gain, ref_lux, ref_y = self.tuning.lux
            y = max(luminance_of(means, (gain_r, gain_b)) * 65536.0, 1.0)
            metadata["Lux"] = ref_lux * (shutter * ref_gain) / max(exposure_us * gain, 1e-3) * y / ref_y
        return metadata


def luminance_of(means: tuple[float, float, float], gains: tuple[float, float]) -> float:
    """The mean luminance (Rec.601 weights) of white-balanced linear means.

    Examples
    --------
    >>> round(luminance_of((0.1, 0.2, 0.2), (2.0, 1.0)), 3)
    0.2
    """
    red, green, blue = means
    return 0.299 * red * gains[0] + 0.587 * green + 0.114 * blue * gains[1]
