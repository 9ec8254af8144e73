"""The project's exception and warning types.

Every problem with a user's input is raised as a :class:`PicamcalError` whose message names the file
(when there is one) and the problem in one line; the command line prints that line and exits with
status 2.
"""

from __future__ import annotations

from collections.abc import Iterable
from os import PathLike


class PicamcalError(Exception):
    """Base class of every error picamcal raises about its inputs.

    Parameters
    ----------
    message : str
        What is wrong, in one line.
    path : path-like, optional
        The file the problem is about; it is put in front of the message.
    """

    def __init__(self, message: str, path: str | PathLike[str] | None = None) -> None:
        self.path = None if path is None else str(path)
        self.problem = message
        super().__init__(message if path is None else f"{path}: {message}")


class RawFormatError(PicamcalError):
    """A file is missing, unreadable, or not a raw image picamcal can read."""


class CalibrationInputError(PicamcalError):
    """The reference images cannot give a trustworthy calibration."""


class CalibrationFileError(PicamcalError):
    """A calibration file is corrupt, of an unknown schema, or does not fit the image."""


class OutputError(PicamcalError):
    """An output cannot be written (exists already, or the place is not writable)."""


class KernelBuildError(PicamcalError):
    """The C kernel cannot be built on this machine: no C compiler, or it failed (:mod:`picamcal.ckernel`)."""


def closest(value: str, choices: Iterable[str], cutoff: float = 0.6, *, parts: bool = False) -> str | None:
    """The choice nearest ``value``, compared case-insensitively, for a "did you mean"; None if none is close.

    With ``parts``, a value that is not near a whole choice may be near one of its parts (the words between
    ``-``, ``_`` and ``+``): ``png`` for ``srgb-png``, the first such choice when several share the part.

    Examples
    --------
    >>> closest("center", ["balance", "flat", "centre", "pure"]), closest("xyz", ["flat"])
    ('centre', None)
    >>> formats = ["float32-tiff", "uint16-tiff", "srgb-png", "srgb-jpeg"]
    >>> closest("png", formats), closest("png", formats, parts=True), closest("jpg", formats, parts=True)
    (None, 'srgb-png', 'srgb-jpeg')
    """
    import difflib
    import re

    choices = list(choices)
    by_key = {c.lower(): c for c in choices}
    close = difflib.get_close_matches(value.lower(), list(by_key), n=1, cutoff=cutoff)
    if close or not parts:
        return by_key[close[0]] if close else None
    by_part: dict[str, str] = {}
    for choice in choices:
        for part in re.split(r"[-_+]", choice.lower()):
            by_part.setdefault(part, choice)
    close = difflib.get_close_matches(value.lower(), list(by_part), n=1, cutoff=max(cutoff, 0.8))
    return by_part[close[0]] if close else None


def short(value: object, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters, for naming a bad value from a file in a one-line message.

    Examples
    --------
    >>> short("x" * 100)[-5:], short(1.5)
    ('xx...', '1.5')
    """
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def one_line(text: str) -> str:
    """Text from a file, fit for a one-line message: control characters and NULs as spaces, trimmed.

    Examples
    --------
    >>> one_line(" RP_imx219\\n\\x00 ")
    'RP_imx219'
    """
    return "".join(c if c.isprintable() else " " for c in text).strip()


def exception_detail(exc: BaseException, limit: int = 80) -> str:
    """What an exception says, for a one-line message: its type and its text, whitespace folded, cut to ``limit``.

    Examples
    --------
    >>> exception_detail(ValueError("bad\\n  header"))
    'ValueError: bad header'
    """
    detail = " ".join(str(exc).split())
    detail = detail if len(detail) <= limit else detail[: limit - 3] + "..."
    return f"{type(exc).__name__}: {detail}"


class PicamcalWarning(UserWarning):
    """Something is suspicious but the result is still usable."""
