"""The TIFF structure of a DNG: reading IFDs and tag values with every offset, type and count checked, and
encoding IFDs for the writer.

A DNG is a TIFF file (TIFF 6.0 section 2): an 8-byte header (byte order, 42, the offset of IFD 0), then image
file directories of 12-byte entries (tag, field type, count, and the value itself when it fits in 4 bytes, else
its offset).
"""

from __future__ import annotations

import io
import math
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

from ...errors import OutputError, RawFormatError, one_line, short
from .tags import (
    ASCII,
    BYTE,
    RATIONAL,
    SRATIONAL,
    STRUCT,
    TAG_NAMES,
    TYPE_NAMES,
    TYPE_SIZE,
    UNDEFINED,
)

#: A real DNG's tags are far smaller: a tag declaring more is refused before its values are read.
_MAX_TAG_BYTES = 4 << 20


def is_dng(head: bytes) -> bool:
    """True if the first bytes of a file are a TIFF header (DNG is a TIFF).

    Examples
    --------
    >>> is_dng(b"II*\\x00\\x08\\x00\\x00\\x00"), is_dng(b"\\x89PNG")
    (True, False)
    """
    return head[:4] in (b"II*\x00", b"MM\x00*")


# --- reading: every offset, type and count checked ------------------------------------------------------------


@dataclass(frozen=True)
class Field:
    """One IFD entry as found: tag code, field type, value count and the file offset of its values."""

    code: int
    type: int
    count: int
    at: int


class TiffFile:
    """A TIFF file's IFDs and tag values, read on demand: only the bytes asked for, each range checked first.

    Nothing here trusts a count or an offset: a value that lies past the end of the file, a tag of another type
    or count than the DNG specification gives, a zero denominator or a non-finite number is a
    :class:`~picamcal.errors.RawFormatError` naming the tag.

    Examples
    --------
    >>> import io
    >>> from picamcal.raw.dng.tags import ASCII, IMAGE_WIDTH, LONG, MAKE, SHORT
    >>> ifd0 = ifd_bytes([entry(IMAGE_WIDTH, LONG, 320), entry(MAKE, ASCII, "Raspberry Pi")], 8)
    >>> data = b"II*\\x00" + struct.pack("<I", 8) + ifd0
    >>> tiff = TiffFile(io.BytesIO(data), len(data), Path("x.dng"))
    >>> fields = tiff.ifd(tiff.first_ifd, "IFD 0")
    >>> tiff.one(fields, IMAGE_WIDTH, (SHORT, LONG)), tiff.tag(fields, MAKE, (ASCII,))
    (320, 'Raspberry Pi')
    >>> tiff.one(fields, MAKE, (SHORT,))
    Traceback (most recent call last):
    ...
    picamcal.errors.RawFormatError: x.dng: DNG tag Make is of type ASCII, not SHORT
    """

    def __init__(self, f: io.BufferedIOBase, size: int, path: Path) -> None:
        self.f, self.size, self.path = f, size, path
        head = self.read(0, 8, "the TIFF header")
        orders = {b"II*\x00": "<", b"MM\x00*": ">"}
        if head[:4] not in orders:
            raise RawFormatError("not a DNG: no TIFF header (II*/MM*; a BigTIFF is not a DNG)", path)
        self.order = orders[head[:4]]
        self.first_ifd = struct.unpack(self.order + "I", head[4:])[0]

    def read(self, offset: int, length: int, what: str) -> bytes:
        if offset + length > self.size:
            raise RawFormatError(
                f"corrupt TIFF/DNG structure: {what} (bytes {offset} to {offset + length}) lies beyond the end of "
                f"the file ({self.size} bytes): a truncated file?",
                self.path,
            )
        self.f.seek(offset)
        data = self.f.read(length)
        if len(data) != length:  # the file shrank while it was read
            raise RawFormatError(f"truncated file: {what} ends early", self.path)
        return data

    def ifd(self, offset: int, what: str) -> dict[int, Field]:
        """The entries of the IFD at ``offset`` by tag code (TIFF forbids repeated tags: the first one counts)."""
        (count,) = struct.unpack(self.order + "H", self.read(offset, 2, what))
        if count == 0:
            raise RawFormatError(f"corrupt TIFF/DNG structure: {what} has no entries", self.path)
        table = self.read(offset + 2, 12 * count, what)
        fields: dict[int, Field] = {}
        for start in range(0, 12 * count, 12):
            code, kind, values = struct.unpack_from(self.order + "HHI", table, start)
            at = offset + 2 + start + 8
            if TYPE_SIZE.get(kind, 0) * values > 4:  # longer values lie elsewhere, at the offset given
                at = struct.unpack_from(self.order + "I", table, start + 8)[0]
            fields.setdefault(code, Field(code, kind, values, at))
        return fields

    def tag(
        self,
        ifd: Mapping[int, Field],
        code: int,
        types: Sequence[int],
        count: int | None = None,
        *,
        default: Any = None,
        positive: bool = False,
    ) -> Any:
        """The values of tag ``code``: a list of numbers (rationals divided out), or text for ASCII.

        ``types`` are the field types the specification allows, ``count`` the number of values it needs (None: at
        least one), ``positive`` requires every value above 0; ``default`` is returned when the tag is absent.
        """
        field = ifd.get(code)
        if field is None:
            return default
        name = TAG_NAMES.get(code, f"#{code}")
        if field.type not in types:
            allowed = " or ".join(TYPE_NAMES[t] for t in types)
            kind = TYPE_NAMES.get(field.type, f"unknown type {field.type}")
            raise RawFormatError(f"DNG tag {name} is of type {kind}, not {allowed}", self.path)
        if field.count == 0 or (count is not None and field.count != count):
            raise RawFormatError(f"DNG tag {name} has {field.count} values, not {count or 'at least 1'}", self.path)
        nbytes = TYPE_SIZE[field.type] * field.count
        if nbytes > _MAX_TAG_BYTES:
            raise RawFormatError(f"DNG tag {name} declares {field.count} values, more than a DNG tag holds", self.path)
        data = self.read(field.at, nbytes, f"the value of DNG tag {name}")
        if field.type == ASCII:
            return tag_text(data)
        if field.type in (BYTE, UNDEFINED):
            values: list[Any] = list(data)
        else:
            code_of_one = STRUCT[field.type]
            flat = struct.unpack(f"{self.order}{len(code_of_one) * field.count}{code_of_one[0]}", data)
            if field.type in (RATIONAL, SRATIONAL):
                if any(den == 0 for den in flat[1::2]):
                    raise RawFormatError(f"DNG tag {name} has a zero denominator: {shown(flat)}", self.path)
                values = [num / den for num, den in zip(flat[::2], flat[1::2], strict=True)]
            else:
                values = list(flat)
        if not all(math.isfinite(v) for v in values):
            raise RawFormatError(f"DNG tag {name} has a value that is not finite: {shown(values)}", self.path)
        if positive and not all(v > 0 for v in values):
            raise RawFormatError(f"DNG tag {name} must be positive, not {shown(values)}", self.path)
        return values

    def one(self, ifd: Mapping[int, Field], code: int, types: Sequence[int], default: Any = None) -> Any:
        """The single value of tag ``code`` (a count other than 1 is an error), or ``default`` when absent."""
        values = self.tag(ifd, code, types, 1)
        return default if values is None else values[0]


