"""Encoders of finished codes: PNG at 8 and 16 bit, deflated in parallel, and JPEG through libjpeg-turbo.

Each takes the codes of a whole image, uint8 (or uint16 for PNG) (H, W, 3), as the correction kernel or
:func:`picamcal.output.encode_srgb` gives them, and writes them with picamcal's metadata: an ICC profile, the JSON
description (PNG ``iTXt picamcal``, JPEG EXIF ``ImageDescription``) and the ``Software`` field
(:data:`picamcal.output.provenance.SOFTWARE`). They do no colour conversion.

PNG (ISO/IEC 15948)
    Every row with the Average filter (type 3, computed with numpy), deflated by :mod:`zlib` at level 1 with the
    run-length strategy, in strips of rows compressed independently on several threads and joined into one zlib
    stream, as pigz does: each strip's raw deflate data ends on a byte boundary (``Z_FULL_FLUSH``, the last
    ``Z_FINISH``), the stream has one zlib header, and its Adler-32 is that of the whole filtered data, combined
    from the strips'. The strips depend on the image's size alone, so the file is the same bytes whatever the
    number of threads. On a corrected 8 MP frame the files are smaller than Pillow's at level 1 (adaptive
    filters, the default strategy: 18 % smaller with the simulator's noise, 9 % without) and imagecodecs' 16-bit
    ones (3 %), and one thread writes them with less than half Pillow's CPU time (benchmarks/bench_outputs.py).
JPEG (ISO/IEC 10918-1, JFIF, EXIF 2.32)
    Baseline, 4:4:4 (no chroma subsampling), through imagecodecs' libjpeg-turbo when it is installed, else
    Pillow's: the same segments, quantisation and Huffman tables, so the same pixels. The EXIF IFD0 holds the
    tags EXIF 2.32 requires of a JPEG (resolution 72 dpi, ``YCbCrPositioning`` centred), which ``exiftool
    -validate`` checks, besides ``ImageDescription`` and ``Software``.

Examples
--------
>>> codes = np.zeros((4, 6, 3), np.uint16)
>>> write_png("black.png", codes, description='{"picamcal": {}}')
>>> import png
>>> png.Reader("black.png").read()[3]["bitdepth"]
16
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import BinaryIO, TypeVar

import numpy as np

from ..kernels import kernel_threads
from .provenance import RECORD_KEY, SOFTWARE

#: zlib's level for PNG: 1, the fastest (with the run-length strategy, zlib's deflate is the same at any level).
PNG_ZLIB_LEVEL = 1

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_AVERAGE = 3  # PNG filter type: each byte less the mean of the byte to its left and the one above
# About this many bytes of filtered rows in a strip: a strip's buffers stay in a core's cache, a strip compresses
# on its own (a new window: the files grow by a few hundredths of a percent), and an 8 MP image has 23 or more
# strips to share among the threads.
_STRIP_BYTES = 1 << 20
_ADLER_BASE = 65521
_JPEG_MAX_SIDE = 65535  # the frame header's 16-bit height and width
_ICC_SEGMENT = 65519  # profile bytes in one APP2 segment: 65535 less the length, "ICC_PROFILE\0" and 2 counters

_T = TypeVar("_T")


def check_codes(codes: np.ndarray, dtypes: Sequence[type] = (np.uint8, np.uint16), what: str = "PNG") -> np.ndarray:
    """``codes`` as an array, refused (ValueError) unless it is an image's codes: (H, W, 3) of one of ``dtypes``.

    Examples
    --------
    >>> check_codes(np.zeros((2, 4, 3), np.uint8)).shape
    (2, 4, 3)
    >>> check_codes(np.zeros((2, 4, 3), np.float32))
    Traceback (most recent call last):
    ...
    ValueError: a PNG is written from uint8 or uint16 codes, not float32 (make them with encode_srgb)
    """
    codes = np.asarray(codes)
    names = " or ".join(np.dtype(d).name for d in dtypes)
    if codes.dtype not in [np.dtype(d) for d in dtypes]:
        raise ValueError(f"a {what} is written from {names} codes, not {codes.dtype} (make them with encode_srgb)")
    if codes.ndim != 3 or codes.shape[2] != 3 or codes.shape[0] < 1 or codes.shape[1] < 1:
        raise ValueError(f"a {what} is written from (H, W, 3) codes with H and W at least 1, not {codes.shape}")
    return codes


def parallel_map(fn: Callable[[int], _T], count: int, threads: int | None = None) -> Iterator[_T]:
    """``fn(i)`` for each ``i`` in ``range(count)``, in order, computed on ``threads`` threads (None: every
    kernel thread).

    The calls run in a pool of threads when there is more than one (numpy's and zlib's work releases the GIL), at
    most twice as many calls under way as threads, so that results wait only briefly for the caller; in this thread
    otherwise. None is :func:`picamcal.kernels.kernel_threads`: every available core, or the share a
    batch gives each of its worker processes.

    Examples
    --------
    >>> list(parallel_map(lambda i: i * i, 5, threads=2))
    [0, 1, 4, 9, 16]
    """
    threads = resolve_threads(threads)
    if threads == 1 or count <= 1:
        yield from (fn(index) for index in range(count))
        return
    pool = ThreadPoolExecutor(min(threads, count), thread_name_prefix="picamcal-encode")
    pending: deque[Future[_T]] = deque()
    try:
        for index in range(count):
            pending.append(pool.submit(fn, index))
            if len(pending) == 2 * threads:  # a few calls ahead of the caller, not the whole image's results
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:  # also when the caller stops early (a failed write): the calls not yet started are dropped
        pool.shutdown(wait=True, cancel_futures=True)


def resolve_threads(threads: int | None) -> int:
    """The number of threads to use: ``threads`` if given (a whole number, at least 1), else every kernel thread.

    Examples
    --------
    >>> resolve_threads(1)
    1
    >>> resolve_threads(None) >= 1
    True
    """
    if threads is None:
        return kernel_threads()
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ValueError(f"threads is a whole number of at least 1, or None for every core, not {threads!r}")
    return int(threads)


# ------------------------------------------------------------------------------------------------------------ PNG
def encode_png(
    codes: np.ndarray,
    *,
    description: str | None = None,
    icc_profile: bytes | None = None,
    software: str | None = SOFTWARE,
    threads: int | None = None,
) -> bytes:
    """A PNG file of uint8 or uint16 RGB codes, as bytes: :func:`write_png`'s file.

    Examples
    --------
    >>> from PIL import Image
    >>> data = encode_png(np.full((3, 5, 3), 200, np.uint8), description='{"picamcal": {}}')
    >>> image = Image.open(io.BytesIO(data))
    >>> image.size, image.mode, image.getpixel((4, 2)), image.info["picamcal"]
    ((5, 3), 'RGB', (200, 200, 200), '{"picamcal": {}}')
    """
    return b"".join(_png_pieces(codes, description, icc_profile, software, threads))


def write_png(
    file: str | os.PathLike[str] | BinaryIO,
    codes: np.ndarray,
    *,
    description: str | None = None,
    icc_profile: bytes | None = None,
    software: str | None = SOFTWARE,
    threads: int | None = None,
) -> None:
    """Write uint8 or uint16 RGB codes (H, W, 3) as a PNG of that bit depth, its strips deflated on several threads.

    The chunks, in this order: ``IHDR``; ``iCCP`` (``icc_profile``, named sRGB) if given; ``iTXt picamcal``
    (``description``, UTF-8) if given; ``tEXt Software`` if ``software``; the ``IDAT`` chunks, one a strip of
    rows; ``IEND``. The file is written as its strips are compressed; the caller makes it atomic
    (:func:`picamcal._atomic.atomic_path`).

    Parameters
    ----------
    file : path-like or binary file
        Where to write.
    codes : ndarray of uint8 or uint16, (H, W, 3)
        The codes, written as they are (16 bit: big-endian, as PNG stores them).
    description : str, optional
        picamcal's JSON record, in the ``iTXt`` chunk ``picamcal``.
    icc_profile : bytes, optional
        The ICC profile (a PNG with an ``iCCP`` chunk has no ``sRGB`` chunk).
    software : str or None
        The ``tEXt Software`` chunk; None writes none.
    threads : int, optional
        Threads that deflate the strips; default :func:`picamcal.kernels.kernel_threads` (every available core,
        or a batch worker's share). 1 compresses in this thread. The file is the same bytes either way.

    Raises
    ------
    ValueError
        ``codes`` are not uint8 or uint16 (H, W, 3), or ``threads`` is not a whole number of at least 1.

    Examples
    --------
    >>> import png
    >>> codes = np.arange(2 * 3 * 3, dtype=np.uint16).reshape(2, 3, 3) * 3000
    >>> write_png("ramp.png", codes, software="picamcal 0.1.0", threads=2)
    >>> width, height, rows, info = png.Reader("ramp.png").read()
    >>> np.array([list(row) for row in rows]).reshape(2, 3, 3)[1, 2].tolist(), info["bitdepth"]
    ([45000, 48000, 51000], 16)
    >>> [kind for kind, _ in png.Reader("ramp.png").chunks()]
    [b'IHDR', b'tEXt', b'IDAT', b'IEND']
    """
    pieces = _png_pieces(codes, description, icc_profile, software, threads)
    if isinstance(file, (str, os.PathLike)):
        with open(file, "wb") as out:
            _write_all(out, pieces)
    else:
        _write_all(file, pieces)


def _write_all(file: BinaryIO, pieces: Iterable[bytes]) -> None:
    for piece in pieces:
        file.write(piece)


def _png_pieces(
    codes: np.ndarray,
    description: str | None,
    icc_profile: bytes | None,
    software: str | None,
    threads: int | None,
) -> Iterator[bytes]:
    """The PNG file in pieces, in order: the head and metadata chunks, each IDAT chunk as its strip is done, IEND.

    The codes and settings are checked here, before the first piece is asked for (and a file opened).
    """
    codes = check_codes(codes)
    threads = resolve_threads(threads)
    height, width = codes.shape[:2]
    if max(height, width) > 2**31 - 1:
        raise ValueError(f"a PNG is at most 2**31 - 1 pixels wide and high, not {width}x{height}")
    return _png_stream(codes, description, icc_profile, software, threads)


def _png_stream(
    codes: np.ndarray, description: str | None, icc_profile: bytes | None, software: str | None, threads: int
) -> Iterator[bytes]:
    height, width = codes.shape[:2]
    bit_depth = 8 * codes.dtype.itemsize
    head = [_PNG_SIGNATURE, _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bit_depth, 2, 0, 0, 0))]
    if icc_profile is not None:
        head.append(_chunk(b"iCCP", b"sRGB\x00\x00" + zlib.compress(icc_profile)))
    if description is not None:
        head.append(_chunk(b"iTXt", RECORD_KEY.encode("latin-1") + b"\x00\x00\x00\x00\x00" + description.encode()))
    if software is not None:
        head.append(_chunk(b"tEXt", b"Software\x00" + software.encode("latin-1")))
    yield b"".join(head)
    bounds = png_strips(codes.shape, codes.dtype.itemsize)
    last = len(bounds) - 1

    def deflate(index: int) -> tuple[bytes, int, int, int]:
        start, stop = bounds[index]
        filtered = _average_filtered(codes, start, stop)
        compressor = zlib.compressobj(PNG_ZLIB_LEVEL, zlib.DEFLATED, -15, 9, zlib.Z_RLE)
        head = b"\x78\x01" if index == 0 else b""  # deflate, 32 kB window, the fastest level; FCHECK: 0x7801 % 31 == 0
        data = b"".join(
            (
                head,
                compressor.compress(filtered.data),
                compressor.flush(zlib.Z_FINISH if index == last else zlib.Z_FULL_FLUSH),
            )
        )
        return data, zlib.crc32(data, zlib.crc32(b"IDAT")), zlib.adler32(filtered.data), filtered.size

    adler = 1  # of nothing
    for index, (data, crc, strip_adler, length) in enumerate(parallel_map(deflate, len(bounds), threads)):
        adler = _adler32_combine(adler, strip_adler, length)
        tail = b""
        if index == last:
            tail = adler.to_bytes(4, "big")
            crc = zlib.crc32(tail, crc)
        yield struct.pack(">I", len(data) + len(tail)) + b"IDAT"
        yield data
        yield tail + struct.pack(">I", crc)
    yield _chunk(b"IEND", b"")


def png_strips(shape: tuple[int, ...], itemsize: int) -> list[tuple[int, int]]:
    """The strips of rows a PNG of ``shape`` (H, W, 3) is deflated in, as (first row, row after the last).

    About a megabyte of filtered rows each, from the shape alone: the same strips on any number of threads.

    Examples
    --------
    >>> strips = png_strips((2464, 3280, 3), 1)
    >>> len(strips), strips[0], strips[-1]
    (24, (0, 106), (2438, 2464))
    """
    height, width = shape[:2]
    rows = max(1, _STRIP_BYTES // (1 + 3 * itemsize * width))
    return [(start, min(start + rows, height)) for start in range(0, height, rows)]


def _average_filtered(codes: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Rows ``start:stop`` as filtered PNG scanlines (rows, 1 + bytes per row): the filter byte, then the Average
    filter's bytes, ``raw[x] - floor((raw[x - bpp] + prior[x]) / 2)`` modulo 256 (ISO/IEC 15948, 9.2)."""
    rows, samples = stop - start, 3 * codes.shape[1]
    bpp = 3 * codes.dtype.itemsize  # bytes per pixel
    # The row above the strip (zeros above the image) and the strip, as PNG stores them: 16 bit is big-endian.
    raw = np.empty((rows + 1, samples), dtype=">u2" if codes.dtype.itemsize == 2 else np.uint8)
    raw[0] = codes[start - 1].reshape(samples) if start else 0
    raw[1:] = codes[start:stop].reshape(rows, samples)
    scan = raw.view(np.uint8)
    row, prior = scan[1:], scan[:-1]
    filtered = np.empty((rows, 1 + scan.shape[1]), np.uint8)
    filtered[:, 0] = _AVERAGE
    out = filtered[:, 1:]
    np.right_shift(prior[:, :bpp], 1, out=out[:, :bpp])  # no byte to the left: it counts as 0
    np.subtract(row[:, :bpp], out[:, :bpp], out=out[:, :bpp])
    left, above, rest = row[:, :-bpp], prior[:, bpp:], out[:, bpp:]
    half = np.bitwise_xor(left, above)  # floor((a + b) / 2) = (a & b) + ((a ^ b) >> 1), without overflow
    np.right_shift(half, 1, out=half)
    np.bitwise_and(left, above, out=rest)
    np.add(rest, half, out=rest)
    np.subtract(row[:, bpp:], rest, out=rest)
    return filtered


def _adler32_combine(adler1: int, adler2: int, length2: int) -> int:
    """The Adler-32 of two pieces of data one after the other, from each one's and the second's length (RFC 1950).

    The sums of the whole are A = A1 + A2 - 1 and B = B1 + length2 * (A1 - 1) + B2, modulo 65521.
    """
    a1, b1, a2, b2 = adler1 & 0xFFFF, adler1 >> 16, adler2 & 0xFFFF, adler2 >> 16
    a = (a1 + a2 - 1) % _ADLER_BASE
    b = (b1 + length2 * (a1 - 1) + b2) % _ADLER_BASE
    return a | b << 16


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)))


