"""The main job, end to end on the simulated camera: references -> calibration -> corrected target -> figures.

This is what ``picamcal demo`` runs. It writes real DNG files and reads them back, so every step is
the one a user's own data goes through.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import atomic_path
from .analysis.metrics import flatness, save_preview, wheel_figures
from .calibrate import calibrate
from .calibration import Calibration
from .correct import correct
from .errors import OutputError
from .modes import Mode
from .raw import RawImage, read_raw
from .references import ROLES
from .report import write_report
from .simulate import run_camera, simulate_references, simulate_run

#: The steps run_demo reports, in order.
STEPS = (
    "simulating the calibration run",
    "reading the references",
    "calibrating",
    *(f"correcting the target ({mode})" for mode in Mode),
    "writing figures",
    "writing the report",
)


def run_demo(
    out_dir: str | Path,
    sensor: str = "imx219",
    *,
    size: tuple[int, int] | None = None,
    seed: int = 0,
    fmt: str = "dng",
    tuning_bases: Sequence[str | Path] = (),
    progress: Callable[[str], None] | None = None,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Simulate a calibration run, calibrate, correct the colour-wheel target in every mode and measure.

    Writes into ``out_dir``: ``raw/`` (the simulated DNG files, layout and ground truth),
    ``calibration.npz``, ``target_<mode>.png`` previews (sRGB), ``lens_shading_legacy.npy`` (the legacy
    firmware's table), ``tuning_<target>.json`` (libcamera tuning files with the calibration's lens shading:
    ``tuning_bcm2835.json`` for a Pi 4 and ``tuning_pisp.json`` for a Pi 5, from the sensor's stock files, or
    one for each base given), ``figures.json`` and the HTML report ``report/index.html``.

    Parameters
    ----------
    out_dir : path
        Output folder: created, or empty.
    sensor : str
        Simulated sensor (``ov5647``, ``imx219``, ``imx477``, ``imx708``).
    size : (width, height), optional
        Simulate a smaller frame (tests use this); default the sensor's full size.
    seed : int
        Random seed of the simulation.
    fmt : str
        Raw format of the simulated files (``dng``, ``brcm``, ``npy``, ``npz``: see
        :data:`picamcal.simulate.RAW_WRITERS`); they are read back through :func:`picamcal.read_raw`.
    tuning_bases : paths
        libcamera tuning files to write a static lens shading table into (one output per base); default the
        sensor's stock files for vc4 and pisp (:func:`picamcal.export.tuning.stock_tuning_bases`), those it has.
    progress : callable, optional
        Called with the description of each step in :data:`STEPS` as it starts.
    overwrite : bool
        Write into a folder that is not empty: one an earlier demo wrote, or one that holds none of the demo's
        file names (other files are never replaced).

    Returns
    -------
    dict
        The figures, per mode: white flatness (CV in %, of an independent white frame, binned),
        corner-vs-centre CIEDE2000 (max and mean), corner saturation relative to the centre, and the
        worst noise penalty; per export (``exports``), the white's flatness through it and, for a tuning
        file, its base and the colour gains that make the white neutral through it.

    Raises
    ------
    OutputError
        The folder is not empty (without ``overwrite``), or holds files of the demo's names that it did not write.
    PicamcalError
        An argument out of range (:func:`picamcal.simulate.run_camera`) or a base that is not a tuning file; all
        are checked before anything is written.

    Examples
    --------
    >>> figures = run_demo("demo-out", "imx219", size=(320, 240))
    >>> figures["modes"]["centre"]["max_delta_e"] < 1.5 < figures["modes"]["uncorrected"]["max_delta_e"]
    True
    >>> sorted(figures["exports"])
    ['lens_shading_legacy.npy', 'tuning_bcm2835.json', 'tuning_pisp.json']
    """
    from .export.tuning import load_tuning, stock_tuning_bases, stock_tuning_files

    step = progress or (lambda _: None)
    out = Path(out_dir)
    camera = run_camera(sensor, size=size, seed=seed, fmt=fmt)
    if not tuning_bases and "" in stock_tuning_files(sensor):  # the sensor's stock files, for each target that has one
        tuning_bases = stock_tuning_bases(sensor)[0]
    bases = [(Path(base), load_tuning(base)) for base in tuning_bases]
    _check_folder(out, overwrite)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the folder: {exc.strerror or exc}", out) from exc

    step(STEPS[0])
    paths = simulate_run(out / "raw", sensor, size=size, seed=seed, fmt=fmt, overwrite=True)
    check_white = simulate_references(camera, seed=seed + 1000)["white"]

    step(STEPS[1])
    white, red, green, blue, black = (read_raw(paths[role]) for role in ROLES)
    target = read_raw(paths["target"])
    layout = json.loads(Path(paths["layout"]).read_text())

    step(STEPS[2])
    cal = calibrate(white, red, green, blue, black)
    cal.save(out / "calibration.npz")

    modes: dict[str, dict[str, float]] = {}
    for mode in Mode:
        step(f"correcting the target ({mode})")
        rgb = correct(target, cal, mode)
        wheels = wheel_figures(rgb, layout)
        white_binned = correct(check_white, cal, mode, binned=True)
        modes[mode.value] = {
            "white_flatness_percent": float(100 * np.max(flatness(white_binned))),
            "max_delta_e": float(wheels["max_delta_e"]),
            "mean_delta_e": float(wheels["mean_delta_e"]),
            "corner_saturation_ratio": float(wheels["mean_saturation_ratio"]),
            "worst_noise_penalty": float(cal.noise_penalty(mode).max()),
        }
        save_preview(out / f"target_{mode}.png", rgb)

    step(STEPS[-2])
    exports = _write_exports(cal, out, bases, check_white)
    figures = {
        "sensor": sensor,
        "size": [target.width, target.height],
        "bin_size": cal.bin_size,
        "seed": seed,
        "format": fmt,
        "modes": modes,
        "exports": exports,
        "mode_meaning": {mode.value: mode.description for mode in Mode},
    }
    with atomic_path(out / "figures.json") as tmp:
        tmp.write_text(json.dumps(figures, indent=2))
    step(STEPS[-1])
    write_report(cal, out / "report", test_images=[target], overwrite=True)
    return figures


