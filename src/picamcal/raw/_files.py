"""Opening a file the user named, with the one-line errors every reader gives."""

from __future__ import annotations

from pathlib import Path

from ..errors import RawFormatError
from ..limits import require_regular_file


def file_head(path: Path, size: int = 8) -> bytes:
    """The first ``size`` bytes of a file, for recognising its format.

    Raises
    ------
    RawFormatError
        No such file, a directory or another thing that is not a regular file (a FIFO would block), unreadable,
        or empty.
    """
    require_regular_file(path)
    try:
        with open(path, "rb") as f:
            head = f.read(size)
    except FileNotFoundError:
        raise RawFormatError("no such file", path) from None
    except IsADirectoryError:
        raise RawFormatError("is a directory, not an image file", path) from None
    except OSError as exc:
        raise RawFormatError(f"cannot read: {exc.strerror or exc}", path) from exc
    if not head:
        raise RawFormatError("empty file (0 bytes)", path)
    return head
