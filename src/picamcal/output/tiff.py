"""Linear TIFF outputs, for measuring: float32 as the values are, uint16 with the white reference at 32768.

Both are one RGB image, interleaved (``PlanarConfiguration`` 1, contiguous) with ``PhotometricInterpretation`` RGB,
which every TIFF reader opens in colour. Neither carries a colour profile or colour-space tag: the values are the
camera's own linear RGB, not any standard space's (the sRGB formats, :mod:`picamcal.output.srgb`, are
colour-managed). The provenance JSON ``{"picamcal": {...}}`` is the ``ImageDescription`` tag, the picamcal version
the ``Software`` tag.

``float32-tiff``
    The values as they are (white reference 1.0).
``uint16-tiff``
    Linear, ``code = round(value * UINT16_WHITE)`` (:data:`picamcal.correct.UINT16_WHITE`; the codes
    ``picamcal.correct(..., dtype=np.uint16)`` returns): the white reference at 32768, so that values up to
    twice the white keep their headroom (clipped at 0 and 65535). What a code means is in the description:
    ``"scale": 32768`` and ``"encoding"`` (``value = code / 32768``), which photo tools leave alone. ImageMagick,
    GIMP, Photoshop and darktable open it as one 16-bit RGB image; Fiji (*File > Open*, or Bio-Formats) as a
    composite of three 16-bit channels, red, green and blue, with the description under *Image > Show Info*.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from .._atomic import atomic_path
from ..ckernel import c_available, encode_c
from ..correct import UINT16_WHITE
from .colour import check_rgb
from .encoders import parallel_map, resolve_threads
from .provenance import SOFTWARE

#: The TIFF formats (they take ``compression="zstd"``), and their file name suffix.
TIFF_FORMATS = ("float32-tiff", "uint16-tiff")
TIFF_SUFFIX = ".tiff"


_CODE_MAX = 65535
# Rows are converted a block of about this many pixels at a time, in a float temporary that stays in a core's cache
# (768 kB in float32); each thread takes a strip of blocks.
_BLOCK_PIXELS = 1 << 16
# A uint16-tiff is written in strips of about this many bytes (tifffile's own strips for compressed data): each is
# converted, and compressed, on one of the threads while the others are written.
_STRIP_BYTES = 1 << 18


def encode_uint16(rgb: np.ndarray, *, threads: int | None = None) -> np.ndarray:
    """Linear RGB to ``uint16-tiff`` codes, (H, W, 3) as the image: ``round(value * UINT16_WHITE)``, clipped; NaN
    gives 0.

    Rounded half to even, in the image's float type (float64 for other types): ``picamcal.correct(...,
    dtype=np.uint16)``'s codes. Computed a block of rows at a time, on ``threads`` threads (default
    :func:`picamcal.kernels.kernel_threads`: every available core, or a batch worker's share).

    Examples
    --------
    >>> encode_uint16(np.array([[[1.0, 0.5, 2.5]]], np.float32)).ravel()
    array([32768, 16384, 65535], dtype=uint16)
    >>> encode_uint16(np.array([[[np.nan, -np.inf, 0.5 / 32768]]]), threads=1).ravel()  # 0.5 rounds to even
    array([0, 0, 0], dtype=uint16)
    """
    rgb = check_rgb(rgb)
    threads = resolve_threads(threads)
    out = np.empty(rgb.shape, dtype=np.uint16)
    height, width = rgb.shape[:2]
    block = max(1, _BLOCK_PIXELS // max(1, width))
    blocks = -(-height // block)
    # A few strips a thread, so that a thread slowed by other work does not hold the others up.
    rows = max(1, -(-blocks // (4 * threads))) * block
    starts = range(0, height, rows)

    def convert(index: int) -> None:
        _encode_rows(rgb[starts[index] : starts[index] + rows], out[starts[index] : starts[index] + rows])

    for _ in parallel_map(convert, len(starts), threads):
        pass
    return out


def _encode_rows(rgb: np.ndarray, out: np.ndarray) -> None:
    """Rows of linear RGB to their codes in ``out``: float32 rows by the compiled kernel on this thread
    (:func:`picamcal.ckernel.encode_c`, the same codes), else a cache-sized block at a time in numpy."""
    if rgb.dtype == np.float32 and c_available():
        encode_c(rgb, out, code_scale=UINT16_WHITE, threads=1)
        return
    work = rgb.dtype if rgb.dtype in (np.float32, np.float64) else np.dtype(np.float64)
    scale, zero, top = work.type(UINT16_WHITE), work.type(0), work.type(_CODE_MAX)
    block = max(1, _BLOCK_PIXELS // max(1, rgb.shape[1]))
    values = np.empty((min(block, len(rgb)), *rgb.shape[1:]), work)
    for y in range(0, len(rgb), block):
        src, dst = rgb[y : y + block], out[y : y + block]
        tmp = values[: len(src)]
        with np.errstate(over="ignore"):  # the largest floats overflow to infinity, which clips as any other
            np.multiply(src, scale, out=tmp, casting="unsafe")
        np.clip(tmp, zero, top, out=tmp)  # a third of the time of fmax and fmin, but NaN stays NaN:
        np.rint(tmp, out=tmp)
        np.copyto(tmp, zero, where=np.isnan(tmp))  # NaN gives 0
        np.copyto(dst, tmp, casting="unsafe")


def write_tiff(
    path: str | os.PathLike[str],
    rgb: np.ndarray,
    output_format: str = "float32-tiff",
    metadata: Mapping[str, Any] | None = None,
    *,
    overwrite: bool = False,
    compression: str | None = None,
    threads: int | None = None,
) -> Path:
    """Write a corrected image as one of the :data:`TIFF_FORMATS`, atomically (:func:`picamcal.output.write_corrected`).

    ``rgb`` is the corrected (H, W, 3) image; for ``uint16-tiff`` a uint16 one is its codes already made
    (``picamcal.correct(..., dtype=np.uint16)``, :func:`encode_uint16`), written as they are. ``metadata`` is
    written as given (``uint16-tiff`` adds its ``encoding`` and ``scale``); ``compression="zstd"`` compresses
    losslessly with a predictor (needs imagecodecs).

    A ``uint16-tiff`` is written in strips of about 256 kB, each converted from the float image and compressed on
    ``threads`` threads (default :func:`picamcal.kernels.kernel_threads`) while the strips before it are written:
    the same file as tifffile writes of the codes with those strips, from the image or from its codes.

    Examples
    --------
    >>> path = write_tiff("white.tiff", np.ones((4, 6, 3), np.float32), "uint16-tiff", {"source": "white.dng"})
    >>> with tifffile.TiffFile(path) as tif:
    ...     page = tif.pages.first
    ...     page.shape, page.dtype, page.photometric.name, json.loads(page.description)["picamcal"]["scale"]
    ((4, 6, 3), dtype('uint16'), 'RGB', 32768)
    >>> codes = np.full((4, 6, 3), UINT16_WHITE, np.uint16)  # as picamcal.correct(..., dtype=np.uint16) gives
    >>> path = write_tiff("codes.tiff", codes, "uint16-tiff", {"source": "white.dng"})
    >>> bool(np.array_equal(tifffile.imread(path), codes))
    True
    """
    if output_format not in TIFF_FORMATS:
        raise ValueError(f"{output_format!r} is not a TIFF format ({', '.join(TIFF_FORMATS)})")
    rgb = check_rgb(rgb)
    if rgb.dtype == np.uint16 and output_format != "uint16-tiff":
        raise ValueError(f"uint16 codes are written as uint16-tiff, not {output_format}")
    info = dict(metadata or {})
    options: dict[str, Any] = {}
    if output_format == "float32-tiff":
        image: Any = np.ascontiguousarray(rgb, dtype=np.float32)
    else:
        info.update(encoding=f"linear: value = code / {UINT16_WHITE} (the white reference at {UINT16_WHITE})")
        info.update(scale=UINT16_WHITE)
        rows = uint16_rows_per_strip(rgb.shape[1])
        options.update(rowsperstrip=rows)
        if rgb.dtype == np.uint16 and compression is None:  # nothing to do but write them, at once
            image = np.ascontiguousarray(rgb)
        else:
            image = _uint16_strips(rgb, rows, compression, resolve_threads(threads))
            options.update(shape=rgb.shape, dtype=np.uint16)
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        tifffile.imwrite(
            tmp,
            image,
            photometric="rgb",
            planarconfig="contig",
            description=json.dumps({"picamcal": info}),
            software=SOFTWARE,
            metadata=None,
            compression=compression,
            predictor=True if compression else None,
            **options,
        )
    return path


def uint16_rows_per_strip(width: int) -> int:
    """The rows in each strip of a ``uint16-tiff`` ``width`` pixels wide: about 256 kB, tifffile's strips.

    Examples
    --------
    >>> uint16_rows_per_strip(3280), uint16_rows_per_strip(4056)
    (13, 10)
    """
    return max(1, _STRIP_BYTES // (6 * max(1, width)))


def _uint16_strips(rgb: np.ndarray, rows: int, compression: str | None, threads: int) -> Iterator[bytes]:
    """The strips of a ``uint16-tiff`` as its file holds them, in order, each made on one of ``threads`` threads:
    the codes (converted from a float image), then, compressed, tifffile's horizontal predictor and zstd."""
    encode: Callable[[np.ndarray], bytes] = np.ndarray.tobytes
    if compression is not None:
        try:
            from imagecodecs import delta_encode, zstd_encode  # what tifffile compresses with (TIFF.COMPRESSORS)
        except ImportError as error:
            raise ImportError("zstd compression of TIFF files needs the imagecodecs package") from error

        def encode(codes: np.ndarray) -> bytes:
            return bytes(zstd_encode(delta_encode(codes, axis=-2)))  # type: ignore[arg-type]  # any buffer does

    starts = range(0, rgb.shape[0], rows)

    def strip(index: int) -> bytes:
        part = rgb[starts[index] : starts[index] + rows]
        if part.dtype == np.uint16:
            return encode(np.ascontiguousarray(part))
        codes = np.empty(part.shape, np.uint16)
        _encode_rows(part, codes)
        return encode(codes)

    return parallel_map(strip, len(starts), threads)


__all__ = ["TIFF_FORMATS", "TIFF_SUFFIX", "UINT16_WHITE", "encode_uint16", "uint16_rows_per_strip", "write_tiff"]
