"""A simulated calibration run written to a folder: the references, the target and the ground truth.

:func:`simulate_run` writes what a real run with ``picamcal acquire`` gives (raw files of the five references
and the colour-wheel target, in any raw format of :data:`RAW_WRITERS`, and the target's layout) and what only
a simulation knows (the ground truth the calibration should recover). ``picamcal simulate`` is its command.

Examples
--------
>>> paths = simulate_run("run1", size=(320, 240), fmt="npz")
>>> sorted(p.name for p in paths.values())[:3]
['black.npz', 'blue.npz', 'green.npz']
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from .._atomic import atomic_path
from ..errors import OutputError, PicamcalError
from ..raw.brcm import write_brcm
from ..raw.dng import write_dng
from ..raw.model import RawImage
from ..raw.npz import write_npz
from ..raw.picamera2 import write_raw_as_picamera2_npy
from ..references import ROLES
from ..sensors import get_sensor
from .physics import SimulatedCamera, check_dust_count, ground_truth, make_camera
from .scenes import check_seed, simulate_references, simulate_target

__all__ = ["RAW_WRITERS", "RawWriter", "run_camera", "simulate_run"]


class RawWriter(Protocol):
    """A raw format's writer: ``writer(path, raw, overwrite=...)`` writes ``raw`` atomically to ``path``."""

    def __call__(self, path: str | os.PathLike[str], raw: RawImage, *, overwrite: bool = ...) -> Path: ...


#: Raw formats simulate_run writes: name -> (writer, file suffix).
RAW_WRITERS: dict[str, tuple[RawWriter, str]] = {
    "dng": (write_dng, ".dng"),
    "brcm": (write_brcm, ".jpg"),
    "npy": (write_raw_as_picamera2_npy, ".npy"),
    "npz": (write_npz, ".npz"),
}


def _write_json(path: Path, record: Mapping[str, Any], overwrite: bool) -> None:
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")


def run_camera(
    sensor: str = "imx219",
    *,
    pattern: str | None = None,
    size: tuple[int, int] | None = None,
    tilt: tuple[float, float] = (0.0, 0.0),
    seed: int = 0,
    dust: int = 0,
    fmt: str = "dng",
) -> SimulatedCamera:
    """The camera :func:`simulate_run` simulates, with every argument checked before anything is written.

    Parameters
    ----------
    sensor, pattern, size, tilt
        As :func:`make_camera`.
    seed : int
        Seed of the noise and dust: a whole number, 0 or more.
    dust : int
        Number of dust specks, 0 to :data:`picamcal.simulate.MAX_DUST`.
    fmt : str
        A raw format of :data:`RAW_WRITERS`; ``"brcm"`` only at one of the sensor's legacy mode sizes.

    Returns
    -------
    SimulatedCamera

    Raises
    ------
    PicamcalError
        Any argument out of range (a frame over the pixel limit of :func:`picamcal.limits.max_pixels` too).

    Examples
    --------
    >>> run_camera("imx219", size=(320, 240), fmt="npz").width
    320
    >>> run_camera("imx219", size=(320, 240), seed=-1)
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: the seed must be a whole number, 0 or more, got -1
    """
    if fmt not in RAW_WRITERS:
        raise PicamcalError(f"unknown raw format {fmt!r} (expected one of {', '.join(RAW_WRITERS)})")
    check_seed(seed)
    check_dust_count(dust)
    camera = make_camera(sensor, pattern=pattern, size=size, tilt=tilt)
    if fmt == "brcm" and not any(
        (m.width, m.height, m.bit_depth) == (camera.width, camera.height, camera.bit_depth)
        for m in get_sensor(sensor).legacy_modes
    ):
        modes = ", ".join(f"{m.width}x{m.height} {m.bit_depth}-bit" for m in get_sensor(sensor).legacy_modes)
        raise PicamcalError(
            f"the legacy JPEG+raw format has no {camera.width}x{camera.height} {camera.bit_depth}-bit mode for the "
            f"{sensor} (modes: {modes or 'none'})"
        )
    return camera


def check_run_outputs(paths: Mapping[str, Path], overwrite: bool) -> None:
    """Refuse a run's outputs that exist, unless ``overwrite`` and the folder is a run picamcal simulated (its
    ``truth_json`` says so): --overwrite replaces only what picamcal wrote."""
    existing = [path for path in paths.values() if path.exists() or path.is_symlink()]
    if existing and not overwrite:
        raise OutputError("exists already (use --overwrite to replace it)", existing[0])
    if existing and not _is_simulated_run(paths["truth_json"]):
        raise OutputError(
            "exists and the folder is not a simulated run (it has no truth.json of one): --overwrite replaces only "
            "what picamcal simulated; choose another output folder",
            existing[0],
        )