#: Names the demo writes in its folder (besides ``tuning_<target>.json``); ``figures.json`` marks a demo's folder.
_OUTPUTS = ("raw", "calibration.npz", *(f"target_{mode}.png" for mode in Mode), "lens_shading_legacy.npy")
_RECORD = "figures.json"


def _check_folder(out: Path, overwrite: bool) -> None:
    """Refuse a folder that is not empty (without ``overwrite``), or that holds the demo's names but is no demo's."""
    if out.exists() and not out.is_dir():
        raise OutputError("is not a folder", out)
    if not out.exists() or not any(out.iterdir()):
        return
    if not overwrite:
        raise OutputError("folder exists and is not empty (use --overwrite to write into it)", out)
    if _is_demo_record(out / _RECORD):
        return
    ours = [out / name for name in (*_OUTPUTS, _RECORD, "report")]
    clash = [path for path in [*ours, *out.glob("tuning_*.json")] if path.exists() or path.is_symlink()]
    if clash:
        raise OutputError(
            "exists in a folder that is not a picamcal demo's (it has no figures.json of one): --overwrite replaces "
            "only what the demo wrote; choose another output folder",
            clash[0],
        )


def _is_demo_record(path: Path) -> bool:
    if not path.is_file() or path.is_symlink():
        return False
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return False
    return isinstance(record, dict) and "mode_meaning" in record and "modes" in record


def _write_exports(cal: Calibration, out: Path, bases: Sequence[tuple[Path, dict]], white: RawImage) -> dict[str, Any]:
    """The legacy table and one tuning file per (path, loaded tuning) base, with the flatness each gives a white."""
    from .bayer import bin_sites
    from .export.isp import apply_tuning
    from .export.legacy import apply_legacy_table, legacy_table, save_legacy_table
    from .export.tuning import export_tuning, save_tuning, sensor_of_tuning_file

    exports: dict[str, Any] = {}
    table = legacy_table(cal)
    save_legacy_table(out / "lens_shading_legacy.npy", table, overwrite=True)
    legacy = bin_sites(apply_legacy_table(white, table), cal.bin_size)
    exports["lens_shading_legacy.npy"] = {"white_flatness_percent": float(100 * np.max(flatness(legacy)))}
    for base, base_tuning in bases:
        tuning = export_tuning(cal, base_tuning, base_sensor=sensor_of_tuning_file(base), base_path=base)
        name = f"tuning_{tuning['target']}.json"
        save_tuning(out / name, tuning, overwrite=True)
        rgb = apply_tuning(white, tuning)
        exports[name] = {
            "base": str(base),
            "white_flatness_percent": float(100 * np.max(flatness(rgb, bin_size=16))),
            "colour_gains": tuning["picamcal"]["colour_gains"],
        }
    return exports
