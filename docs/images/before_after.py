"""Render the README's picture: the simulated colour-wheel target as the sensor saw it and corrected (mode centre).

A simulated Camera Module v2 (IMX219, 640 x 480, behind normally incident optics) is calibrated from its five
references (seed 1) and photographs the target (seed 2, no noise, so that the picture stays small); the two
corrections, sRGB-encoded, are put side by side at 320 x 240 each, with a 16-pixel dark grey gap. Regenerate it from
the repository's root with

    python3 docs/images/before_after.py

``tests/test_docs_site.py`` runs :func:`make_image` and compares it with the committed picture.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

import picamcal
from picamcal.analysis.metrics import encode_srgb
from picamcal.simulate import make_camera, simulate_references, simulate_target

#: The picture, beside this script.
NAME = "before-after.png"
GAP = 16


def make_image() -> np.ndarray:
    """The picture as an (240, 656, 3) uint8 sRGB array: uncorrected on the left, mode centre on the right."""
    camera = make_camera("imx219", size=(640, 480))
    cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    target, _ = simulate_target(camera, seed=2, noise=False)
    halves = []
    for mode in ("uncorrected", "centre"):
        rgb = picamcal.correct(target, cal, mode=mode)
        small = rgb.reshape(240, 2, 320, 2, 3).mean(axis=(1, 3))  # 2 x 2 binning: the linear mean
        halves.append(encode_srgb(small))
    gap = np.full((240, GAP, 3), 64, np.uint8)
    return np.concatenate([halves[0], gap, halves[1]], axis=1)


if __name__ == "__main__":
    path = Path(__file__).resolve().parent / NAME
    Image.fromarray(make_image()).save(path, optimize=True)
    print(path, path.stat().st_size, "bytes")