def _is_simulated_run(truth_json: Path) -> bool:
    """Whether ``truth_json`` is the record :func:`simulate_run` writes (a regular file: a FIFO would block)."""
    if not truth_json.is_file() or truth_json.is_symlink():
        return False
    try:
        record = json.loads(truth_json.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return False
    return isinstance(record, dict) and isinstance(record.get("optics"), dict) and "files" in record


def simulate_run(
    out_dir: str | os.PathLike[str],
    sensor: str = "imx219",
    *,
    pattern: str | None = None,
    size: tuple[int, int] | None = None,
    tilt: tuple[float, float] = (0.0, 0.0),
    seed: int = 0,
    noise: bool = True,
    dust: int = 0,
    bin_size: int = 16,
    fmt: str = "dng",
    overwrite: bool = False,
) -> dict[str, Path]:
    """Simulate a whole calibration run and write it to a directory, with its ground truth.

    Writes ``white``, ``red``, ``green``, ``blue``, ``black`` and ``target`` raw files (``.dng``, or
    another format with ``fmt``), ``layout.json`` (:func:`picamcal.colour_wheel.wheel_layout`), ``truth.npz``
    (:func:`ground_truth` arrays and ``bin_size``) and ``truth.json`` (sensor, pattern, size, tilt, seed,
    optics, exposure scale, dust specks, layout). Every file is written atomically.

    Parameters
    ----------
    out_dir : path-like
        Directory, created if missing.
    sensor, pattern, size, tilt
        As :func:`make_camera`.
    seed : int
        Seed of the noise and dust.
    noise : bool
        Add shot and read noise.
    dust : int
        Number of dust specks on the white reference.
    bin_size : int
        Bin size of the ground truth.
    fmt : {"dng", "brcm", "npy", "npz"}
        Raw file format: DNG, the legacy firmware's JPEG with a BRCM raw block (``.jpg``; only at the
        sensor's legacy mode sizes), picamera2's packed raw buffer as ``.npy`` with a JSON sidecar, or
        picamcal ``.npz``.
    overwrite : bool
        Replace the files of an earlier simulated run (a folder with its ``truth.json``); otherwise nothing is
        written if any output exists. Files in a folder that is not a simulated run are never replaced.

    Returns
    -------
    dict of str to Path
        The written files, keyed ``white`` ... ``black``, ``target``, ``layout``, ``truth_npz``, ``truth_json``.

    Raises
    ------
    OutputError
        An output file exists already and ``overwrite`` is False or the folder is not a simulated run, or the
        directory is not writable.
    PicamcalError
        An argument out of range (:func:`run_camera`).

    Examples
    --------
    >>> paths = simulate_run("run1", size=(320, 240), dust=3)
    >>> paths["white"], paths["truth_json"]
    (PosixPath('run1/white.dng'), PosixPath('run1/truth.json'))
    """
    camera = run_camera(sensor, pattern=pattern, size=size, tilt=tilt, seed=seed, dust=dust, fmt=fmt)
    writer, suffix = RAW_WRITERS[fmt]
    out = Path(out_dir)
    paths = {name: out / f"{name}{suffix}" for name in (*ROLES, "target")}
    paths.update(layout=out / "layout.json", truth_npz=out / "truth.npz", truth_json=out / "truth.json")
    check_run_outputs(paths, overwrite)
    truth = ground_truth(camera, bin_size=bin_size)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the directory: {exc.strerror or exc}", out) from exc

    frames = simulate_references(camera, noise=noise, seed=seed, dust=dust)
    target, layout = simulate_target(camera, noise=noise, seed=seed)
    frames["target"] = target
    for name, raw in frames.items():
        writer(paths[name], raw, overwrite=overwrite)
    _write_json(paths["layout"], layout, overwrite)
    arrays: dict[str, Any] = {**truth, "bin_size": np.array(bin_size)}
    with atomic_path(paths["truth_npz"], overwrite=overwrite) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)
    record = {
        "sensor": camera.sensor,
        "pattern": camera.pattern,
        "size": [camera.width, camera.height],
        "tilt": list(camera.tilt),
        "seed": int(seed),
        "noise": bool(noise),
        "bin_size": int(bin_size),
        "bit_depth": camera.bit_depth,
        "black_level": camera.black_level,
        "white_level": camera.white_level,
        "scale": camera.scale,
        "optics": asdict(camera.optics),
        "vignetting_centre": list(camera.vignetting_centre),
        "dust": frames["white"].metadata.get("dust", []),
        "layout": layout,
        "files": {name: path.name for name, path in paths.items()},
    }
    _write_json(paths["truth_json"], record, overwrite)
    return paths
