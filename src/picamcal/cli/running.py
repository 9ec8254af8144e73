"""The commands that run the whole method: ``simulate`` (a camera without one), ``acquire`` (the rig), ``verify`` (which
lens shading table is in force on the Pi) and ``demo``."""

# Annotations are not postponed (no `from __future__ import annotations`): typer reads every command's on each run,
# and would evaluate them from strings each time.

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from .._atomic import refuse_inputs_as_output
from ._common import (
    _parse_sensor_mode,
    app,
    choice,
    console,
    in_range,
    parse_colour_options,
    parse_size,
    progress_bar,
    stdout_console,
)

if TYPE_CHECKING:
    from ..acquire.verify import Verification

#: ``--illuminator`` of the commands that drive the rig.
ILLUMINATOR_HELP = (
    "serial (serial:PORT), gpio (gpio:PIN, default D18), screen (full-screen on this display, or prompts; "
    "screen:DISPLAY, screen:prompt), manual, sim, or virtual (the light of picamcal virtual-camera)."
)


@app.command("simulate")
def simulate_cmd(
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")],
    sensor: Annotated[
        str, typer.Option(help="Any colour sensor of the registry: imx219, imx477, ov5647, imx708, ...")
    ] = "imx219",
    tilt: Annotated[tuple[float, float], typer.Option(help="Sensor tilt about x and y, degrees.")] = (0.0, 0.0),
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    pattern: Annotated[str | None, typer.Option(help="Bayer order (default: the sensor's).")] = None,
    size: Annotated[str | None, typer.Option(help="Simulate WIDTHxHEIGHT instead of the full sensor.")] = None,
    noise: Annotated[bool, typer.Option(help="Shot and read noise.")] = True,
    dust: Annotated[int, typer.Option(help="Number of dust specks on the white reference.")] = 0,
    fmt: Annotated[str, typer.Option("--format", help="Raw format: dng, brcm (legacy JPEG+raw), npy, npz.")] = "dng",
    overwrite: Annotated[bool, typer.Option(help="Replace existing files.")] = False,
    spectral: Annotated[
        bool, typer.Option(help="The spectral model (docs/simulator.md): spectra, lenses, monitor and print targets.")
    ] = False,
    source: Annotated[
        str | None, typer.Option(help="With --spectral: the references' light, jig (LED) or monitor (full-screen).")
    ] = None,
    target: Annotated[
        str | None, typer.Option(help="With --spectral: the target shown, monitor, print or led.")
    ] = None,
    lens: Annotated[
        str | None, typer.Option(help="With --spectral: the optics for the target, none, long or short.")
    ] = None,
    colour: Annotated[
        list[str] | None,
        typer.Option(
            help="With --spectral: an extra reference NAME=R,G,B, 0-255 as for target and acquire (repeatable; "
            "default cyan, magenta, yellow)."
        ),
    ] = None,
) -> None:
    """Simulate a calibration run: five references, `picamcal target`'s target filling the frame, the ground truth."""
    from ..simulate import LENSES, RAW_WRITERS, SOURCES, TARGETS, simulate_run

    common: dict[str, Any] = {
        "pattern": pattern,
        "size": parse_size(size),
        "tilt": tilt,
        "seed": seed,
        "noise": noise,
        "fmt": choice(fmt, list(RAW_WRITERS), "--format"),
        "overwrite": overwrite,
    }
    if spectral:
        from ..simulate.spectral_run import amounts_of, simulate_spectral_run

        if dust:
            raise typer.BadParameter("--dust is not simulated with --spectral")
        with console().status(f"simulating {sensor} (spectral)"):
            paths = simulate_spectral_run(
                out,
                sensor,
                source=choice(source or "jig", list(SOURCES), "--source"),
                target=choice(target or "monitor", list(TARGETS), "--target"),
                lens=choice(lens or "none", list(LENSES), "--lens"),
                colours=None if colour is None else amounts_of(parse_colour_options(colour)),
                **common,
            )
    else:
        options = {"--source": source, "--target": target, "--lens": lens, "--colour": colour}
        given = [name for name, value in options.items() if value is not None]
        if given:
            raise typer.BadParameter(f"{given[0]} needs --spectral")
        with console().status(f"simulating {sensor}"):
            paths = simulate_run(out, sensor, dust=dust, **common)
    console().print(f"wrote {len(paths)} files to {out}")


