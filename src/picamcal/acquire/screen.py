"""The screen illuminator: the references shown full-screen on a monitor, for an in-situ calibration in its spectra.

A monitor's red, green and blue are not the jig's LEDs: a calibration made with the LEDs and used on a monitor
(or anything else whose spectra differ) keeps an error the per-bin 3 x 3 cannot remove (issue 13's floor).
Calibrating with the monitor's own full-screen white, red, green and blue, photographed through the optics,
removes it. :class:`ScreenWindow` shows each colour in a borderless full-screen window on the Pi's display
(tkinter, the standard library's Tk; cursor hidden) and returns once the X server has drawn it;
:class:`ScreenPrompt` asks the user to show the matching ``screen_ROLE.png`` (``picamcal target --screens``) in
a full-screen image viewer, for a monitor the Pi does not drive or when there is no display.
:func:`open_screen` picks one: ``screen`` (the window on ``$DISPLAY``, else the prompts), ``screen:DISPLAY``
(that display, or an error) or ``screen:prompt``.

Keep the monitor's brightness fixed and its automatic dimming, night light and power saving off for the whole
run: the calibration takes the colours to be the same in every frame.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Mapping
from typing import Any

from ..errors import PicamcalWarning
from ..references import colour_role
from ..target import SCREEN_COLOURS, screen_name
from .base import IlluminatorError, check_rgb

__all__ = ["ScreenPrompt", "ScreenWindow", "open_screen"]

#: How long the window may take to appear (a window manager may animate it in), in seconds.
_MAP_TIMEOUT_S = 10.0
#: After the X server has drawn a colour, a compositor (Wayland's Xwayland, picom) shows it at its next frames:
#: two frames at 30 Hz or faster.
_COMPOSITOR_S = 2 / 30


def _screen_names(colours: Mapping[str, tuple[int, int, int]] | None) -> dict[tuple[int, int, int], str]:
    """Which ``screen_*.png`` shows each colour: the references' first, then the extra colours'."""
    extra = {colour_role(name): tuple(rgb) for name, rgb in (colours or {}).items()}
    names: dict[tuple[int, int, int], str] = {}
    for role, rgb in {**SCREEN_COLOURS, **extra}.items():
        names.setdefault(check_rgb(*rgb), screen_name(role))
    return names


class ScreenPrompt:
    """Asks the user to show each colour full-screen (``screen_red.png``, ...) and press Enter.

    For a monitor the Pi does not drive (a laptop's, a tablet's) or a Pi without a display. The images are
    those of ``picamcal target --screens`` (:func:`picamcal.target.save_screens`), at the monitor's size.

    Parameters
    ----------
    colours : mapping, optional
        Extra colours, name -> (R, G, B), so that the prompt names their ``screen_colour_NAME.png``.
    why : str, optional
        Why the screen is not driven directly (no display), for :meth:`describe`.
    input_fn : callable
        Shows a prompt and waits for Enter (``input``).
    output : callable
        Prints a message (``print``).

    Examples
    --------
    >>> screen = ScreenPrompt({"cyan": (0, 255, 255)}, input_fn=lambda prompt: print(prompt) or "")
    >>> screen.set_rgb(255, 0, 0)
    Show screen_red.png full-screen, then press Enter
    >>> screen.set_rgb(0, 255, 255)
    Show screen_colour_cyan.png full-screen, then press Enter
    >>> screen.set_rgb(0, 255, 255)  # shown already: no question
    >>> screen.describe()
    {'kind': 'screen', 'shows': 'prompt'}
    """

    def __init__(
        self,
        colours: Mapping[str, tuple[int, int, int]] | None = None,
        *,
        why: str | None = None,
        input_fn: Callable[[str], Any] = input,
        output: Callable[[str], Any] = print,
    ) -> None:
        self._names = _screen_names(colours)
        self.why = why
        self._input = input_fn
        self._output = output
        self.rgb: tuple[int, int, int] | None = None

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        """Ask the user to show the colour's image full-screen, unless it is shown already."""
        rgb = check_rgb(red, green, blue)
        if rgb == self.rgb:
            return
        name = self._names.get(rgb)
        what = f"{name} full-screen" if name else f"a full-screen colour {rgb} (not one of picamcal's screen images)"
        try:
            self._input(f"Show {what}, then press Enter")
        except EOFError:
            raise IlluminatorError("no answer (end of input) when asked to show the screen") from None
        self.rgb = rgb

    def close(self) -> None:
        """Tell the user the screens are no longer needed."""
        if self.rgb is not None:
            self._output("You can close the full-screen image now.")
        self.rgb = None

    def describe(self) -> dict[str, Any]:
        """Kind ``screen``, shown by the user (``"shows": "prompt"``), and why when no display could be used."""
        described: dict[str, Any] = {"kind": "screen", "shows": "prompt"}
        if self.why:
            described["why"] = self.why
        return described


