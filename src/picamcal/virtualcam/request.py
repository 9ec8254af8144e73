"""Capture requests, and libcamera's way of saying what went wrong (its log lines, the bindings' errors).

A ``Request`` holds the buffers to fill, the controls to apply (converted as the bindings convert them,
``py_helpers.cpp``; a control the camera does not handle is dropped with libcamera's error line,
``controls.cpp``) and, once complete, the metadata (``request.cpp``, ``py_main.cpp``).

Examples
--------
>>> str(RequestStatus.Complete), int(ReuseFlag.ReuseBuffers)
('RequestStatus.Complete', 1)
"""

from __future__ import annotations

import errno
import os
import sys
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol

from .buffers import FrameBuffer
from .controls import CONTROLS, ControlId, ControlInfo, ConvertibleEnum, control_value, metadata_value

if TYPE_CHECKING:
    from .config import Stream

_LEVELS = ("DEBUG", "INFO", "WARN", "ERROR", "FATAL")


def _threshold(category: str) -> int:
    """The lowest level logged for a category: ``LIBCAMERA_LOG_LEVELS`` (``category:level`` or ``*:level``, names
    or numbers, comma separated; libcamera's ``log.cpp``), INFO by default."""
    threshold = 1
    for item in os.environ.get("LIBCAMERA_LOG_LEVELS", "").split(","):
        name, _, level = item.strip().rpartition(":")
        if name in ("*", category) and level:
            level = level.upper()
            threshold = int(level) if level.isdigit() else _LEVELS.index(level) if level in _LEVELS else threshold
    return threshold


def log(level: str, category: str, source: str, message: str) -> None:
    """A line as libcamera logs it (``[time] [pid] LEVEL Category file message``): to descriptor 2, as libcamera's C++
    logger writes it, so that a program that silences what C libraries print silences it too."""
    if _LEVELS.index(level) < _threshold(category):
        return
    seconds = time.monotonic()
    stamp = f"{int(seconds // 3600)}:{int(seconds % 3600 // 60):02d}:{seconds % 60:012.9f}"
    line = f"[{stamp}] [{os.getpid()}] {level:>5} {category} {source} {message}\n"
    sys.stderr.flush()  # after what Python printed before it
    os.write(2, line.encode())


def fail(what: str, code: int) -> RuntimeError:
    """The bindings' ``std::system_error`` as pybind11 raises it."""
    return RuntimeError(f"{what}: {os.strerror(code)}")


class RequestStatus(ConvertibleEnum):
    Pending = 0
    Complete = 1
    Cancelled = 2


class ReuseFlag(ConvertibleEnum):
    Default = 0
    ReuseBuffers = 1


class RequestOwner(Protocol):
    """What a request needs of the camera that made it (libcamera's ``Request::camera()``): the controls it handles
    now (they follow the configured sensor mode). The camera also tells its own requests by it."""

    @property
    def control_infos(self) -> Mapping[ControlId, ControlInfo]: ...


class Request:
    """A capture request: buffers to fill, controls to apply, and the metadata that comes back."""

    Status = RequestStatus
    Reuse = ReuseFlag

    def __init__(self, owner: RequestOwner, cookie: int) -> None:
        self._owner = owner
        self._cookie = int(cookie)
        self._buffers: dict[Stream, FrameBuffer] = {}
        self._controls: dict[str, Any] = {}
        self._metadata: dict[str, Any] = {}
        self._status = RequestStatus.Pending
        self._sequence = 0
        self._pending = 0

    status = property(lambda self: self._status)
    cookie = property(lambda self: self._cookie)
    sequence = property(lambda self: self._sequence)
    has_pending_buffers = property(lambda self: self._pending > 0)

    @property
    def buffers(self) -> dict[Stream, FrameBuffer]:
        return dict(self._buffers)

    @property
    def metadata(self) -> dict[ControlId, Any]:
        return {CONTROLS[name]: metadata_value(value) for name, value in self._metadata.items()}

    def add_buffer(self, stream: Stream, buffer: FrameBuffer) -> None:
        if stream is None or not isinstance(buffer, FrameBuffer):
            raise fail("Failed to add buffer", errno.EINVAL)
        if stream in self._buffers:
            raise fail("Failed to add buffer", errno.EEXIST)
        self._buffers[stream] = buffer
        self._pending += 1

    def set_control(self, control: ControlId, value: Any) -> None:
        if control not in self._owner.control_infos:
            log("ERROR", "Controls", "controls.cpp", f"Control 0x{control.id:08x} is not supported")
            return
        self._controls[control.name] = control_value(control, value)

    def reuse(self) -> None:
        self._status = RequestStatus.Pending
        self._controls, self._metadata = {}, {}
        self._pending = len(self._buffers)

    def __str__(self) -> str:
        state = {RequestStatus.Pending: "P", RequestStatus.Complete: "C", RequestStatus.Cancelled: "X"}[self._status]
        return f"Request({self._sequence}:{state}:{self._pending}/{len(self._buffers)}:{self._cookie})"
