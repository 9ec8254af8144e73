"""The interfaces every camera and illuminator implements (FORMATS.md section 7, the paper's rig)."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from ..errors import PicamcalError


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
