"""The raw image model shared by every format reader and writer."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import RawFormatError

PATTERNS = ("RGGB", "GBRG", "BGGR", "GRBG")
CHANNELS = "RGB"


def site_channels(pattern: str) -> np.ndarray:
    """Channel index (0 R, 1 G, 2 B) of each site of the 2x2 Bayer block, row-major.

    Examples
    --------
    >>> site_channels("BGGR").tolist()
    [2, 1, 1, 0]
    """
    if pattern not in PATTERNS:
        raise RawFormatError(f"unknown Bayer pattern {pattern!r} (expected one of {', '.join(PATTERNS)})")
    return np.array([CHANNELS.index(c) for c in pattern], dtype=np.intp)


def require_black_level(raw: RawImage) -> None:
    """Raise if ``raw``'s black level is unknown (NaN): the file records none and its sensor is not known.

    Never take 0 silently: a wrong black level skews every ratio the calibration measures.

    Examples
    --------
    >>> require_black_level(RawImage(np.zeros((2, 2), np.uint16), "RGGB", 64, 1023, 10))
    """
    if not np.all(np.isfinite(raw.black_level)):
        raise RawFormatError(
            "no black level: the file records none and its sensor is not in picamcal's registry; give "
            "--black-level N, a dark frame (--black FILE) or --sensor NAME",
            raw.source,
        )


@dataclass
class RawImage:
    """A raw Bayer mosaic with what is needed to interpret it.

    Attributes
    ----------
    bayer : ndarray of uint16, shape (H, W)
        The mosaic at native bit depth (not scaled to 16 bits).
    pattern : str
        Colours of the top-left 2x2 block read row-wise: ``"RGGB"``, ``"GBRG"``, ``"BGGR"`` or ``"GRBG"``.
    black_level : tuple of 4 float
        Black level in DN of each site of the 2x2 block, row-major; NaN where unknown (a headless dump of a
        sensor picamcal does not know, with no level given): see :func:`require_black_level`.
    white_level : int
        Saturation value in DN.
    bit_depth : int
        Bits per pixel of the sensor's output.
    sensor : str or None
        Sensor name from the registry, when the file says.
    metadata : dict
        Exposure, gains and whatever else the file records; ``metadata["format"]`` names the format read.
    """

    bayer: np.ndarray
    pattern: str
    black_level: tuple[float, float, float, float]
    white_level: int
    bit_depth: int
    sensor: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        bayer = np.asarray(self.bayer)
        if bayer.ndim != 2 or bayer.shape[0] < 2 or bayer.shape[1] < 2:
            raise RawFormatError(f"a Bayer mosaic must be a 2-D array, got shape {bayer.shape}")
        if bayer.shape[0] % 2 or bayer.shape[1] % 2:
            raise RawFormatError(f"a Bayer mosaic needs even width and height, got {bayer.shape[1]}x{bayer.shape[0]}")
        if bayer.dtype != np.uint16:
            raise RawFormatError(f"a Bayer mosaic must be uint16, got {bayer.dtype}")
        site_channels(self.pattern)
        black = tuple(float(b) for b in np.asarray(self.black_level, dtype=float).reshape(-1))
        if len(black) == 1:
            black = black * 4
        if len(black) != 4:
            raise RawFormatError(f"black_level needs 1 or 4 values, got {len(black)}")
        self.bayer = bayer
        self.black_level = black  # type: ignore[assignment]

    @property
    def height(self) -> int:
        """Mosaic height in pixels."""
        return int(self.bayer.shape[0])

    @property
    def width(self) -> int:
        """Mosaic width in pixels."""
        return int(self.bayer.shape[1])

    @property
    def source(self) -> str:
        """Where the image came from (its path, or a description), for messages."""
        return str(self.metadata.get("path", "<array>"))

    def black_subtracted(self) -> np.ndarray:
        """The mosaic as float32 with each site's black level subtracted (may go negative with noise)."""
        out = self.bayer.astype(np.float32)
        for k, level in enumerate(self.black_level):
            out[k // 2 :: 2, k % 2 :: 2] -= np.float32(level)
        return out