@app.command("acquire")
def acquire_cmd(
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder of the run: created, or resumed if it holds one.")],
    camera: Annotated[str, typer.Option(help="picamera2 (picamera2:N for camera N) or sim.")] = "picamera2",
    illuminator: Annotated[str, typer.Option(help=ILLUMINATOR_HELP)] = "serial",
    sensor_mode: Annotated[
        str | None,
        typer.Option(
            "--sensor-mode",
            help="WIDTHxHEIGHT[:BITS]: the sensor mode to acquire in (--camera picamera2; default the full-resolution "
            "one). A cropped mode's calibration, and the lens shading table exported from it, cover that crop only.",
            callback=_parse_sensor_mode,
        ),
    ] = None,
    colour: Annotated[
        list[str] | None,
        typer.Option(
            help="An extra colour reference NAME=R,G,B (0-255), captured as colour_NAME after the five (repeatable)."
        ),
    ] = None,
    extra: Annotated[
        list[str] | None,
        typer.Option(help="An extra image at the same settings, e.g. target; asked for before each (repeatable)."),
    ] = None,
    target_fraction: Annotated[
        float,
        typer.Option(
            help="Where the white's 99.9th percentile should land, as a fraction of full scale.",
            callback=in_range(0, 1, above=True, below=True),
        ),
    ] = 0.8,
    settle: Annotated[
        float,
        typer.Option(help="Seconds to wait after changing the light.", callback=in_range(0, 600, unit=" s")),
    ] = 0.5,
    max_exposure: Annotated[
        float,
        typer.Option(
            help="Longest exposure time to use, in seconds.", callback=in_range(0, 3600, above=True, unit=" s")
        ),
    ] = 1.0,
    sensor: Annotated[str, typer.Option(help="Simulated sensor (--camera sim).")] = "imx219",
    size: Annotated[str | None, typer.Option(help="Simulate WIDTHxHEIGHT instead of the full sensor.")] = None,
    seed: Annotated[int, typer.Option(help="Random seed of the simulated camera.", callback=in_range(0))] = 0,
) -> None:
    """Capture a calibration run: auto-expose on white, freeze, then white, red, green, blue, black, colours, extras."""
    from ..acquire.acquisition import acquire, open_rig

    colours = parse_colour_options(colour)

    def show(message: str, done: int, total: int) -> None:
        # One line per step rather than a live bar, so it never draws over the prompts.
        console().print(f"[{done}/{total}] {message}")

    with open_rig(
        camera,
        illuminator,
        sensor=sensor,
        size=parse_size(size),
        seed=seed,
        sensor_mode=sensor_mode,
        colours=colours,
        prompt=input,
    ) as rig:
        light = rig.illuminator.describe()
        if light.get("shows") == "window":
            console().print(f"showing the colours full-screen on the display {light['display']}")
        elif light.get("shows") == "prompt":
            why = f" ({light['why']})" if "why" in light else ""
            console().print(f"you show the colours: picamcal target --screens writes the images{why}")
        manifest = acquire(
            rig.camera,
            rig.illuminator,
            out,
            colours=colours,
            extras=extra or (),
            target_fraction=target_fraction,
            settle_s=settle,
            max_exposure_s=max_exposure,
            prompt=rig.prompt,
            progress=show,
        )
    console().print(f"wrote {manifest}; calibrate with: picamcal calibrate {out}")


