"""Frame buffers and their memory: ``FrameBuffer``, its planes and metadata, ``FrameBufferAllocator``, and the
memfd-backed memory that stands in for the kernel's DMA buffers.

A plane's file descriptor is duplicated when it is set, and closed when the last copy of the plane goes, as
libcamera's ``SharedFD`` does (``py_main.cpp``: ``p.fd = SharedFD(fd)``): picamera2 relies on it, keeping its own
descriptors apart from libcamera's (``allocators/dmaallocator.py``). Buffers are mapped once, shared between the
camera that fills them and the program that reads them.

Examples
--------
>>> fd = allocate_memory("example", 4096)
>>> plane = FrameBuffer.Plane(fd, 0, 4096)
>>> plane.fd != fd, plane.length  # the plane holds a duplicate, as libcamera's SharedFD does
(True, 4096)
>>> os.close(fd)
"""

from __future__ import annotations

import mmap
import os
import threading
from typing import Any

from .controls import ConvertibleEnum

#: The memfd names that mark the virtual camera's buffers (what :mod:`picamcal.virtualcam.kernel` recognises).
BUFFER_NAME = "picamcal-dma-buf"


def allocate_memory(name: str, size: int) -> int:
    """A new anonymous memory file of ``size`` bytes, as a DMA heap gives one (close-on-exec)."""
    fd = os.memfd_create(f"{BUFFER_NAME}:{name}", os.MFD_CLOEXEC)
    try:
        os.ftruncate(fd, int(size))
    except OSError:
        os.close(fd)
        raise
    return fd


class _SharedFD:
    """A duplicated descriptor, closed when nothing refers to it any more (libcamera's ``SharedFD``)."""

    def __init__(self, fd: int) -> None:
        self.fd = os.dup(int(fd)) if fd >= 0 else -1

    def __del__(self) -> None:
        # The number stays: at interpreter exit objects are finalised in any order, and picamera2's allocator
        # still looks its buffers up by plane.fd then (its DmaAllocator.__del__).
        if self.fd >= 0:
            try:
                os.close(self.fd)
            except OSError:
                pass


class FrameBufferPlane:
    """``FrameBuffer.Plane``: ``fd`` (duplicated when set), ``offset``, ``length``."""

    def __init__(self, fd: int | None = None, offset: int = 0, length: int = 0) -> None:
        self._shared = _SharedFD(int(fd)) if fd is not None else None
        self.offset, self.length = int(offset), int(length)

    @property
    def fd(self) -> int:
        return self._shared.fd if self._shared is not None else -1

    @fd.setter
    def fd(self, value: int) -> None:
        self._shared = _SharedFD(int(value))

    def _copy(self) -> FrameBufferPlane:
        other = FrameBufferPlane(None, self.offset, self.length)
        other._shared = self._shared
        return other


class FrameMetadataStatus(ConvertibleEnum):
    """``FrameMetadata.Status`` as the bindings name it; libcamera's ``FrameStartup`` (3) has no Python name."""

    Success = 0
    Error = 1
    Cancelled = 2
    Startup_ = 3  # framebuffer.h FrameStartup: not exported by py_main.cpp, so never Success


class _MetadataPlane:
    def __init__(self, bytes_used: int) -> None:
        self.bytes_used = int(bytes_used)


class FrameMetadata:
    """What the camera says about a buffer it filled: ``status``, ``sequence``, ``timestamp``, ``planes``."""

    Status = FrameMetadataStatus
    Plane = _MetadataPlane

    def __init__(self) -> None:
        self._status = FrameMetadataStatus.Success
        self._sequence = 0
        self._timestamp = 0
        self._planes: list[int] = []

    status = property(lambda self: self._status)
    sequence = property(lambda self: self._sequence)
    timestamp = property(lambda self: self._timestamp)

    @property
    def planes(self) -> list[_MetadataPlane]:
        return [_MetadataPlane(n) for n in self._planes]

    def _set(self, status: FrameMetadataStatus, sequence: int, timestamp: int, used: list[int]) -> None:
        self._status, self._sequence, self._timestamp, self._planes = status, sequence, timestamp, used


class FrameBuffer:
    """A buffer the camera fills: its ``planes`` (copies), ``metadata`` and ``cookie``."""

    Plane = FrameBufferPlane

    def __init__(self, planes: list[FrameBufferPlane], cookie: int = 0) -> None:
        planes = list(planes)
        if not all(isinstance(p, FrameBufferPlane) for p in planes):
            raise TypeError("FrameBuffer(): planes must be FrameBuffer.Plane objects")
        self._planes = [p._copy() for p in planes]
        self._metadata = FrameMetadata()
        self._cookie = int(cookie)
        self._map: mmap.mmap | None = None
        self._lock = threading.Lock()
        self._request: Any = None

    @property
    def planes(self) -> list[FrameBufferPlane]:
        return [p._copy() for p in self._planes]

    @property
    def metadata(self) -> FrameMetadata:
        return self._metadata

    @property
    def cookie(self) -> int:
        return self._cookie

    @cookie.setter
    def cookie(self, value: int) -> None:
        self._cookie = int(value)

    def mapping(self) -> mmap.mmap:
        """The buffer's memory (all planes share the first plane's descriptor), mapped once."""
        with self._lock:
            if self._map is None:
                plane = self._planes[0]
                end = max(p.offset + p.length for p in self._planes)
                self._map = mmap.mmap(plane.fd, end, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
            return self._map

    def __del__(self) -> None:
        if self._map is not None:
            try:
                self._map.close()
            except (BufferError, ValueError):
                pass  # still exported to a numpy array somewhere: the mapping goes with it


class FrameBufferAllocator:
    """libcamera's own allocator: buffers for a configured stream (``FrameBufferAllocator``)."""

    def __init__(self, camera: Any) -> None:
        self._camera = camera
        self._buffers: dict[Any, list[FrameBuffer]] = {}

    def allocate(self, stream: Any) -> int:
        """Allocate the stream's ``buffer_count`` buffers; returns how many."""
        if stream not in self._camera._active_streams():
            raise RuntimeError("Failed to allocate buffers: Invalid argument")
        if stream in self._buffers:
            raise RuntimeError("Failed to allocate buffers: Device or resource busy")
        config = stream.configuration
        buffers = []
        for i in range(config.buffer_count):
            fd = allocate_memory(f"libcamera-{i}", config.frame_size)
            buffers.append(FrameBuffer([FrameBufferPlane(fd, 0, config.frame_size)]))
            os.close(fd)
        self._buffers[stream] = buffers
        return len(buffers)

    @property
    def allocated(self) -> bool:
        return bool(self._buffers)

    def buffers(self, stream: Any) -> list[FrameBuffer]:
        return list(self._buffers.get(stream, []))
