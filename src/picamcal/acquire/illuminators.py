"""Illuminators behind the :class:`~picamcal.acquire.base.Illuminator` interface (FORMATS.md section 7).

``serial`` (the paper's Arduino, :mod:`picamcal.acquire.serial_illuminator`), ``gpio`` (a NeoPixel on a Pi
pin through the CircuitPython NeoPixel library, an optional extra), ``screen`` (the colours full-screen on a
monitor, :mod:`picamcal.acquire.screen`), ``manual`` (asks the user) and ``sim`` (the light the simulated camera
sees). :func:`open_illuminator` opens one from its command-line name.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..errors import PicamcalError
from ..references import ROLES
from .base import Illuminator, IlluminatorError, check_rgb

__all__ = [
    "REFERENCE_LIGHTS",
    "GpioIlluminator",
    "ManualIlluminator",
    "SimIlluminator",
    "VirtualIlluminator",
    "open_illuminator",
]

#: The LED setting (R, G, B, 0-255) of each reference role (:data:`picamcal.references.ROLES`), in the order
#: they are captured.
REFERENCE_LIGHTS: dict[str, tuple[int, int, int]] = dict(
    zip(ROLES, ((255, 255, 255), (255, 0, 0), (0, 255, 0), (0, 0, 255), (0, 0, 0)), strict=True)
)
_NAMES = {rgb: name for name, rgb in REFERENCE_LIGHTS.items()}


class SimIlluminator:
    """The light the simulated camera (:class:`~picamcal.acquire.cameras.SimCamera`) sees.

    Attributes
    ----------
    rgb : (int, int, int)
        The current LED setting; (0, 0, 0) at first and after :meth:`close`.

    Examples
    --------
    >>> light = SimIlluminator()
    >>> light.set_rgb(255, 0, 51)
    >>> light.amounts.tolist()
    [1.0, 0.0, 0.2]
    """

    def __init__(self) -> None:
        self.rgb: tuple[int, int, int] = (0, 0, 0)

    @property
    def amounts(self) -> np.ndarray:
        """The amounts of the red, green and blue primaries, ``rgb / 255`` (float64, shape (3,))."""
        return np.asarray(self.rgb, dtype=np.float64) / 255.0

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        """Set the LEDs."""
        self.rgb = check_rgb(red, green, blue)

    def close(self) -> None:
        """Turn the light off."""
        self.rgb = (0, 0, 0)

    def describe(self) -> dict[str, Any]:
        """``{"kind": "sim"}``."""
        return {"kind": "sim"}


class ManualIlluminator:
    """Asks the user to set each colour by hand and press Enter.

    Parameters
    ----------
    input_fn : callable
        Shows a prompt and waits for Enter (``input``).
    output : callable
        Prints a message (``print``).
    colours : mapping, optional
        The run's extra colours, name -> (R, G, B), so that the question names them.

    Examples
    --------
    >>> light = ManualIlluminator(input_fn=lambda prompt: print(prompt) or "", colours={"cyan": (0, 255, 255)})
    >>> light.set_rgb(255, 0, 0)
    Set the light to red (255, 0, 0) and press Enter
    >>> light.set_rgb(255, 0, 0)  # already red: no question
    >>> light.set_rgb(0, 255, 255)
    Set the light to cyan (0, 255, 255) and press Enter
    """

    def __init__(
        self,
        input_fn: Callable[[str], Any] = input,
        output: Callable[[str], Any] = print,
        colours: Mapping[str, tuple[int, int, int]] | None = None,
    ) -> None:
        self._input = input_fn
        self._output = output
        self._names: dict[tuple[int, int, int], str] = {
            **_NAMES,
            **{check_rgb(*rgb): name for name, rgb in (colours or {}).items()},
        }
        self.rgb: tuple[int, int, int] | None = None

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        """Ask the user to set the colour, unless it is set already."""
        rgb = check_rgb(red, green, blue)
        if rgb == self.rgb:
            return
        if rgb == (0, 0, 0):
            question = f"Turn the light off {rgb} and press Enter"
        else:
            question = f"Set the light to {self._names.get(rgb, 'the colour')} {rgb} and press Enter"
        try:
            self._input(question)
        except EOFError:
            raise IlluminatorError("no answer (end of input) when asked to set the light") from None
        self.rgb = rgb

    def close(self) -> None:
        """Remind the user to turn the light off."""
        if self.rgb not in (None, (0, 0, 0)):
            self._output("You can turn the light off now.")
        self.rgb = None

    def describe(self) -> dict[str, Any]:
        """``{"kind": "manual"}``."""
        return {"kind": "manual"}


class VirtualIlluminator:
    """The light of the virtual camera's scene (``picamcal virtual-camera``): a rig for picamera2 on a PC.

    ``picamcal virtual-camera -- picamcal acquire --camera picamera2 --illuminator virtual`` acquires a calibration
    run through the real picamera2 as on a Raspberry Pi, the references lit as the simulator's jig lights them
    (amounts ``rgb / 255`` of the primaries; :class:`SimIlluminator`).

    Raises
    ------
    IlluminatorError
        Not inside the virtual camera, or (on the first colour) no virtual camera opened in this process.

    Examples
    --------
    >>> VirtualIlluminator().describe()  # inside picamcal virtual-camera  # doctest: +SKIP
    {'kind': 'virtual'}
    """

    def __init__(self) -> None:
        from ..virtualcam.options import VARIABLES

        if VARIABLES["platform"] not in os.environ:
            raise IlluminatorError(
                "the virtual illuminator lights the virtual camera only: run picamcal virtual-camera -- picamcal "
                "acquire --camera picamera2 --illuminator virtual"
            )
        self.rgb: tuple[int, int, int] = (0, 0, 0)

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        """Set the light of the virtual camera's scene."""
        from ..virtualcam.camera import set_light

        rgb = check_rgb(red, green, blue)
        try:
            set_light((rgb[0] / 255, rgb[1] / 255, rgb[2] / 255))
        except PicamcalError as exc:
            raise IlluminatorError(str(exc)) from None
        self.rgb = rgb

    def close(self) -> None:
        """Leave the light as it is (the virtual camera ends with its process)."""

    def describe(self) -> dict[str, Any]:
        """``{"kind": "virtual"}``."""
        return {"kind": "virtual"}