def tag_text(data: bytes) -> str:
    """ASCII tag bytes as text: up to the first NUL, undecodable bytes replaced, no control characters."""
    return one_line(data.split(b"\x00", 1)[0].decode("utf-8", "replace"))


def shown(values: Any) -> str:
    """A tag's value for a one-line message (a tuple of values shown as a list)."""
    return short(list(values) if isinstance(values, tuple) else values)


# --- writing: little-endian IFDs -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Entry:
    """One IFD entry: tag code, field type, value count and the values' bytes (little-endian)."""

    code: int
    type: int
    count: int
    data: bytes


def entry(code: int, kind: int, values: Any) -> Entry:
    """Encode values of a field type: text for ASCII, bytes for BYTE/UNDEFINED, numbers otherwise."""
    if kind == ASCII:
        data = str(values).encode("ascii", "replace") + b"\x00"
        return Entry(code, kind, len(data), data)
    if kind in (BYTE, UNDEFINED):
        data = bytes(values)
        return Entry(code, kind, len(data), data)
    numbers = list(values) if isinstance(values, Iterable) else [values]
    flat: list[int] = []
    for number in numbers:
        flat.extend(rational(number, signed=kind == SRATIONAL) if kind in (RATIONAL, SRATIONAL) else [number])
    data = struct.pack(f"<{len(flat)}{STRUCT[kind][0]}", *flat)
    return Entry(code, kind, len(numbers), data)


def rational(value: float, *, signed: bool = False) -> tuple[int, int]:
    """The nearest fraction with a denominator up to 10**6 that fits the TIFF (S)RATIONAL field.

    Examples
    --------
    >>> rational(0.02), rational(-1 / 3, signed=True)
    ((1, 50), (-1, 3))
    """
    limit = 2**31 - 1 if signed else 2**32 - 1
    if not math.isfinite(value) or (value < 0 and not signed) or abs(value) > limit:
        raise OutputError(f"{value} does not fit a TIFF {'signed ' if signed else ''}rational")
    f = Fraction(value).limit_denominator(1_000_000)
    while abs(f.numerator) > limit or f.denominator > limit:
        f = f.limit_denominator(max(1, f.denominator // 10))
    return f.numerator, f.denominator


def ifd_bytes(entries: Sequence[Entry], offset: int) -> bytes:
    """An IFD placed at ``offset`` (even), followed by its values longer than 4 bytes, each at an even offset.

    Entries are written in ascending tag order (TIFF 6.0 section 2) and the next-IFD offset is 0.
    """
    entries = sorted(entries, key=lambda e: e.code)
    table = bytearray(struct.pack("<H", len(entries)))
    values = bytearray()
    values_at = offset + 2 + 12 * len(entries) + 4
    for e in entries:
        if len(e.data) <= 4:
            table += struct.pack("<HHI", e.code, e.type, e.count) + e.data.ljust(4, b"\x00")
        else:
            table += struct.pack("<HHII", e.code, e.type, e.count, values_at + len(values))
            values += e.data + b"\x00" * (len(e.data) % 2)
    return bytes(table + struct.pack("<I", 0) + values)


def align_up(offset: int, to: int) -> int:
    """``offset`` rounded up to a multiple of ``to``."""
    return -(-offset // to) * to
