"""The Pi 5's lossy raw compression, ``<order>_PISP_COMP1``: decoding only (picamcal never writes it).

Following the Linux kernel's description ("Raspberry Pi PiSP compressed 8-bit Bayer formats",
``V4L2_PIX_FMT_PISP_COMP1_*``) and rpicam-apps' ``image/dng.cpp`` decoder: each 8-byte block holds 8 pixels as two
little-endian 32-bit words (even pixels, then odd); a word's 2 low bits pick a quantisation mode (0: steps of 16
up to level 320, then 32; 1: 64; 2: 128; 3: an escape coding each pair in 15 bits with steps of 256, then 512),
the inner two samples are coded as a minimum and a difference and the outer two relative to their inner
neighbour. libcamera compresses with an offset of 2048 (mode 1), added back with saturation at 65535.
"""

from __future__ import annotations

import functools

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
