"""MIPI CSI-2 RAW10, RAW12 and RAW14 bit packing, shared by the legacy BRCM block and picamera2 buffers.

RAW10 packs 4 pixels in 5 bytes: bytes 0-3 hold the 8 most significant bits of pixels 0-3, byte 4
their two least significant bits (pixel 0 in bits 1:0, pixel 1 in 3:2, pixel 2 in 5:4, pixel 3 in 7:6).
RAW12 packs 2 pixels in 3 bytes: bytes 0-1 hold the 8 MSBs, byte 2's low nibble pixel 0's 4 LSBs and
its high nibble pixel 1's (FORMATS.md section 2; picamera 1.13 and the paper's code got the RAW10 order
wrong, by up to 3 DN). RAW14 packs 4 pixels in 7 bytes: the 8 MSBs of each, then their 6 LSBs as one
little-endian 24-bit word (Linux kernel ``V4L2_PIX_FMT_SBGGR14P``, pixfmt-srggb14p: byte 4 holds pixel 0's
bits 5-0 and pixel 1's 1-0, byte 5 pixel 1's bits 5-2 and pixel 2's 3-0, byte 6 pixel 2's bits 5-4 and pixel
3's 5-0). picamcal reads RAW14 (picamera2 buffers) but writes only RAW10 and RAW12.
"""

from __future__ import annotations

import numpy as np

_GROUP = {10: (4, 5), 12: (2, 3), 14: (4, 7)}  # pixels per group, bytes per group
_WRITTEN = (10, 12)


def packed_row_bytes(width: int, bit_depth: int) -> int:
    """Bytes of pixel data in one packed row (before any stride padding).

    Examples
    --------
    >>> packed_row_bytes(3280, 10), packed_row_bytes(4056, 12), packed_row_bytes(4608, 14)
    (4100, 6084, 8064)
    """
    pixels, nbytes = _GROUP[bit_depth]
    return -(-width // pixels) * nbytes


def unpack(rows: np.ndarray, width: int, bit_depth: int) -> np.ndarray:
    """Unpack CSI-2 packed rows to a uint16 (H, W) mosaic at native bit depth.

    Parameters
    ----------
    rows : ndarray of uint8, shape (H, stride)
        Packed rows; bytes beyond the pixel data of a row (stride padding) are ignored.
    width : int
        Pixels per row.
    bit_depth : {10, 12, 14}

    Examples
    --------
    >>> unpack(np.array([[0xFF, 0x00, 0x80, 0x01, 0b11_10_01_00]], np.uint8), 4, 10).tolist()
    [[1020, 1, 514, 7]]
    >>> unpack(np.array([[0xFF, 0x00, 0x80, 0x01, 0b01_000011, 0b0010_0000, 0b111111_00]], np.uint8), 4, 14).tolist()
    [[16323, 1, 8194, 127]]
    """
    if bit_depth not in _GROUP:
        raise ValueError(f"CSI-2 packing is defined for 10, 12 and 14 bits, not {bit_depth}")
    pixels, nbytes = _GROUP[bit_depth]
    need = packed_row_bytes(width, bit_depth)
    if rows.ndim != 2 or rows.shape[1] < need:
        raise ValueError(f"rows of {rows.shape[-1]} bytes are too short for {width} pixels at {bit_depth} bits")
    groups = rows[:, :need].reshape(rows.shape[0], -1, nbytes)
    out = np.empty((rows.shape[0], groups.shape[1], pixels), dtype=np.uint16)
    np.left_shift(groups[..., :pixels], bit_depth - 8, out=out, dtype=np.uint16)
    if bit_depth == 10:
        low = groups[..., pixels]
        for k in range(4):
            out[..., k] |= (low >> (2 * k)) & 0x3
    elif bit_depth == 12:
        low = groups[..., pixels]
        out[..., 0] |= low & 0xF
        out[..., 1] |= low >> 4
    else:
        word = groups[..., 4].astype(np.uint32) | groups[..., 5].astype(np.uint32) << 8
        word |= groups[..., 6].astype(np.uint32) << 16
        for k in range(4):
            out[..., k] |= ((word >> (6 * k)) & 0x3F).astype(np.uint16)
    return out.reshape(rows.shape[0], -1)[:, :width]


def pack(mosaic: np.ndarray, bit_depth: int, stride: int | None = None) -> np.ndarray:
    """Pack a uint16 (H, W) mosaic into CSI-2 rows of ``stride`` bytes (zero padded), the inverse of :func:`unpack`.

    Examples
    --------
    >>> pack(np.array([[1020, 1, 514, 7]], np.uint16), 10).tolist()
    [[255, 0, 128, 1, 228]]
    """
    if bit_depth not in _WRITTEN:
        raise ValueError(f"CSI-2 packing is defined for 10 and 12 bits, not {bit_depth}")
    pixels, nbytes = _GROUP[bit_depth]
    height, width = mosaic.shape
    need = packed_row_bytes(width, bit_depth)
    stride = need if stride is None else stride
    if stride < need:
        raise ValueError(f"stride {stride} is shorter than the {need} bytes of a row")
    padded = np.zeros((height, need // nbytes * pixels), dtype=np.uint16)
    padded[:, :width] = mosaic
    groups = padded.reshape(height, -1, pixels)
    out = np.zeros((height, stride), dtype=np.uint8)
    packed = out[:, :need].reshape(height, -1, nbytes)
    packed[..., :pixels] = groups >> (bit_depth - 8)
    low = np.zeros(groups.shape[:2], dtype=np.uint16)
    if bit_depth == 10:
        for k in range(4):
            low |= (groups[..., k] & 0x3) << (2 * k)
    else:
        low |= (groups[..., 0] & 0xF) | ((groups[..., 1] & 0xF) << 4)
    packed[..., pixels] = low
    return out
