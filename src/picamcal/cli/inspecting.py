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

    from ..describe import inspection_table

    columns, rows, lines, warned = inspection_table(records)
    table = Table()
    for heading in columns:
        table.add_column(heading)
    for row in rows:
        # Text, not markup: a file's name or metadata may hold brackets that rich would take for markup.
        table.add_row(*(Text(cell) for cell in row))
    stdout = stdout_console()
    stdout.print(table)
    for line in lines:
        style = "yellow" if line in warned else None
        stdout.print(line, style=style, markup=False, highlight=False, soft_wrap=True)
