"""The commands that make and apply a calibration: ``calibrate`` and ``correct``."""

# Annotations are not postponed (no `from __future__ import annotations`): typer reads every command's on each run,
# and would evaluate them from strings each time.

import os
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from ._common import (
    MAX_WORKERS_PER_CORE,
    MODE_HELP,
    BlackOption,
    FrameOption,
    PatternOption,
    RawFormatOption,
    RawSensorOption,
    RawSizeOption,
    SensorCropOption,
    SensorModeOption,
    StrideOption,
    app,
    check_output,
    choice,
    console,
    in_range,
    parse_mode_option,
    parse_tiles,
    progress_bar,
    read_options,
    reader,
)


@app.command("calibrate")
def calibrate_cmd(
    folder: Annotated[
        Path | None,
        typer.Argument(
            help="Folder holding the white (white_1, white_2, ... to average), optional red, green and blue (all "
            "three or none), optional extra colours (colour_NAME, for a least-squares unmixing) and optional black "
            "references."
        ),
    ] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Calibration file to write (.npz).")] = Path(
        "calibration.npz"
    ),
    white: Annotated[
        list[Path] | None, typer.Option(help="White reference raw file(s); several frames are averaged.")
    ] = None,
    red: Annotated[list[Path] | None, typer.Option(help="Red reference raw file(s).")] = None,
    green: Annotated[list[Path] | None, typer.Option(help="Green reference raw file(s).")] = None,
    blue: Annotated[list[Path] | None, typer.Option(help="Blue reference raw file(s).")] = None,
    black: Annotated[list[Path] | None, typer.Option(help="Dark frame(s) (optional).")] = None,
    colour: Annotated[
        list[str] | None,
        typer.Option(
            "--colour",
            help="Extra colour reference (an LED mixture, a screen colour) for a least-squares unmixing: FILE named "
            "colour_NAME..., or NAME=FILE; repeatable, one per colour.",
        ),
    ] = None,
    max_noise_penalty: Annotated[
        float | None,
        typer.Option(
            help="Bound the centre mode's noise penalty: where a bin's would exceed it, its unmixing is blended "
            "towards the flat field (costing colour, reported). At least 1, and at least the flat field's own.",
            callback=in_range(1, why="the factor by which the correction may multiply noise; 1 = not at all"),
        ),
    ] = None,
    unmixing_from: Annotated[
        Path | None,
        typer.Option(help="In situ: take the unmixing from this jig calibration; only --white (and --black) needed."),
    ] = None,
    bin_size: Annotated[int, typer.Option(help="Bin edge in sensor pixels (even).")] = 16,
    smoothing: Annotated[
        float,
        typer.Option(
            help="Gaussian smoothing of the fields, in bins (0 = none; at most a quarter of the bin grid's shorter "
            "side).",
            callback=in_range(0, unit=" bins"),
        ),
    ] = 0.0,
    pattern: PatternOption = None,
    black_level: BlackOption = None,
    raw_format: RawFormatOption = None,
    size: RawSizeOption = None,
    stride: StrideOption = None,
    frame: FrameOption = None,
    sensor: RawSensorOption = None,
    sensor_crop: SensorCropOption = None,
    sensor_mode: SensorModeOption = None,
    light: Annotated[
        str | None,
        typer.Option(
            help="The light of the references: jig (the jig's LEDs), screen (a monitor's full-screen colours) or "
            "sheets (printed sheets), for the report's expected accuracy; read from the manifest of a folder that "
            "picamcal acquire wrote. Default: unknown."
        ),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output file.")] = False,
) -> None:
    """Measure the flat field, and with red, green and blue references the colour-unmixing field.

    With a white alone (and optionally a dark frame) the calibration is a flat field: vignetting and colour
    balance, for correct --mode uncorrected|flat, export-tuning and export-lst. With --unmixing-from, a white
    through your own optics takes the unmixing of a jig calibration. Prints the checks that need a look.
    """
    import dataclasses

    from ..analysis.diagnostics import diagnose
    from ..calibrate import calibrate, calibrate_in_situ
    from ..calibration import LIGHTS, is_calibration_file
    from ..references import COLOURS, colour_name, find_references, reference_light

    light = choice(light, tuple(LIGHTS), "--light") if light is not None else None
    named = {"white": white, "red": red, "green": green, "blue": blue, "black": black}
    refs: dict[str, Any] = find_references(folder, in_situ=unmixing_from is not None) if folder is not None else {}
    refs.update({role: paths[0] if len(paths) == 1 else paths for role, paths in named.items() if paths})
    refs.update(_colour_options(colour or []))
    colours = [role for role in COLOURS if role in refs]
    if "white" not in refs:
        raise typer.BadParameter("give a folder of references or --white")
    if unmixing_from is not None and colours:
        raise typer.BadParameter("--unmixing-from takes the colours from the jig calibration: drop --" + colours[0])
    if unmixing_from is not None and (colour or max_noise_penalty is not None):
        raise typer.BadParameter(
            "--unmixing-from takes the unmixing from the jig calibration: give --colour and --max-noise-penalty "
            "when making that",
            param_hint="--colour" if colour else "--max-noise-penalty",
        )
    paths = [p for ref in refs.values() for p in (ref if isinstance(ref, list) else [ref])]
    check_output(out, overwrite, is_calibration_file, "a picamcal calibration", [*paths, unmixing_from, folder])
    light = reference_light(folder, light)
    read = reader(pattern, black_level, raw_format=raw_format, size=size, stride=stride, frame=frame, sensor=sensor)

    def frames(role: str) -> Any:  # several frames are read one at a time, as the calibration averages them
        ref = refs[role]
        return (read(path) for path in ref) if isinstance(ref, list) else read(ref)

    with console().status("calibrating"):
        if unmixing_from is not None:
            black_frames = frames("black") if "black" in refs else None
            cal = calibrate_in_situ(frames("white"), unmixing_from, black_frames, smoothing=smoothing)
        else:
            cal = calibrate(
                **{role: frames(role) for role in refs if not colour_name(role)},
                colours={name: frames(role) for role in refs if (name := colour_name(role))} or None,
                max_noise_penalty=max_noise_penalty,
                bin_size=bin_size,
                smoothing=smoothing,
                sensor_crop=sensor_crop,  # type: ignore[arg-type]  # the option's callback parsed it
                sensor_mode=sensor_mode,
            )
        if light is not None:  # else what calibrate gave: unknown, or in situ the jig calibration's
            cal = dataclasses.replace(cal, light=light)
        cal.save(out, overwrite=overwrite)
        checks = diagnose(cal)
    what = (
        f"worst noise penalty (centre mode) {float(cal.noise_penalty('centre').max()):.2f}"
        if cal.has_unmixing
        else f"a flat field from the white{_and_dark(cal)} (modes uncorrected and flat, no colour unmixing), "
        f"worst noise penalty (flat mode) {float(cal.noise_penalty('flat').max()):.2f}"
    )
    lines = [
        f"wrote {out}: {cal.sensor or 'unknown sensor'} {cal.width}x{cal.height} {cal.pattern}, "
        f"{cal.white.shape[1]}x{cal.white.shape[0]} bins of {cal.bin_size} px, {what}; sensor mode "
        f"{cal.geometry.describe() if cal.geometry else 'unknown'}"
        + (f", unmixing from {unmixing_from.name}" if unmixing_from else "")
        + (f", light {cal.light} ({LIGHTS[cal.light]})" if cal.light else "")
    ]
    for info in cal.inputs:
        if info.get("frame_count", 1) > 1:
            lines.append(
                f"{info['role']}: {info['frame_count']} frames averaged: temporal noise "
                f"{info['temporal_noise_dn']:.2f} DN per pixel in one frame, {info['averaged_noise_dn']:.2f} DN in "
                "their average"
            )
    fitted = [info for info in cal.inputs if "fit_residual" in info]
    if fitted:
        lines.append(
            f"least-squares unmixing from {len(fitted)} colour references; RMS fit error per reference: "
            + ", ".join(f"{info['role']} {100 * info['fit_residual']:.2f} %" for info in fitted)
        )
    lines += [f"{c.name}: {c.summary}" for c in checks if c.name == "noise_limit" and c.verdict == "pass"]
    lines += [f"needs a look: {check.name}: {check.summary}" for check in checks if check.verdict == "warn"]
    for line in lines:
        console().print(line, markup=False, soft_wrap=True)


