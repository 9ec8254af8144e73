"""A virtual Raspberry Pi camera on which the real picamera2 runs unchanged (docs/virtual-camera.md).

picamcal emulates what picamera2 uses under it, behind the exact interfaces it uses:

- libcamera's Python bindings (the ``libcamera`` module: :mod:`.values`, :mod:`.controls`, :mod:`.config`,
  :mod:`.buffers`, :mod:`.camera`), with the Raspberry Pi pipeline's configurations for a Pi 4 (``vc4``) and a
  Pi 5 (``pisp``), its IPA (:mod:`.ipa`: the tuning file, exposure, white balance, metadata) and ISP (:mod:`.isp`);
- the sensor (:mod:`.modes`, :mod:`.frames`): picamcal's simulated optics behind a registry sensor's modes;
- the kernel's DMA-heap buffers, from memfd (:mod:`.kernel`);
- where its CPU time goes, stage by stage, when ``PICAMCAL_VIRTUAL_CAMERA_TIMING`` is set (:mod:`.timing`).

It is put in place for a command by ``picamcal virtual-camera -- COMMAND`` (:func:`run_with_virtual_camera`) or
in Python by :func:`install` before picamera2 is imported.

Examples
--------
>>> sorted(Options().environment())[:2]
['PICAMCAL_VIRTUAL_CAMERA_BRIGHTNESS', 'PICAMCAL_VIRTUAL_CAMERA_PLATFORM']
"""

from __future__ import annotations

from .install import check, environment, install, real_camera, run_with_virtual_camera, shim_directory
from .options import DEFAULT_SENSOR, PLATFORMS, VARIABLES, Options, VirtualCameraError

__all__ = [
    "DEFAULT_SENSOR",
    "PLATFORMS",
    "VARIABLES",
    "Options",
    "VirtualCameraError",
    "check",
    "environment",
    "install",
    "real_camera",
    "run_with_virtual_camera",
    "shim_directory",
]
