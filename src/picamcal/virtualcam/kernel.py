"""What picamera2 asks of the kernel, answered without a camera: DMA-heap buffers from memfd, and the platform.

picamera2's default allocator (``picamera2/dma_heap.py``, ``allocators/dmaallocator.py``) opens
``/dev/dma_heap/vidbuf_cached`` or ``/dev/dma_heap/linux,cma``, allocates each buffer with the
``DMA_HEAP_IOCTL_ALLOC`` ioctl, names it with ``DMA_BUF_SET_NAME``, maps it with ``mmap`` and brackets each read
with ``DMA_BUF_IOCTL_SYNC``; ``picamera2/platform.py`` tells a Pi 5 by a ``/dev/video*`` node whose card is
``pispbe``; ``Picamera2.load_tuning_file`` reads the stock tuning files libcamera installs in
``/usr/share/libcamera/ipa/rpi``. Inside the virtual camera (and only there: :func:`install_hooks` is called by
the ``libcamera`` shim that ``picamcal virtual-camera`` or :func:`picamcal.virtualcam.install` puts on the import
path), the ``os`` and
``fcntl`` those picamera2 modules see (and ``open`` in its main module) are replaced by thin wrappers: opening a heap
path gives a memfd that stands for the heap, the allocation ioctl on it gives a new memfd of the asked size, the
naming and sync ioctls on the virtual camera's buffers succeed, and libcamera's installed tuning files are the
copies picamcal ships where the machine has none; every other call goes to the real ``os``, ``fcntl`` and
``open``. The platform is
set on ``picamera2.platform`` after it has looked for itself. picamera2's code is not changed.

Examples
--------
>>> fd = VIRTUAL_OS.open(HEAP_PATHS[0], os.O_RDWR | os.O_CLOEXEC)
>>> kind_of(fd)
'heap'
>>> os.close(fd)
"""

from __future__ import annotations

import builtins
import ctypes
import fcntl
import importlib.abc
import importlib.util
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from ..export.tuning import BUNDLED_TUNING_DIR
from .buffers import BUFFER_NAME, allocate_memory
from .raspios_pidng import patch_request_module

#: Where libcamera installs the Raspberry Pi IPA's tuning files, and picamcal's copies of them.
_INSTALLED = {f"/usr/share/libcamera/ipa/rpi/{p}/": BUNDLED_TUNING_DIR / p for p in ("vc4", "pisp")}
#: The heaps picamera2 opens (``picamera2/dma_heap.py`` ``heapNames``).
HEAP_PATHS = ("/dev/dma_heap/vidbuf_cached", "/dev/dma_heap/linux,cma")
_HEAP_NAME = "picamcal-dma-heap"
# linux/dma-heap.h and linux/dma-buf.h: the ioctl "types" and numbers.
_HEAP_TYPE, _HEAP_ALLOC = ord("H"), 0
_BUF_TYPE, _BUF_SYNC, _BUF_SET_NAME = ord("b"), 0, 1


def kind_of(fd: int) -> str | None:
    """``"heap"`` or ``"buffer"`` for the virtual camera's memfds, else None (any other descriptor)."""
    try:
        target = os.readlink(f"/proc/self/fd/{int(fd)}")
    except OSError:
        return None
    if target.startswith(f"/memfd:{_HEAP_NAME}"):
        return "heap"
    if target.startswith(f"/memfd:{BUFFER_NAME}"):
        return "buffer"
    return None


def installed(path: Any) -> Any:
    """Where a file libcamera installs is: its stock tuning files (``/usr/share/libcamera/ipa/rpi/<platform>/``)
    are the copies picamcal ships when the machine has none; any other path is itself."""
    try:
        text = os.fspath(path)
    except TypeError:
        return path
    for prefix, bundled in _INSTALLED.items():
        if isinstance(text, str) and text.startswith(prefix) and not os.path.exists(text):
            return str(bundled / text[len(prefix) :])
    return path


class _VirtualPath:
    """``os.path`` as picamera2 sees it: libcamera's installed files are there (:func:`installed`)."""

    def __getattr__(self, name: str) -> Any:
        return getattr(os.path, name)

    def isfile(self, path: Any) -> bool:
        return os.path.isfile(installed(path))

    def exists(self, path: Any) -> bool:
        return os.path.exists(installed(path))


def _open(file: Any, *args: Any, **kwargs: Any) -> Any:
    """``open`` as picamera2's main module sees it: libcamera's installed files are there (:func:`installed`)."""
    return builtins.open(installed(file), *args, **kwargs)


class _VirtualOs:
    """``os`` as picamera2 sees it: the heap paths open a stand-in for the heap, and libcamera's installed files
    are there."""

    path = _VirtualPath()

    def __getattr__(self, name: str) -> Any:
        return getattr(os, name)

    def open(self, path: Any, flags: int, mode: int = 0o777, *, dir_fd: int | None = None) -> int:
        if os.fspath(path) in HEAP_PATHS:
            return os.memfd_create(_HEAP_NAME, os.MFD_CLOEXEC)
        return os.open(path, flags, mode, dir_fd=dir_fd)


