"""The ``Software`` field every output carries, recognising the images picamcal wrote by it, and reading their record.

``overwrite`` replaces only what picamcal wrote itself (:func:`picamcal._atomic.refuse_foreign`): an image
whose TIFF ``Software`` tag, PNG ``tEXt Software`` chunk or JPEG EXIF ``Software`` names picamcal. Each of them
carries picamcal's JSON record ``{"picamcal": {...}}`` too (TIFF and DNG ``ImageDescription``, PNG ``iTXt
picamcal``, JPEG EXIF ``ImageDescription``), which :func:`read_record` gives back whatever the format: a batch
reads there the settings an output was made with (``made_with``, :mod:`picamcal.batch.record`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import tifffile

from .._version import __version__

#: The ``Software`` of every image picamcal writes.
SOFTWARE = f"picamcal {__version__}"
#: The key of picamcal's record in an output's JSON description.
RECORD_KEY = "picamcal"


def is_picamcal_output(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is an image picamcal wrote (its Software field names picamcal): one ``overwrite`` may replace.

    Examples
    --------
    >>> from picamcal.output import write_corrected
    >>> path = write_corrected("mine.png", np.ones((4, 4, 3), np.float32), "srgb-png")
    >>> from PIL import Image
    >>> Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save("theirs.png")
    >>> is_picamcal_output(path), is_picamcal_output("theirs.png")
    (True, False)
    """
    return _software_and_description(Path(path))[0].startswith("picamcal")


def read_record(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """picamcal's record in an image it wrote (TIFF, DNG, PNG or JPEG); None if picamcal did not write it.

    An image of picamcal's whose description is missing or not picamcal's JSON gives an empty record.

    Raises
    ------
    OSError
        The file cannot be read.

    Examples
    --------
    >>> from picamcal.output import write_corrected
    >>> path = write_corrected("mine.tiff", np.ones((4, 4, 3), np.float32), "float32-tiff", {"mode": "flat"})
    >>> read_record(path)
    {'mode': 'flat'}
    """
    software, description = _software_and_description(Path(path))
    if not software.startswith("picamcal"):
        return None
    try:
        record = json.loads(description)
    except ValueError:
        return {}
    ours = record.get(RECORD_KEY) if isinstance(record, dict) else None
    return ours if isinstance(ours, dict) else {}


def _software_and_description(path: Path) -> tuple[str, str]:
    """The file's Software field and its picamcal description (empty strings for those it lacks)."""
    with open(path, "rb") as f:
        head = f.read(8)
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        with tifffile.TiffFile(path) as tif:
            tags = tif.pages.first.tags
            software, description = tags.get(305), tags.get(270)  # Software, ImageDescription
            return (
                "" if software is None else str(software.value),
                "" if description is None else str(description.value),
            )
    from PIL import Image

    with Image.open(path) as image:
        exif = image.getexif()
        software = image.info.get("Software") or exif.get(0x0131) or ""
        description = image.info.get(RECORD_KEY) or exif.get(0x010E) or ""
    return str(software), str(description)


__all__ = ["RECORD_KEY", "SOFTWARE", "is_picamcal_output", "read_record"]