class GpioIlluminator:
    """A NeoPixel (WS2812) driven from a Raspberry Pi pin with the CircuitPython NeoPixel library.

    Parameters
    ----------
    pin : str
        The ``board`` pin name: D18 (PWM, the default), D12, D21 or D10 (SPI, no root needed).
    count : int
        Number of pixels on the strip; all are set to the same colour.
    pixel_order : str
        The pixels' colour order as the library names it (``"GRB"`` for WS2812).

    Raises
    ------
    IlluminatorError
        The library is missing (install ``picamcal[pi]``), not on a Pi, no such pin, or the pixel
        cannot be driven (PWM pins need root).

    Examples
    --------
    >>> light = GpioIlluminator("D18")  # doctest: +SKIP
    >>> light.set_rgb(255, 0, 0)  # doctest: +SKIP
    """

    def __init__(self, pin: str = "D18", *, count: int = 1, pixel_order: str = "GRB") -> None:
        try:
            import board
            import neopixel
        except ImportError:
            raise IlluminatorError(
                "the gpio illuminator needs the CircuitPython NeoPixel library: on a Raspberry Pi install picamcal[pi]"
            ) from None
        except (NotImplementedError, RuntimeError) as exc:
            raise IlluminatorError(f"the gpio illuminator runs on a Raspberry Pi only ({exc})") from exc
        self.pin = pin.upper()
        board_pin = getattr(board, self.pin, None)
        order = getattr(neopixel, pixel_order.upper(), None)
        if board_pin is None:
            raise IlluminatorError(f"the board has no pin {pin} (a NeoPixel works on D18, D12, D21 or D10)")
        if order is None:
            raise IlluminatorError(f"unknown NeoPixel colour order {pixel_order!r} (GRB, RGB, GRBW, ...)")
        self.count = int(count)
        self.pixel_order = pixel_order.upper()
        try:
            self._pixels = neopixel.NeoPixel(board_pin, self.count, brightness=1.0, auto_write=False, pixel_order=order)
        except (RuntimeError, OSError, ValueError) as exc:
            raise IlluminatorError(
                f"cannot drive a NeoPixel on {self.pin} ({exc}): run as root for D18, D12 or D21, or use D10 (SPI)"
            ) from exc

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        """Set every pixel and send the data."""
        rgb = check_rgb(red, green, blue)
        try:
            self._pixels.fill(rgb)
            self._pixels.show()
        except (RuntimeError, OSError, ValueError) as exc:
            raise IlluminatorError(f"the NeoPixel on {self.pin} stopped answering ({exc})") from exc

    def close(self) -> None:
        """Turn the pixels off and release the pin."""
        try:
            self._pixels.fill((0, 0, 0))
            self._pixels.show()
        finally:
            self._pixels.deinit()

    def describe(self) -> dict[str, Any]:
        """Kind ``gpio``, pin, pixel count and colour order."""
        return {"kind": "gpio", "pin": self.pin, "count": self.count, "pixel_order": self.pixel_order}


def open_illuminator(
    spec: str,
    *,
    colours: Mapping[str, tuple[int, int, int]] | None = None,
    input_fn: Callable[[str], Any] = input,
) -> Illuminator:
    """Open an illuminator named on the command line.

    Parameters
    ----------
    spec : str
        ``serial`` (find the Arduino) or ``serial:PORT``; ``gpio`` (pin D18) or ``gpio:PIN``; ``screen`` (a
        full-screen window on ``$DISPLAY``, else prompts to show the images), ``screen:DISPLAY`` or
        ``screen:prompt`` (:func:`~picamcal.acquire.screen.open_screen`); ``manual``; ``sim``; ``virtual`` (the
        virtual camera's light, :class:`VirtualIlluminator`).
    colours : mapping, optional
        The run's extra colours, name -> (R, G, B): ``manual`` and the screen's prompts name them.
    input_fn : callable
        What ``manual`` and the screen's prompts wait on (``input``).

    Raises
    ------
    PicamcalError
        An unknown kind; :class:`IlluminatorError` when the device cannot be opened.

    Examples
    --------
    >>> open_illuminator("sim").describe()
    {'kind': 'sim'}
    >>> open_illuminator("screen:prompt").describe()
    {'kind': 'screen', 'shows': 'prompt'}
    """
    kind, colon, argument = spec.partition(":")
    kind = kind.strip().lower()
    if kind == "serial":
        from .serial_illuminator import open_serial_illuminator

        return open_serial_illuminator(spec)
    if kind == "gpio":
        return GpioIlluminator(argument or "D18")
    if kind == "screen":
        from .screen import open_screen

        return open_screen(argument.strip() or None, colours=colours, input_fn=input_fn)
    if kind in ("manual", "sim", "virtual") and not colon:
        if kind == "virtual":
            return VirtualIlluminator()
        return ManualIlluminator(input_fn, colours=colours) if kind == "manual" else SimIlluminator()
    raise PicamcalError(
        f"unknown illuminator {spec!r} (expected serial, serial:PORT, gpio, gpio:PIN, screen, screen:DISPLAY, "
        "screen:prompt, manual, sim or virtual)"
    )