class ScreenWindow:
    """Shows each colour in a borderless window over the whole screen of an X display, the cursor hidden.

    The window (Tk, through the standard library's tkinter) covers the screen from its top-left corner; it
    is drawn in the exact 8-bit code values given (a display of fewer bits a channel rounds them, with a
    warning; :meth:`describe` records the depth). :meth:`set_rgb` returns once the X server has drawn the new colour and
    a compositor has had two frames to show it.

    Parameters
    ----------
    display : str
        The X display (``":0"``).

    Raises
    ------
    IlluminatorError
        tkinter is missing (``apt install python3-tk``), or the display cannot be opened, or the window does
        not appear.

    Examples
    --------
    On the Pi's desktop (or any X display; here a virtual one, ``Xvfb :7``)::

        screen = ScreenWindow(":7")
        screen.set_rgb(255, 0, 0)  # the whole screen is red when this returns
        screen.close()
    """

    def __init__(self, display: str) -> None:
        try:
            import tkinter
        except ImportError:
            raise IlluminatorError(
                "the screen illuminator needs tkinter (on Raspberry Pi OS: sudo apt install python3-tk), "
                "or use --illuminator screen:prompt"
            ) from None
        self._tk_error = tkinter.TclError
        self.display = display
        try:
            self._root = tkinter.Tk(screenName=display, className="picamcal-screen")
        except tkinter.TclError as exc:
            raise IlluminatorError(f"cannot open the display {display!r} ({exc})") from None
        try:
            root = self._root
            self.size = (root.winfo_screenwidth(), root.winfo_screenheight())
            self.depth = root.winfo_depth()
            if self.depth < 24:
                warnings.warn(
                    f"the display {display} has {self.depth} bits a pixel: it rounds the colours (set it to 24 bits "
                    "for exact references)",
                    PicamcalWarning,
                    stacklevel=2,
                )
            root.title("picamcal screen illuminator")
            # Override-redirect: no window manager decorates, moves or shrinks it; it lies over the whole screen.
            root.overrideredirect(True)
            root.geometry(f"{self.size[0]}x{self.size[1]}+0+0")
            root.configure(background="#000000", cursor="none", highlightthickness=0, borderwidth=0)
            root.attributes("-topmost", True)
            self.rgb: tuple[int, int, int] | None = None
            deadline = time.monotonic() + _MAP_TIMEOUT_S
            root.update()
            while not root.winfo_viewable():
                if time.monotonic() > deadline:
                    raise IlluminatorError(f"the full-screen window did not appear on {display} in {_MAP_TIMEOUT_S} s")
                time.sleep(0.01)
                root.update()
        except BaseException:
            self._destroy()
            raise

    def set_rgb(self, red: int, green: int, blue: int) -> None:
        """Fill the screen with the colour; return once it is drawn."""
        rgb = check_rgb(red, green, blue)
        try:
            self._root.configure(background="#{:02x}{:02x}{:02x}".format(*rgb))
            # Tk's update redraws, flushes and XSyncs: when it returns the X server has drawn the colour.
            self._root.update()
        except self._tk_error as exc:
            raise IlluminatorError(f"the full-screen window on {self.display} is gone ({exc})") from None
        time.sleep(_COMPOSITOR_S)
        self.rgb = rgb

    def close(self) -> None:
        """Close the window."""
        self._destroy()
        self.rgb = None

    def _destroy(self) -> None:
        try:
            self._root.destroy()
        except self._tk_error:  # closed already
            pass

    def describe(self) -> dict[str, Any]:
        """Kind ``screen`` shown in a window (``"shows": "window"``), the display, its size and depth."""
        return {
            "kind": "screen",
            "shows": "window",
            "display": self.display,
            "size": list(self.size),
            "depth": self.depth,
        }


def open_screen(
    display: str | None = None,
    *,
    colours: Mapping[str, tuple[int, int, int]] | None = None,
    input_fn: Callable[[str], Any] = input,
) -> ScreenWindow | ScreenPrompt:
    """The screen illuminator: a full-screen window on a display, or prompts to show the images by hand.

    Parameters
    ----------
    display : str, optional
        None: the window on ``$DISPLAY``, or the prompts (saying why) when it is unset or cannot be opened.
        ``"prompt"``: the prompts. Anything else (``":0"``, ``"1"`` for ``":1"``): the window on that display,
        or an error.
    colours : mapping, optional
        Extra colours, name -> (R, G, B), for the prompts' file names.
    input_fn : callable
        What the prompts wait on (``input``).

    Raises
    ------
    IlluminatorError
        A display named explicitly cannot be used.

    Examples
    --------
    >>> screen = open_screen("prompt", input_fn=lambda prompt: print(prompt) or "")
    >>> screen.set_rgb(255, 255, 255)
    Show screen_white.png full-screen, then press Enter
    """
    if display == "prompt":
        return ScreenPrompt(colours, input_fn=input_fn)
    if display is not None:
        return ScreenWindow(f":{display}" if display.replace(".", "").isdigit() else display)
    default = os.environ.get("DISPLAY", "")
    if not default:
        why = "no display (DISPLAY is not set)"
    else:
        try:
            return ScreenWindow(default)
        except IlluminatorError as exc:
            why = str(exc)
    return ScreenPrompt(colours, why=why, input_fn=input_fn)