class _VirtualFcntl:
    """``fcntl`` as picamera2's DMA-heap modules see it: the heap's and buffers' ioctls answered."""

    def __getattr__(self, name: str) -> Any:
        return getattr(fcntl, name)

    def ioctl(self, fd: Any, request: int, arg: Any = 0, mutate_flag: bool = True) -> Any:
        number = fd if isinstance(fd, int) else fd.fileno()
        kind = kind_of(number)
        kind_char, code = (int(request) >> 8) & 0xFF, int(request) & 0xFF
        if kind == "heap" and (kind_char, code) == (_HEAP_TYPE, _HEAP_ALLOC):
            length = int(_field(arg, "len", 0, 8))
            _set_field(arg, "fd", 8, allocate_memory("picamera2", length))
            return 0
        if kind == "buffer" and kind_char == _BUF_TYPE and code in (_BUF_SYNC, _BUF_SET_NAME):
            return 0
        return fcntl.ioctl(fd, request, arg, mutate_flag)


def _field(arg: Any, name: str, offset: int, size: int) -> int:
    """A field of an ioctl argument: a ctypes structure, or a writable buffer in the kernel's layout."""
    if isinstance(arg, ctypes.Structure):
        return int(getattr(arg, name))
    return int.from_bytes(memoryview(arg).cast("B")[offset : offset + size], "little")


def _set_field(arg: Any, name: str, offset: int, value: int) -> None:
    if isinstance(arg, ctypes.Structure):
        setattr(arg, name, value)
    else:
        memoryview(arg).cast("B")[offset : offset + 4] = int(value).to_bytes(4, "little")


VIRTUAL_OS = _VirtualOs()
VIRTUAL_FCNTL = _VirtualFcntl()


def _patch_heap(module: ModuleType) -> None:
    module.os = VIRTUAL_OS  # type: ignore[attr-defined]
    module.fcntl = VIRTUAL_FCNTL  # type: ignore[attr-defined]


def _patch_files(module: ModuleType) -> None:
    module.os = VIRTUAL_OS  # type: ignore[attr-defined]
    module.open = _open  # type: ignore[attr-defined]


def _patch_platform(platform: str) -> Callable[[ModuleType], None]:
    def patch(module: ModuleType) -> None:
        enum = module.Platform
        module._platform = enum.PISP if platform == "pisp" else enum.VC4  # type: ignore[attr-defined]

    return patch


class _AfterImport(importlib.abc.MetaPathFinder):
    """Runs a patch on a module right after it is first imported."""

    def __init__(self, patches: dict[str, Callable[[ModuleType], None]]) -> None:
        self.patches = patches

    def find_spec(self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None) -> Any:
        patch = self.patches.get(fullname)
        if patch is None:
            return None
        spec = None
        for finder in sys.meta_path:
            if finder is not self and hasattr(finder, "find_spec"):
                spec = finder.find_spec(fullname, path, target)
                if spec is not None:
                    break
        if spec is None or spec.loader is None:
            return None
        loader = spec.loader
        execute = loader.exec_module

        def exec_module(module: ModuleType) -> None:
            execute(module)
            patch(module)

        loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


class _DisplayStandIn(importlib.abc.MetaPathFinder):
    """``import pykms`` answered by :mod:`picamcal.virtualcam.display` where no kms++ module (``pykms``, ``kms``)
    is importable."""

    def find_spec(self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None) -> Any:
        if fullname != "pykms":
            return None
        for name in ("pykms", "kms"):
            for finder in sys.meta_path:
                if finder is not self and not isinstance(finder, _AfterImport) and hasattr(finder, "find_spec"):
                    if finder.find_spec(name, None) is not None:
                        return None
        return importlib.util.spec_from_file_location("pykms", Path(__file__).with_name("display.py"))


def install_hooks(platform: str) -> None:
    """Answer picamera2's kernel calls from the virtual camera, in modules imported now or later (once); stand in
    for kms++ where it is missing (:mod:`picamcal.virtualcam.display`); give picamera2 the PiDNG interface of
    Raspberry Pi OS (:mod:`picamcal.virtualcam.raspios_pidng`)."""
    patches: dict[str, Callable[[ModuleType], None]] = {
        "picamera2.dma_heap": _patch_heap,
        "picamera2.allocators.dmaallocator": _patch_heap,
        "picamera2.platform": _patch_platform(platform),
        "picamera2.picamera2": _patch_files,
        "picamera2.request": patch_request_module,
    }
    if any(isinstance(finder, _AfterImport) for finder in sys.meta_path):
        return
    for name, patch in patches.items():
        if name in sys.modules:
            patch(sys.modules[name])
    picamera2 = sys.modules.get("picamera2.picamera2")
    if picamera2 is not None and "picamera2.platform" in sys.modules:
        picamera2.Picamera2.platform = sys.modules["picamera2.platform"].get_platform()
    sys.meta_path.insert(0, _AfterImport(patches))
    sys.meta_path.append(_DisplayStandIn())
