"""Raw image formats behind one function, :func:`read_raw`.

Each format lives in its own module (``dng``, ``npz``); nothing outside that module knows its
byte layout.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path

from ..errors import PicamcalWarning, RawFormatError
from ._files import file_head
from .brcm import is_jpeg, read_brcm, write_brcm
from .dng import is_dng, read_dng, write_dng
from .model import PATTERNS, RawImage, site_channels
from .npz import read_npz, write_npz
from .picamera2 import from_picamera2, is_npy, read_picamera2_npy, to_picamera2, write_picamera2_npy
from .verify import check_metadata

__all__ = [
    "PATTERNS",
    "RawImage",
    "check_metadata",
    "from_picamera2",
    "is_jpeg",
    "is_npy",
    "override",
    "read_brcm",
    "read_dng",
    "read_npz",
    "read_picamera2_npy",
    "read_raw",
    "site_channels",
    "to_picamera2",
    "write_brcm",
    "write_dng",
    "write_npz",
    "write_picamera2_npy",
]

_SIGNATURES = {
    b"\x89PNG": "a PNG image",
    b"GIF8": "a GIF image",
    b"%PDF": "a PDF document",
}


def read_raw(
    path: str | os.PathLike[str],
    *,
    pattern: str | None = None,
    black_level: float | Sequence[float] | None = None,
    raw_format: str | None = None,
    size: tuple[int, int] | None = None,
    stride: int | None = None,
    frame: int | None = None,
    sensor: str | None = None,
    verify: bool = True,
) -> RawImage:
    """Read a raw Bayer image from a file, whatever its format.

    The format is recognised from the file's first bytes, not its name. Supported: DNG (read by
    LibRaw through rawpy), the legacy firmware's JPEG with a BRCM raw block, picamera2 raw buffers
    saved as ``.npy`` with a JSON sidecar, and picamcal's own raw ``.npz`` (docs/formats.md).

    What the file declares is checked against its data (:func:`picamcal.raw.verify.check_metadata`):
    a Bayer order whose greens sit on the wrong diagonal, or a missing black level, gives a
    ``PicamcalWarning`` saying what to override.

    Parameters
    ----------
    path : path-like
        The raw file.
    pattern : str, optional
        Override the file's Bayer order (``RGGB``, ``GBRG``, ``BGGR``, ``GRBG``).
    black_level : float or 4 floats, optional
        Override the file's black level (DN; one value, or one per 2x2 site row-major).
    raw_format : str, optional
        Read the file as a headless raw dump (``rpicam-raw``, ``libcamera-raw``) in this libcamera format
        (``SBGGR10_CSI2P``, ``SRGGB12_CSI2P``, ``SGBRG16``, ...); needs ``size``.
    size : (width, height), optional
        With ``raw_format``: the frame size in pixels.
    stride : int, optional
        With ``raw_format``: bytes per row (default: libcamera's alignment).
    frame : int, optional
        With ``raw_format``: which frame of a dump of several frames (default 0, the first).
    sensor : str, optional
        The sensor, for files that do not say (a headless dump): its registry constants are used.
    verify : bool
        Check the declared metadata against the data and warn.

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
    raw = _read_by_signature(path, file_head(path))
    if pattern is not None or black_level is not None:
        raw = override(raw, pattern=pattern, black_level=black_level)
    if verify:
        for problem in check_metadata(raw):
            warnings.warn(f"{path}: {problem}", PicamcalWarning, stacklevel=2)
    return raw


def _read_by_signature(path: Path, head: bytes) -> RawImage:
    if is_dng(head):
        return read_dng(path)
    if is_jpeg(head) or head.startswith(b"BRCM"):
        return read_brcm(path)
    if head.startswith(b"PK"):
        return read_npz(path)
    if is_npy(head):
        return read_picamera2_npy(path)
    for signature, what in _SIGNATURES.items():
        if head.startswith(signature):
            raise RawFormatError(f"{what}, not a raw image", path)
    raise RawFormatError("not a raw image format picamcal reads (DNG, JPEG+raw, picamera2 .npy or picamcal .npz)", path)


def override(
    raw: RawImage, *, pattern: str | None = None, black_level: float | Sequence[float] | None = None
) -> RawImage:
    """A copy of ``raw`` with its Bayer order or black level replaced; the declared values stay in the metadata.

    Examples
    --------
    >>> override(raw, pattern="BGGR", black_level=64).pattern  # doctest: +SKIP
    'BGGR'
    """
    meta = dict(raw.metadata)
    if pattern is not None and pattern != raw.pattern:
        meta["declared_pattern"] = raw.pattern
    if black_level is not None:
        meta["declared_black_level"] = list(raw.black_level)
    try:
        return RawImage(
            raw.bayer,
            pattern if pattern is not None else raw.pattern,
            raw.black_level if black_level is None else black_level,  # type: ignore[arg-type]
            raw.white_level,
            raw.bit_depth,
            raw.sensor,
            meta,
        )
    except RawFormatError as exc:
        raise RawFormatError(exc.problem, raw.source) from None
