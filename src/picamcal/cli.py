"""The ``picamcal`` command line: a thin skin over the library.

Each command parses its arguments, calls the library and prints. Every PicamcalError becomes one
line on stderr and exit status 2, here in :func:`main` and nowhere else.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from ._atomic import atomic_path, refuse_foreign, refuse_inputs_as_output
from ._version import __version__
from .errors import OutputError, PicamcalError, PicamcalWarning, closest
from .modes import MODE_NAMES, Mode, parse_mode

app = typer.Typer(
    help="Flat-field and colour-crosstalk calibration for Raspberry Pi cameras behind custom optics.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
console = Console(stderr=True)
MODE_HELP = "; ".join(f"{mode.value}: {mode.description}" for mode in Mode)
PatternOption = Annotated[
    str | None, typer.Option("--pattern", help="Override the files' Bayer order (RGGB, GBRG, BGGR, GRBG).")
]
BlackOption = Annotated[
    str | None, typer.Option("--black-level", help="Override the files' black level: one value or four (DN).")
]


#: No raw format holds more than 16 bits, so no black level reaches 2**16 DN.
_MAX_BLACK_LEVEL = 65535


def _black_level(text: str | None) -> list[float] | None:
    if text is None:
        return None
    try:
        values = [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not one number or four", param_hint="--black-level") from None
    if len(values) not in (1, 4):
        raise typer.BadParameter("give one value or four (one per 2x2 site)", param_hint="--black-level")
    if not all(math.isfinite(v) and 0 <= v <= _MAX_BLACK_LEVEL for v in values):
        raise typer.BadParameter(
            f"{text!r}: each level must be a number from 0 to {_MAX_BLACK_LEVEL} DN (no raw format has more than 16 "
            "bits)",
            param_hint="--black-level",
        )
    return values


def _in_range(
    low: float | None = None,
    high: float | None = None,
    *,
    above: bool = False,
    below: bool = False,
    unit: str = "",
    why: str = "",
) -> Callable[[Any], Any]:
    """A typer callback refusing a number outside ``low``..``high`` (``above``/``below``: the bound itself excluded).

    NaN and infinities are always refused; click's own ranges let NaN through. The message names the value, the
    accepted range and, with ``why``, the reason for it.
    """
    if low is not None and high is not None:
        text = f"{'more than' if above else 'from'} {low:g} {'and less than' if below else 'to'} {high:g}"
    elif low is not None:
        text = f"more than {low:g}" if above else f"{low:g} or more"
    else:
        text = f"less than {high:g}" if below else f"{high:g} or less"
    accepted = f"{text}{unit}" + (f" ({why})" if why else "")

    def check(value: Any) -> Any:
        for number in value if isinstance(value, tuple) else () if value is None else (value,):
            fits = math.isfinite(number)
            fits = fits and (low is None or (number > low if above else number >= low))
            fits = fits and (high is None or (number < high if below else number <= high))
            if not fits:
                raise typer.BadParameter(f"{number:g} is outside the accepted range, {accepted}")
        return value

    return check


#: libcamera's Raspberry Pi IPA takes ColourGains from 0 to 32 (src/ipa/rpi/common/ipa_base.cpp).
_MAX_COLOUR_GAIN = 32
#: More worker processes than this per core only cost memory (each holds a frame and the calibration).
_MAX_WORKERS_PER_CORE = 4
#: Colour temperatures of real light sources, from candle light (about 1900 K) to a clear blue sky (10000 K and more).
_COLOUR_TEMPERATURE = _in_range(1000, 20000, unit=" K", why="the colour temperature of a light source")

RawFormatOption = Annotated[
    str | None,
    typer.Option(
        "--raw-format",
        help="Read headless raw dumps (rpicam-raw, libcamera-raw) in this libcamera format: SBGGR10_CSI2P, "
        "SRGGB12_CSI2P, SGBRG16, ...",
    ),
]
RawSizeOption = Annotated[str | None, typer.Option("--size", help="With --raw-format: WIDTHxHEIGHT of a frame.")]
StrideOption = Annotated[
    int | None,
    typer.Option(
        "--stride", help="With --raw-format: bytes per row (default: libcamera's alignment).", callback=_in_range(1)
    ),
]
FrameOption = Annotated[
    int | None,
    typer.Option(
        "--frame", help="With --raw-format: the frame of a multi-frame dump (0 = the first).", callback=_in_range(0)
    ),
]
RawSensorOption = Annotated[
    str | None, typer.Option("--sensor", help="The sensor, for files that do not say (headless dumps).")
]


def _choice(value: str, choices: Sequence[str], option: str) -> str:
    """``value`` as one of ``choices``, compared case-insensitively; a near miss gets "did you mean"."""
    by_key = {c.lower(): c for c in choices}
    if value.lower() in by_key:
        return by_key[value.lower()]
    near = closest(value, choices)
    hint = f"; did you mean {near}?" if near else ""
    raise typer.BadParameter(f"{value!r} is not one of {', '.join(choices)}{hint}", param_hint=option)


def _mode(value: str) -> str:
    """``--mode`` as a mode's name; an old name (balance) is accepted with a warning."""
    try:
        return parse_mode(value.lower()).value
    except ValueError:
        return _choice(value, MODE_NAMES, "--mode")  # not a mode: the usage error, with "did you mean"


