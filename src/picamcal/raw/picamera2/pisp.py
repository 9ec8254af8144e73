"""The Pi 5's lossy raw compression, ``<order>_PISP_COMP1``: decoding, and encoding for the virtual camera
(:mod:`picamcal.virtualcam`; picamcal never writes it to files).

Following the Linux kernel's description ("Raspberry Pi PiSP compressed 8-bit Bayer formats",
``V4L2_PIX_FMT_PISP_COMP1_*``) and rpicam-apps' ``image/dng.cpp`` decoder: each 8-byte block holds 8 pixels as two
little-endian 32-bit words (even pixels, then odd); a word's 2 low bits pick a quantisation mode (0: steps of 16
up to level 320, then 32; 1: 64; 2: 128; 3: an escape coding each pair in 15 bits with steps of 256, then 512),
the inner two samples are coded as a minimum and a difference and the outer two relative to their inner
neighbour. libcamera compresses with an offset of 2048 (mode 1), added back with saturation at 65535.
"""

from __future__ import annotations

import functools
import sys
from typing import Any

import numpy as np

# PiSP compression as libcamera configures it for the raw stream: mode 1 with an offset of 2048 on the 16-bit
# scale (libcamera pipeline/rpi/pisp/pisp.cpp DefaultCompressionOffset/Mode; rpicam-apps image/dng.cpp).
_PISP_OFFSET = 2048
_PISP_MAX_Q = 640  # decoded quantisation levels stay below this in every mode (largest: 511 + 127 = 638)


@functools.lru_cache(maxsize=16)
def _levels(bits: int) -> np.ndarray:
    """Decoded value of every (quantisation mode, level) as ``mode * _PISP_MAX_Q + level``, at ``bits`` bits.

    Dequantisation per the kernel's description (FSD = 65536) and rpicam-apps' ``dequantize``, then the
    compression offset added back with saturation (``postprocess``), then rounding to ``bits`` bits.
    """
    q = np.arange(_PISP_MAX_Q, dtype=np.int64)
    levels = np.stack(
        [
            np.where(q < 320, 16 * q, 32 * (q - 160)),  # mode 0: 321 levels of FSD/4096, then FSD/2048
            64 * q,  # mode 1: FSD/1024
            128 * q,  # mode 2: FSD/512
            np.where(q < 94, 256 * q, 512 * (q - 47)),  # mode 3 escape: 95 levels of FSD/256, then FSD/128
        ]
    )
    values = np.minimum(np.minimum(levels, 0xFFFF) + _PISP_OFFSET, 0xFFFF)
    if bits < 16:
        shift = 16 - bits
        values = np.minimum((values + (1 << (shift - 1))) >> shift, (1 << bits) - 1)
    return values.astype(np.uint16).ravel()


