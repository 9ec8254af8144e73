"""picamcal: flat-field and colour-crosstalk calibration for Raspberry Pi cameras behind custom optics.

Implements Bowman, Vodenicharski, Collins and Stirling, "Flat-field and colour correction for the
Raspberry Pi camera module".
"""

from __future__ import annotations

from ._version import __version__
from .calibrate import calibrate, calibrate_in_situ
from .calibration import Calibration, load_calibration
from .correct import correct
from .errors import (
    CalibrationFileError,
    CalibrationInputError,
    OutputError,
    PicamcalError,
    PicamcalWarning,
    RawFormatError,
)
from .modes import Mode
from .raw import RawImage, from_picamera2, read_raw, write_brcm, write_dng, write_npz

__all__ = [
    "Calibration",
    "CalibrationFileError",
    "CalibrationInputError",
    "Mode",
    "OutputError",
    "PicamcalError",
    "PicamcalWarning",
    "RawFormatError",
    "RawImage",
    "__version__",
    "calibrate",
    "calibrate_in_situ",
    "correct",
    "from_picamera2",
    "load_calibration",
    "read_raw",
    "write_brcm",
    "write_dng",
    "write_npz",
]
