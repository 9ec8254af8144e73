"""The commands that carry a calibration into the camera's own pipeline: ``export-tuning``, ``export-lst``, and
``apply-tuning``, which shows on a PC what a tuning file does to a raw image."""

# Annotations are not postponed (no `from __future__ import annotations`): typer reads every command's on each run,
# and would evaluate them from strings each time.

from pathlib import Path
from typing import Annotated

import typer

from .._atomic import refuse_inputs_as_output
from ..errors import OutputError, PicamcalError
from ..limits import MAX_COLOUR_GAIN
from ._common import (
    COLOUR_TEMPERATURE,
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
    parse_numbers,
    parse_size,
    reader,
)

#: What export-tuning and export-lst take as their calibration.
SOURCE_HELP = (
    "Calibration (.npz), or a lens shading table: a legacy .npy (export-lst), an OpenFlexure microscope_settings.npz, "
    "a C header (ls_table.h), a libcamera tuning file (.json)."
)


@app.command("export-tuning")
def export_tuning_cmd(
    calibration: Annotated[Path, typer.Argument(help=SOURCE_HELP)],
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
    variant: Annotated[
        str | None,
        typer.Option(
            help="Without --base: the stock file of a variant of the sensor (noir, wide, wide_noir, scientific, "
            "6mm, 16mm, ...: those Raspberry Pi ships for it)."
        ),
    ] = None,
    ct: Annotated[
        int, typer.Option(help="Colour temperature of the table entry, kelvin.", callback=COLOUR_TEMPERATURE)
    ] = 4500,
    luminance_strength: Annotated[
        float, typer.Option(help="libcamera luminance_strength (1 = full correction).")
    ] = 1.0,
    ccm: Annotated[bool, typer.Option("--ccm", help="Also write a static rpi.ccm from the calibration.")] = False,
    clip_gains: Annotated[bool, typer.Option(help="Clip gains above the hardware limit instead of refusing.")] = False,
    sensor: Annotated[
        str | None,
        typer.Option(
            help="The sensor, where the calibration or table does not say it (picks the stock file); with --base, the "
            "sensor the base is for (default: from its name)."
        ),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace existing output files.")] = False,
) -> None:
    """Write libcamera tuning files with a static lens shading table (rpi.alsc) from the calibration.

    The calibration may also be a lens shading table you have (a legacy .npy, an OpenFlexure microscope_settings.npz,
    a C header, a libcamera tuning file: its flat field is exported, so a Pi 4 tuning converts to a Pi 5 one).
    Without --base, starts from the sensor's stock file (or its --variant's): libcamera's own on a Raspberry Pi,
    else the copy picamcal ships (libcamera's uncalibrated.json for a sensor with none); --target both (the
    default) writes one for a Pi 4 (vc4) and one for a Pi 5 (pisp). Each file records, and this prints, the colour
    gains that make the calibration's white neutral through it.
    """
    from ..export.tuning import (
        TARGET_NAMES,
        check_tuning,
        export_bases,
        export_tuning,
        is_tuning_file,
        load_calibration_to_export,
        load_export_base,
        save_tuning,
    )

    cal = load_calibration_to_export(calibration, sensor)
    names = list(TARGET_NAMES) if choice(target, (*TARGET_NAMES, "both"), "--target") == "both" else [target.lower()]
    chosen = export_bases(
        cal, base=base, targets=[TARGET_NAMES[name] for name in names], variant=variant, sensor=sensor
    )
    bases = chosen.paths
    tunings = [load_export_base(path, chosen) for path in bases]
    if len(bases) > 1 and out.suffix.lower() == ".json":
        raise typer.BadParameter("two targets need a folder (or --target vc4 or pisp for one file)", param_hint="--out")
    if out.suffix.lower() == ".json":
        outputs = [out]
    else:
        label = {target: name for name, target in TARGET_NAMES.items()}
        outputs = [out / f"{chosen.stem}_{label[check_tuning(tuning)]}.json" for tuning in tunings]
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
            base_sensor=chosen.sensor,
            base_path=base_path,
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
        record = tuning["picamcal"]
        if "colour_gains" not in record:  # a table's flat field: no colour balance to speak of
            line = (
                f"wrote {path}: static lens shading for {tuning['target']} from {calibration.name} (base {base_path}); "
                f"colour gains: {record['colour_gains_use']}"
            )
            console().print(line, markup=False, highlight=False, soft_wrap=True)
            continue
        red, blue = record["colour_gains"]
        lines = [
            f"wrote {path}: static lens shading for {tuning['target']} from {calibration.name} (base {base_path}); "
            f"for a neutral white in the calibration's mode ({cal.width}x{cal.height}) use "
            f"--awbgains {red:g},{blue:g} / ColourGains ({red:g}, {blue:g}); in each sensor mode:",
            *(
                f"  {name}: --awbgains {r:g},{b:g}"
                + (" (extrapolated: outside the calibration's crop)" if name in record["modes_extrapolated"] else "")
                for name, (r, b) in record["colour_gains_by_mode"].items()
            ),
        ]
        for line in lines:
            console().print(line, markup=False, highlight=False, soft_wrap=True)
    if chosen.note:
        console().print(chosen.note, markup=False, highlight=False, soft_wrap=True)


@app.command("export-lst")
def export_lst_cmd(
    calibration: Annotated[Path, typer.Argument(help=SOURCE_HELP)],
    out: Annotated[Path, typer.Option("--out", "-o", help="Table to write (.npy).")],
    sensor: Annotated[
        str | None, typer.Option(help="The sensor, where the calibration or table does not say it.")
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output file.")] = False,
) -> None:
    """Write the legacy firmware's lens shading table (uint8 .npy for the picamera fork).

    The calibration may also be a lens shading table you have (a libcamera tuning file, an OpenFlexure
    microscope_settings.npz, a C header): its flat field is written as the legacy table.
    """
    from ..export.legacy import is_legacy_table, legacy_table, save_legacy_table
    from ..export.tuning import load_calibration_to_export

    check_output(out, overwrite, is_legacy_table, "a legacy lens shading table", [calibration])

    table = legacy_table(load_calibration_to_export(calibration, sensor))
    save_legacy_table(out, table, overwrite=overwrite)
    console().print(f"wrote {out}: {table.shape} uint8, gains {table.min() / 32:.2f} to {table.max() / 32:.2f}")


@app.command("apply-tuning")
def apply_tuning_cmd(
    tuning_file: Annotated[
        Path,
        typer.Argument(
            help="libcamera tuning file (.json); or a legacy lens shading table (.npy, an OpenFlexure "
            "microscope_settings.npz, a C header), applied through the sensor's Pi 5 tuning."
        ),
    ],
    image: Annotated[Path, typer.Argument(help="Raw image.")],
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            "-o",
            help="Output: .tiff (float32 linear RGB), .png (16-bit sRGB) or .jpg (sRGB); the white level is 1.",
        ),
    ],
    ccm: Annotated[bool, typer.Option("--ccm", help="Also apply the tuning's rpi.ccm.")] = False,
    colour_gains: Annotated[
        str | None,
        typer.Option(
            help="Red and blue gains R,B (default: those the tuning file records as making its calibration's white "
            "neutral, else the image's, else 1,1)."
        ),
    ] = None,
    sensor_crop: SensorCropOption = None,
    sensor_mode: SensorModeOption = None,
    sensor_size: Annotated[
        str | None,
        typer.Option(
            help="Full sensor WIDTHxHEIGHT, for a raw image of a sensor picamcal does not know (default: what the "
            "file says, else the sensor registry's, else the image's)."
        ),
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
    """Apply a tuning file's black level, static lens shading, colour gains (and CCM) to a raw image on a PC.

    The lens shading is computed for the raw image's sensor mode (--sensor-crop or --sensor-mode where the file does
    not say it), as libcamera does; the output (the mode's whole image, as the ISP gives it before any ScalerCrop)
    records that mode and its area, which correct --processed reads.
    """
    import numpy as np

    from ..export.isp import applied_colour_gains, apply_tuning, full_sensor_size, mode_for_image
    from ..export.tables import looks_like_table
    from ..export.tuning import load_tuning, table_tuning
    from ..output import NO_MATRIX, ColourMatrix, is_picamcal_output, write_corrected
    from ..raw.model import raw_geometry

    # An input given as the output is the worse mistake: said first, whatever the suffix.
    check_output(out, overwrite, is_picamcal_output, "an image picamcal wrote", [image, tuning_file])
    output_format = _APPLY_TUNING_FORMATS.get(out.suffix.lower())
    if output_format is None:
        raise typer.BadParameter(
            f"{out.name}: apply-tuning writes .tiff (float32 linear RGB), .png (16-bit sRGB) or .jpg (sRGB), "
            f"not {out.suffix or 'a file without a suffix'}",
            param_hint="--out",
        )
    gains = parse_numbers(colour_gains, 2, "--colour-gains")
    if gains is not None and not all(0 < g <= MAX_COLOUR_GAIN for g in gains):
        raise typer.BadParameter(
            f"{colour_gains!r}: each gain must be more than 0 and at most {MAX_COLOUR_GAIN} (libcamera's range)",
            param_hint="--colour-gains",
        )
    crop_box: tuple[int, int, int, int] | None = sensor_crop  # type: ignore[assignment]  # the option's callback parsed it
    given_size = parse_size(sensor_size, "--sensor-size")
    headless = {"raw_format": raw_format, "size": size, "stride": stride, "frame": frame, "sensor": raw_sensor}
    if looks_like_table(tuning_file):  # a legacy table: its flat field through the sensor's Pi 5 tuning
        raw = reader(pattern, black_level, **headless)(image)
        tuning = table_tuning(tuning_file, raw_sensor or raw.sensor)
    else:
        tuning = load_tuning(tuning_file)
        raw = reader(pattern, black_level, **headless)(image)
    image_size = (raw.width, raw.height)
    if given_size is not None:
        mode = mode_for_image(given_size, image_size, crop_box)
    else:
        mode = raw_geometry(raw, sensor_crop=crop_box, sensor_mode=sensor_mode)
        if mode.source == "assumed" and mode.sensor_size != full_sensor_size(raw):
            # A size no mode of its sensor gives: refused, saying what to give.
            mode = mode_for_image(full_sensor_size(raw), image_size)
    # The gains applied: those given, else those an exported file records as making its white neutral, else the
    # raw's; recorded so that `correct --processed --tuning` divides out these very ones.
    applied = applied_colour_gains(raw, (gains[0], gains[1]) if gains else None, tuning)
    try:
        rgb = apply_tuning(raw, tuning, colour_gains=applied, ccm=ccm, mode=mode, ct=ct)
    except PicamcalError as exc:
        if exc.path is None:  # a problem with the tuning's content: the tuning dict does not know its file
            raise type(exc)(exc.problem, tuning_file) from None
        raise
    info = {
        "source": image.name,
        "tuning": tuning_file.name,
        "ccm": ccm,
        "colour_gains": list(applied),
        "sensor_mode": mode.to_record(),
        "scaler_crop": list(mode.crop),
    }
    # The sRGB files show the emulated ISP's output as it is: the sensor's white level at sRGB's, no other matrix.
    matrix = ColourMatrix(np.eye(3), f"{tuning_file.name} rpi.ccm, applied by apply-tuning" if ccm else NO_MATRIX)
    write_corrected(out, rgb, output_format, info, colour_matrix=matrix, white_level=1.0, overwrite=overwrite)
    console().print(
        f"wrote {out} ({output_format}, colour gains {applied[0]:g},{applied[1]:g})",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )


#: What apply-tuning writes for each suffix of --out: picamcal's own writers (picamcal.output.write_corrected).
_APPLY_TUNING_FORMATS = {
    ".tif": "float32-tiff",
    ".tiff": "float32-tiff",
    ".png": "srgb-png16",
    ".jpg": "srgb-jpeg",
    ".jpeg": "srgb-jpeg",
}
