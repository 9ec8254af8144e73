"""Cameras behind one small interface: the Raspberry Pi camera through picamera2, and the simulator.

:class:`~picamcal.acquire.base.Camera` is what the acquisition (:mod:`picamcal.acquire.acquisition`) needs of a
camera: a raw stream in one sensor mode (the full-resolution one by default), explicit exposure time, analogue gain
and colour gains (so nothing adapts), and unpacked raw frames with their metadata.
:class:`~picamcal.acquire.pi_camera.Picamera2Camera` is a thin adapter over picamera2 (in
:mod:`picamcal.acquire.pi_camera`, re-exported here), which also gives the processed stream of any sensor mode (what
``picamcal verify`` measures, :mod:`picamcal.acquire.verify`); :class:`SimCamera` serves frames from
:mod:`picamcal.simulate`, lit by a :class:`~picamcal.acquire.illuminators.SimIlluminator`, so the same acquisition
code runs and is tested everywhere. :func:`open_camera` opens either from its command-line name.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..errors import PicamcalError
from ..raw.model import RawImage
from ..references import ROLES
from ..simulate import SimulatedCamera, make_camera, render
from .base import Camera, CameraError, CameraLimits
from .illuminators import REFERENCE_LIGHTS, SimIlluminator

# The Raspberry Pi camera's adapter and its helpers, at the paths they had before they moved to pi_camera.
from .pi_camera import GAIN_STEP as GAIN_STEP
from .pi_camera import Picamera2Camera, picamera2_number
from .pi_camera import check_tuning_target as check_tuning_target
from .pi_camera import list_cameras as list_cameras
from .pi_camera import picamera2_target as picamera2_target
from .pi_camera import raw_sensor_modes as raw_sensor_modes

__all__ = [
    "Camera",
    "CameraError",
    "CameraLimits",
    "Picamera2Camera",
    "SimCamera",
    "open_camera",
]


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


def open_camera(
    spec: str,
    *,
    sensor: str = "imx219",
    size: tuple[int, int] | None = None,
    seed: int = 0,
    sensor_mode: str | None = None,
) -> Camera:
    """Open a camera named on the command line: ``picamera2`` (or ``picamera2:N``) or ``sim``.

    Parameters
    ----------
    spec : str
        ``picamera2[:N]`` for camera N of the Pi (default 0), ``sim`` for the simulator.
    sensor, size, seed
        For ``sim`` only: as :class:`SimCamera`.
    sensor_mode : str, optional
        For ``picamera2`` only: the sensor mode ``WIDTHxHEIGHT[:BITS]`` (:class:`Picamera2Camera`).

    Raises
    ------
    PicamcalError
        An unknown kind, or a sensor mode for the simulator; :class:`CameraError` when the camera cannot be opened.

    Examples
    --------
    >>> open_camera("sim", size=(64, 48)).describe()["size"]
    [64, 48]
    """
    number = picamera2_number(spec)
    if number is not None:
        return Picamera2Camera(number, sensor_mode=sensor_mode)
    kind, _, argument = spec.partition(":")
    if kind.strip().lower() == "sim" and not argument:
        if sensor_mode is not None:
            raise PicamcalError(
                "--sensor-mode chooses a mode of a Raspberry Pi camera (--camera picamera2); the simulated camera "
                "takes --size"
            )
        return SimCamera(sensor, size=size, seed=seed)
    raise PicamcalError(f"unknown camera {spec!r} (expected picamera2, picamera2:N or sim)")