@app.command("verify")
def verify_cmd(
    camera: Annotated[str, typer.Option(help="picamera2 (picamera2:N for camera N).")] = "picamera2",
    tuning: Annotated[
        Path | None,
        typer.Option(
            help="The libcamera tuning file to check (picamcal export-tuning writes one); default the one the camera "
            "loads when given none, picamera2's stock file for the sensor."
        ),
    ] = None,
    illuminator: Annotated[str, typer.Option(help=ILLUMINATOR_HELP)] = "serial",
    tolerance: Annotated[
        str,
        typer.Option(
            help="FLAT,NEUTRAL in %: a mode passes when every corner is within FLAT % of its centre, per channel, "
            "and the centre's R/G and B/G within NEUTRAL % of 1."
        ),
    ] = "2,3",
    settle: Annotated[
        float,
        typer.Option(help="Seconds to wait after turning the white on.", callback=in_range(0, 600, unit=" s")),
    ] = 0.5,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Check which lens shading table is in force: the white through the camera's own pipeline, in every sensor mode.

    Each mode picamera2 reports is captured under the illuminator's white, with the tuning file given (or the one
    the camera loads by default) in which only the tone curve and the colour matrix are made identity, so that
    lens shading alone is measured; the colour gains are those the file records for the mode (picamcal
    export-tuning writes them), else the auto white balance's. Per mode it prints each channel's corner over the
    centre (the worst corner) and the centre's R/G and B/G. Exit status 0 when every mode is flat and neutral within
    the tolerance, 1 otherwise, 2 for a bad input (a missing file, a tuning for another sensor or the other Pi).
    """
    from ..acquire.pi_camera import picamera2_number
    from ..acquire.verify import verify_modes

    number = picamera2_number(camera)
    if number is None:
        raise typer.BadParameter(
            f"{camera!r}: verify checks a Raspberry Pi camera's own pipeline: picamera2 or picamera2:N (on a PC, "
            "under picamcal virtual-camera)",
            param_hint="--camera",
        )
    flatness, neutrality = _parse_tolerance(tolerance)
    with progress_bar() as progress:
        task = progress.add_task("verify", total=None)

        def step(mode: str, done: int, total: int) -> None:
            progress.update(task, description=mode, completed=done, total=total)

        result = verify_modes(
            number,
            tuning,
            illuminator,
            flatness_tolerance=flatness,
            neutrality_tolerance=neutrality,
            settle_s=settle,
            progress=step,
        )
    if as_json:
        print(json.dumps(result.to_record(), indent=2))
    else:
        _print_verification(result)
    if not result.passed:
        raise typer.Exit(1)


def _parse_tolerance(text: str) -> tuple[float, float]:
    """``--tolerance FLAT[,NEUTRAL]`` in % as fractions; NEUTRAL is 3 % when left out."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) == 1:
        values.append(3.0)
    if len(values) != 2:
        raise typer.BadParameter(f"{text!r} is not FLAT or FLAT,NEUTRAL in % (2 or 2,3)", param_hint="--tolerance")
    if not all(0 < v < 100 for v in values):  # NaN fails this too
        raise typer.BadParameter(
            f"{text!r}: each tolerance is a percentage above 0 and below 100", param_hint="--tolerance"
        )
    return values[0] / 100, values[1] / 100


#: How the table names where each mode's colour gains came from.
_GAINS_SOURCES = {"colour_gains_by_mode": "mode's", "colour_gains": "file's", "auto white balance": "AWB"}


