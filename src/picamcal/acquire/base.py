"""The interfaces every camera and illuminator implements (FORMATS.md section 7, the paper's rig)."""

from __future__ import annotations

from typing import Any, Protocol

from ..errors import PicamcalError


class IlluminatorError(PicamcalError):
    """The illuminator cannot be found, does not answer, or answers with an error."""


class Illuminator(Protocol):
    """A light source that can be set to an RGB colour (0-255 each), as the paper's NeoPixel rig.

    Implementations: ``serial`` (the paper's Arduino), ``gpio`` (a NeoPixel on a Pi pin), ``manual``
    (asks the user) and ``sim`` (drives the simulated camera).
    """

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        """Set the colour and return when the light is set (the caller then waits for it to settle)."""

    def close(self) -> None:
        """Turn the light off and release the device."""

    def describe(self) -> dict[str, Any]:
        """A JSON-serialisable description for the acquisition manifest (kind, port, firmware, ...)."""
