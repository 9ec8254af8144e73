"""What an input may be before picamcal reads it: a regular file, of a size a real camera makes.

Every reader checks the size a file declares here, before it allocates or decodes anything, so that a forged
header costs no more memory than its own bytes. The limit is stated and can be raised::

    PICAMCAL_MAX_PIXELS=200000000 picamcal correct cal.npz huge.dng --out corrected
"""

from __future__ import annotations

import os
import stat
from collections.abc import Sequence

from .errors import CalibrationFileError, PicamcalError, RawFormatError

#: The largest sensor in the registry (OV64A40, 9248 x 6944) is 64 MP; a little over it, so a stitched mosaic
#: of a few frames still reads.
DEFAULT_MAX_PIXELS = 100_000_000
#: Largest colour gain libcamera's Raspberry Pi IPA takes (the ``ColourGains`` control's range, 0 to 32).
MAX_COLOUR_GAIN = 32.0
#: The environment variable that overrides :data:`DEFAULT_MAX_PIXELS`.
MAX_PIXELS_VARIABLE = "PICAMCAL_MAX_PIXELS"


def max_pixels() -> int:
    """The most pixels picamcal decodes from one image: ``$PICAMCAL_MAX_PIXELS``, else :data:`DEFAULT_MAX_PIXELS`.

    Examples
    --------
    >>> max_pixels() >= 64_000_000
    True
    """
    value = os.environ.get(MAX_PIXELS_VARIABLE, "").strip()
    if not value:
        return DEFAULT_MAX_PIXELS
    try:
        limit = int(value)
    except ValueError:
        limit = 0
    if limit <= 0:
        raise PicamcalError(f"{MAX_PIXELS_VARIABLE}={value!r} is not a positive whole number of pixels")
    return limit


class SizeBound(tuple):
    """(height, width) that an image may be at most, rather than exactly: the ``expected_shape`` of a frame that may
    be of any sensor mode inside a calibration's crop (:func:`check_size`; every reader passes it through).

    Examples
    --------
    >>> check_size("binned.dng", 1640, 1232, SizeBound((2464, 3280)))
    """

    __slots__ = ()


def check_size(
    path: str | os.PathLike[str],
    width: int,
    height: int,
    expected: Sequence[int] | None = None,
    what: str = "image",
) -> None:
    """Raise if a declared ``width`` x ``height`` is impossible, not the ``expected`` (height, width), or too large.

    Called by every reader with the size its file's header declares, before anything of that size is allocated.

    Parameters
    ----------
    path : path-like
        The file, named in the error.
    width, height : int
        The size the file declares, in pixels (the Bayer mosaic's, for a raw image).
    expected : (height, width), optional
        The size the caller needs (the calibration's): a mismatch raises ``CalibrationFileError``; a
        :class:`SizeBound` is the largest it may be.
    what : str
        What is being sized, for the message.

    Examples
    --------
    >>> check_size("white.dng", 3280, 2464, expected=(2464, 3280))
    >>> check_size("forged.dng", 34000, 34000)
    Traceback (most recent call last):
    ...
    picamcal.errors.RawFormatError: forged.dng: declares an image of 34000x34000 pixels (1156 MP), over the limit \
of 100 MP (set PICAMCAL_MAX_PIXELS to read larger images)
    """
    if not (isinstance(width, int) and isinstance(height, int)) or width <= 0 or height <= 0:
        raise RawFormatError(f"declares an {what} of {width}x{height} pixels", path)
    if isinstance(expected, SizeBound):
        if width > expected[1] or height > expected[0]:
            raise CalibrationFileError(
                f"{what} does not match the calibration: size {width}x{height}, larger than the calibration's "
                f"{expected[1]}x{expected[0]} sensor area, so outside it: calibrate in a mode that covers it (a "
                "full-sensor or binned mode covers every mode)",
                path,
            )
    elif expected is not None and (height, width) != (int(expected[0]), int(expected[1])):
        raise CalibrationFileError(
            f"{what} does not match the calibration: size {width}x{height}, calibration is for "
            f"{int(expected[1])}x{int(expected[0])}",
            path,
        )
    limit = max_pixels()
    if width * height > limit:
        raise RawFormatError(
            f"declares an {what} of {width}x{height} pixels ({_megapixels(width * height)}), over the limit of "
            f"{_megapixels(limit)} (set {MAX_PIXELS_VARIABLE} to read larger images)",
            path,
        )


def _megapixels(pixels: int) -> str:
    """``pixels`` as megapixels for a message; exact below one, whatever its size (no float overflow)."""
    return f"{pixels // 1_000_000} MP" if pixels >= 1_000_000 else f"{pixels} pixels"


def require_regular_file(path: str | os.PathLike[str], error: type[PicamcalError] = RawFormatError) -> int:
    """The size in bytes of ``path``, raising ``error`` unless it is a regular file (following symlinks).

    A FIFO, device or socket would block or never end when read, so it is refused before it is opened.

    Examples
    --------
    >>> require_regular_file(__file__) > 0
    True
    >>> require_regular_file("/dev/null")
    Traceback (most recent call last):
    ...
    picamcal.errors.RawFormatError: /dev/null: is a character device, not a regular file
    """
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise error("no such file", path) from None
    except OSError as exc:
        raise error(f"cannot read: {exc.strerror or exc}", path) from None
    if stat.S_ISDIR(info.st_mode):
        raise error("is a directory, not a file", path)
    if not stat.S_ISREG(info.st_mode):
        raise error(f"is {_kind(info.st_mode)}, not a regular file", path)
    return info.st_size


def _kind(mode: int) -> str:
    kinds = {stat.S_ISFIFO: "a FIFO (named pipe)", stat.S_ISCHR: "a character device", stat.S_ISBLK: "a block device"}
    kinds[stat.S_ISSOCK] = "a socket"
    return next((name for test, name in kinds.items() if test(mode)), "not a file")


__all__ = [
    "DEFAULT_MAX_PIXELS",
    "MAX_PIXELS_VARIABLE",
    "SizeBound",
    "check_size",
    "max_pixels",
    "require_regular_file",
]
