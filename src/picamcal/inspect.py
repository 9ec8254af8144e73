"""What a file is: the record ``picamcal inspect`` prints."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from .errors import RawFormatError
from .raw import RawImage, read_raw
from .raw.processed import read_processed

_METADATA_KEYS = ("exposure_time_s", "analogue_gain", "digital_gain", "iso", "make", "model", "legacy_mode")


def describe(path: str | Path, read: Callable[[Path], RawImage] = read_raw) -> dict[str, Any]:
    """A JSON-serialisable description of a raw or processed image file.

    Raw files give format, sensor, size, Bayer pattern, bit depth, black and white levels and the
    exposure metadata; a file that is not raw but is an image (a JPEG without a raw block, a PNG) is
    described as processed. Anything else raises the reader's error.

    Examples
    --------
    >>> describe("white.dng")["pattern"]  # doctest: +SKIP
    'BGGR'
    """
    path = Path(path)
    try:
        raw = read(path)
    except RawFormatError as raw_error:
        try:
            image = read_processed(path, "linear")
        except RawFormatError:
            raise raw_error from None
        return {
            "path": str(path),
            "format": f"processed {image.metadata['format']}",
            "raw": False,
            "width": image.width,
            "height": image.height,
            "bit_depth": image.bit_depth,
            "note": str(raw_error.problem),
            **{k: image.metadata[k] for k in _METADATA_KEYS if k in image.metadata},
        }
    record: dict[str, Any] = {
        "path": str(path),
        "format": raw.metadata.get("format", "?"),
        "raw": True,
        "sensor": raw.sensor,
        "width": raw.width,
        "height": raw.height,
        "pattern": raw.pattern,
        "bit_depth": raw.bit_depth,
        "black_level": list(raw.black_level),
        "white_level": raw.white_level,
    }
    record.update({k: raw.metadata[k] for k in (*_METADATA_KEYS, "declared_pattern") if k in raw.metadata})
    return record
