"""picamcal in napari: a reader for every raw format picamcal reads and for calibrations, the Correct, Calibrate and
Inspect widgets, sample data and writers (``napari.yaml``, found by napari through the ``napari.manifest`` entry
point; docs/napari.md). Install with ``pip install "picamcal[napari]"``.

napari loads the modules behind these names when it needs them, and the names below are imported when first used
(PEP 562), so ``import picamcal.napari`` imports neither napari nor Qt; only the widgets need Qt. The same functions
work without a viewer, on picamcal's own values: a raw frame or a calibration as napari layer data.

>>> from picamcal.napari import raw_layers
>>> from picamcal.simulate import make_camera, simulate_references
>>> white = simulate_references(make_camera("imx219", size=(320, 240)), seed=1)["white"]
>>> [(kind, data.shape) for data, _, kind in raw_layers(white, "white")]
[('image', (240, 320, 3)), ('image', (240, 320))]
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ._calibrate_widget import CalibrateWidget
    from ._correct_widget import CorrectWidget, correct_layer, noise_penalty_layer
    from ._layers import calibration_layers, image_layer, linear_rgb, raw_layers
    from ._reader import get_reader
    from ._sample import calibration_run, colour_wheel
    from ._widgets import InspectWidget
    from ._writer import write_ome_zarr, write_tiff

#: Each public name and the module that defines it.
_LAZY = {
    "get_reader": "_reader",
    "raw_layers": "_layers",
    "linear_rgb": "_layers",
    "calibration_layers": "_layers",
    "image_layer": "_layers",
    "correct_layer": "_correct_widget",
    "noise_penalty_layer": "_correct_widget",
    "write_tiff": "_writer",
    "write_ome_zarr": "_writer",
    "calibration_run": "_sample",
    "colour_wheel": "_sample",
    "CorrectWidget": "_correct_widget",
    "CalibrateWidget": "_calibrate_widget",
    "InspectWidget": "_widgets",
}

__all__ = [
    "CalibrateWidget",
    "CorrectWidget",
    "InspectWidget",
    "calibration_layers",
    "calibration_run",
    "colour_wheel",
    "correct_layer",
    "get_reader",
    "image_layer",
    "linear_rgb",
    "noise_penalty_layer",
    "raw_layers",
    "write_ome_zarr",
    "write_tiff",
]


def __getattr__(name: str) -> Any:
    """A name of ``__all__``, imported from its module when first asked for (PEP 562)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