# ----------------------------------------------------------------------------------------------------------- JPEG
def encode_jpeg(
    codes: np.ndarray,
    *,
    quality: int,
    description: str | None = None,
    icc_profile: bytes | None = None,
    software: str | None = SOFTWARE,
) -> bytes:
    """A baseline JPEG file of uint8 RGB codes, 4:4:4, as bytes: :func:`write_jpeg`'s file.

    Examples
    --------
    >>> from PIL import Image
    >>> data = encode_jpeg(np.full((16, 16, 3), 128, np.uint8), quality=95, description='{"picamcal": {}}')
    >>> image = Image.open(io.BytesIO(data))
    >>> image.size, image.getpixel((8, 8)), image.getexif()[0x010E]
    ((16, 16), (128, 128, 128), '{"picamcal": {}}')
    """
    codes = check_codes(codes, (np.uint8,), "JPEG")
    if isinstance(quality, bool) or not isinstance(quality, (int, np.integer)) or not 1 <= quality <= 100:
        raise ValueError(f"a JPEG's quality is a whole number from 1 to 100, not {quality!r}")
    height, width = codes.shape[:2]
    if max(height, width) > _JPEG_MAX_SIDE:
        raise ValueError(f"a JPEG is at most {_JPEG_MAX_SIDE} pixels wide and high, not {width}x{height}")
    exif = _jpeg_exif(description, software)
    encode = _libjpeg_turbo()
    if encode is None:
        from PIL import Image

        encoded = io.BytesIO()
        Image.fromarray(codes).save(
            encoded, "JPEG", quality=int(quality), subsampling=0, icc_profile=icc_profile, exif=exif
        )
        return encoded.getvalue()
    # Where Pillow puts them: after the JFIF APP0 segment, the EXIF (APP1), then the ICC profile (APP2).
    data = encode(np.ascontiguousarray(codes), level=int(quality), subsampling="444")
    after = 2 + (2 + int.from_bytes(data[4:6], "big") if data[2:4] == b"\xff\xe0" else 0)
    segments = [_jpeg_segment(0xE1, exif)] if exif else []
    segments += _icc_segments(icc_profile) if icc_profile else []
    return b"".join((data[:after], *segments, data[after:]))