@app.command("correct")
def correct_cmd(
    calibration: Annotated[Path, typer.Argument(help="Calibration file (.npz).")],
    inputs: Annotated[
        list[Path], typer.Argument(help="Images, folders of them, or glob patterns (quoted: for very many files).")
    ],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Output folder for <stem>.tiff (.png, .jpg) files.")
    ] = None,
    zarr_path: Annotated[
        Path | None, typer.Option("--zarr", help="Write one OME-Zarr stack (t, c, y, x) instead of TIFF files.")
    ] = None,
    mosaic: Annotated[
        str | None,
        typer.Option(help="With --zarr: place the frames as COLUMNSxROWS tiles of one mosaic, row by row."),
    ] = None,
    mode: Annotated[
        str | None,
        typer.Option(
            help=MODE_HELP + ". Default: the best the calibration does (centre; flat for a white-only calibration)."
        ),
    ] = None,
    binned: Annotated[bool, typer.Option(help="Write the bin-resolution image instead of full resolution.")] = False,
    processed: Annotated[
        bool, typer.Option(help="The images are processed (JPEG/PNG/TIFF from the camera's ISP), not raw.")
    ] = False,
    input_encoding: Annotated[
        str | None,
        typer.Option(
            help="With --processed: srgb, linear, gamma:G or tuning:FILE (its rpi.contrast curve); default srgb, "
            "or the --tuning file's curve."
        ),
    ] = None,
    tuning_file: Annotated[
        Path | None,
        typer.Option(
            "--tuning",
            help="With --processed: the tuning file the camera ran with; its lens shading and CCM are accounted for. "
            "With raw images and an srgb-* --output-format: its rpi.ccm is the colour matrix to sRGB.",
        ),
    ] = None,
    white_image: Annotated[
        Path | None, typer.Option("--white", help="With --processed: a processed white reference (residual flat).")
    ] = None,
    output_format: Annotated[
        str,
        typer.Option(
            help="float32-tiff (linear, white = 1.0), uint16-tiff (linear, scale in the metadata), srgb-png, "
            "srgb-png16 or srgb-jpeg (colour-managed, to look at); for raw editors: linear-dng (the corrected "
            "image) or dng-gainmap (the raw frame unchanged, the flat field as DNG GainMap opcodes)."
        ),
    ] = "float32-tiff",
    pattern: PatternOption = None,
    black_level: BlackOption = None,
    raw_format: RawFormatOption = None,
    size: RawSizeOption = None,
    stride: StrideOption = None,
    frame: FrameOption = None,
    sensor: RawSensorOption = None,
    sensor_crop: SensorCropOption = None,
    sensor_mode: SensorModeOption = None,
    workers: Annotated[
        int | None,
        typer.Option(
            help="Worker processes (default: one per core; 0: no pool, work in this process).",
            callback=in_range(
                0,
                MAX_WORKERS_PER_CORE * (os.cpu_count() or 1),
                why=f"{MAX_WORKERS_PER_CORE} per core: more "
                "processes than cores only add memory, a frame and the calibration each",
            ),
        ),
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Run on this dask.distributed scheduler instead (tcp://host:port).")
    ] = None,
    compression: Annotated[str | None, typer.Option(help="Compress the outputs: zstd.")] = None,
    overwrite: Annotated[
        bool,
        typer.Option(
            help="Replace existing outputs picamcal wrote (without it, those made with the same settings are skipped: "
            "an interrupted batch resumes; those made with other settings are kept and named)."
        ),
    ] = False,
) -> None:
    """Correct raw (or, with --processed, ISP-processed) images in parallel; write one image file per input.

    float32 linear RGB TIFF by default; uint16 linear TIFF for Fiji/ImageJ; sRGB PNG (8 or 16 bit) or
    JPEG, colour-managed, to look at (docs/outputs.md). Existing outputs made with the same settings are skipped,
    so running the same command again resumes an interrupted batch (Ctrl-C or SIGTERM stop it within about a
    second); outputs made with other settings are kept and named (exit status 1) unless --overwrite. Batches
    writing into one folder at once share the work. The output folder may lie inside a folder of inputs
    (scans/corrected for scans/). A file that fails is reported and does not stop the others (exit status 1); a
    single file that fails is an error (exit status 2).
    """
    from ..batch import COMPRESSIONS, BatchInterrupted, BatchOptionError, BatchOptions, run_batch
    from ..output import BATCH_FORMATS

    mode = None if mode is None else parse_mode_option(mode)
    output_format = choice(output_format, BATCH_FORMATS, "--output-format")
    compression = None if compression is None else choice(compression, COMPRESSIONS, "--compression")
    try:
        options = BatchOptions(
            out_dir=out,
            zarr_path=zarr_path,
            mosaic=parse_tiles(mosaic),
            mode=mode,
            binned=binned,
            workers=workers,
            scheduler=scheduler,
            overwrite=overwrite,
            compression=compression,
            processed=processed,
            input_encoding=input_encoding,
            output_format=output_format,
            **_batch_read_options(pattern, black_level, raw_format, size, stride, frame, sensor),
            white=white_image,
            tuning=tuning_file,
            sensor_crop=sensor_crop,  # type: ignore[arg-type]  # the option's callback parsed it
            sensor_mode=sensor_mode,
        )
    except BatchOptionError as exc:  # options that do not go together, under their command-line names
        hint = _BATCH_OPTION_NAMES.get(exc.option) if exc.option else None
        raise typer.BadParameter(exc.message(_BATCH_OPTION_NAMES), param_hint=hint) from None
    progress = progress_bar(rate=True)
    bar: dict = {}

    def show(finished: int, total: int) -> None:
        if not bar:  # the bar appears when the work starts, after every check has passed
            bar.update(task=progress.add_task("correcting", total=total, rate=""), start=time.monotonic())
            progress.start()
        elapsed = time.monotonic() - bar["start"]
        progress.update(bar["task"], completed=finished, rate=f"{finished / elapsed:.1f} files/s" if finished else "")

    def say(line: str) -> None:
        console().print(line, markup=False, highlight=False, soft_wrap=True)

    try:
        result = run_batch(calibration, inputs, options, progress=show)
    except BatchInterrupted as stopped:  # the files that failed, then how far it got, in one line
        progress.stop()
        for path, reason in stopped.result.failed:
            say(f"picamcal: failed: {path}: {reason}")
        say(f"picamcal: {stopped}")
        raise typer.Exit(128 + stopped.signum) from None
    finally:
        progress.stop()
    if (error := result.failure_of_one_file()) is not None:  # one file: its one line, exit status 2
        raise error
    for path, reason in result.failed:
        say(f"picamcal: failed: {path}: {reason}")
    elapsed = time.monotonic() - bar["start"] if bar else 0.0
    rate = f" ({len(result.done) / elapsed:.1f} files/s)" if result.done and elapsed > 0 else ""
    why = f" ({result.mode_reason})" if result.mode_reason else ""
    if (kept := result.kept_message()) is not None:  # outputs not made as asked: said, and exit status 1
        say(f"picamcal: {kept}")
    others = (
        f"; {len(result.by_another_run)} written by another run into the same folder" if result.by_another_run else ""
    )
    say(
        f"wrote {len(result.done)} image(s) to {zarr_path or out}{rate} in mode {result.mode}{why}; skipped "
        f"{len(result.skipped)} (done already){others}; failed {len(result.failed)}"
    )
    if result.failed or result.kept:
        raise typer.Exit(1)


