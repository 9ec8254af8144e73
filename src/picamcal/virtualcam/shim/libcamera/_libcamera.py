"""The module the bindings build (``libcamera._libcamera``, ``src/py/libcamera/py_main.cpp``), from the virtual
camera's classes."""

from picamcal.virtualcam.buffers import FrameBuffer, FrameBufferAllocator, FrameMetadata
from picamcal.virtualcam.camera import Camera, CameraManager
from picamcal.virtualcam.config import (
    CameraConfiguration,
    SensorConfiguration,
    Stream,
    StreamConfiguration,
    StreamFormats,
    StreamRole,
)
from picamcal.virtualcam.controls import ControlId, ControlInfo, ControlType, controls, properties
from picamcal.virtualcam.request import Request
from picamcal.virtualcam.values import (
    FORMATS,
    ColorSpace,
    Orientation,
    PixelFormat,
    Point,
    Rectangle,
    Size,
    SizeRange,
    Transform,
)

formats = type("formats", (), {name: PixelFormat(name) for name in FORMATS})


def log_set_level(category: str, level: str) -> None:
    """libcamera's log levels; the virtual camera logs its errors whatever they are set to."""


__all__ = [
    "Camera",
    "CameraConfiguration",
    "CameraManager",
    "ColorSpace",
    "ControlId",
    "ControlInfo",
    "ControlType",
    "FrameBuffer",
    "FrameBufferAllocator",
    "FrameMetadata",
    "Orientation",
    "PixelFormat",
    "Point",
    "Rectangle",
    "Request",
    "SensorConfiguration",
    "Size",
    "SizeRange",
    "Stream",
    "StreamConfiguration",
    "StreamFormats",
    "StreamRole",
    "Transform",
    "controls",
    "formats",
    "log_set_level",
    "properties",
]
