"""The ``virtual-camera`` command: run a program with a virtual Raspberry Pi camera under picamera2
(docs/virtual-camera.md)."""

# Annotations are not postponed (no `from __future__ import annotations`): typer reads every command's on each run.

from typing import Annotated

import typer

from ._common import app, choice, parse_size


@app.command(
    "virtual-camera",
    context_settings={"allow_interspersed_args": False, "ignore_unknown_options": True},
)
def virtual_camera_cmd(
    command: Annotated[
        list[str] | None, typer.Argument(help="The command to run, after --: python3 script.py, picamcal acquire ...")
    ] = None,
    platform: Annotated[str, typer.Option(help="pisp (a Raspberry Pi 5) or vc4 (a Raspberry Pi 4).")] = "pisp",
    sensor: Annotated[str, typer.Option(help="The sensor: imx477 (HQ camera), imx219, imx708, ov5647, ...")] = "imx477",
    size: Annotated[
        str | None, typer.Option(help="Simulate a WIDTHxHEIGHT pixel array instead of the full sensor (faster).")
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the sensor noise.", min=0)] = 0,
    scene: Annotated[
        str,
        typer.Option(
            help="What the camera sees: white (a white diffuser), wheel (the colour-wheel target) or an image."
        ),
    ] = "white",
    brightness: Annotated[
        float | None,
        typer.Option(
            help="The light: the exposure fraction of the brightest white pixel at 10 ms and gain 1 (default 0.25)."
        ),
    ] = None,
    force: Annotated[
        bool, typer.Option(help="Run even where a real camera is found (a real libcamera, a Pi camera device).")
    ] = False,
) -> int:
    """Run a command with a virtual Raspberry Pi camera: picamera2 from PyPI sees a simulated sensor behind the
    optics picamcal simulates, on a simulated Pi 5 or Pi 4 (docs/virtual-camera.md)."""
    from ..virtualcam import PLATFORMS, Options, run_with_virtual_camera

    light = {} if brightness is None else {"brightness": brightness}
    options = Options(
        platform=choice(platform, PLATFORMS, "--platform"),
        sensor=sensor,
        size=parse_size(size),
        seed=seed,
        scene=scene,
        **light,
    )
    return run_with_virtual_camera(command or [], options, force=force)