def _read_options(
    pattern: str | None,
    black_level: str | None,
    raw_format: str | None = None,
    size: str | None = None,
    stride: int | None = None,
    frame: int | None = None,
    sensor: str | None = None,
) -> dict[str, Any]:
    """The keyword arguments of read_raw that a command's reading options stand for."""
    from .raw import PATTERNS

    if raw_format is None and (size is not None or stride is not None or frame is not None):
        raise typer.BadParameter("--size, --stride and --frame describe a headless dump: give --raw-format too")
    return {
        "pattern": None if pattern is None else _choice(pattern, PATTERNS, "--pattern"),
        "black_level": _black_level(black_level),
        "raw_format": raw_format,
        "size": _parse_size(size, "--size") if size is not None else None,
        "stride": stride,
        "frame": frame,
        "sensor": sensor,
    }


def _reader(pattern: str | None, black_level: str | None, **headless: Any) -> Callable[[Path], Any]:
    """A read_raw with the command's overrides and headless-dump options applied."""
    from .raw import read_raw

    options = _read_options(pattern, black_level, **headless)

    def read(path: Path):
        return read_raw(path, **options)

    return read


def _progress() -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,  # off a terminal, rich would leave an empty line on stderr
    )


def _version(value: bool) -> None:
    if value:
        print(f"picamcal {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool | None, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")
    ] = None,
) -> None:
    """Flat-field and colour-crosstalk calibration for Raspberry Pi cameras behind custom optics."""


