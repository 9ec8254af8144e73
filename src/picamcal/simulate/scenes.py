"""What the simulated camera is shown: the five reference illuminations and the colour-wheel target.

The references are uniform illuminations by the LEDs (:data:`picamcal.references.ROLES`); the target is the
one colour-wheel target of :mod:`picamcal.colour_wheel`, the same that ``picamcal target`` writes, laid out
on the simulated frame (``wheel_layout(width, height)``: the file ``picamcal target --size WIDTHxHEIGHT``
writes for the sensor's size, photographed so that it fills the frame) and rendered in amounts of the LED
primaries. Every frame of a run draws its noise from its own random stream of the run's seed.

Examples
--------
>>> from picamcal.simulate import make_camera
>>> camera = make_camera("imx219", size=(320, 240))
>>> target, layout = simulate_target(camera, seed=1)
>>> target.metadata["scene"], [w["name"] for w in layout["wheels"]][:3]
('target', ['centre', 'top-left', 'top'])
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..colour_wheel import wheel_layout, wheel_scene
from ..errors import PicamcalError
from ..raw.model import RawImage
from ..references import ROLES
from .physics import SimulatedCamera, dust_specks, render, white_balance_gains

__all__ = ["DUST_STREAM", "TARGET_STREAM", "check_seed", "simulate_references", "simulate_target", "stream"]

# Independent random streams of one run (numpy SeedSequence spawn keys): one per reference, in the order of
# ROLES, then the dust positions and the target. picamcal.acquire's simulated camera draws the same ones.
#: Spawn key of the dust positions of a run.
DUST_STREAM = len(ROLES)
#: Spawn key of the target's noise.
TARGET_STREAM = len(ROLES) + 1


def check_seed(seed: int) -> int:
    """``seed`` if numpy can seed with it: a whole number, 0 or more.

    Examples
    --------
    >>> check_seed(7)
    7
    >>> check_seed(-1)
    Traceback (most recent call last):
    ...
    picamcal.errors.PicamcalError: the seed must be a whole number, 0 or more, got -1
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise PicamcalError(f"the seed must be a whole number, 0 or more, got {seed!r}")
    return int(seed)


def stream(seed: int, index: int) -> np.random.Generator:
    """Independent random stream ``index`` of a run with this seed.

    Examples
    --------
    >>> bool(stream(1, TARGET_STREAM).random() == stream(1, TARGET_STREAM).random())
    True
    """
    return np.random.default_rng(np.random.SeedSequence(check_seed(seed), spawn_key=(index,)))


def simulate_references(
    camera: SimulatedCamera, *, noise: bool = True, seed: int = 0, dust: int = 0
) -> dict[str, RawImage]:
    """Render the five reference illuminations: white, red, green, blue (the LEDs) and black (LED off).

    Parameters
    ----------
    camera : SimulatedCamera
    noise : bool
        Add shot and read noise.
    seed : int
        Seed of the noise and of the dust positions (each frame has its own stream).
    dust : int
        Number of dust specks on the white reference only (listed in its ``metadata["dust"]``).

    Returns
    -------
    dict of str to RawImage
        Keyed by :data:`picamcal.references.ROLES`, in that order. Each carries the camera's white balance as
        ``metadata["colour_gains"]`` (red, blue), what a camera with its white balance frozen on the white records.

    Examples
    --------
    >>> from picamcal.simulate import make_camera
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> refs = simulate_references(camera, noise=False, dust=2)
    >>> list(refs), len(refs["white"].metadata["dust"])
    (['white', 'red', 'green', 'blue', 'black'], 2)
    """
    specks = dust_specks(camera, dust, rng=stream(seed, DUST_STREAM))
    frames = {
        name: render(camera, name, noise=noise, rng=stream(seed, i), dust=specks if name == "white" else None)
        for i, name in enumerate(ROLES)
    }
    gains = white_balance_gains(camera)
    for raw in frames.values():
        raw.metadata["colour_gains"] = list(gains)
    return frames


def simulate_target(camera: SimulatedCamera, *, noise: bool = True, seed: int = 0) -> tuple[RawImage, dict[str, Any]]:
    """Render the colour-wheel target filling the frame, with the same frozen settings as the references.

    Returns
    -------
    RawImage
        The frame, ``metadata["scene"] == "target"``, with the references' ``metadata["colour_gains"]``.
    dict
        Its layout, :func:`picamcal.colour_wheel.wheel_layout` of the frame's size: nine wheels and five
        fiducial marks, what ``picamcal target --size WIDTHxHEIGHT`` writes for this frame size.

    Examples
    --------
    >>> from picamcal.simulate import make_camera
    >>> camera = make_camera("imx219", size=(320, 240))
    >>> raw, layout = simulate_target(camera, seed=3)
    >>> raw.metadata["scene"], len(layout["wheels"]), len(layout["fiducials"])
    ('target', 9, 5)
    """
    layout = wheel_layout(camera.width, camera.height)
    raw = render(camera, wheel_scene(layout), noise=noise, rng=stream(seed, TARGET_STREAM))
    raw.metadata["scene"] = "target"
    raw.metadata["colour_gains"] = white_balance_gains(camera)
    return raw, layout
