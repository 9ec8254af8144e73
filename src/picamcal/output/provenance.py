"""The ``Software`` field every output carries, and recognising the images picamcal wrote by it.

``overwrite`` replaces only what picamcal wrote itself (:func:`picamcal._atomic.refuse_foreign`): an image
whose TIFF ``Software`` tag, PNG ``tEXt Software`` chunk or JPEG EXIF ``Software`` names picamcal.
"""

from __future__ import annotations

import os
from pathlib import Path

import tifffile

from .._version import __version__

#: The ``Software`` of every image picamcal writes.
SOFTWARE = f"picamcal {__version__}"


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
    path = Path(path)
    with open(path, "rb") as f:
        head = f.read(8)
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        with tifffile.TiffFile(path) as tif:
            tag = tif.pages.first.tags.get(305)  # Software
            return tag is not None and str(tag.value).startswith("picamcal")
    from PIL import Image

    with Image.open(path) as image:
        software = image.info.get("Software") or image.getexif().get(0x0131) or ""
    return str(software).startswith("picamcal")


__all__ = ["SOFTWARE", "is_picamcal_output"]
