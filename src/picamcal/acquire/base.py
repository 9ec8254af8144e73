"""The interfaces every camera and illuminator implements (FORMATS.md section 7, the paper's rig)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..errors import PicamcalError
from ..raw.model import RawImage


class IlluminatorError(PicamcalError):
    """The illuminator cannot be found, does not answer, or answers with an error."""


class Illuminator(Protocol):
    """A light source that can be set to an RGB colour (0-255 each), as the paper's NeoPixel rig.

    Implementations: ``serial`` (the paper's Arduino), ``gpio`` (a NeoPixel on a Pi pin), ``screen`` (a
    monitor, full-screen), ``manual`` (asks the user) and ``sim`` (drives the simulated camera).
    """

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        """Set the colour and return when the light is set (the caller then waits for it to settle)."""

    def close(self) -> None:
        """Turn the light off and release the device."""

    def describe(self) -> dict[str, Any]:
        """A JSON-serialisable description for the acquisition manifest (kind, port, firmware, ...)."""


def check_rgb(red: int, green: int, blue: int) -> tuple[int, int, int]:
    """The colour every illuminator's ``set_rgb`` is given, checked: three whole numbers 0-255.

    Raises
    ------
    IlluminatorError
        A value is not a whole number (a float or a bool is refused) or is outside 0-255.

    Examples
    --------
    >>> check_rgb(255, np.uint8(0), 51)
    (255, 0, 51)
    >>> check_rgb(256, 0, 0)
    Traceback (most recent call last):
    ...
    picamcal.acquire.base.IlluminatorError: a colour is three whole numbers 0-255, got (256, 0, 0)
    """
    rgb = (red, green, blue)
    if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and 0 <= v <= 255 for v in rgb):
        raise IlluminatorError(f"a colour is three whole numbers 0-255, got {rgb}")
    return int(red), int(green), int(blue)


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

    Implementations: :class:`~picamcal.acquire.pi_camera.Picamera2Camera` (the Pi) and
    :class:`~picamcal.acquire.cameras.SimCamera` (the simulator).
    """

    def configure_raw(self) -> None:
        """Set up an unpacked raw stream of the camera's sensor mode with a neutral pipeline, and start the camera."""

    def set_controls(
        self, exposure_time_us: float, analogue_gain: float, colour_gains: tuple[float, float] | None = None
    ) -> None:
        """Fix the exposure time (µs), analogue gain and (when given) the red and blue colour gains."""

    def capture(self) -> RawImage:
        """One raw frame at the current settings (unpacked, the whole sensor mode), with its metadata."""

    def limits(self) -> CameraLimits:
        """The exposure time and gain ranges."""

    def describe(self) -> dict[str, Any]:
        """A JSON-serialisable description with at least ``kind``, ``sensor`` and ``size``."""

    def close(self) -> None:
        """Stop the camera and release it."""
