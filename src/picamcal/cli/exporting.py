"""The commands that carry a calibration into the camera's own pipeline: ``export-tuning``, ``export-lst``, and
``apply-tuning``, which shows on a PC what a tuning file does to a raw image."""

# Annotations are not postponed (no `from __future__ import annotations`): typer reads every command's on each run,
# and would evaluate them from strings each time.

import math
from pathlib import Path
from typing import Annotated

import typer

from .._atomic import refuse_inputs_as_output
from ..errors import OutputError, PicamcalError
from ._common import (
    COLOUR_TEMPERATURE,
    MAX_COLOUR_GAIN,
    BlackOption,
    FrameOption,
    PatternOption,
    RawFormatOption,
    RawSensorOption,
    RawSizeOption,
    StrideOption,
    app,
    check_output,
    choice,
    console,
    parse_numbers,
    parse_size,
    reader,
)


@app.command("export-tuning")
def export_tuning_cmd(
    calibration: Annotated[Path, typer.Argument(help="Calibration file (.npz).")],
    out: Annotated[
        Path,
        typer.Option(
            "--out", "-o", help="Folder for <sensor>_vc4.json and <sensor>_pisp.json, or a .json file for one target."
        ),
    ],
    base: Annotated[
        Path | None,
        typer.Option(help="Tuning file to start from (default: the sensor's stock file, for --target)."),
    ] = None,
    target: Annotated[str, typer.Option(help="Without --base: vc4 (Pi 4 and earlier), pisp (Pi 5) or both.")] = "both",
    ct: Annotated[
        int, typer.Option(help="Colour temperature of the table entry, kelvin.", callback=COLOUR_TEMPERATURE)
    ] = 4500,
    luminance_strength: Annotated[
        float, typer.Option(help="libcamera luminance_strength (1 = full correction).")
    ] = 1.0,
    ccm: Annotated[bool, typer.Option("--ccm", help="Also write a static rpi.ccm from the calibration.")] = False,
    clip_gains: Annotated[bool, typer.Option(help="Clip gains above the hardware limit instead of refusing.")] = False,
    sensor: Annotated[
        str | None, typer.Option(help="The sensor the base file is for (default: from its name).")
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace existing output files.")] = False,
) -> None:
    """Write libcamera tuning files with a static lens shading table (rpi.alsc) from the calibration.

    Without --base, starts from the sensor's stock file: libcamera's own on a Raspberry Pi, else the copy
    picamcal ships; --target both (the default) writes one for a Pi 4 (vc4) and one for a Pi 5 (pisp).
    """
    from ..calibration import load_calibration
    from ..export.tuning import (
        TARGET_NAMES,
        check_tuning,
        export_tuning,
        is_tuning_file,
        load_tuning,
        save_tuning,
        sensor_of_tuning_file,
        stock_tuning_path,
    )

    cal = load_calibration(calibration)
    if base is not None:
        bases = [base]
    else:
        if cal.sensor is None:
            raise typer.BadParameter("the calibration does not say its sensor: give --base")
        names = list(TARGET_NAMES) if choice(target, (*TARGET_NAMES, "both"), "--target") == "both" else [target]
        bases = [stock_tuning_path(cal.sensor, TARGET_NAMES[name.lower()]) for name in names]
    tunings = [load_tuning(path) for path in bases]
    if len(bases) > 1 and out.suffix.lower() == ".json":
        raise typer.BadParameter("two targets need a folder (or --target vc4 or pisp for one file)", param_hint="--out")
    if out.suffix.lower() == ".json":
        outputs = [out]
    else:
        label = {target: name for name, target in TARGET_NAMES.items()}
        outputs = [
            out / f"{cal.sensor or sensor_of_tuning_file(path)}_{label[check_tuning(tuning)]}.json"
            for path, tuning in zip(bases, tunings, strict=True)
        ]
    refuse_inputs_as_output(out, [*bases, calibration])
    for path in outputs:
        check_output(path, overwrite, is_tuning_file, "a libcamera tuning file", [*bases, calibration])
    exported = [
        export_tuning(
            cal,
            tuning,
            ct=ct,
            luminance_strength=luminance_strength,
            ccm=ccm,
            clip_gains=clip_gains,
            base_sensor=sensor or sensor_of_tuning_file(base_path),
        )
        for tuning, base_path in zip(tunings, bases, strict=True)
    ]  # all before writing any: a table the Pi 5 cannot apply leaves nothing half-done
    if out.suffix.lower() != ".json":
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create the folder: {exc.strerror or exc}", out) from exc
    for path, tuning, base_path in zip(outputs, exported, bases, strict=True):
        save_tuning(path, tuning, overwrite=overwrite)
        console().print(
            f"wrote {path}: static lens shading for {tuning['target']} from {calibration.name} (base {base_path})",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )


@app.command("export-lst")
def export_lst_cmd(
    calibration: Annotated[Path, typer.Argument(help="Calibration file (.npz).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Table to write (.npy).")],
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output file.")] = False,
) -> None:
    """Write the legacy firmware's lens shading table (uint8 .npy for the picamera fork)."""
    from ..calibration import load_calibration
    from ..export.legacy import is_legacy_table, legacy_table, save_legacy_table

    check_output(out, overwrite, is_legacy_table, "a legacy lens shading table", [calibration])

    table = legacy_table(load_calibration(calibration))
    save_legacy_table(out, table, overwrite=overwrite)
    console().print(f"wrote {out}: {table.shape} uint8, gains {table.min() / 32:.2f} to {table.max() / 32:.2f}")


@app.command("apply-tuning")
def apply_tuning_cmd(
    tuning_file: Annotated[Path, typer.Argument(help="libcamera tuning file (.json).")],
    image: Annotated[Path, typer.Argument(help="Raw image.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output TIFF (float32 linear RGB).")],
    ccm: Annotated[bool, typer.Option("--ccm", help="Also apply the tuning's rpi.ccm.")] = False,
    colour_gains: Annotated[
        str | None, typer.Option(help="Red and blue gains R,B (default: from the image, else 1,1).")
    ] = None,
    sensor_crop: Annotated[
        str | None, typer.Option(help="X,Y,WIDTH,HEIGHT of the sensor mode's crop, in full-sensor pixels.")
    ] = None,
    sensor_size: Annotated[
        str | None, typer.Option(help="Full sensor WIDTHxHEIGHT (default: the sensor registry's, or the image's).")
    ] = None,
    ct: Annotated[
        float | None,
        typer.Option(help="Colour temperature for the tables (default: the file's).", callback=COLOUR_TEMPERATURE),
    ] = None,
    pattern: PatternOption = None,
    black_level: BlackOption = None,
    raw_format: RawFormatOption = None,
    size: RawSizeOption = None,
    stride: StrideOption = None,
    frame: FrameOption = None,
    raw_sensor: RawSensorOption = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output file.")] = False,
) -> None:
    """Apply a tuning file's black level, static lens shading, colour gains (and CCM) to a raw image on a PC."""
    from ..export.isp import applied_colour_gains, apply_tuning, full_sensor_size, mode_for_image
    from ..export.tuning import load_tuning
    from ..output import is_picamcal_output, write_rgb_tiff

    gains = parse_numbers(colour_gains, 2, "--colour-gains")
    if gains is not None and not all(0 < g <= MAX_COLOUR_GAIN for g in gains):
        raise typer.BadParameter(
            f"{colour_gains!r}: each gain must be more than 0 and at most {MAX_COLOUR_GAIN} (libcamera's range)",
            param_hint="--colour-gains",
        )
    crop = parse_numbers(sensor_crop, 4, "--sensor-crop")
    if crop is not None and not (
        all(math.isfinite(v) and v == int(v) for v in crop) and min(crop[:2]) >= 0 and min(crop[2:]) > 0
    ):
        raise typer.BadParameter(
            f"{sensor_crop!r}: X and Y must be whole numbers, 0 or more, and WIDTH and HEIGHT whole numbers above 0",
            param_hint="--sensor-crop",
        )
    given_size = parse_size(sensor_size, "--sensor-size")
    check_output(out, overwrite, is_picamcal_output, "an image picamcal wrote", [image, tuning_file])
    tuning = load_tuning(tuning_file)
    headless = {"raw_format": raw_format, "size": size, "stride": stride, "frame": frame, "sensor": raw_sensor}
    raw = reader(pattern, black_level, **headless)(image)
    full = given_size or full_sensor_size(raw)
    crop_box = (int(crop[0]), int(crop[1]), int(crop[2]), int(crop[3])) if crop else None
    mode = mode_for_image(full, (raw.width, raw.height), crop_box)
    given_gains = (gains[0], gains[1]) if gains else None
    try:
        rgb = apply_tuning(raw, tuning, colour_gains=given_gains, ccm=ccm, mode=mode, ct=ct)
    except PicamcalError as exc:
        if exc.path is None:  # a problem with the tuning's content: the tuning dict does not know its file
            raise type(exc)(exc.problem, tuning_file) from None
        raise
    # The gains applied, so that `correct --processed --tuning` divides out these very ones.
    applied = list(applied_colour_gains(raw, given_gains))
    info = {"source": image.name, "tuning": tuning_file.name, "ccm": ccm, "colour_gains": applied}
    write_rgb_tiff(out, rgb, info, overwrite=overwrite)
    console().print(f"wrote {out}")
