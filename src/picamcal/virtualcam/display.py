"""A stand-in for kms++'s Python module (``pykms``), which picamera2 imports for its DRM preview.

Raspberry Pi OS installs kms++ with picamera2; PyPI has no such package, and picamera2's
``previews/drm_preview.py`` imports it (or ``kms``) when picamera2 itself is imported. Inside the virtual camera,
where neither is importable, this module answers ``import pykms`` (:mod:`picamcal.virtualcam.kernel`): the names
picamera2 reads at import exist, and a DRM preview, which would need a display, fails with one line saying to use
``Preview.NULL``.

Examples
--------
>>> PixelFormat.XBGR8888
'XB24'
>>> Card("/dev/dri/card0")
Traceback (most recent call last):
...
RuntimeError: the virtual camera has no display (DRM/KMS): use Preview.NULL, or start() without a preview
"""

from __future__ import annotations

from typing import Any

_MESSAGE = "the virtual camera has no display (DRM/KMS): use Preview.NULL, or start() without a preview"


class PixelFormat:
    """The DRM pixel formats picamera2's DRM preview names."""

    RGB888 = "RG24"
    BGR888 = "BG24"
    XRGB8888 = "XR24"
    XBGR8888 = "XB24"
    ARGB8888 = "AR24"
    ABGR8888 = "AB24"
    YUV420 = "YU12"
    YVU420 = "YV12"
    NV12 = "NV12"
    NV21 = "NV21"
    YUYV = "YUYV"
    YVYU = "YVYU"


class PlaneType:
    """DRM plane types."""

    Overlay = 0
    Primary = 1
    Cursor = 2


class Card:
    """A DRM device: there is none."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        raise RuntimeError(_MESSAGE)


ResourceManager = DumbFramebuffer = DmabufFramebuffer = AtomicReq = Card