def write_jpeg(
    file: str | os.PathLike[str] | BinaryIO,
    codes: np.ndarray,
    *,
    quality: int,
    description: str | None = None,
    icc_profile: bytes | None = None,
    software: str | None = SOFTWARE,
) -> None:
    """Write uint8 RGB codes (H, W, 3) as a baseline JPEG, 4:4:4, with its EXIF and ICC profile.

    Through imagecodecs' libjpeg-turbo when it is installed (it holds no copy of the image as Pillow does), else
    Pillow's: the same segments and tables either way, so the same pixels. The EXIF IFD0 holds
    ``ImageDescription`` (``description``: ASCII, as :func:`json.dumps` writes), ``Software``, ``XResolution``
    and ``YResolution`` (72), ``ResolutionUnit`` (inches) and ``YCbCrPositioning`` (centred), as ``exiftool
    -validate`` asks; the ICC profile is in APP2 segments.

    Parameters
    ----------
    file : path-like or binary file
        Where to write.
    codes : ndarray of uint8, (H, W, 3)
        The codes.
    quality : int
        libjpeg's quality, 1 to 100 (picamcal writes :data:`picamcal.output.JPEG_QUALITY`).
    description : str, optional
        picamcal's JSON record.
    icc_profile : bytes, optional
        The ICC profile.
    software : str or None
        The ``Software`` tag; None writes none.

    Raises
    ------
    ValueError
        ``codes`` are not uint8 (H, W, 3), are over 65535 pixels wide or high, or ``quality`` is not 1 to 100.

    Examples
    --------
    >>> from PIL import Image
    >>> write_jpeg("grey.jpg", np.full((8, 8, 3), 100, np.uint8), quality=95, software="picamcal 0.1.0")
    >>> Image.open("grey.jpg").getexif()[0x0131]
    'picamcal 0.1.0'
    """
    data = encode_jpeg(codes, quality=quality, description=description, icc_profile=icc_profile, software=software)
    if isinstance(file, (str, os.PathLike)):
        Path(file).write_bytes(data)
    else:
        file.write(data)


