"""The directory the virtual camera puts on the import path: it holds the ``libcamera`` package only.

Nothing here is on the import path by default (this is ``picamcal.virtualcam.shim``); ``picamcal virtual-camera``
and :func:`picamcal.virtualcam.install` put this directory first on it, so that ``import libcamera`` finds the
virtual camera's bindings (:mod:`picamcal.virtualcam.shim.libcamera`).
"""
