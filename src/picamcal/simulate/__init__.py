"""A physical simulator of a Raspberry Pi camera sensor under normally incident light, and what it is shown.

Three modules, one per responsibility:

- :mod:`picamcal.simulate.physics`: the sensor model (lenslets shifted for the stock lens's chief rays,
  colour filters, photodiodes, shot and read noise), :func:`make_camera`, :func:`render`,
  :func:`expected_response` and the :func:`ground_truth` a calibration should recover;
- :mod:`picamcal.simulate.scenes`: the five reference illuminations (:func:`simulate_references`) and the
  colour-wheel target of :mod:`picamcal.colour_wheel` filling the frame (:func:`simulate_target`);
- :mod:`picamcal.simulate.run`: a whole simulated run written to a folder (:func:`simulate_run`, the
  ``picamcal simulate`` command) in any raw format of :data:`RAW_WRITERS`.

The spectral model (``picamcal simulate --spectral``, docs/simulator.md), where light is a spectrum and a per-bin
3 x 3 is no longer exact by construction:

- :mod:`picamcal.simulate.spectra`: sensor sensitivities, the jig's LED, a white LED, a monitor, printed inks;
- :mod:`picamcal.simulate.spectral`: the spectral camera behind a lens (:func:`make_spectral_camera`,
  :func:`render_spectral`);
- :mod:`picamcal.simulate.spectral_scenes`: references of a light source and the target on a monitor or in print;
- :mod:`picamcal.simulate.spectral_accuracy`: the truth, the floor of a target and the accuracy of each workflow
  (:func:`measure_workflow`);
- :mod:`picamcal.simulate.spectral_run`: a spectral run written to a folder (:func:`simulate_spectral_run`).

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
from .spectral import LENSES, SpectralCamera, make_spectral_camera, render_spectral
from .spectral_accuracy import WORKFLOWS, floor_unmixing, measure_workflow, score_target
from .spectral_run import simulate_spectral_run
from .spectral_scenes import SOURCES, TARGETS, spectral_references, spectral_target

__all__ = [
    "LENSES",
    "MAX_DUST",
    "RAW_WRITERS",
    "REFERENCE_AMOUNTS",
    "SOURCES",
    "TARGETS",
    "WORKFLOWS",
    "Optics",
    "SimulatedCamera",
    "SpectralCamera",
    "dust_specks",
    "expected_response",
    "floor_unmixing",
    "ground_truth",
    "make_camera",
    "make_spectral_camera",
    "measure_workflow",
    "render",
    "render_spectral",
    "run_camera",
    "score_target",
    "simulate_references",
    "simulate_run",
    "simulate_spectral_run",
    "simulate_target",
    "spectral_references",
    "spectral_target",
    "wheel_layout",
    "wheel_scene",
]