def pisp_decompress(rows: np.ndarray, width: int, bits: int = 16) -> np.ndarray:
    """Decode PiSP compression mode 1 rows (uint8, >= 8 * ceil(width / 8) bytes each) to a uint16 mosaic.

    Each 8-pixel block is two little-endian 32-bit words, the even pixels then the odd ones; the fields of a word,
    from its least significant bit: quantisation mode (2 bits), then for modes 0-2 the inner pair as min(q1, q2)
    (9 bits) and q2 - q1 + 64 (7 bits), then q0 and q3 relative to their inner neighbour (7 bits each); for mode 3
    two 15-bit fields 2816 * (qa >> 4) + 16 * qb + (qa & 15) for (q0, q1) and (q2, q3).

    Examples
    --------
    One block of 8 pixels in mode 1 (steps of 64): the inner samples at level 100, the outer ones at
    ``max(0, 100 - 64) + 0``; libcamera's offset of 2048 added back:

    >>> word = 1 | 100 << 2 | 64 << 11  # mode 1, min(q1, q2) = 100, q2 - q1 + 64 = 64, outer offsets 0
    >>> rows = np.array([[word, word]], dtype="<u4").view(np.uint8)  # the even pixels' word, then the odd ones'
    >>> pisp_decompress(rows, 8).tolist()
    [[4352, 4352, 8448, 8448, 8448, 8448, 4352, 4352]]
    >>> pisp_decompress(rows, 8, bits=10).tolist()
    [[68, 68, 132, 132, 132, 132, 68, 68]]
    """
    height, blocks = rows.shape[0], -(-width // 8)
    words = np.ascontiguousarray(rows[:, : blocks * 8]).view("<u4").reshape(height, blocks, 2)  # (.., phase)
    mode = (words & 3).astype(np.int32)
    field0 = ((words >> 2) & 511).astype(np.int32)
    difference = ((words >> 11) & 127).astype(np.int32) - 64  # q2 - q1
    q = np.empty((4, *words.shape), dtype=np.int32)
    np.subtract(field0, np.minimum(difference, 0), out=q[1])
    np.add(field0, np.maximum(difference, 0), out=q[2])
    # Mode 2 codes an inner pair with both samples in [384, 511] as q1 (9 bits) and q2 - 384 (7 bits).
    high_pair = np.nonzero((mode == 2) & (field0 >= 384))
    q[1][high_pair] = field0[high_pair]
    q[2][high_pair] = difference[high_pair] + 64 + 384
    # The outer samples are offsets from max(0, inner - 64), capped at 384 in mode 2.
    cap = np.where(mode == 2, 384, _PISP_MAX_Q)
    q[0] = np.minimum(np.maximum(q[1] - 64, 0), cap) + ((words >> 18) & 127)
    q[3] = np.minimum(np.maximum(q[2] - 64, 0), cap) + ((words >> 25) & 127)
    escape = np.nonzero(mode == 3)  # the "7.5-bit" escape; rare in real images, so decoded where it occurs
    if escape[0].size:
        for k, shift in ((0, 2), (2, 17)):
            pair = ((words[escape] >> shift) & 32767).astype(np.int32)
            q[k][escape] = (pair & 15) + 16 * ((pair >> 8) // 11)
            q[k + 1][escape] = (pair >> 4) % 176
    q += mode * _PISP_MAX_Q
    levels = _levels(bits)
    out = np.empty((height, blocks, 4, 2), dtype=np.uint16)  # (.., k, phase) holds pixel 8 * block + 2 * k + phase
    for k in range(4):
        out[:, :, k, :] = levels[q[k]]
    return out.reshape(height, blocks * 8)[:, :width]


def pisp_compress(
    mosaic: np.ndarray, stride: int | None = None, *, shift: int = 0, out: np.ndarray | None = None
) -> np.ndarray:
    """Encode a 16-bit mosaic in PiSP compression mode 1, as the Pi 5's front end writes the raw stream; the inverse
    of :func:`pisp_decompress` up to its quantisation.

    libcamera's offset of 2048 is subtracted (saturating at 0); each word (4 samples of one phase of an 8-pixel
    block) takes the finest quantisation mode (0, 1, then 2) that codes its samples without clamping, else mode 2
    with the samples clamped to what it can code. The "escape" mode 3 is not used (the decoder reads it; the
    hardware's choice between the modes is not published). Rows are zero padded to ``stride`` bytes (default: the
    width rounded up to 8).

    Parameters
    ----------
    mosaic : ndarray of uint16, shape (H, W)
    stride : int, optional
    shift : int
        Bits to shift the samples left first (a mosaic at ``16 - shift`` bits).
    out : ndarray of uint8, shape (H, stride), optional
        Where to write the rows (returned); a new array if not given.

    Examples
    --------
    >>> mosaic = np.array([[4352, 4352, 8448, 8448, 8448, 8448, 4352, 4352]], dtype=np.uint16)
    >>> rows = pisp_compress(mosaic)
    >>> rows.shape, pisp_decompress(rows, 8).tolist() == mosaic.tolist()
    ((1, 8), True)
    >>> pisp_compress(mosaic >> 4, shift=4).tolist() == rows.tolist()
    True
    """
    height, width = mosaic.shape
    blocks = -(-width // 8)
    stride = (blocks * 8 if stride is None else stride) if out is None else out.shape[1]
    if stride < blocks * 8:
        raise ValueError(f"stride {stride} is shorter than the {blocks * 8} bytes of a compressed row")
    if out is None:
        out = np.zeros((height, stride), dtype=np.uint8)
    else:
        out[:, blocks * 8 :] = 0
    kernel = _compiled_words()
    if kernel is not None and sys.byteorder == "little" and stride % 4 == 0 and out.flags.c_contiguous:
        kernel(mosaic, shift, blocks, out.view(np.uint32))  # the words written in place, in memory order
        return out
    chunk = max(1, (1 << 16) // blocks)  # rows at a time, so that the temporaries stay in the cache
    for top in range(0, height, chunk):
        rows = mosaic[top : top + chunk]
        words = _pisp_words(rows, width, blocks, shift)
        out[top : top + len(rows), : blocks * 8] = words.reshape(len(rows), blocks * 2).astype("<u4").view(np.uint8)
    return out


def _quantise(x: int, mode: int) -> int:  # pragma: no cover - compiled by numba
    """A sample's level in quantisation mode 0 or 1 (rounded to the nearest)."""
    if mode == 0:
        return (x + 8) >> 4 if x < 5112 else ((x + 16) >> 5) + 160
    return (x + 32) >> 6


def _fitted(q0: int, q1: int, q2: int, q3: int, mode: int) -> tuple[bool, int]:  # pragma: no cover - numba
    """Whether a word's levels in mode 0 or 1 fit its fields without clamping, and the word they make."""
    field0, diff = min(q1, q2), q2 - q1
    base0, base3 = max(q1 - 64, 0), max(q2 - 64, 0)
    fits = (field0 <= 511) & (diff >= -64) & (diff <= 63) & (q0 >= base0) & (q0 <= base0 + 127)
    fits &= (q3 >= base3) & (q3 <= base3 + 127)
    return fits, mode | field0 << 2 | (diff + 64) << 11 | (q0 - base0) << 18 | (q3 - base3) << 25


def _clamped(x0: int, x1: int, x2: int, x3: int) -> int:  # pragma: no cover - compiled by numba
    """The mode-2 word of four samples, clamped to what mode 2 codes as :func:`_pisp_words` clamps them."""
    q0, q1, q2, q3 = (
        min((x0 + 64) >> 7, 511),
        min((x1 + 64) >> 7, 511),
        min((x2 + 64) >> 7, 511),
        min((x3 + 64) >> 7, 511),
    )
    high = (q1 >= 384) & (q2 >= 384)
    q2 = q2 if high else min(max(q2, q1 - 64), q1 + 63)
    low = (not high) & (min(q1, q2) > 383)
    q1 = min(q1, 383 + max(q1 - q2, 0)) if low else q1
    q2 = min(max(q2, q1 - 64), min(q1 + 63, 383 + max(q2 - q1, 0))) if low else q2
    field0 = q1 if high else min(q1, q2)
    diff = q2 - 448 if high else q2 - q1
    base0, base3 = min(max(q1 - 64, 0), 384), min(max(q2 - 64, 0), 384)
    q0, q3 = min(max(q0, base0), base0 + 127), min(max(q3, base3), base3 + 127)
    return 2 | field0 << 2 | (diff + 64) << 11 | (q0 - base0) << 18 | (q3 - base3) << 25


def _word_loop(  # pragma: no cover - compiled by numba
    mosaic: np.ndarray, shift: int, blocks: int, words: np.ndarray
) -> None:
    """:func:`_pisp_words` row by row (for numba): ``words`` the rows as 32-bit words, in memory order.

    Each row's samples are shifted, less the offset (saturating at 0; 0 past the row's end), and sorted into the
    four samples of each word; then every word is made in all three modes and the finest that fits taken, with no
    branch, so that the compiler vectorises the loop (a branch per mode costs twice the time, more on busy frames).
    """
    width = mosaic.shape[1]
    n = 2 * blocks
    samples = np.zeros(8 * blocks, np.int32)
    x0, x1, x2, x3 = np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int32)
    for r in range(mosaic.shape[0]):
        row, out = mosaic[r], words[r]
        for i in range(width):
            samples[i] = max((np.int32(row[i]) << shift) - _PISP_OFFSET, 0)
        for w in range(n):
            i = 8 * (w >> 1) + (w & 1)
            x0[w], x1[w], x2[w], x3[w] = samples[i], samples[i + 2], samples[i + 4], samples[i + 6]
        for w in range(n):
            a, b, c, d = x0[w], x1[w], x2[w], x3[w]
            fits0, word0 = _fitted(_quantise(a, 0), _quantise(b, 0), _quantise(c, 0), _quantise(d, 0), 0)
            fits1, word1 = _fitted(_quantise(a, 1), _quantise(b, 1), _quantise(c, 1), _quantise(d, 1), 1)
            out[w] = word0 if fits0 else (word1 if fits1 else _clamped(a, b, c, d))


@functools.cache
def _compiled_words() -> Any:
    """:func:`_word_loop` compiled by numba (cached on disk), or None where numba is not installed."""
    global _quantise, _fitted, _clamped
    try:
        import numba
    except ImportError:
        return None
    # The helpers become compiled module globals, which the compiled loop calls inlined (numba caches by name).
    _quantise, _fitted, _clamped = (
        numba.njit(cache=True, inline="always", error_model="numpy")(getattr(f, "py_func", f))
        for f in (_quantise, _fitted, _clamped)
    )
    return numba.njit(cache=True, nogil=True, error_model="numpy")(_word_loop)


def _pisp_words(mosaic: np.ndarray, width: int, blocks: int, shift: int = 0) -> np.ndarray:
    """The compressed words of some rows, (rows, blocks, phase), for :func:`pisp_compress`."""
    padded = np.zeros((mosaic.shape[0], blocks * 8), dtype=np.int32)
    padded[:, :width] = mosaic
    padded <<= shift
    np.subtract(padded, _PISP_OFFSET, out=padded)
    np.maximum(padded, 0, out=padded)
    x = padded.reshape(mosaic.shape[0], blocks, 4, 2)  # (.., k, phase): sample k of the word of each phase
    words = np.zeros((mosaic.shape[0], blocks, 2), dtype=np.uint32)
    todo = np.ones(words.shape, dtype=bool)
    largest = int(padded.max(initial=0))
    for mode in (0, 1, 2):
        if mode < 2 and int(padded.min(initial=0)) >= (5112 if mode == 0 else 32704):
            continue  # no sample is small enough for this mode's range
        if mode == 0:  # steps of 16 up to level 320, then 32 (level q >= 320 decodes to 32 * (q - 160))
            q = np.where(x < 5112, (x + 8) >> 4, ((x + 16) >> 5) + 160)
        else:
            shift = 6 if mode == 1 else 7
            q = (x + np.int32(1 << (shift - 1))) >> shift
        q0, q1, q2, q3 = q[:, :, 0], q[:, :, 1], q[:, :, 2], q[:, :, 3]
        last = mode == 2
        if last:  # clamp to what mode 2 codes
            q0, q1, q2, q3 = (np.minimum(v, 511) for v in (q0, q1, q2, q3))
            high = (q1 >= 384) & (q2 >= 384)
            q2 = np.where(high, q2, np.clip(q2, q1 - 64, q1 + 63))
            low = ~high & (np.minimum(q1, q2) > 383)
            q1 = np.where(low, np.minimum(q1, 383 + np.maximum(q1 - q2, 0)), q1)
            q2 = np.where(low, np.clip(q2, q1 - 64, np.minimum(q1 + 63, 383 + np.maximum(q2 - q1, 0))), q2)
            field0 = np.where(high, q1, np.minimum(q1, q2))
            diff = np.where(high, q2 - 448, q2 - q1)
            base0 = np.minimum(np.maximum(q1 - 64, 0), 384)
            base3 = np.minimum(np.maximum(q2 - 64, 0), 384)
            q0, q3 = np.clip(q0, base0, base0 + 127), np.clip(q3, base3, base3 + 127)
            fits = todo
        else:
            field0 = np.minimum(q1, q2)
            diff = q2 - q1
            base0, base3 = np.maximum(q1 - 64, 0), np.maximum(q2 - 64, 0)
            fits = todo & (field0 <= 511) & (diff >= -64) & (diff <= 63)
            fits &= (q0 >= base0) & (q0 <= base0 + 127) & (q3 >= base3) & (q3 <= base3 + 127)
        word = (
            np.uint32(mode)
            | field0.astype(np.uint32) << 2
            | (diff + 64).astype(np.uint32) << 11
            | (q0 - base0).astype(np.uint32) << 18
            | (q3 - base3).astype(np.uint32) << 25
        )
        np.copyto(words, word, where=fits)
        todo &= ~fits
        if not todo.any():
            break
    del largest
    return words
