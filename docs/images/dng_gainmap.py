"""Render the pictures of docs/dng.md: a simulated frame developed by darktable without and with the GainMap.

The simulated IMX219 (640 x 480) photographs the colour-wheel target; its calibration's flat field goes into one DNG
as GainMap opcodes, the other DNG is the same mosaic without them. darktable-cli develops both with its defaults,
to 320 px wide PNGs. Regenerate them (darktable installed, Debian: darktable) from the repository's root with

    PYTHONPATH=src python3 docs/images/dng_gainmap.py

``tests/test_dng_gainmap.py`` runs :func:`make_images` into a temporary folder and checks what the pictures show.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import picamcal
from picamcal.raw import write_dng
from picamcal.simulate import make_camera, simulate_references, simulate_target

#: The pictures, under docs/images: without the map, with it.
NAMES = ("dng-without-gainmap.png", "dng-with-gainmap.png")


def make_images(folder: Path, width: int = 320) -> list[Path]:
    """Write the two PNGs into ``folder`` and return their paths (without the map, with it)."""
    camera = make_camera("imx219", size=(640, 480))
    cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    target, _ = simulate_target(camera, noise=False)  # no noise: the pictures stay small, the shading shows
    outputs = []
    with tempfile.TemporaryDirectory() as work:
        home = Path(work)
        for name, gain_map in zip(NAMES, (None, cal), strict=True):
            source = write_dng(home / Path(name).with_suffix(".dng"), target, gain_map=gain_map)
            out = folder / name
            out.unlink(missing_ok=True)  # darktable-cli never overwrites: it would write name_01.png
            command = [
                "darktable-cli", str(source), str(out), "--width", str(width), "--core",
                "--configdir", str(home / "dt"), "--library", ":memory:",
            ]  # fmt: skip
            subprocess.run(command, capture_output=True, check=True, env={**os.environ, "HOME": str(home)})
            outputs.append(out)
    return outputs


if __name__ == "__main__":
    for path in make_images(Path(__file__).resolve().parent):
        print(path, path.stat().st_size, "bytes", file=sys.stderr)
