"""A spectral simulated run written to a folder: ``picamcal simulate --spectral``.

The same kind of folder as :func:`picamcal.simulate.simulate_run` writes (the five references, the target, its
``layout.json``, ``truth.npz`` and ``truth.json``), from the spectral model (:mod:`picamcal.simulate.spectral`):
references of the jig's LED (taken in the jig, at normal incidence) or of the monitor's full-screen colours
(through the lens), the colour-wheel target shown on the monitor or printed, photographed through the lens.
With the jig's references and a lens, ``in_situ/white`` is the target's white through the lens, for
``picamcal calibrate-in-situ``. The truth holds what the centre of the sensor sees of the target's colours
and the floor (:mod:`picamcal.simulate.spectral_accuracy`).

Examples
--------
>>> paths = simulate_spectral_run("spectral1", size=(320, 240), source="jig", target="print", lens="long", fmt="npz")
>>> sorted(p.name for p in paths.values())[:3], paths["in_situ_white"].as_posix()
(['black.npz', 'blue.npz', 'colour_cyan.npz'], 'spectral1/in_situ/white.npz')
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_path
from ..calibrate import calibrate_in_situ
from ..correct import correct
from ..errors import OutputError, PicamcalError
from ..references import ROLES
from .run import RAW_WRITERS, _write_json, check_run_outputs
from .scenes import check_seed, stream
from .spectral import LENSES, SpectralCamera, least_squares_unmixing, make_spectral_camera, render_spectral
from .spectral_accuracy import (
    calibrate_references,
    floor_calibration,
    score_target,
    target_truth,
    unmixing_residual,
)
from .spectral_scenes import (
    SECONDARY_COLOURS,
    SOURCES,
    TARGETS,
    LightSource,
    TargetScene,
    colour_amounts,
    spectral_references,
    spectral_target,
    target_white,
)

__all__ = ["amounts_of", "simulate_spectral_run"]


def amounts_of(colours: Mapping[str, tuple[int, int, int]]) -> dict[str, tuple[float, float, float]]:
    """Extra colours as ``--colour`` gives them, 0-255 (:func:`picamcal.references.parse_colours`), as amounts 0 to 1
    of the source's primaries: the drive levels the jig or the monitor is set to.

    Examples
    --------
    >>> amounts_of({"amber": (255, 128, 0)})
    {'amber': (1.0, 0.502, 0.0)}
    """
    return {name: (round(r / 255, 3), round(g / 255, 3), round(b / 255, 3)) for name, (r, g, b) in colours.items()}


def simulate_spectral_run(
    out_dir: str | os.PathLike[str],
    sensor: str = "imx219",
    *,
    source: str = "jig",
    target: str = "monitor",
    lens: str = "none",
    colours: Mapping[str, tuple[float, float, float]] | None = None,
    pattern: str | None = None,
    size: tuple[int, int] | None = None,
    tilt: tuple[float, float] = (0.0, 0.0),
    seed: int = 0,
    noise: bool = True,
    bin_size: int = 16,
    fmt: str = "dng",
    overwrite: bool = False,
) -> dict[str, Path]:
    """Simulate a whole calibration run with the spectral model and write it to a directory, with its truth.

    Parameters
    ----------
    out_dir : path-like
        Directory, created if missing.
    sensor, pattern, size, tilt
        As :func:`picamcal.simulate.spectral.make_spectral_camera`.
    source : {"jig", "monitor"}
        The references' light: the jig's LED at normal incidence, or the monitor's full-screen colours through
        the lens.
    target : {"monitor", "print", "led"}
        The colour-wheel target's form (:data:`picamcal.simulate.spectral_scenes.TARGETS`).
    lens : {"none", "long", "short"}
        The optics the target (and the monitor's references) is photographed through (:data:`LENSES`).
    colours : mapping of str to 3 amounts, optional
        Extra ``colour_<name>`` references; default the secondaries
        (:data:`picamcal.simulate.spectral_scenes.SECONDARY_COLOURS`). Empty for none.
    seed, noise, bin_size, fmt, overwrite
        As :func:`picamcal.simulate.simulate_run`.

    Returns
    -------
    dict of str to Path
        The written files, keyed by role (and ``colour_<name>``), ``target``, ``in_situ_white`` (jig with a
        lens), ``layout``, ``truth_npz`` and ``truth_json``.

    Raises
    ------
    OutputError
        As :func:`picamcal.simulate.simulate_run`.
    PicamcalError
        An argument out of range.

    Examples
    --------
    >>> paths = simulate_spectral_run("spectral2", size=(320, 240), source="monitor", lens="short", colours={})
    >>> paths["white"].name, paths["target"].name, "in_situ_white" in paths
    ('white.dng', 'target.dng', False)
    """
    if source not in SOURCES:
        raise PicamcalError(f"unknown reference source {source!r} (expected one of {', '.join(SOURCES)})")
    if target not in TARGETS:
        raise PicamcalError(f"unknown target {target!r} (expected one of {', '.join(TARGETS)})")
    if lens not in LENSES:
        raise PicamcalError(f"unknown lens {lens!r} (expected one of {', '.join(LENSES)})")
    if fmt not in RAW_WRITERS or fmt == "brcm":
        raise PicamcalError(f"a spectral run writes dng, npy or npz, not {fmt!r}")
    check_seed(seed)
    extra = dict(SECONDARY_COLOURS if colours is None else colours)
    for name, amounts in extra.items():
        colour_amounts(f"colour_{name}", amounts)
    white = target_white(target)
    camera = make_spectral_camera(sensor, pattern=pattern, size=size, tilt=tilt, lens=lens, white=white)
    jig = make_spectral_camera(sensor, pattern=pattern, size=size, tilt=tilt, lens="none")
    writer, suffix = RAW_WRITERS[fmt]
    out = Path(out_dir)
    names = [*ROLES, *(f"colour_{name}" for name in extra), "target"]
    paths = {name: out / f"{name}{suffix}" for name in names}
    in_situ = source == "jig" and lens != "none"
    if in_situ:
        paths["in_situ_white"] = out / "in_situ" / f"white{suffix}"
    paths.update(layout=out / "layout.json", truth_npz=out / "truth.npz", truth_json=out / "truth.json")
    check_run_outputs(paths, overwrite)
    try:
        paths["layout"].parent.mkdir(parents=True, exist_ok=True)
        if in_situ:
            paths["in_situ_white"].parent.mkdir(exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the directory: {exc.strerror or exc}", out) from exc

    reference_camera = jig if source == "jig" else camera
    light = SOURCES[source]()
    frames = spectral_references(reference_camera, light, colours=extra, noise=noise, seed=seed)
    frames["target"], scene = spectral_target(camera, target, noise=noise, seed=seed)
    if in_situ:
        frames["in_situ_white"] = render_spectral(camera, white, noise=noise, rng=stream(seed, 0), scene="white")
    for name, raw in frames.items():
        writer(paths[name], raw, overwrite=overwrite)
    _write_json(paths["layout"], scene.layout, overwrite)
    truth, scores = _truth(camera, reference_camera, light, scene, in_situ, bin_size)
    arrays: dict[str, Any] = {**truth, "bin_size": np.array(bin_size)}
    with atomic_path(paths["truth_npz"], overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)
    record: dict[str, Any] = {
        "spectral": True,
        "sensor": camera.sensor,
        "pattern": camera.pattern,
        "size": [camera.width, camera.height],
        "tilt": list(camera.base.tilt),
        "seed": int(seed),
        "noise": bool(noise),
        "bin_size": int(bin_size),
        "source": source,
        "target": target,
        "lens": lens,
        "chief_ray_corner_deg": camera.chief_ray_corner_deg,
        "colours": {name: list(amounts) for name, amounts in extra.items()},
        "bit_depth": camera.base.bit_depth,
        "black_level": camera.base.black_level,
        "white_level": camera.base.white_level,
        "spot_optical": camera.spot_optical,
        "spot_diffusion": camera.spot_diffusion,
        "optics": {k: getattr(camera.base.optics, k) for k in ("photodiode_width", "lenslet_shift_corner")},
        "target_colours": scene.colour_names,
        **scores,
        "layout": scene.layout,
        "files": {name: path.relative_to(out).as_posix() for name, path in paths.items()},
    }
    _write_json(paths["truth_json"], record, overwrite)
    return paths


def _truth(
    camera: SpectralCamera,
    reference_camera: SpectralCamera,
    light: LightSource,
    scene: TargetScene,
    in_situ: bool,
    bin_size: int,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The noiseless calibration of the run's workflow, the target's truth, its floor field and the floor's scores."""
    cal = calibrate_references(spectral_references(reference_camera, light, noise=False), bin_size=bin_size)
    if in_situ:
        white = render_spectral(camera, target_white(scene.kind), noise=False, scene="white")
        cal = calibrate_in_situ(white, cal)
    flat, truth = target_truth(camera, cal, scene)
    fitted = least_squares_unmixing(flat, truth)
    floor = fitted.astype(np.float32)
    raw, _ = spectral_target(camera, scene.kind, noise=False)
    arrays = {"target_flat": flat, "target_truth": truth, "floor_unmixing": floor, "site_white": cal.site_white}
    scores = {
        "floor": score_target(correct(raw, floor_calibration(cal, floor), "centre"), scene),
        "floor_residual": unmixing_residual(flat, truth, fitted),
        "noiseless_centre": score_target(correct(raw, cal, "centre"), scene),
    }
    return arrays, scores
