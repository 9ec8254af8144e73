"""Decoding a DNG's mosaic with LibRaw (rawpy), its sizes checked before it allocates, its messages caught.

LibRaw prints its data errors on the process's standard error itself; they are folded into picamcal's one-line
error (or warning) instead.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ...errors import RawFormatError
from ...limits import check_size
from ..model import PATTERNS

_MAX_SAID_BYTES = 64 << 10  # of LibRaw's stderr, enough for its first few messages
_C_STDERR_LOCK = threading.Lock()


@contextlib.contextmanager
def _c_stderr(said: list[str]) -> Iterator[None]:
    """Capture what C code (LibRaw) writes to the process's stderr meanwhile; its lines land in ``said``.

    LibRaw prints its data errors ("data corrupted at 352", "Unexpected end of file") to file descriptor 2
    itself, which would add lines to picamcal's one-line error. The descriptor is pointed at a temporary file and
    restored however the block ends; a lock keeps two threads from swapping it under each other (what another
    thread writes to stderr meanwhile is caught too).
    """
    with _C_STDERR_LOCK, tempfile.TemporaryFile() as sink:
        with contextlib.suppress(AttributeError, OSError, ValueError):  # no sys.stderr, or a closed one
            sys.stderr.flush()
        try:
            saved = os.dup(2)
        except OSError:  # no descriptor 2 at all (a daemon): nothing to capture
            saved = None
        if saved is None:
            yield
            return
        try:
            os.dup2(sink.fileno(), 2)
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read(_MAX_SAID_BYTES).decode("utf-8", "replace")
            said.extend(line.strip() for line in text.splitlines() if line.strip())


def _libraw_said(said: list[str], path: Path) -> str:
    """LibRaw's own messages, once each and without the file name it puts in front, for a one-line message."""
    prefix = f"{path}: "
    lines = list(dict.fromkeys(line.removeprefix(prefix) for line in said))
    text = "; ".join(lines[:3]) + ("; ..." if len(lines) > 3 else "")
    return text if len(text) <= 200 else text[:197] + "..."


def _libraw_error(exc: BaseException) -> str:
    message = exc.args[0] if exc.args else ""
    message = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


def _check_libraw_sizes(path: Path, sizes: Any, expected_shape: Sequence[int] | None) -> tuple[int, int]:
    """Check the sizes LibRaw found before it allocates the mosaic; the visible area's even (height, width)."""
    check_size(path, int(sizes.raw_width), int(sizes.raw_height))
    height, width = int(sizes.height), int(sizes.width)
    if (
        height < 2
        or width < 2
        or sizes.top_margin + height > sizes.raw_height
        or sizes.left_margin + width > sizes.raw_width
    ):
        raise RawFormatError(
            f"corrupt file: LibRaw finds a visible area of {width}x{height} at ({sizes.left_margin}, "
            f"{sizes.top_margin}) in a {sizes.raw_width}x{sizes.raw_height} mosaic",
            path,
        )
    shape = (height // 2 * 2, width // 2 * 2)
    check_size(path, shape[1], shape[0], expected_shape)
    return shape


class Decoded(NamedTuple):
    """What LibRaw found: the visible mosaic (even-sized), its pattern, per-site black levels and white level, and
    what it printed while reading ("" if nothing)."""

    bayer: np.ndarray
    pattern: str
    black: tuple[float, float, float, float]
    white: int
    said: str


def decode(path: Path, expected_shape: Sequence[int] | None, problems: list[str]) -> Decoded:
    """The visible mosaic of the DNG ``path`` and its levels, from LibRaw; its sizes checked before it is decoded.

    What LibRaw printed is returned for a warning when it still succeeded. If
    LibRaw fails, the error says what it printed and the malformed metadata picamcal found (``problems``): LibRaw
    gives up on some of it (an EXIF IFD past the end of the file) with nothing more than "Input/output error".

    Examples
    --------
    >>> from picamcal.raw import RawImage, write_dng
    >>> _ = write_dng("x.dng", RawImage(np.full((32, 48), 300, np.uint16), "GRBG", 64, 1023, 10, "imx219"))
    >>> found = decode(Path("x.dng"), None, [])
    >>> found.bayer.shape, found.pattern, found.black, found.white, found.said
    ((32, 48), 'GRBG', (64.0, 64.0, 64.0, 64.0), 1023, '')
    """
    import rawpy

    failures = (rawpy.LibRawError, rawpy.NotSupportedError, NotImplementedError, MemoryError, OSError)
    said: list[str] = []
    try:
        with _c_stderr(said), rawpy.RawPy() as rp:
            rp.open_file(os.fspath(path))
            height, width = _check_libraw_sizes(path, rp.sizes, expected_shape)
            rp.unpack()
            desc = rp.color_desc.decode("latin-1")
            cfa = rp.raw_colors_visible[:2, :2].ravel().tolist() if rp.raw_pattern is not None else []
            per_channel = [float(v) for v in rp.black_level_per_channel]
            if rp.num_colors != 3 or len(cfa) != 4 or max(cfa) >= min(len(desc), len(per_channel)):
                raise RawFormatError("not a Bayer raw image (LibRaw finds no 2x2 colour filter pattern)", path)
            white = int(rp.white_level)
            bayer = np.array(rp.raw_image_visible[:height, :width], dtype=np.uint16, copy=True)
    except failures as exc:
        told = f"; LibRaw said: {_libraw_said(said, path)}" if said else ""
        told += f"; malformed: {'; '.join(problems)}" if problems else ""
        raise RawFormatError(f"LibRaw cannot read it as a raw image ({_libraw_error(exc)}{told})", path) from exc
    pattern = "".join(desc[i] for i in cfa)
    if pattern not in PATTERNS:
        raise RawFormatError(f"unsupported colour filter pattern {pattern!r}", path)
    black = (per_channel[cfa[0]], per_channel[cfa[1]], per_channel[cfa[2]], per_channel[cfa[3]])
    if not (all(math.isfinite(b) and b >= 0 for b in black) and max(black) < white <= 0xFFFF):
        raise RawFormatError(f"LibRaw finds black levels {list(black)} and white level {white}: no usable range", path)
    return Decoded(bayer, pattern, black, white, _libraw_said(said, path) if said else "")