_BATCH_OPTION_NAMES = {
    "out_dir": "--out",
    "zarr_path": "--zarr",
    "mosaic": "--mosaic",
    "binned": "--binned",
    "processed": "--processed",
    "input_encoding": "--input-encoding",
    "white": "--white",
    "tuning": "--tuning",
    "output_format": "--output-format",
    "compression": "--compression",
    "workers": "--workers",
    "scheduler": "--scheduler",
}


def _and_dark(cal: Any) -> str:
    """What a flat field was made from besides its white: its dark frame, or nothing else."""
    return " and the dark frame" if cal.black_level_source == "dark frame" else " alone"


def _batch_read_options(*args: Any) -> dict[str, Any]:
    """run_batch's keywords for the reading options (its ``raw_size`` is read_raw's ``size``)."""
    options = read_options(*args)
    options["raw_size"] = options.pop("size")
    return options


def _colour_options(values: list[str]) -> dict[str, Path]:
    """calibrate's ``--colour`` values (``NAME=FILE``, or a FILE named ``colour_NAME...``) as roles -> files."""
    from ..references import COLOUR_NAME, colour_name, colour_role, role_of

    roles: dict[str, Path] = {}
    for value in values:
        name, sep, file = value.partition("=")
        if not (sep and COLOUR_NAME.fullmatch(name)):  # a path that holds "=" is a path
            name, file = colour_name(role_of(Path(value).name) or "") or "", value
        if not name or not file:
            raise typer.BadParameter(
                f"{value!r}: name the colour, NAME=FILE (NAME of letters, digits and '-'), or name the file "
                "colour_NAME.dng",
                param_hint="--colour",
            )
        role = colour_role(name)
        if role in roles:
            raise typer.BadParameter(
                f"two references are named {name.lower()} ({roles[role]}, {file}): give each colour once",
                param_hint="--colour",
            )
        roles[role] = Path(file)
    return roles
