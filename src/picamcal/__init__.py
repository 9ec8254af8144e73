"""picamcal: flat-field and colour-crosstalk calibration for Raspberry Pi cameras behind custom optics.

Implements Bowman, Vodenicharski, Collins and Stirling, "Flat-field and colour correction for the
Raspberry Pi camera module".

The names below are imported when first used (PEP 562), so that ``import picamcal`` and the ``picamcal`` command
start without numpy, scipy or numba: ``from picamcal import calibrate`` and ``picamcal.calibrate(...)`` work as
usual, and load what the function needs then. Subpackages are reached the same way (``picamcal.simulate``).

>>> import picamcal
>>> picamcal.Mode.CENTRE.value
'centre'
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

from ._version import __version__
from .errors import (
    CalibrationFileError,
    CalibrationInputError,
    OutputError,
    PicamcalError,
    PicamcalWarning,
    RawFormatError,
)
from .modes import Mode

if TYPE_CHECKING:
    from .calibrate import calibrate, calibrate_in_situ
    from .calibration import Calibration, load_calibration
    from .correct import correct
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

#: Each name imported on first use -> the module that defines it (the imports under TYPE_CHECKING, for the checkers).
_LAZY = {
    "calibrate": "calibrate",
    "calibrate_in_situ": "calibrate",
    "Calibration": "calibration",
    "load_calibration": "calibration",
    "correct": "correct",
    "RawImage": "raw",
    "from_picamera2": "raw",
    "read_raw": "raw",
    "write_brcm": "raw",
    "write_dng": "raw",
    "write_npz": "raw",
}


def __getattr__(name: str) -> Any:
    """A name of ``__all__`` or a subpackage, imported when first asked for and then kept (PEP 562)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    if not name.startswith("__"):
        try:
            return importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":  # the submodule exists, something it imports does not
                raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


class _Package(types.ModuleType):
    """picamcal itself, keeping ``picamcal.calibrate`` and ``picamcal.correct`` the functions.

    Loading a submodule makes it an attribute of its package, and two submodules have the name of the function they
    define. When the package imported them eagerly the functions came after and stayed; imported lazily, the module
    would replace the function (``picamcal.calibrate(...)`` failing after any ``import picamcal.calibrate``).
    """

    def __setattr__(self, name: str, value: Any) -> None:
        if name in ("calibrate", "correct") and isinstance(value, types.ModuleType):
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