@app.command("calibrate")
def calibrate_cmd(
    folder: Annotated[
        Path | None,
        typer.Argument(
            help="Folder holding the white (white_1, white_2, ... to average), optional red, green and blue (all "
            "three or none), and optional black references."
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
            callback=_in_range(0, unit=" bins"),
        ),
    ] = 0.0,
    pattern: PatternOption = None,
    black_level: BlackOption = None,
    raw_format: RawFormatOption = None,
    size: RawSizeOption = None,
    stride: StrideOption = None,
    frame: FrameOption = None,
    sensor: RawSensorOption = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing output file.")] = False,
) -> None:
    """Measure the flat field, and with red, green and blue references the colour-unmixing field.

    With a white alone (and optionally a dark frame) the calibration is a flat field: vignetting and colour
    balance, for correct --mode uncorrected|flat, export-tuning and export-lst. With --unmixing-from, a white
    through your own optics takes the unmixing of a jig calibration. Prints the checks that need a look.
    """
    from .analysis.diagnostics import diagnose
    from .calibrate import calibrate, calibrate_in_situ
    from .calibration import is_calibration_file
    from .references import COLOURS, find_references

    named = {"white": white, "red": red, "green": green, "blue": blue, "black": black}
    refs: dict[str, Any] = find_references(folder, in_situ=unmixing_from is not None) if folder is not None else {}
    refs.update({role: paths[0] if len(paths) == 1 else paths for role, paths in named.items() if paths})
    colours = [role for role in COLOURS if role in refs]
    if "white" not in refs:
        raise typer.BadParameter("give a folder of references or --white")
    if unmixing_from is not None and colours:
        raise typer.BadParameter("--unmixing-from takes the colours from the jig calibration: drop --" + colours[0])
    if 0 < len(colours) < 3:
        missing = " and ".join(f"--{role}" for role in COLOURS if role not in refs)
        raise typer.BadParameter(f"give {missing} too, or no colour references for a flat field (white only)")
    paths = [p for ref in refs.values() for p in (ref if isinstance(ref, list) else [ref])]
    refuse_inputs_as_output(out, [*paths, unmixing_from, folder])
    if out.exists() and not overwrite:
        raise OutputError("exists already (use --overwrite to replace it)", out)
    refuse_foreign(out, is_calibration_file, "a picamcal calibration")
    read = _reader(pattern, black_level, raw_format=raw_format, size=size, stride=stride, frame=frame, sensor=sensor)

    def frames(role: str) -> Any:  # several frames are read one at a time, as the calibration averages them
        ref = refs[role]
        return (read(path) for path in ref) if isinstance(ref, list) else read(ref)

    with console.status("calibrating"):
        if unmixing_from is not None:
            black_frames = frames("black") if "black" in refs else None
            cal = calibrate_in_situ(frames("white"), unmixing_from, black_frames, smoothing=smoothing)
        else:
            cal = calibrate(**{role: frames(role) for role in refs}, bin_size=bin_size, smoothing=smoothing)
        cal.save(out, overwrite=overwrite)
        checks = diagnose(cal)
    what = (
        f"worst noise penalty (centre mode) {float(cal.noise_penalty('centre').max()):.2f}"
        if cal.has_unmixing
        else "a flat field from the white alone (modes uncorrected and flat, no colour unmixing), "
        f"worst noise penalty (flat mode) {float(cal.noise_penalty('flat').max()):.2f}"
    )
    lines = [
        f"wrote {out}: {cal.sensor or 'unknown sensor'} {cal.width}x{cal.height} {cal.pattern}, "
        f"{cal.white.shape[1]}x{cal.white.shape[0]} bins of {cal.bin_size} px, {what}"
        + (f", unmixing from {unmixing_from.name}" if unmixing_from else "")
    ]
    for info in cal.inputs:
        if info.get("frame_count", 1) > 1:
            lines.append(
                f"{info['role']}: {info['frame_count']} frames averaged: temporal noise "
                f"{info['temporal_noise_dn']:.2f} DN per pixel in one frame, {info['averaged_noise_dn']:.2f} DN in "
                "their average"
            )
    lines += [f"needs a look: {check.name}: {check.summary}" for check in checks if check.verdict == "warn"]
    for line in lines:
        console.print(line, markup=False, soft_wrap=True)


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
    mode: Annotated[str, typer.Option(help=MODE_HELP)] = "centre",
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
            "srgb-png16 or srgb-jpeg (colour-managed, to look at)."
        ),
    ] = "float32-tiff",
    pattern: PatternOption = None,
    black_level: BlackOption = None,
    raw_format: RawFormatOption = None,
    size: RawSizeOption = None,
    stride: StrideOption = None,
    frame: FrameOption = None,
    sensor: RawSensorOption = None,
    workers: Annotated[
        int | None,
        typer.Option(
            help="Worker processes (default: one per core; 0: no pool, work in this process).",
            callback=_in_range(
                0,
                _MAX_WORKERS_PER_CORE * (os.cpu_count() or 1),
                why=f"{_MAX_WORKERS_PER_CORE} per core: more "
                "processes than cores only add memory, a frame and the calibration each",
            ),
        ),
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Run on this dask.distributed scheduler instead (tcp://host:port).")
    ] = None,
    compression: Annotated[str | None, typer.Option(help="Compress the outputs: zstd.")] = None,
    overwrite: Annotated[
        bool, typer.Option(help="Replace existing outputs (without it they are skipped: an interrupted batch resumes).")
    ] = False,
) -> None:
    """Correct raw (or, with --processed, ISP-processed) images in parallel; write one image file per input.

    float32 linear RGB TIFF by default; uint16 linear TIFF for Fiji/ImageJ; sRGB PNG (8 or 16 bit) or
    JPEG, colour-managed, to look at (docs/outputs.md). Existing outputs are skipped, so running the same
    command again resumes an interrupted batch. A file that fails is reported at the end and does not stop
    the others (exit status 1).
    """
    import time

    from rich.progress import TimeRemainingColumn

    from .batch import BatchOptionError, BatchOptions, run_batch
    from .output import OUTPUT_FORMATS

    mode = _mode(mode)
    output_format = _choice(output_format, OUTPUT_FORMATS, "--output-format")
    try:
        options = BatchOptions(
            out_dir=out,
            zarr_path=zarr_path,
            mosaic=_parse_tiles(mosaic),
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
        )
    except BatchOptionError as exc:  # options that do not go together, under their command-line names
        hint = _BATCH_OPTION_NAMES.get(exc.option) if exc.option else None
        raise typer.BadParameter(exc.message(_BATCH_OPTION_NAMES), param_hint=hint) from None
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,  # off a terminal, rich would leave an empty line on stderr
    )
    bar: dict = {}

    def show(finished: int, total: int) -> None:
        if not bar:  # the bar appears when the work starts, after every check has passed
            bar.update(task=progress.add_task(f"correcting ({mode})", total=total, rate=""), start=time.monotonic())
            progress.start()
        elapsed = time.monotonic() - bar["start"]
        progress.update(bar["task"], completed=finished, rate=f"{finished / elapsed:.1f} files/s" if finished else "")

    try:
        result = run_batch(calibration, inputs, options, progress=show)
    finally:
        progress.stop()
    elapsed = time.monotonic() - bar["start"] if bar else 0.0
    rate = f" ({len(result.done) / elapsed:.1f} files/s)" if result.done and elapsed > 0 else ""
    console.print(
        f"wrote {len(result.done)} image(s) to {zarr_path or out}{rate}; skipped {len(result.skipped)} "
        f"(done already); failed {len(result.failed)}",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    for path, reason in result.failed:
        console.print(f"picamcal: failed: {path}: {reason}", markup=False, highlight=False, soft_wrap=True)
    if result.failed:
        raise typer.Exit(1)


#: The command-line names of the batch options (BatchOptions fields) that ``correct`` takes.
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


def _batch_read_options(*args: Any) -> dict[str, Any]:
    """run_batch's keywords for the reading options (its ``raw_size`` is read_raw's ``size``)."""
    options = _read_options(*args)
    options["raw_size"] = options.pop("size")
    return options


def _load_tuning(path: Path) -> dict:
    from .export.tuning import load_tuning

    return load_tuning(path)


def _parse_tiles(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        columns, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not COLUMNSxROWS", param_hint="--mosaic") from None
    return columns, rows


def _parse_size(size: str | None, option: str = "--size") -> tuple[int, int] | None:
    if size is None:
        return None
    try:
        w, h = (int(v) for v in size.lower().split("x"))
    except ValueError:
        raise typer.BadParameter(f"{size!r} is not WIDTHxHEIGHT", param_hint=option) from None
    if w < 16 or h < 16 or w % 2 or h % 2:
        raise typer.BadParameter(f"{size!r}: width and height must be even and at least 16", param_hint=option)
    return w, h


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
) -> None:
    """Simulate a calibration run: five references, `picamcal target`'s target filling the frame, the ground truth."""
    from .simulate import RAW_WRITERS, simulate_run

    fmt = _choice(fmt, list(RAW_WRITERS), "--format")
    with console.status(f"simulating {sensor}"):
        paths = simulate_run(
            out,
            sensor,
            pattern=pattern,
            size=_parse_size(size),
            tilt=tilt,
            seed=seed,
            noise=noise,
            dust=dust,
            fmt=fmt,
            overwrite=overwrite,
        )
    console.print(f"wrote {len(paths)} files to {out}")


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
        int, typer.Option(help="Colour temperature of the table entry, kelvin.", callback=_COLOUR_TEMPERATURE)
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
    from .calibration import load_calibration
    from .export.tuning import (
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
        names = list(TARGET_NAMES) if _choice(target, (*TARGET_NAMES, "both"), "--target") == "both" else [target]
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
    for path in {out, *outputs}:
        refuse_inputs_as_output(path, [*bases, calibration])
    for path in outputs:
        if path.exists() and not overwrite:
            raise OutputError("exists already (use --overwrite to replace it)", path)
        refuse_foreign(path, is_tuning_file, "a libcamera tuning file")
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
        console.print(
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
    from .calibration import load_calibration
    from .export.legacy import is_legacy_table, legacy_table, save_legacy_table

    refuse_inputs_as_output(out, [calibration])
    if out.exists() and not overwrite:
        raise OutputError("exists already (use --overwrite to replace it)", out)
    refuse_foreign(out, is_legacy_table, "a legacy lens shading table")

    table = legacy_table(load_calibration(calibration))
    save_legacy_table(out, table, overwrite=overwrite)
    console.print(f"wrote {out}: {table.shape} uint8, gains {table.min() / 32:.2f} to {table.max() / 32:.2f}")


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
        typer.Option(help="Colour temperature for the tables (default: the file's).", callback=_COLOUR_TEMPERATURE),
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
    from .export.isp import apply_tuning, full_sensor_size, mode_for_image
    from .output import is_picamcal_output, write_rgb_tiff

    gains = _numbers(colour_gains, 2, "--colour-gains")
    if gains is not None and not all(0 < g <= _MAX_COLOUR_GAIN for g in gains):
        raise typer.BadParameter(
            f"{colour_gains!r}: each gain must be more than 0 and at most {_MAX_COLOUR_GAIN} (libcamera's range)",
            param_hint="--colour-gains",
        )
    crop = _numbers(sensor_crop, 4, "--sensor-crop")
    if crop is not None and not (
        all(math.isfinite(v) and v == int(v) for v in crop) and min(crop[:2]) >= 0 and min(crop[2:]) > 0
    ):
        raise typer.BadParameter(
            f"{sensor_crop!r}: X and Y must be whole numbers, 0 or more, and WIDTH and HEIGHT whole numbers above 0",
            param_hint="--sensor-crop",
        )
    given_size = _parse_size(sensor_size, "--sensor-size")
    refuse_inputs_as_output(out, [image, tuning_file])
    if out.exists() and not overwrite:
        raise OutputError("exists already (use --overwrite to replace it)", out)
    refuse_foreign(out, is_picamcal_output, "an image picamcal wrote")
    tuning = _load_tuning(tuning_file)
    headless = {"raw_format": raw_format, "size": size, "stride": stride, "frame": frame, "sensor": raw_sensor}
    raw = _reader(pattern, black_level, **headless)(image)
    full = given_size or full_sensor_size(raw)
    crop_box = (int(crop[0]), int(crop[1]), int(crop[2]), int(crop[3])) if crop else None
    mode = mode_for_image(full, (raw.width, raw.height), crop_box)
    try:
        rgb = apply_tuning(
            raw, tuning, colour_gains=(gains[0], gains[1]) if gains else None, ccm=ccm, mode=mode, ct=ct
        )
    except PicamcalError as exc:
        if exc.path is None:  # a problem with the tuning's content: the tuning dict does not know its file
            raise type(exc)(exc.problem, tuning_file) from None
        raise
    info = {"source": image.name, "tuning": tuning_file.name, "ccm": ccm}
    write_rgb_tiff(out, rgb, info, overwrite=overwrite)
    console.print(f"wrote {out}")


def _numbers(text: str | None, count: int, option: str) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.replace(",", " ").split())
    except ValueError:
        values = ()
    if len(values) != count:
        raise typer.BadParameter(f"{text!r} is not {count} comma-separated numbers", param_hint=option)
    return values


@app.command("inspect")
def inspect_cmd(
    files: Annotated[list[Path], typer.Argument(help="Files and folders (every file of a folder is listed).")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    pattern: PatternOption = None,
    black_level: BlackOption = None,
    raw_format: RawFormatOption = None,
    size: RawSizeOption = None,
    stride: StrideOption = None,
    frame: FrameOption = None,
    sensor: RawSensorOption = None,
) -> None:
    """Show what each file is: format, sensor, size, Bayer order, bit depth, levels, exposure; and what looks wrong.

    Every file is listed, also those that are not images (sidecars, calibrations) and those that cannot be read
    (with the reason); the exit status is 1 if any could not be read. One file that cannot be read is one error
    line (exit status 2), as in every other command.
    """
    import json
    import warnings

    from .describe import files_of, survey

    read = _reader(pattern, black_level, raw_format=raw_format, size=size, stride=stride, frame=frame, sensor=sensor)
    records = []
    for path in files_of(files):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            record = survey(path, read)
        record["warnings"] = [
            str(w.message).removeprefix(f"{path}: ") for w in caught if issubclass(w.category, PicamcalWarning)
        ]
        records.append(record)
    unreadable = [r for r in records if not r["readable"]]
    if len(files) == 1 and not files[0].is_dir() and unreadable:
        raise PicamcalError(unreadable[0]["error"], unreadable[0].get("error_path", files[0]))
    if as_json:
        print(json.dumps(_json_safe(records), indent=2, default=str))
    else:
        _print_inspection(records)
    if unreadable:
        raise typer.Exit(1)


def _json_safe(value: Any) -> Any:
    """Plain JSON: an unknown black level (NaN), or any number that is not finite, becomes null, as JSON has none."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def _print_inspection(records: list[dict[str, Any]]) -> None:
    table = Table()
    headings = ["file", "format", "sensor", "size", "pattern", "bits", "black", "white", "exposure", "gain"]
    frames = any("frames" in r for r in records)
    for heading in [*headings, "frames"] if frames else headings:
        table.add_column(heading)
    for r in records:
        if "width" not in r:  # not an image: a sidecar, a calibration, or unreadable
            table.add_row(Text(Path(r["path"]).name), Text(r["format"] if r["readable"] else "unreadable"))
            continue
        row = [
            Path(r["path"]).name,
            r["format"],
            r.get("sensor") or ("?" if r["raw"] else "-"),
            f"{r['width']}x{r['height']}",
            r.get("pattern", "-"),
            r["bit_depth"],
            _levels(r.get("black_level")),
            r.get("white_level", "-"),
            _figure(r.get("exposure_time_s"), 1e3, " ms"),
            _figure(r.get("analogue_gain")),
            *([r.get("frames", "-")] if frames else []),
        ]
        # Text, not markup: a file's name or metadata may hold brackets that rich would take for markup.
        table.add_row(*(Text(str(cell)) for cell in row))
    stdout = _stdout()
    stdout.print(table)
    for r in records:
        name = Path(r["path"]).name
        if "error" in r:
            stdout.print(f"{name}: cannot read: {r['error']}", markup=False, highlight=False, soft_wrap=True)
        if "note" in r:
            stdout.print(f"{name}: not raw: {r['note']}", markup=False, highlight=False, soft_wrap=True)
        for warning in r["warnings"]:
            stdout.print(f"{name}: {warning}", style="yellow", markup=False, highlight=False, soft_wrap=True)


def _stdout() -> Console:
    """Standard output; not squeezed to 80 columns when it is a file or a pipe."""
    console = Console()
    return console if console.is_terminal else Console(width=200)


def _levels(levels: list[float] | None) -> str:
    if not levels:
        return "-"
    return f"{levels[0]:g}" if len(set(levels)) == 1 else ",".join(f"{v:g}" for v in levels)


def _figure(value: Any, scale: float = 1.0, unit: str = "") -> str:
    """A number of a file's metadata as the table shows it: "-" when absent or zero, as it is when not a number."""
    if not value:
        return "-"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{scale * value:.3g}{unit}"
    return str(value)


@app.command("target")
def target_cmd(
    out: Annotated[Path, typer.Option("--out", "-o", help="TARGET.png or TARGET.pdf; the layout goes to TARGET.json.")],
    size: Annotated[
        str, typer.Option(help="WIDTHxHEIGHT in pixels (your monitor's, to show it full-screen).")
    ] = "1920x1080",
    overwrite: Annotated[bool, typer.Option(help="Replace existing files.")] = False,
) -> None:
    """Write the colour-wheel test target (PNG to show full-screen, or PDF to print) and its layout.

    The same target `picamcal simulate` photographs, laid out on WIDTHxHEIGHT pixels.
    """
    from .target import is_target_file, save_target

    width, height = _parse_size(size) or (1920, 1080)
    if out.suffix.lower() not in (".png", ".pdf"):
        raise typer.BadParameter("the target is written as .png or .pdf", param_hint="--out")
    for path in (out, out.with_suffix(".json")):
        if path.exists() and not overwrite:
            raise OutputError("exists already (use --overwrite to replace it)", path)
        refuse_foreign(path, is_target_file, "a target picamcal wrote")
    image, layout = save_target(out, width, height, overwrite=overwrite)
    console.print(f"wrote {image} and its layout {layout}")


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
    import json

    from .analysis.images import images_by_mode
    from .analysis.wheels import analyse, find_wheels, polar_plot
    from .calibration import load_calibration

    refuse_inputs_as_output(out, [*images, calibration, layout])
    cal = load_calibration(calibration) if calibration is not None else None
    target_layout = _read_layout(layout) if layout is not None else None
    outputs = [out / f"{image.stem}_analysis.json" for image in images]
    for path in outputs:
        if path.exists() and not overwrite:
            raise OutputError("exists already (use --overwrite to replace it)", path)
    table = Table(title="CIEDE2000 of the wheels against the centre wheel")
    for heading in ("image", "mode", "max", "mean", "saturation"):
        table.add_column(heading)
    with _progress() as progress:
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
    _stdout().print(table)


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
            callback=_in_range(
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
    from .calibration import load_calibration
    from .report import write_report

    cal = load_calibration(calibration)
    target_layout = _read_layout(layout) if layout is not None else None
    with console.status("writing the report") as status:
        index = write_report(
            cal,
            out,
            test_images=test or (),
            layout=target_layout,
            cra_corner_deg=cra,
            overwrite=overwrite,
            progress=lambda text: status.update(f"report: {text}"),
        )
    console.print(f"wrote {index}")


def _read_layout(path: Path) -> dict:
    from .analysis.wheels import read_layout

    return read_layout(path)


@app.command("acquire")
def acquire_cmd(
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder of the run: created, or resumed if it holds one.")],
    camera: Annotated[str, typer.Option(help="picamera2 (picamera2:N for camera N) or sim.")] = "picamera2",
    illuminator: Annotated[
        str, typer.Option(help="serial (serial:PORT), gpio (gpio:PIN, default D18), manual or sim.")
    ] = "serial",
    extra: Annotated[
        list[str] | None,
        typer.Option(help="An extra image at the same settings, e.g. target; asked for before each (repeatable)."),
    ] = None,
    target_fraction: Annotated[
        float,
        typer.Option(
            help="Where the white's 99.9th percentile should land, as a fraction of full scale.",
            callback=_in_range(0, 1, above=True, below=True),
        ),
    ] = 0.8,
    settle: Annotated[
        float,
        typer.Option(help="Seconds to wait after changing the light.", callback=_in_range(0, 600, unit=" s")),
    ] = 0.5,
    max_exposure: Annotated[
        float,
        typer.Option(
            help="Longest exposure time to use, in seconds.", callback=_in_range(0, 3600, above=True, unit=" s")
        ),
    ] = 1.0,
    sensor: Annotated[str, typer.Option(help="Simulated sensor (--camera sim).")] = "imx219",
    size: Annotated[str | None, typer.Option(help="Simulate WIDTHxHEIGHT instead of the full sensor.")] = None,
    seed: Annotated[int, typer.Option(help="Random seed of the simulated camera.", callback=_in_range(0))] = 0,
) -> None:
    """Capture a calibration run: auto-expose on white, freeze, then white, red, green, blue, black and extras."""
    from .acquire.acquisition import acquire, open_rig

    def show(message: str, done: int, total: int) -> None:
        # One line per step rather than a live bar, so it never draws over the prompts.
        console.print(f"[{done}/{total}] {message}")

    with open_rig(camera, illuminator, sensor=sensor, size=_parse_size(size), seed=seed, prompt=input) as rig:
        manifest = acquire(
            rig.camera,
            rig.illuminator,
            out,
            extras=extra or (),
            target_fraction=target_fraction,
            settle_s=settle,
            max_exposure_s=max_exposure,
            prompt=rig.prompt,
            progress=show,
        )
    console.print(f"wrote {manifest}; calibrate with: picamcal calibrate {out}")


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
        typer.Option(help="A libcamera tuning file to write the lens shading into (repeatable)."),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Write into a folder that is not empty.")] = False,
) -> None:
    """Run the whole method on the simulated camera and print the figures before and after."""
    from .demo import STEPS, run_demo
    from .simulate import RAW_WRITERS

    fmt = _choice(fmt, list(RAW_WRITERS), "--format")
    refuse_inputs_as_output(out, tuning_base or ())
    with _progress() as progress:
        task = progress.add_task("demo", total=len(STEPS))

        def step(description: str) -> None:
            progress.update(task, description=description, completed=STEPS.index(description))

        figures = run_demo(
            out,
            sensor,
            size=_parse_size(size),
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
    stdout = _stdout()
    stdout.print(table)
    for mode, meaning in figures["mode_meaning"].items():
        stdout.print(f"  {mode}: {meaning}")
    for name, record in figures["exports"].items():
        stdout.print(f"  {name}: an independent white is flat to {record['white_flatness_percent']:.2f} % with it")
    stdout.print(f"Calibration, previews (target_<mode>.png) and figures.json are in {out}/")
    stdout.print(f"The report: {out / 'report' / 'index.html'}")


#: picamcal's warnings of this command, and the lines libraries logged: printed when it ends well, and when it
#: fails, the warnings folded into the one error line (the libraries' lines are their own view of the same problem).
_held_warnings: list[str] = []
_held_log: list[str] = []


def _warn(message, category, filename, lineno, file=None, line=None) -> None:
    if issubclass(category, PicamcalWarning):
        _held_warnings.append(str(message))


class _HoldLog(logging.Handler):
    def emit(self, record: logging.LogRecord) -> None:
        _held_log.append(f"{record.name}: {record.getMessage()}")


@contextlib.contextmanager
def _hold_native_stderr() -> Iterator[Callable[[], bytes]]:
    """Catch what C libraries write straight to file descriptor 2 (LibRaw's "Unexpected end of file").

    Descriptor 2 points at a temporary file while the command runs, and ``sys.stderr`` (picamcal's own lines,
    rich's progress) at a duplicate of the real one. Yields a function that reads what was caught. Nothing changes
    when ``sys.stderr`` is not descriptor 2 (a test capturing it).
    """
    try:
        native = sys.stderr.fileno() == 2
    except (AttributeError, OSError, ValueError):
        native = False
    if not native:
        yield lambda: b""
        return
    sys.stderr.flush()
    python_stderr = sys.stderr
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        sys.stderr = open(  # closed below, after descriptor 2 is restored
            saved, "w", encoding=python_stderr.encoding, errors=python_stderr.errors, buffering=1, closefd=False
        )

        def caught() -> bytes:
            held.seek(0)
            return held.read()

        try:
            yield caught
        finally:
            sys.stderr.flush()
            sys.stderr.close()
            sys.stderr = python_stderr
            os.dup2(saved, 2)
            os.close(saved)


def _release_held(native: bytes) -> None:
    """Print what was held back during a command that did not fail."""
    sys.stderr.flush()
    if native:
        os.write(2, native)
    for line in _held_log:
        print(line, file=sys.stderr)
    for message in _held_warnings:
        print(f"picamcal: warning: {message}", file=sys.stderr)


def _spread_role_options(args: list[str]) -> list[str]:
    """``calibrate --white a.dng b.dng`` as ``--white a.dng --white b.dng``: several frames per reference role.

    Click options take one value each; the values after a role option that name existing files (not folders,
    not options) are taken as more frames of that role.
    """
    if "calibrate" not in args[:1]:
        return args
    roles = {f"--{role}" for role in ("white", "red", "green", "blue", "black")}
    out: list[str] = []
    role = None
    for arg in args:
        if arg in roles:
            role = arg
        elif role is not None and out and out[-1] != role and not arg.startswith("-") and Path(arg).is_file():
            out.append(role)
        elif arg.startswith("-") or out[-1:] != [role]:
            role = None
        out.append(arg)
    return out


def _fail(message: str) -> None:
    """The one error line every problem ends in (never wrapped, whatever the terminal), and exit status 2.

    Warnings given before the error are folded into it, so that the line stays one.
    """
    if _held_warnings:
        message += f" (after {len(_held_warnings)} warning(s): {'; '.join(_held_warnings)})"
    print(f"picamcal: error: {' '.join(message.split())}", file=sys.stderr)
    sys.exit(2)


def _click_exceptions() -> Any:
    """click's exceptions module: typer 0.2x carries its own copy of click."""
    import importlib

    try:
        return importlib.import_module("typer._click.exceptions")
    except ImportError:
        return importlib.import_module("click.exceptions")


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``picamcal`` command: runs the app and turns every error into one line and exit status 2."""
    click = _click_exceptions()

    warnings.showwarning = _warn
    _held_warnings.clear()
    _held_log.clear()
    # picamcal says what is wrong with a file in its own one line; tifffile would log its own view of it too.
    logging.getLogger("tifffile").setLevel(logging.CRITICAL)
    hold_log = _HoldLog(logging.WARNING)
    logging.getLogger().addHandler(hold_log)
    args = _spread_role_options(list(sys.argv[1:] if argv is None else argv))
    try:
        with _hold_native_stderr() as native:
            try:
                code = app(args=args, prog_name="picamcal", standalone_mode=False)
            except click.UsageError as exc:
                command = exc.ctx.command_path if exc.ctx is not None else "picamcal"
                _fail(f"{exc.format_message().rstrip('.')} (see {command} --help)")
            except click.ClickException as exc:
                _fail(exc.format_message())
            except typer.Abort:
                _release_held(native())
                print("picamcal: interrupted", file=sys.stderr)
                sys.exit(130)
            except PicamcalError as exc:
                _fail(str(exc))
            _release_held(native())
    finally:
        logging.getLogger().removeHandler(hold_log)
    sys.exit(code if isinstance(code, int) else 0)