def _jpeg_exif(description: str | None, software: str | None) -> bytes:
    """The EXIF APP1 payload ("Exif\\0\\0" and a TIFF IFD0), as Pillow writes it."""
    from PIL import Image

    exif = Image.Exif()
    if description is not None:
        exif[0x010E] = description  # ImageDescription
    if software is not None:
        exif[0x0131] = software  # Software
    # The tags EXIF 2.32 requires in a JPEG's IFD0 (exiftool -validate): 72 dpi, centred chroma samples.
    exif.update({0x011A: 72.0, 0x011B: 72.0, 0x0128: 2, 0x0213: 1})
    return exif.tobytes()


def _jpeg_segment(marker: int, payload: bytes) -> bytes:
    return bytes((0xFF, marker)) + struct.pack(">H", 2 + len(payload)) + payload


def _icc_segments(profile: bytes) -> list[bytes]:
    """The ICC profile in APP2 segments, each ``ICC_PROFILE\\0``, its number from 1 and the count (ICC.1, B.4)."""
    parts = [profile[i : i + _ICC_SEGMENT] for i in range(0, len(profile), _ICC_SEGMENT)]
    return [_jpeg_segment(0xE2, b"ICC_PROFILE\x00" + bytes((k, len(parts))) + part) for k, part in enumerate(parts, 1)]


def _libjpeg_turbo() -> Callable[..., bytes | bytearray] | None:
    """imagecodecs' JPEG encoder when imagecodecs is installed with it, else None (Pillow's is used)."""
    try:
        import imagecodecs
    except ImportError:
        return None
    if not getattr(imagecodecs, "JPEG8", None) or not imagecodecs.JPEG8.available:
        return None
    return imagecodecs.jpeg8_encode


__all__ = [
    "PNG_ZLIB_LEVEL",
    "check_codes",
    "encode_jpeg",
    "encode_png",
    "parallel_map",
    "png_strips",
    "resolve_threads",
    "write_jpeg",
    "write_png",
]
