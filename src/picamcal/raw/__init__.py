"""Raw image formats behind one function, :func:`read_raw`.

Each format lives in its own module (``dng``, ``npz``); nothing outside that module knows its
byte layout.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import RawFormatError
from .dng import is_dng, read_dng, write_dng
from .model import PATTERNS, RawImage, site_channels
from .npz import read_npz, write_npz

__all__ = ["PATTERNS", "RawImage", "read_dng", "read_npz", "read_raw", "site_channels", "write_dng", "write_npz"]

_SIGNATURES = {
    b"\x89PNG": "a PNG image",
    b"\xff\xd8\xff": "a JPEG image",
    b"GIF8": "a GIF image",
    b"%PDF": "a PDF document",
}


def read_raw(path: str | os.PathLike[str]) -> RawImage:
    """Read a raw Bayer image from a file, whatever its format.

    The format is recognised from the file's first bytes, not its name. Supported: DNG (read by
    LibRaw through rawpy) and picamcal's own raw ``.npz``.

    Parameters
    ----------
    path : path-like
        The raw file.

    Returns
    -------
    RawImage
        The mosaic with its pattern, black and white levels, sensor and metadata
        (``metadata["format"]`` names the format).

    Raises
    ------
    RawFormatError
        The file is missing, unreadable, empty or not a raw image.

    Examples
    --------
    >>> import picamcal
    >>> raw = picamcal.read_raw("white.dng")  # doctest: +SKIP
    >>> raw.bayer.shape, raw.pattern  # doctest: +SKIP
    ((2464, 3280), 'BGGR')
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except FileNotFoundError:
        raise RawFormatError("no such file", path) from None
    except IsADirectoryError:
        raise RawFormatError("is a directory, not a raw image file", path) from None
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from exc
    if not head:
        raise RawFormatError("empty file (0 bytes)", path)
    if is_dng(head):
        return read_dng(path)
    if head.startswith(b"PK"):
        return read_npz(path)
    for signature, what in _SIGNATURES.items():
        if head.startswith(signature):
            raise RawFormatError(f"{what}, not a raw image", path)
    raise RawFormatError("not a raw image format picamcal reads (DNG or picamcal .npz)", path)
