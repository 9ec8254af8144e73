"""``inspect``: what each file is, and what looks wrong with it."""

# Annotations are not postponed (no `from __future__ import annotations`): typer reads every command's on each run,
# and would evaluate them from strings each time.

import json
import math
from pathlib import Path
from typing import Annotated, Any

import typer

from ._common import (
    BlackOption,
    FrameOption,
    PatternOption,
    RawFormatOption,
    RawSensorOption,
    RawSizeOption,
    StrideOption,
    app,
    reader,
    stdout_console,
)


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
    """Show what each file is: format, sensor, size, Bayer order, bit depth, levels, signal, exposure; and what looks
    wrong.

    The signal is the median DN over black ("dark" for a frame at black: a dark frame). Every file is listed, also
    those that are not images (sidecars, calibrations, notes: "not an image") and those that cannot be read (with
    the reason); the exit status is 1 if any could not be read. A folder that is empty or holds only files that are
    not images, or one file that cannot be read or is not an image, is one error line (exit status 2), as in every
    other command.
    """
    from ..describe import inspect_files

    read = reader(pattern, black_level, raw_format=raw_format, size=size, stride=stride, frame=frame, sensor=sensor)
    records = inspect_files(files, read)
    unreadable = [r for r in records if not r["readable"]]
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
    from rich.table import Table
    from rich.text import Text

    table = Table()
    headings = [
        "file",
        "format",
        "sensor",
        "size",
        "sensor mode",
        "pattern",
        "bits",
        "black",
        "white",
        "signal",
        "exposure",
        "gain",
    ]
    frames = any("frames" in r for r in records)
    for heading in [*headings, "frames"] if frames else headings:
        table.add_column(heading)
    for r in records:
        if "width" not in r:  # not an image (a sidecar, a calibration, notes), or unreadable
            table.add_row(Text(Path(r["path"]).name), Text(r["format"] if r["readable"] else "unreadable"))
            continue
        row = [
            Path(r["path"]).name,
            r["format"],
            r.get("sensor") or ("?" if r["raw"] else "-"),
            f"{r['width']}x{r['height']}",
            _mode(r.get("geometry")),
            r.get("pattern", "-"),
            r["bit_depth"],
            _levels(r.get("black_level")) if r["raw"] else "-",
            r.get("white_level", "-"),
            _signal(r),
            _figure(r.get("exposure_time_s"), 1e3, " ms"),
            _gain(r),
            *([r.get("frames", "-")] if frames else []),
        ]
        # Text, not markup: a file's name or metadata may hold brackets that rich would take for markup.
        table.add_row(*(Text(str(cell)) for cell in row))
    stdout = stdout_console()
    stdout.print(table)
    said: dict[str, list[str]] = {}  # each note or warning, with the files that gave it, in the order first given
    for r in records:
        name = Path(r["path"]).name
        if "error" in r:
            stdout.print(f"{name}: cannot read: {r['error']}", markup=False, highlight=False, soft_wrap=True)
        if "note" in r:
            stdout.print(f"{name}: not raw: {r['note']}", markup=False, highlight=False, soft_wrap=True)
        if "width" not in r and "sensor_mode" in r:  # a calibration: where on the sensor it was taken
            stdout.print(f"{name}: sensor mode {r['sensor_mode']}", markup=False, highlight=False, soft_wrap=True)
        for warning in [*r.get("notes", []), *r["warnings"]]:
            said.setdefault(warning, []).append(name)
    # Once each: a folder of frames of one size gives every one the same "taken as the imx296".
    for warning, names in said.items():
        who = names[0] if len(names) == 1 else f"{names[0]} and {len(names) - 1} more"
        stdout.print(f"{who}: {warning}", style="yellow", markup=False, highlight=False, soft_wrap=True)


def _mode(geometry: dict[str, Any] | None) -> str:
    """A frame's sensor mode in a few characters: ``full``, ``full /2`` (binned 2 x 2), ``1920x1080@680,692``;
    ``?`` when nothing said it (the whole sensor assumed)."""
    if not geometry:
        return "-"
    x, y, w, h = geometry["crop"]
    where = "full" if [x, y, w, h] == [0, 0, *geometry["sensor_size"]] else f"{w}x{h}@{x},{y}"
    binned = f" /{geometry['binning']}" if geometry["binning"] > 1 else ""
    return f"{where}{binned}" + (" ?" if geometry["source"] == "assumed" else "")


def _levels(levels: list[float] | None) -> str:
    if not levels:
        return "-"
    if not all(math.isfinite(v) for v in levels):  # the notes below the table say why
        return "unknown"
    return f"{levels[0]:g}" if len(set(levels)) == 1 else ",".join(f"{v:g}" for v in levels)


def _signal(record: dict[str, Any]) -> str:
    """The median DN over black, ``dark`` for a dark frame; ``?`` where the black level is unknown."""
    if not record["raw"]:
        return "-"
    signal = record.get("signal_dn")
    if signal is None:
        return "?"
    text = f"{signal:.0f}" if abs(signal) >= 10 else f"{signal:.1f}"
    return f"{text} dark" if record.get("dark") else text


def _gain(record: dict[str, Any]) -> str:
    """The analogue gain, else the ISO the file gives (legacy JPEG+raw and DNG files say that instead)."""
    if record.get("analogue_gain"):
        return _figure(record["analogue_gain"])
    return f"ISO {_figure(record['iso'])}" if record.get("iso") else "-"


def _figure(value: Any, scale: float = 1.0, unit: str = "") -> str:
    """A number of a file's metadata as the table shows it: "-" when absent or zero, as it is when not a number."""
    if not value:
        return "-"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{scale * value:.3g}{unit}"
    return str(value)
