"""A physical simulator of a Raspberry Pi camera sensor under normally incident light, and what it is shown.

Three modules, one per responsibility:

- :mod:`picamcal.simulate.physics`: the sensor model (lenslets shifted for the stock lens's chief rays,
  colour filters, photodiodes, shot and read noise), :func:`make_camera`, :func:`render`,
  :func:`expected_response` and the :func:`ground_truth` a calibration should recover;
- :mod:`picamcal.simulate.scenes`: the five reference illuminations (:func:`simulate_references`) and the
  colour-wheel target of :mod:`picamcal.colour_wheel` filling the frame (:func:`simulate_target`);
- :mod:`picamcal.simulate.run`: a whole simulated run written to a folder (:func:`simulate_run`, the
  ``picamcal simulate`` command) in any raw format of :data:`RAW_WRITERS`.

Examples
--------
>>> camera = make_camera("imx219", size=(320, 240))
>>> refs = simulate_references(camera, seed=1)
>>> refs["white"].bayer.shape, refs["white"].pattern
((240, 320), 'BGGR')
"""

from __future__ import annotations

from ..colour_wheel import wheel_layout, wheel_scene
from .physics import (
    MAX_DUST,
    REFERENCE_AMOUNTS,
    Optics,
    SimulatedCamera,
    dust_specks,
    expected_response,
    ground_truth,
    make_camera,
    render,
)
from .run import RAW_WRITERS, run_camera, simulate_run
from .scenes import simulate_references, simulate_target

__all__ = [
    "MAX_DUST",
    "RAW_WRITERS",
    "REFERENCE_AMOUNTS",
    "Optics",
    "SimulatedCamera",
    "dust_specks",
    "expected_response",
    "ground_truth",
    "make_camera",
    "render",
    "run_camera",
    "simulate_references",
    "simulate_run",
    "simulate_target",
    "wheel_layout",
    "wheel_scene",
]
