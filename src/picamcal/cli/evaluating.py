"""The commands that show how good a calibration is: ``target`` (the colour-wheel test target), ``analyse``
(its images) and ``report``."""

# Annotations are not postponed (no `from __future__ import annotations`): typer reads every command's on each run,
# and would evaluate them from strings each time.

import json
from pathlib import Path
from typing import Annotated

import typer

from .._atomic import atomic_path, refuse_inputs_as_output
from ..errors import OutputError, PicamcalError
from ._common import (
    app,
    check_output,
    console,
    in_range,
    parse_colour_options,
    parse_size,
    progress_bar,
    stdout_console,
)


@app.command("target")
def target_cmd(
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            "-o",
            help="TARGET.png or TARGET.pdf; the layout goes to TARGET.json. With --screens: a FOLDER for the screens "
            "alone, or TARGET.png to write the screens beside it.",
        ),
    ],
    size: Annotated[
        str, typer.Option(help="WIDTHxHEIGHT in pixels (your monitor's, to show it full-screen).")
    ] = "1920x1080",
    screens: Annotated[
        bool,
        typer.Option(
            help="Write the full-screen references screen_white.png, screen_red.png, screen_green.png, "
            "screen_blue.png, screen_black.png (and screen_colour_NAME.png) into --out, or beside TARGET.png."
        ),
    ] = False,
    colour: Annotated[
        list[str] | None,
        typer.Option(help="With --screens: an extra full-screen colour NAME=R,G,B (0-255) (repeatable)."),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace existing files.")] = False,
) -> None:
    """Write the colour-wheel test target (PNG to show full-screen, or PDF to print) and its layout.

    The same target `picamcal simulate` photographs, laid out on WIDTHxHEIGHT pixels. With --screens, the
    full-screen references too, for a calibration in the monitor's own colours.
    """
    from ..target import is_target_file, save_screens, save_target

    width, height = parse_size(size) or (1920, 1080)
    if colour and not screens:
        raise typer.BadParameter("it names a full-screen colour: give --screens too", param_hint="--colour")
    colours = parse_colour_options(colour)
    target = not screens or out.suffix.lower() in (".png", ".pdf")
    if target and out.suffix.lower() not in (".png", ".pdf"):
        raise typer.BadParameter("the target is written as .png or .pdf", param_hint="--out")
    if target:
        for path in (out, out.with_suffix(".json")):
            check_output(path, overwrite, is_target_file, "a target picamcal wrote")
    if screens:  # first: save_screens refuses every existing screen before it writes any
        folder = out.parent if target else out
        paths = save_screens(folder, width, height, colours, overwrite=overwrite)
        console().print(f"wrote {len(paths)} full-screen references to {folder}: {', '.join(p.name for p in paths)}")
        console().print("show each full-screen, unscaled, with the monitor's brightness fixed and auto-dimming off")
    if target:
        image, layout = save_target(out, width, height, overwrite=overwrite)
        console().print(f"wrote {image} and its layout {layout}")


@app.command("analyse")
def analyse_cmd(
    images: Annotated[list[Path], typer.Argument(help="Images of the colour-wheel target (raw or processed).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")],
    calibration: Annotated[Path | None, typer.Option(help="Calibration: analyse every correction mode.")] = None,
    layout: Annotated[
        Path | None, typer.Option(help="The target's layout (TARGET.json), to use its fiducials.")
    ] = None,
    input_encoding: Annotated[
        str, typer.Option(help="For processed images: srgb, linear, gamma:G, tuning:FILE.")
    ] = "srgb",
    overwrite: Annotated[bool, typer.Option(help="Replace existing outputs.")] = False,
) -> None:
    """Find the colour wheels, compare each with the centre wheel (CIEDE2000, hue, saturation), draw polar plots."""
    from rich.table import Table

    from ..analysis.images import images_by_mode
    from ..analysis.wheels import analyse, find_wheels, polar_plot, read_layout
    from ..calibration import load_calibration

    refuse_inputs_as_output(out, [*images, calibration, layout])
    cal = load_calibration(calibration) if calibration is not None else None
    target_layout = read_layout(layout) if layout is not None else None
    outputs = [out / f"{image.stem}_analysis.json" for image in images]
    for path in outputs:
        if path.exists() and not overwrite:
            raise OutputError("exists already (use --overwrite to replace it)", path)
    table = Table(title="CIEDE2000 of the wheels against the centre wheel")
    for heading in ("image", "mode", "max", "mean", "saturation"):
        table.add_column(heading)
    with progress_bar() as progress:
        task = progress.add_task("analysing", total=len(images))
        for image, output in zip(images, outputs, strict=True):
            by_mode = images_by_mode(image, cal, input_encoding=input_encoding)
            first = next(iter(by_mode.values()))
            try:
                found = find_wheels(first, layout=target_layout)
            except PicamcalError as exc:
                raise PicamcalError(exc.problem, image) from None
            result = analyse(by_mode, found)
            try:  # only now: an image that cannot be analysed leaves no folder behind
                out.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise OutputError(f"cannot create the folder: {exc.strerror or exc}", out) from exc
            for mode in by_mode:
                polar_plot(result[mode], out / f"{image.stem}_{mode}_polar.png", title=f"{image.name}: {mode}")
                summary = result[mode].get("summary", result[mode])
                table.add_row(
                    image.name,
                    mode,
                    f"{summary['max_delta_e']:.2f}",
                    f"{summary['mean_delta_e']:.2f}",
                    f"{summary['mean_saturation_ratio']:.2f}",
                )
            with atomic_path(output, overwrite=True) as tmp:
                tmp.write_text(
                    json.dumps({"image": str(image), "layout": found, "analysis": result}, indent=2, default=float)
                )
            progress.advance(task)
    stdout_console().print(table)


@app.command("report")
def report_cmd(
    calibration: Annotated[Path, typer.Argument(help="Calibration file (.npz).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Report folder (index.html and figures).")],
    test: Annotated[
        list[Path] | None, typer.Option(help="A raw image of the colour-wheel target (repeatable).")
    ] = None,
    layout: Annotated[Path | None, typer.Option(help="The target's layout (TARGET.json).")] = None,
    cra: Annotated[
        float | None,
        typer.Option(
            help="Chief ray angle of the lenslets at the sensor corner, degrees (for tilt).",
            callback=in_range(
                0,
                90,
                above=True,
                below=True,
                unit=" degrees",
                why="the tilt is the vignetting centre's offset times tan(CRA): 0 is a sensor without lenslet shift, "
                "whose vignetting centre says nothing about tilt, and 90 is a ray along the sensor",
            ),
        ),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing report.")] = False,
) -> None:
    """Write an HTML report: diagnostics with verdicts, maps, and before/after evidence from test images."""
    from ..analysis.wheels import read_layout
    from ..calibration import load_calibration
    from ..export.tables import refuse_table
    from ..report import write_report

    refuse_table(calibration, "the report")  # a lens shading table is told what takes it
    cal = load_calibration(calibration)
    target_layout = read_layout(layout) if layout is not None else None
    with console().status("writing the report") as status:
        index = write_report(
            cal,
            out,
            test_images=test or (),
            layout=target_layout,
            cra_corner_deg=cra,
            overwrite=overwrite,
            progress=lambda text: status.update(f"report: {text}"),
        )
    console().print(f"wrote {index}")
