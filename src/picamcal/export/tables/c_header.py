"""Legacy lens shading tables as C headers: ``ls_table.h`` of 6by9's ``lens_shading`` tool, ArduCAM's
``ls_table_<W>x<H>.h`` and the scripts that copy them.

The layout these tools write::

    uint8_t ls_grid[] = {
    //R - Ch 3
    32, 33, 35, ... ,
    ...
    };
    uint32_t ref_transform = 3;
    uint32_t grid_width = 52;
    uint32_t grid_height = 39;

one initialiser of 4 x rows x columns whole numbers (planes R, Gr, Gb, B, each row of cells on a line), and the grid's
size. Some scripts swap ``grid_width`` and ``grid_height``, so the size is taken as the order that fits the numbers
per line. The text is parsed, never compiled or run: comments are dropped, the first brace initialiser is read, its
numbers must be decimal, hexadecimal or octal literals of 0..255, and the file is at most :data:`MAX_HEADER_BYTES`.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...limits import require_regular_file
from .model import MAX_CELLS, TableFileError, check_legacy_gains

#: A header of the largest table (4 x 512 x 512 numbers, five characters each) fits well within this.
MAX_HEADER_BYTES = 8 << 20
#: Suffixes of the C sources picamcal reads as tables.
HEADER_SUFFIXES = (".h", ".hpp", ".c", ".inc")

_INITIALISER = re.compile(r"\[[^\[\]{};]*\]\s*=\s*\{([^{}]*)\}")
_SCALAR = re.compile(r"\b(grid_width|grid_height|ref_transform)\s*=\s*(\w+)\s*;")
_NUMBER = re.compile(r"(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)[uUlL]*")


def _without_comments(text: str) -> str:
    """The text with its ``//`` and ``/* */`` comments as spaces, in one pass (an unclosed ``/*`` runs to the end)."""
    kept: list[str] = []
    at = 0
    line = block = -1  # where the next of each starts, searched again only once passed
    while at < len(text):
        if 0 <= line < at or line == -1:
            line = text.find("//", at)
            line = len(text) if line < 0 else line
        if 0 <= block < at or block == -1:
            block = text.find("/*", at)
            block = len(text) if block < 0 else block
        start = min(line, block)
        kept.append(text[at:start])
        if start == len(text):
            break
        if start == line:
            end = text.find("\n", start)
            at = len(text) if end < 0 else end
        else:
            end = text.find("*/", start + 2)
            at = len(text) if end < 0 else end + 2
            kept.append(" ")
    return "".join(kept)


def _literal(text: str) -> int | None:
    """A C integer literal's value, or None."""
    match = _NUMBER.fullmatch(text)
    if match is None:
        return None
    digits = match[1]
    return int(digits, 16 if digits[:2].lower() == "0x" else 8 if len(digits) > 1 and digits[0] == "0" else 10)


def read_header_table(
    path: str | os.PathLike[str], shapes: Sequence[tuple[int, int]] = ()
) -> tuple[np.ndarray, dict[str, Any]]:
    """The legacy table (uint8, (4, rows, cols)) of a C header, and what else the header says (``ref_transform``,
    ``grid_width``, ``grid_height``).

    The grid's rows and columns are, in this order of preference: ``grid_width`` and ``grid_height`` (either way
    round) where the numbers per line of the initialiser say which; the numbers per line and the lines per plane;
    one of ``shapes`` (the tables of the sensors picamcal knows, (rows, columns)) that fits the count.

    Raises
    ------
    TableFileError
        Not text, no brace initialiser (not a table), something in it that is not a whole number of 0..255, a count
        that is not 4 planes of any grid, zeros; one line naming the file.

    Examples
    --------
    >>> rows = "\\n".join(", ".join(["32"] * 6) + "," for _ in range(4))
    >>> text = "uint8_t ls_grid[] = {\\n" + "\\n".join(f"//{c}\\n{rows}" for c in ("R", "Gr", "Gb", "B")) + "\\n};\\n"
    >>> _ = Path("ls_table.h").write_text(text + "uint32_t grid_width = 6;\\nuint32_t grid_height = 4;\\n")
    >>> table, said = read_header_table("ls_table.h")
    >>> table.shape, said["grid_width"]
    ((4, 4, 6), 6)
    """
    path = Path(path)
    size = require_regular_file(path, TableFileError)
    if size > MAX_HEADER_BYTES:
        raise TableFileError(f"a C header of {size} bytes is far larger than any lens shading table's", path)
    raw = path.read_bytes()
    if b"\x00" in raw:
        raise TableFileError("not a C header (binary data): expected a lens shading table's text", path)
    text = _without_comments(raw.decode("utf-8", "replace"))
    match = _INITIALISER.search(text)
    if match is None:
        raise TableFileError(
            "a C header with no table (no 'name[] = { ... }' initialiser): expected a legacy lens shading table "
            "such as ls_table.h",
            path,
        )
    said: dict[str, Any] = {}
    for name, value in _SCALAR.findall(text):
        number = _literal(value)
        if number is not None:
            said[name] = number
    lines = [line for line in match[1].splitlines() if line.strip(" \t\r,")]
    values: list[int] = []
    per_line: list[int] = []
    for line in lines:
        items = [item.strip() for item in line.split(",") if item.strip()]
        for item in items:
            number = _literal(item)
            if number is None or number > 255:
                shown = item if len(item) <= 20 else item[:17] + "..."
                raise TableFileError(
                    f"its table holds {shown!r}, expected whole numbers 0..255 (u3.5 gains, 32 = 1.0)", path
                )
            values.append(number)
        per_line.append(len(items))
    shape = _grid(len(values), said, per_line, shapes)
    if shape is None:
        raise TableFileError(
            f"its table of {len(values)} numbers is not 4 planes (R, Gr, Gb, B) of a grid picamcal can tell"
            + (
                f" (grid_width {said.get('grid_width')}, grid_height {said.get('grid_height')})"
                if "grid_width" in said or "grid_height" in said
                else ""
            ),
            path,
        )
    table = np.array(values, dtype=np.int64).reshape(4, *shape)
    return check_legacy_gains(table, path), said


def _grid(
    count: int, said: dict[str, Any], per_line: list[int], shapes: Sequence[tuple[int, int]]
) -> tuple[int, int] | None:
    """(rows, columns) of a table of ``count`` numbers, or None."""
    if count % 4 or count == 0:
        return None
    cells = count // 4
    columns = per_line[0] if per_line and len(set(per_line)) == 1 else None
    width, height = said.get("grid_width"), said.get("grid_height")
    fitting = [
        (rows, cols)
        for rows, cols in ((height, width), (width, height))
        if isinstance(rows, int) and isinstance(cols, int) and rows * cols == cells
    ]
    if fitting:
        if columns is not None:
            return next((shape for shape in fitting if shape[1] == columns), fitting[0])
        return fitting[0]
    if columns and cells % columns == 0 and 2 <= cells // columns <= MAX_CELLS and 2 <= columns <= MAX_CELLS:
        return cells // columns, columns
    return next(((rows, cols) for rows, cols in shapes if rows * cols == cells), None)


def is_header_file(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is named as a C source (:data:`HEADER_SUFFIXES`): what picamcal reads as a table's header.

    Examples
    --------
    >>> is_header_file("ls_table_1160x800.h"), is_header_file("white.dng")
    (True, False)
    """
    return Path(path).suffix.lower() in HEADER_SUFFIXES
