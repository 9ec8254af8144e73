"""The correction modes: one definition used by the library, the command line's help and the docs.

Each mode is a step further along the paper's correction (its Fig. 1 and equations for ``Cb LST``, ``U`` and
``Cx``):

``uncorrected``
    Colour balance only (one gain per channel, from the centre of the white reference): the image as the sensor
    saw it, with a neutral white at the centre. This is the baseline the other modes are compared with.
``flat``
    The flat field: each Bayer site divided by its white response (``Cb LST = 1 / W``), which removes vignetting
    and the colour cast of the edges; the white reference becomes 1.0 everywhere.
``centre``
    ``flat``, then the colour-unmixing field ``U``, which restores the colours of the sensor centre everywhere.
``pure``
    ``flat``, then ``Cx U``: unmixes to pure primaries (more saturated, and more noise).

A ``flat`` calibration (white reference only) does ``uncorrected`` and ``flat``; ``centre`` and ``pure`` need the
colour-unmixing field of a ``full`` one. Where no mode is given, a correction takes the best the calibration does
(:func:`best_mode`): ``centre`` with an unmixing field, ``flat`` without. ``balance``, the name of ``uncorrected``
before version 0.2, is still accepted with a warning.
"""

from __future__ import annotations

import warnings
from enum import Enum

from .errors import PicamcalWarning


class Mode(str, Enum):
    """A correction mode; its value is the name used on the command line and in file names.

    Examples
    --------
    >>> Mode("flat").needs_unmixing
    False
    >>> [mode.value for mode in Mode]
    ['uncorrected', 'flat', 'centre', 'pure']
    """

    UNCORRECTED = "uncorrected"
    FLAT = "flat"
    CENTRE = "centre"
    PURE = "pure"

    @property
    def needs_unmixing(self) -> bool:
        """True for the modes that apply the colour-unmixing field (only a ``full`` calibration has one)."""
        return self in (Mode.CENTRE, Mode.PURE)

    @property
    def description(self) -> str:
        """One line saying what the mode does, for help texts and reports."""
        return _DESCRIPTIONS[self]

    def __str__(self) -> str:
        return self.value


_DESCRIPTIONS = {
    Mode.UNCORRECTED: "colour balance only: the image as the sensor saw it",
    Mode.FLAT: "flat field: vignetting and the edges' colour cast removed",
    Mode.CENTRE: "flat field and colour unmixing to the colours of the sensor centre",
    Mode.PURE: "flat field and colour unmixing to pure primaries",
}
#: Names of all modes, in order, for messages and choices.
MODE_NAMES = tuple(mode.value for mode in Mode)
#: Older names still accepted -> the mode they mean.
_ALIASES = {"balance": Mode.UNCORRECTED}


def parse_mode(value: str | Mode) -> Mode:
    """The :class:`Mode` named by ``value``; an older name gives a :class:`~picamcal.errors.PicamcalWarning`.

    Raises
    ------
    ValueError
        An unknown name; the message lists the modes.

    Examples
    --------
    >>> parse_mode("centre")
    <Mode.CENTRE: 'centre'>
    >>> parse_mode("sharp")
    Traceback (most recent call last):
    ...
    ValueError: unknown mode 'sharp': choose one of uncorrected, flat, centre, pure
    """
    if isinstance(value, Mode):
        return value
    if value in _ALIASES:
        mode = _ALIASES[value]
        warnings.warn(f"mode {value!r} is now called {mode.value!r}", PicamcalWarning, stacklevel=2)
        return mode
    try:
        return Mode(value)
    except ValueError:
        raise ValueError(f"unknown mode {value!r}: choose one of {', '.join(MODE_NAMES)}") from None


def best_mode(has_unmixing: bool) -> Mode:
    """The mode a correction takes when none is given: the best a calibration does.

    ``centre`` (the paper's recommended correction) for a calibration with a colour-unmixing field, ``flat``
    for one without (a white reference alone): the most either can correct.

    Examples
    --------
    >>> best_mode(has_unmixing=True), best_mode(has_unmixing=False)
    (<Mode.CENTRE: 'centre'>, <Mode.FLAT: 'flat'>)
    >>> best_mode_reason(False)
    'the best this calibration does: it has no colour references, only a white'
    """
    return Mode.CENTRE if has_unmixing else Mode.FLAT


def best_mode_reason(has_unmixing: bool) -> str:
    """Why :func:`best_mode` chose its mode, in a few words for a summary line.

    Examples
    --------
    >>> f"in mode {best_mode(has_unmixing=True).value} ({best_mode_reason(True)})"
    'in mode centre (the best this calibration does: it has colour unmixing)'
    """
    return "the best this calibration does: " + (
        "it has colour unmixing" if has_unmixing else "it has no colour references, only a white"
    )
