"""napari's sample data of picamcal (File > Open Sample > picamcal): a simulated calibration run and its target.

Both come from one run of the simulator (:func:`picamcal.simulate.simulate_run`: an IMX219 at 640 x 480, the five
references and the colour-wheel target as DNG files, with the target's layout), made the first time a sample is
opened and kept in picamcal's cache folder (:func:`picamcal.ckernel.cache_dir`: ``$PICAMCAL_CACHE_DIR``, else
``~/.cache/picamcal``), under ``napari-samples/`` in a folder named for this version of the sample and of picamcal.
It is written in a temporary folder and renamed when complete, so a run cut short leaves nothing that looks made, and
two processes making it at once keep one. Later samples read it from there.

The layers are the reader's (:func:`._layers.raw_layers`), named for their role, with the files' paths in their
``metadata["picamcal"]`` so that a widget can read the files again (the Calibrate widget takes them as its roles).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from ._layers import METADATA_KEY, LayerData, raw_layers

__all__ = ["SAMPLE_SENSOR", "SAMPLE_SIZE", "calibration_run", "colour_wheel", "sample_folder"]

#: The simulated camera of the samples, and the seed of their noise.
SAMPLE_SENSOR = "imx219"
SAMPLE_SIZE = (640, 480)
SAMPLE_SEED = 1
#: Raise when the samples change (another camera, size, seed or format): the cache is then made again.
SAMPLE_VERSION = 1
#: The files of a complete sample run.
_FILES = ("white.dng", "red.dng", "green.dng", "blue.dng", "black.dng", "target.dng", "layout.json", "truth.json")


def sample_folder() -> Path:
    """The folder of the simulated run the samples come from, made on first use (a second or two) and then kept.

    Examples
    --------
    >>> folder = sample_folder()
    >>> folder.parent.name, sorted(p.name for p in folder.glob("*.dng"))[:3]
    ('napari-samples', ['black.dng', 'blue.dng', 'green.dng'])
    >>> sample_folder() == folder  # made once: the second call finds it
    True
    """
    from .._version import __version__
    from ..ckernel import cache_dir

    root = cache_dir() / "napari-samples"
    folder = root / f"calibration-run-v{SAMPLE_VERSION}-picamcal-{__version__}"
    if all((folder / name).is_file() for name in _FILES):
        return folder
    return _make(root, folder)


def _make(root: Path, folder: Path) -> Path:
    """Simulate the run into a temporary folder beside ``folder`` and rename it to ``folder`` once complete."""
    from ..errors import OutputError
    from ..simulate import simulate_run

    try:
        root.mkdir(parents=True, exist_ok=True)
        if folder.exists():  # incomplete: a file of it was removed
            shutil.rmtree(folder)
        temporary = Path(tempfile.mkdtemp(prefix=f".{folder.name}-", dir=root))
    except OSError as exc:
        raise OutputError(f"cannot make the sample data here: {exc.strerror or exc}", root) from exc
    try:
        simulate_run(temporary, SAMPLE_SENSOR, size=SAMPLE_SIZE, seed=SAMPLE_SEED, fmt="dng")
        try:
            os.rename(temporary, folder)
        except OSError as exc:
            if not all((folder / name).is_file() for name in _FILES):  # not made meanwhile by another process
                raise OutputError(f"cannot keep the sample data: {exc.strerror or exc}", folder) from exc
    finally:
        shutil.rmtree(temporary, ignore_errors=True)  # gone already once renamed
    return folder


def _layers_of(path: Path, name: str, **extra: Any) -> list[LayerData]:
    """The reader's layers of one sample file, named ``name``, with ``extra`` added to their record."""
    import warnings

    from ..errors import PicamcalWarning
    from ..raw import read_raw

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PicamcalWarning)
        raw = read_raw(path)
    said = [str(w.message) for w in caught if issubclass(w.category, PicamcalWarning)]
    layers = raw_layers(raw, name, warnings=said)
    for _, kwargs, _ in layers:
        kwargs["metadata"][METADATA_KEY].update(extra)
    return layers


def calibration_run() -> list[LayerData]:
    """The five references of a simulated IMX219 calibration run, as the linear RGB layers ``white``, ``red``,
    ``green``, ``blue`` and ``black`` (the white shown), each with its file's path and RawImage in its record.

    Examples
    --------
    >>> layers = calibration_run()
    >>> [(kwargs["name"], kwargs["visible"]) for _, kwargs, _ in layers][:2]
    [('white', True), ('red', False)]
    >>> record = layers[0][1]["metadata"]["picamcal"]
    >>> Path(record["path"]).name, record["role"], record["raw"].bayer.shape
    ('white.dng', 'white', (480, 640))
    """
    from ..references import ROLES

    folder = sample_folder()
    layers = []
    for role in ROLES:
        rgb_layer = _layers_of(folder / f"{role}.dng", role, role=role, sample_folder=str(folder))[0]
        rgb_layer[1]["visible"] = role == "white"
        layers.append(rgb_layer)
    return layers


def colour_wheel() -> list[LayerData]:
    """The colour-wheel target of the simulated run, its linear RGB and its mosaic, with the target's layout
    (:func:`picamcal.colour_wheel.wheel_layout`, the wheels' centres and radii in pixels) as ``layout`` in the record.

    Examples
    --------
    >>> (rgb, kwargs, _), (mosaic, _, _) = colour_wheel()
    >>> kwargs["name"], rgb.shape, mosaic.shape, len(kwargs["metadata"]["picamcal"]["layout"]["wheels"])
    ('colour-wheel target', (480, 640, 3), (480, 640), 9)
    """
    folder = sample_folder()
    layout = json.loads((folder / "layout.json").read_text(encoding="utf-8"))
    return _layers_of(folder / "target.dng", "colour-wheel target", layout=layout, sample_folder=str(folder))