def _print_verification(result: "Verification") -> None:
    from rich.table import Table

    table = Table(title=f"picamcal verify: {result.sensor} ({result.platform}), {result.tuning}")
    figures = ("R corner", "G corner", "B corner", "centre R/G", "centre B/G")
    for heading in (
        "mode",
        "crop on the sensor",
        *figures[:3],
        "worst corner",
        *figures[3:],
        "colour gains",
        "verdict",
    ):
        table.add_column(heading, justify="right" if heading in figures else "left")
    for check in result.modes:
        x, y, w, h = check.crop
        problems = [
            *([f"not flat ({100 * check.flatness:.1f} %)"] if not check.is_flat(result.flatness_tolerance) else []),
            *(
                [f"not neutral ({100 * check.neutrality:.1f} %)"]
                if not check.is_neutral(result.neutrality_tolerance)
                else []
            ),
        ]
        table.add_row(
            check.mode,
            f"{w}x{h} at {x},{y}",
            *(f"{v:.3f}" for v in check.worst),
            check.worst_corner,
            f"{check.centre[0]:.3f}",
            f"{check.centre[1]:.3f}",
            f"{check.colour_gains[0]:.3f},{check.colour_gains[1]:.3f} {_GAINS_SOURCES.get(check.gains_source, '')}",
            "; ".join(problems) or "ok",
        )
    stdout = stdout_console()
    stdout.print(table)
    for line in (
        "R, G, B corner: each channel's corner furthest from the centre, over the centre (linear: the tone curve and "
        "the colour matrix made identity); worst corner: the corner furthest in any channel. Colour gains: the "
        "tuning file's for the mode, the file's own, or the auto white balance's (AWB).",
        f"Tolerance: flat when every corner is within {100 * result.flatness_tolerance:g} % of the centre in each "
        f"channel; neutral when the centre's R/G and B/G are within {100 * result.neutrality_tolerance:g} % of 1.",
    ):
        stdout.print(line, markup=False, highlight=False)
    failed = [check.mode for check in result.modes if not result.passes(check)]
    if failed:
        stdout.print(f"{len(failed)} of {len(result.modes)} modes fail: {', '.join(failed)}", markup=False)
    else:
        stdout.print(f"every mode ({len(result.modes)}) is flat and neutral", markup=False)


@app.command("demo")
def demo_cmd(
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")] = Path("picamcal-demo"),
    sensor: Annotated[str, typer.Option(help="Simulated sensor.")] = "imx219",
    size: Annotated[str | None, typer.Option(help="Simulate WIDTHxHEIGHT instead of the full sensor.")] = None,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    fmt: Annotated[
        str, typer.Option("--format", help="Raw format of the simulated files: dng, brcm, npy, npz.")
    ] = "dng",
    tuning_base: Annotated[
        list[Path] | None,
        typer.Option(
            help="A libcamera tuning file to write the lens shading into (repeatable; default: the sensor's stock "
            "vc4 and pisp files)."
        ),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Write into a folder that is not empty.")] = False,
) -> None:
    """Run the whole method on the simulated camera and print the figures before and after."""
    from rich.table import Table

    from ..demo import STEPS, run_demo
    from ..simulate import RAW_WRITERS

    fmt = choice(fmt, list(RAW_WRITERS), "--format")
    refuse_inputs_as_output(out, tuning_base or ())
    with progress_bar() as progress:
        task = progress.add_task("demo", total=len(STEPS))

        def step(description: str) -> None:
            progress.update(task, description=description, completed=STEPS.index(description))

        figures = run_demo(
            out,
            sensor,
            size=parse_size(size),
            seed=seed,
            fmt=fmt,
            tuning_bases=tuning_base or (),
            progress=step,
            overwrite=overwrite,
        )
        progress.update(task, description="done", completed=len(STEPS))
    size_text = f"{figures['size'][0]}x{figures['size'][1]}"
    table = Table(title=f"picamcal demo: simulated {sensor} {size_text}, {fmt} files")
    table.add_column("mode")
    for heading in (
        "white flatness CV %",
        "corner ΔE2000 max",
        "corner ΔE2000 mean",
        "corner saturation",
        "noise penalty",
    ):
        table.add_column(heading, justify="right")
    for mode, row in figures["modes"].items():
        table.add_row(
            mode,
            f"{row['white_flatness_percent']:.2f}",
            f"{row['max_delta_e']:.2f}",
            f"{row['mean_delta_e']:.2f}",
            f"{row['corner_saturation_ratio']:.2f}",
            f"{row['worst_noise_penalty']:.2f}",
        )
    stdout = stdout_console()
    stdout.print(table)
    for mode, meaning in figures["mode_meaning"].items():
        stdout.print(f"  {mode}: {meaning}")
    for name, record in figures["exports"].items():
        gains = record.get("colour_gains")
        neutral = f" (neutral with colour gains {gains[0]:g},{gains[1]:g})" if gains else ""
        stdout.print(
            f"  {name}: an independent white is flat to {record['white_flatness_percent']:.2f} % with it{neutral}"
        )
    stdout.print(f"Calibration, previews (target_<mode>.png), the exports above and figures.json are in {out}/")
    stdout.print(f"The report: {out / 'report' / 'index.html'}")
