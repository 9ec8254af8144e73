"""libcamera's Python bindings, emulated by picamcal's virtual Raspberry Pi camera (:mod:`picamcal.virtualcam`).

Imported as ``libcamera`` (with the shim directory on the import path), it also answers picamera2's kernel calls
from the virtual camera (:func:`picamcal.virtualcam.kernel.install_hooks`), for the platform the environment
gives (``PICAMCAL_VIRTUAL_CAMERA_PLATFORM``).
"""

from . import _libcamera
from ._libcamera import *  # noqa: F403 - the bindings' module is libcamera._libcamera, re-exported whole

if __name__ == "libcamera":
    from picamcal.virtualcam.kernel import install_hooks
    from picamcal.virtualcam.options import Options

    install_hooks(Options.from_environment().platform)

__all__ = [name for name in dir(_libcamera) if not name.startswith("_")]
