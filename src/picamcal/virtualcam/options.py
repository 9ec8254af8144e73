"""The virtual camera's settings, and how they travel to the program that uses it (environment variables).

Examples
--------
>>> options = Options(platform="vc4", sensor="imx219", size=(640, 480), seed=3)
>>> environment = options.environment()
>>> environment["PICAMCAL_VIRTUAL_CAMERA_SIZE"], Options.from_environment(environment) == options
('640x480', True)
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..errors import PicamcalError
from ..sensors import given_sensor

#: The platforms: a Raspberry Pi 4 (and earlier) and a Raspberry Pi 5, by libcamera's IPA names.
PLATFORMS = ("pisp", "vc4")
#: The environment variables that carry the settings to the program (and its children).
VARIABLES = {
    "platform": "PICAMCAL_VIRTUAL_CAMERA_PLATFORM",
    "sensor": "PICAMCAL_VIRTUAL_CAMERA_SENSOR",
    "size": "PICAMCAL_VIRTUAL_CAMERA_SIZE",
    "seed": "PICAMCAL_VIRTUAL_CAMERA_SEED",
    "scene": "PICAMCAL_VIRTUAL_CAMERA_SCENE",
    "brightness": "PICAMCAL_VIRTUAL_CAMERA_BRIGHTNESS",
}
DEFAULT_SENSOR = "imx477"


class VirtualCameraError(PicamcalError):
    """The virtual camera cannot be set up as asked."""


@dataclass(frozen=True)
class Options:
    """How the virtual camera is set up.

    Attributes
    ----------
    platform : str
        ``pisp`` (Raspberry Pi 5) or ``vc4`` (Raspberry Pi 4 and earlier).
    sensor : str
        A colour sensor of picamcal's registry (default the HQ camera's ``imx477``).
    size : (int, int) or None
        The simulated pixel array, smaller than the sensor's to go faster; None for the full sensor.
    seed : int
        Seed of the noise.
    scene : str
        ``white`` (a white diffuser), ``wheel`` (picamcal's colour-wheel target) or an image file.
    brightness : float
        Exposure fraction of the brightest white pixel at 10 ms and gain 1.
    """

    platform: str = "pisp"
    sensor: str = DEFAULT_SENSOR
    size: tuple[int, int] | None = None
    seed: int = 0
    scene: str = "white"
    brightness: float = 0.25

    def __post_init__(self) -> None:
        if self.platform not in PLATFORMS:
            raise VirtualCameraError(f"unknown platform {self.platform!r} (expected {' or '.join(PLATFORMS)})")
        object.__setattr__(self, "sensor", given_sensor(self.sensor, warn=False))
        if self.size is not None:
            width, height = (int(v) for v in self.size)
            if width < 16 or height < 16 or width % 2 or height % 2:
                raise VirtualCameraError(f"the size must be even and at least 16x16, not {width}x{height}")
            object.__setattr__(self, "size", (width, height))
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise VirtualCameraError(f"the seed must be a whole number from 0, not {self.seed!r}")
        if not 0 < float(self.brightness) < 1e6:
            raise VirtualCameraError(f"the brightness must be positive, not {self.brightness!r}")

    def environment(self) -> dict[str, str]:
        """The environment variables that give these settings to a program."""
        return {
            VARIABLES["platform"]: self.platform,
            VARIABLES["sensor"]: self.sensor,
            VARIABLES["size"]: "" if self.size is None else f"{self.size[0]}x{self.size[1]}",
            VARIABLES["seed"]: str(self.seed),
            VARIABLES["scene"]: str(Path(self.scene).resolve()) if self.scene not in ("white", "wheel") else self.scene,
            VARIABLES["brightness"]: repr(float(self.brightness)),
        }

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] | None = None) -> Options:
        """The settings a program was given (defaults for those not set).

        Raises
        ------
        VirtualCameraError
            A variable that does not hold a valid setting (naming it).
        """
        environ = os.environ if environ is None else environ
        values: dict[str, object] = {}
        for name, variable in VARIABLES.items():
            text = environ.get(variable, "").strip()
            if not text:
                continue
            try:
                if name == "size":
                    width, height = (int(v) for v in text.lower().split("x"))
                    values[name] = (width, height)
                elif name == "seed":
                    values[name] = int(text)
                elif name == "brightness":
                    values[name] = float(text)
                else:
                    values[name] = text
            except ValueError:
                raise VirtualCameraError(f"{variable}={text!r} is not a valid {name}") from None
        try:
            return cls(**values)  # type: ignore[arg-type]
        except PicamcalError as exc:
            raise VirtualCameraError(f"the virtual camera's settings in the environment: {exc}") from None
