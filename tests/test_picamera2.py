"""picamera2 raw buffers: every layout bit-exact, PiSP decoding against the kernel's description, dumps, bad input."""

from __future__ import annotations

import enum
import functools
import io
import json
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from picamcal.errors import OutputError, PicamcalWarning, RawFormatError
from picamcal.raw.model import PATTERNS, RawImage, raw_geometry, require_black_level
from picamcal.raw.packing import pack, packed_row_bytes
from picamcal.raw.picamera2 import capture_raw, from_picamera2, is_npy, read_picamera2_npy, write_picamera2_npy

BLACK_16 = (4096, 4160, 4224, 4288)  # SensorBlackLevels R, Gr, Gb, B on the 16-bit scale: 64, 65, 66, 67 at 10 bits


def _aligned(nbytes: int, align: int) -> int:
    return -(-nbytes // align) * align


def _config(fmt: str, width: int, height: int, stride: int) -> dict:
    return {"format": fmt, "size": (width, height), "stride": stride, "framesize": stride * height}


def _unpacked_buffer(mosaic: np.ndarray, bits: int, stride: int) -> np.ndarray:
    """Rows as the Pi writes them: one byte per pixel at 8 bits, else little-endian uint16, zero padded."""
    data = mosaic.astype(np.uint8) if bits == 8 else mosaic.astype("<u2").view(np.uint8)
    out = np.zeros((mosaic.shape[0], stride), np.uint8)
    out[:, : data.shape[1]] = data
    return out


def _pack_raw14(mosaic: np.ndarray, stride: int) -> np.ndarray:
    """RAW14 byte by byte from the kernel's V4L2_PIX_FMT_SBGGR14P table (independent of the reader's word maths)."""
    height, width = mosaic.shape
    p = mosaic.reshape(height, -1, 4).astype(np.uint16)
    out = np.zeros((height, stride), np.uint8)
    groups = out[:, : width // 4 * 7].reshape(height, -1, 7)
    groups[..., :4] = p >> 6
    groups[..., 4] = (p[..., 0] & 0x3F) | (p[..., 1] & 0x3) << 6
    groups[..., 5] = (p[..., 1] >> 2) & 0xF | (p[..., 2] & 0xF) << 4
    groups[..., 6] = (p[..., 2] >> 4) & 0x3 | (p[..., 3] & 0x3F) << 2
    return out


def _mosaic(bits: int, height: int = 6, width: int = 40, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 2**bits, size=(height, width), dtype=np.uint16)


def _quiet(*args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PicamcalWarning)
        return from_picamera2(*args, **kwargs)


# --- unpacked and CSI-2 packed layouts -------------------------------------------------------------------------


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("bits", [8, 10, 12, 14, 16])
@pytest.mark.parametrize("align", [32, 64])
def test_unpacked_round_trip_is_bit_exact(pattern, bits, align):
    mosaic = _mosaic(bits)
    stride = _aligned(mosaic.shape[1] * (1 if bits == 8 else 2), align)
    buffer = _unpacked_buffer(mosaic, bits, stride)
    buffer[:, mosaic.shape[1] * (1 if bits == 8 else 2) :] = 0xAB  # padding must be ignored
    config = _config(f"S{pattern}{bits}", 40, 6, stride)
    raw = from_picamera2(buffer, config, {"SensorBlackLevels": BLACK_16})
    np.testing.assert_array_equal(raw.bayer, mosaic)
    assert (raw.pattern, raw.bit_depth, raw.white_level) == (pattern, bits, 2**bits - 1)
    assert raw.metadata["format"] == "picamera2" and raw.metadata["raw_format"] == f"S{pattern}{bits}"
    if bits > 8:  # picamera2 users often pass .view(np.uint16) of the same buffer
        view = from_picamera2(buffer.view(np.uint16), config, {"SensorBlackLevels": BLACK_16})
        np.testing.assert_array_equal(view.bayer, mosaic)


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("bits", [10, 12, 14])
@pytest.mark.parametrize("align", [32, 64])
def test_csi2_packed_round_trip_is_bit_exact(pattern, bits, align):
    mosaic = _mosaic(bits, width=3280 // 40 * 4)  # 328 pixels: rows of 410 (RAW10), 492 (RAW12), 574 (RAW14) bytes
    width = mosaic.shape[1]
    row_bytes = width * bits // 8
    stride = _aligned(row_bytes, align)
    buffer = _pack_raw14(mosaic, stride) if bits == 14 else pack(mosaic, bits, stride)
    buffer[:, row_bytes:] = 0xFF
    raw = from_picamera2(buffer, _config(f"S{pattern}{bits}_CSI2P", width, 6, stride), {"SensorBlackLevels": BLACK_16})
    np.testing.assert_array_equal(raw.bayer, mosaic)
    assert (raw.pattern, raw.bit_depth, raw.white_level, raw.metadata["stride"]) == (pattern, bits, 2**bits - 1, stride)


def test_csi2_bit_order_of_hand_packed_pixels():
    # Pixels 0x3FF, 0x001, 0x2AA, 0x155: MSB bytes FF 00 AA 55; LSB pairs 3, 1, 2, 1 from bit 0 up = 0b01_10_01_11.
    # picamera 1.13's reversed pair order would read 0x3FD, 0x002, 0x2A9, 0x157 instead.
    raw10 = np.zeros((2, 32), np.uint8)
    raw10[:, :5] = [0xFF, 0x00, 0xAA, 0x55, 0b01_10_01_11]
    image = from_picamera2(raw10, _config("SRGGB10_CSI2P", 4, 2, 32), {"SensorBlackLevels": BLACK_16})
    assert image.bayer.tolist() == [[0x3FF, 0x001, 0x2AA, 0x155]] * 2
    # RAW12 0xFFF, 0x001, 0xABC, 0x123: FF 00 then nibbles 1|F; AB 12 then 3|C.
    raw12 = np.zeros((2, 64), np.uint8)
    raw12[:, :6] = [0xFF, 0x00, 0x1F, 0xAB, 0x12, 0x3C]
    image = from_picamera2(raw12, _config("SRGGB12_CSI2P", 4, 2, 64), {"SensorBlackLevels": BLACK_16})
    assert image.bayer.tolist() == [[0xFFF, 0x001, 0xABC, 0x123]] * 2
    # RAW14 0x3FFF, 0x0001, 0x2AAA, 0x1555: MSBs FF 00 AA 55; 6-bit LSBs 0x3F, 0x01, 0x2A, 0x15 give
    # byte 4 = 01 111111 (p1 bits 1-0, p0), byte 5 = 1010 0000 (p2 bits 3-0, p1 bits 5-2), byte 6 = 010101 10.
    raw14 = np.zeros((2, 32), np.uint8)
    raw14[:, :7] = [0xFF, 0x00, 0xAA, 0x55, 0x7F, 0xA0, 0x56]
    image = from_picamera2(raw14, _config("SRGGB14_CSI2P", 4, 2, 32), {"SensorBlackLevels": BLACK_16})
    assert image.bayer.tolist() == [[0x3FFF, 0x0001, 0x2AAA, 0x1555]] * 2


def test_flat_buffer_and_whole_camera_configuration_are_accepted():
    mosaic = _mosaic(10, width=64)
    stride = _aligned(packed_row_bytes(64, 10), 32)
    buffer = pack(mosaic, 10, stride)
    whole = {
        "use_case": "still",
        "main": {"format": "BGR888", "size": (640, 480), "stride": 1920},
        "raw": {"format": "SGRBG10_CSI2P", "size": [64, 6], "stride": stride, "framesize": stride * 6},
        "sensor": {"bit_depth": 10, "output_size": (64, 6)},
        "model": "imx219",
    }
    raw = from_picamera2(buffer.ravel(), whole, {"SensorBlackLevels": BLACK_16})
    np.testing.assert_array_equal(raw.bayer, mosaic)
    assert (raw.pattern, raw.sensor, raw.metadata["model"], raw.metadata["sensor_bit_depth"]) == (
        "GRBG",
        "imx219",
        "imx219",
        10,
    )
    buffer[0, 0] ^= 0xFF  # the result is a copy: the caller's buffer can be reused by the camera
    np.testing.assert_array_equal(raw.bayer, mosaic)


def test_pi5_sixteen_bit_is_shifted_back_to_the_sensor_bit_depth():
    mosaic = _mosaic(10, width=64)
    buffer = _unpacked_buffer(mosaic << 6, 16, 128)  # the Pi 5 front end writes left-justified 16-bit samples
    config = {"raw": _config("SBGGR16", 64, 6, 128), "sensor": {"bit_depth": 10}}
    raw = from_picamera2(buffer, config, {"SensorBlackLevels": (4096,) * 4})
    np.testing.assert_array_equal(raw.bayer, mosaic)
    assert (raw.bit_depth, raw.white_level, raw.black_level) == (10, 1023, (64.0,) * 4)
    # Without the sensor's bit depth the samples stay on the 16-bit scale (black levels too).
    raw16 = from_picamera2(buffer, config["raw"], {"SensorBlackLevels": (4096,) * 4})
    np.testing.assert_array_equal(raw16.bayer, mosaic << 6)
    assert (raw16.bit_depth, raw16.white_level, raw16.black_level) == (16, 65535, (4096.0,) * 4)
    # Samples that are not left-justified 10-bit data are kept as they are, with a warning.
    odd = buffer.copy()
    odd[0, 0] |= 1
    with pytest.warns(PicamcalWarning, match="not multiples of 64"):
        kept = from_picamera2(odd, config, {"SensorBlackLevels": (4096,) * 4})
    assert (kept.bit_depth, int(kept.bayer[0, 0])) == (16, int(mosaic[0, 0] << 6) | 1)


# --- black levels, sensor and exposure metadata ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("pattern", "sites"),
    [  # black level per 2x2 site (row-major) of R=64, Gr=65, Gb=66, B=67; Gr is the green on the red row
        ("RGGB", (64, 65, 66, 67)),
        ("GRBG", (65, 64, 67, 66)),
        ("GBRG", (66, 67, 64, 65)),
        ("BGGR", (67, 66, 65, 64)),
    ],
)
@pytest.mark.parametrize("bits", [10, 12, 16])
def test_sensor_black_levels_map_to_sites_and_scale_from_16_bits(pattern, sites, bits):
    mosaic = _mosaic(bits, width=8)
    raw = from_picamera2(
        _unpacked_buffer(mosaic, bits, 32), _config(f"S{pattern}{bits}", 8, 6, 32), {"SensorBlackLevels": BLACK_16}
    )
    # 4096 on the 16-bit scale is 64 at 10 bits, 256 at 12: exact powers of two, so compared exactly.
    assert raw.black_level == tuple(s * 2.0 ** (bits - 10) for s in sites)
    assert raw.metadata["black_level_source"] == "SensorBlackLevels"


def test_black_level_falls_back_to_the_registry_then_unknown_never_zero():
    buffer = _unpacked_buffer(_mosaic(12, width=8), 12, 32)
    config = _config("SRGGB12", 8, 6, 32)
    raw = from_picamera2(buffer, {**config, "model": "imx477"})  # the HQ camera: 256 DN at 12 bits
    assert (raw.sensor, raw.black_level, raw.metadata["black_level_source"]) == ("imx477", (256.0,) * 4, "registry")
    raw = from_picamera2(_unpacked_buffer(_mosaic(10, width=8), 10, 32), _config("SRGGB10", 8, 6, 32), sensor="IMX477")
    assert raw.black_level == (64.0,) * 4  # 256 at 12 bits scales to 64 at 10
    with warnings.catch_warnings():
        warnings.simplefilter("error", PicamcalWarning)  # nothing to warn about: unknown is said where it matters
        raw = from_picamera2(buffer, config)
    assert raw.sensor is None and raw.metadata["black_level_source"] == "none"
    assert all(np.isnan(raw.black_level))
    with pytest.raises(RawFormatError, match=r"no black level.*give --black-level N or --sensor NAME$"):
        require_black_level(raw)


def test_new_registry_sensors_give_their_black_level():
    # imx296.json 3840 on the 16-bit scale is 60 at 10 bits; imx283.json 3200 is 200 at 12 bits.
    raw = from_picamera2(
        _unpacked_buffer(_mosaic(10, width=8), 10, 32), {**_config("SBGGR10", 8, 6, 32), "model": "imx296"}
    )
    assert (raw.sensor, raw.black_level) == ("imx296", (60.0,) * 4)
    raw = from_picamera2(_unpacked_buffer(_mosaic(12, width=8), 12, 32), _config("SRGGB12", 8, 6, 32), sensor="imx283")
    assert (raw.sensor, raw.black_level) == ("imx283", (200.0,) * 4)


def test_a_monochrome_sensor_or_format_is_refused():
    buffer = _unpacked_buffer(_mosaic(10, width=8), 10, 32)
    with pytest.raises(RawFormatError, match="OV9281 is a monochrome sensor"):
        from_picamera2(buffer, {**_config("SBGGR10", 8, 6, 32), "model": "ov9281"})
    with pytest.raises(RawFormatError, match="R10 is a monochrome"):
        from_picamera2(buffer, _config("R10", 8, 6, 32))


def test_to_picamera2_keeps_an_unknown_black_level_unknown():
    from picamcal.raw import to_picamera2

    raw = RawImage(_mosaic(10, height=6, width=8), "RGGB", float("nan"), 1023, 10)
    array, config, metadata = to_picamera2(raw)
    assert "SensorBlackLevels" not in metadata
    assert all(np.isnan(from_picamera2(array, config, metadata).black_level))


def test_sensor_name_comes_from_the_argument_or_the_model():
    buffer, config = _unpacked_buffer(_mosaic(10, width=8), 10, 32), _config("SRGGB10", 8, 6, 32)
    meta = {"SensorBlackLevels": BLACK_16}
    assert from_picamera2(buffer, {**config, "model": "imx708_wide"}, meta).sensor == "imx708"
    assert from_picamera2(buffer, {**config, "model": "imx708_wide"}, meta, sensor="imx219").sensor == "imx219"
    with pytest.warns(PicamcalWarning, match="not in picamcal's registry"):
        raw = from_picamera2(buffer, config, meta, sensor="imx298")
    assert (raw.sensor, raw.metadata["model"]) == (None, "imx298")


def test_exposure_metadata_is_kept_in_picamcal_units():
    buffer, config = _unpacked_buffer(_mosaic(10, width=8), 10, 32), _config("SBGGR10", 8, 6, 32)
    metadata = {
        "SensorBlackLevels": BLACK_16,
        "ExposureTime": 20000,
        "AnalogueGain": 2.5,
        "DigitalGain": np.float32(1.0),
        "ColourGains": (1.8, 1.5),
        "ColourCorrectionMatrix": tuple(float(i == j) for i in range(3) for j in range(3)),
        "ColourTemperature": 5000,
        "Lux": 400.0,
        "SensorTimestamp": 123456789012,
        "FocusFoM": 1234,  # other controls are ignored
    }
    meta = from_picamera2(buffer, config, metadata).metadata
    assert meta["exposure_time_s"] == pytest.approx(0.02, rel=1e-12)
    assert (meta["analogue_gain"], meta["digital_gain"], meta["colour_gains"]) == (2.5, 1.0, [1.8, 1.5])
    assert (meta["colour_temperature"], meta["lux"], meta["sensor_timestamp_ns"]) == (5000, 400.0, 123456789012)
    assert meta["colour_correction_matrix"][:4] == [1.0, 0.0, 0.0, 0.0]
    assert "FocusFoM" not in meta and "focus_fom" not in meta


# --- PiSP compression (Pi 5) ------------------------------------------------------------------------------------
# Written from the Linux kernel's description (Documentation/userspace-api/media/v4l/pixfmt-srggb8-pisp-comp.rst),
# not from the reader: quantisation levels, field layout and the encoder. libcamera compresses after subtracting an
# offset of 2048 (pisp.cpp DefaultCompressionOffset), which the decoder adds back.

FSD, OFFSET = 65536, 2048
HALF_STEP = {0: 16, 1: 32, 2: 64, 3: 256}  # largest rounding error of each quantisation mode (half its coarsest step)


def _spec_level(mode: int, q: int) -> int:
    """Reconstruction level q of a quantisation mode, before the offset; the progressions extend past valid codes."""
    if mode == 0:  # the lowest 321 levels are multiples of FSD/4096, the rest successive multiples of FSD/2048
        return q * FSD // 4096 if q <= 320 else 320 * FSD // 4096 + (q - 320) * FSD // 2048
    if mode in (1, 2):  # linear with steps FSD/1024 and FSD/512
        return q * FSD // (1024 if mode == 1 else 512)
    # mode 3: 176 levels, the lowest 95 multiples of FSD/256, the rest multiples of FSD/128 (175 is FSD: saturate)
    return q * FSD // 256 if q <= 94 else 94 * FSD // 256 + (q - 94) * FSD // 128


def _spec_decode_word(word: int) -> list[int]:
    """Four samples (16-bit scale, offset added back, saturating) of one 32-bit word, by the description."""
    mode = word & 3
    if mode == 3:  # two 15-bit fields 2816 * (qa >> 4) + 16 * qb + (qa & 15) for (q0, q1) and (q2, q3)
        q = []
        for pair in ((word >> 2) & 0x7FFF, (word >> 17) & 0x7FFF):
            q += [(pair >> 4) // 176 * 16 + (pair & 15), (pair >> 4) % 176]
    else:  # fields of 2, 9, 7, 7, 7 bits from the least significant end
        f0, f1, f2, f3 = (word >> 2) & 511, (word >> 11) & 127, (word >> 18) & 127, (word >> 25) & 127
        if mode == 2 and f0 >= 384:  # 9 bits of q1 then 7 bits of q2 & 127, both in [384, 511]
            q1, q2 = f0, 384 + f1
        elif f1 >= 64:  # f0 = min(q1, q2), f1 = q2 - q1 + 64
            q1, q2 = f0, f0 + f1 - 64
        else:
            q1, q2 = f0 + 64 - f1, f0

        def outer(field: int, inner: int) -> int:
            return field + (384 if mode == 2 and inner >= 448 else max(0, inner - 64))

        q = [outer(f2, q1), q1, q2, outer(f3, q2)]
    return [min(FSD - 1, min(FSD - 1, _spec_level(mode, k)) + OFFSET) for k in q]


@functools.lru_cache
def _spec_levels(mode: int) -> np.ndarray:
    """All levels a mode can code: 512 (9-bit fields) in modes 0-2, 176 in mode 3."""
    return np.array([_spec_level(mode, k) for k in range(176 if mode == 3 else 512)])


def _spec_encode_group(samples) -> tuple[int, int]:
    """Encode 4 samples of one phase: the finest quantisation mode whose fields fit, else the mode 3 escape."""
    values = [max(0, int(s) - OFFSET) for s in samples]
    for mode in (0, 1, 2):
        levels = _spec_levels(mode)
        if max(values) > levels[-1]:
            continue
        q0, q1, q2, q3 = (int(np.argmin(np.abs(levels - v))) for v in values)  # nearest level
        if mode == 2 and min(q1, q2) >= 384:
            inner = (q1, q2 & 127)
        else:
            inner = (min(q1, q2), q2 - q1 + 64)
        outer = [qo - (384 if mode == 2 and qi >= 448 else max(0, qi - 64)) for qo, qi in ((q0, q1), (q3, q2))]
        if 0 <= inner[1] <= 127 and all(0 <= f <= 127 for f in outer):
            return mode | inner[0] << 2 | inner[1] << 11 | outer[0] << 18 | outer[1] << 25, mode
    q = [int(np.argmin(np.abs(_spec_levels(3) - v))) for v in values]
    fields = [2816 * (a >> 4) + 16 * b + (a & 15) for a, b in ((q[0], q[1]), (q[2], q[3]))]
    return 3 | fields[0] << 2 | fields[1] << 17, 3


def _spec_compress(mosaic: np.ndarray, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """A PISP_COMP1 buffer of a 16-bit-scale mosaic, and the quantisation mode used for each pixel."""
    height, width = mosaic.shape
    blocks = -(-width // 8)
    padded = np.pad(mosaic.astype(np.int64), ((0, 0), (0, blocks * 8 - width)), mode="edge")  # padding: unspecified
    words = np.zeros((height, blocks * 2), np.uint32)
    modes = np.zeros((height, blocks * 8), np.int64)
    for y in range(height):
        for b in range(blocks):
            for phase in (0, 1):  # even pixels, then odd, in successive words
                word, mode = _spec_encode_group(padded[y, 8 * b + phase : 8 * b + 8 : 2])
                words[y, 2 * b + phase] = word
                modes[y, 8 * b + phase : 8 * b + 8 : 2] = mode
    out = np.zeros((height, stride), np.uint8)
    out[:, : blocks * 8] = words.astype("<u4").view(np.uint8)
    return out, modes[:, :width]


def _words_buffer(words: np.ndarray, stride: int = 64) -> np.ndarray:
    out = np.zeros((words.shape[0], stride), np.uint8)
    out[:, : words.shape[1] * 4] = np.asarray(words, dtype="<u4").view(np.uint8)
    return out


def test_pisp_hand_worked_blocks():
    # Mode 0, q = (46, 100, 105, 44): inner min 100, 105 - 100 + 64 = 69; outer 46 - (100 - 64) = 10, 44 - 41 = 3.
    even = 0 | 100 << 2 | 69 << 11 | 10 << 18 | 3 << 25  # values 16 q + 2048 = 2784, 3648, 3728, 2752
    # Mode 1, q = (300, 300, 250, 186): inner min 250, 250 - 300 + 64 = 14; outer 300 - 236 = 64, 186 - 186 = 0.
    odd = 1 | 250 << 2 | 14 << 11 | 64 << 18 | 0 << 25  # 64 q + 2048 = 21248, 21248, 18048, 13952
    # Mode 0 above level 320, q = (350, 400, 390, 400): 32 (q - 160) + 2048 = 8128, 9728, 9408, 9728.
    mode0_high = 0 | 390 << 2 | 54 << 11 | (350 - 336) << 18 | (400 - 326) << 25
    # Mode 2 with both inner samples in [384, 511]: q1 = 450, q2 = 470 as 450 and 470 & 127 = 86; the outer samples
    # of inner samples >= 448 are coded as q - 384: q0 = 400 -> 16, q3 = 460 -> 76. 128 q + 2048, saturating.
    mode2_high = 2 | 450 << 2 | 86 << 11 | 16 << 18 | 76 << 25  # 53248, 59648, 62208, 60928
    # Mode 3 escape, q = (100, 175, 3, 94): 2816 * 6 + 16 * 175 + 4 = 19700 and 2816 * 0 + 16 * 94 + 3 = 1507.
    # 256 q below level 95, else 512 (q - 47), then + 2048 saturating: 29184, 65535, 2816, 26112.
    escape = 3 | 19700 << 2 | 1507 << 17
    words = np.array([[even, odd, mode0_high, mode2_high, escape, even]] * 2, dtype=np.uint32)
    with pytest.warns(PicamcalWarning, match="lossy"):
        raw = from_picamera2(
            _words_buffer(words), _config("RGGB_PISP_COMP1", 24, 2, 64), {"SensorBlackLevels": BLACK_16}
        )
    assert raw.bayer[0, :8].tolist() == [2784, 21248, 3648, 21248, 3728, 18048, 2752, 13952]
    assert raw.bayer[0, 8:16:2].tolist() == [8128, 9728, 9408, 9728]
    assert raw.bayer[0, 9:16:2].tolist() == [53248, 59648, 62208, 60928]
    assert raw.bayer[0, 16:24:2].tolist() == [29184, 65535, 2816, 26112]
    assert (raw.bit_depth, raw.white_level, raw.black_level) == (16, 65535, (4096.0, 4160.0, 4224.0, 4288.0))
    assert raw.metadata["lossy_compression"] == "PISP_COMP1"


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(np.uint32, st.tuples(st.sampled_from([2, 4]), st.integers(1, 6).map(lambda b: 2 * b))))
def test_pisp_decoder_matches_the_description_for_any_word(words):
    height, nwords = words.shape
    raw = _quiet(
        _words_buffer(words, stride=_aligned(nwords * 4, 64)),
        _config("BGGR_PISP_COMP1", nwords * 4, height, _aligned(nwords * 4, 64)),
    )
    expected = np.zeros((height, nwords * 4), np.int64)
    for y in range(height):
        for i, word in enumerate(words[y].tolist()):
            block, phase = divmod(i, 2)
            expected[y, 8 * block + phase : 8 * block + 8 : 2] = _spec_decode_word(word)
    np.testing.assert_array_equal(raw.bayer, expected)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_pisp_round_trip_stays_within_the_schemes_error_bound(pattern):
    rng = np.random.default_rng(3)
    height, width = 8, 44  # not a multiple of 8: the last block is padded
    y, x = np.mgrid[0:height, 0:width]
    smooth = 2500 + 60 * x + 300 * y + rng.integers(-20, 20, (height, width))  # a dark gradient with noise
    noisy = rng.integers(OFFSET, FSD, (height, width))  # anything, up to full scale
    for mosaic in (smooth, noisy):
        buffer, modes = _spec_compress(mosaic, 64)
        config = {"raw": _config(f"{pattern}_PISP_COMP1", width, height, 64), "sensor": {"bit_depth": 10}}
        decoded = _quiet(buffer, config["raw"]).bayer.astype(np.int64)
        error = np.abs(decoded - mosaic)
        bound = np.vectorize(HALF_STEP.get)(modes)
        assert (error <= bound).all(), error.max()  # rounding to the nearest level of the mode used
        native = _quiet(buffer, config).bayer.astype(np.int64)  # 10 bits: (v + 32) >> 6, so at most 0.5 DN more
        assert (np.abs(native - mosaic / 64) <= bound / 64 + 0.5).all()
        assert native.max() <= 1023
    assert (modes == 3).any()  # the noisy frame exercised the escape
    _, smooth_modes = _spec_compress(smooth, 64)
    assert (smooth_modes == 0).all()  # a smooth dark frame is in the finest mode: error <= 16, a quarter DN at 10 bits


# --- .npy dumps ------------------------------------------------------------------------------------------------


class _NoiseReduction(enum.Enum):
    Fast = 1


def _pi4_capture() -> tuple[np.ndarray, dict, dict, np.ndarray]:
    mosaic = _mosaic(10, height=8, width=64)
    stride = _aligned(packed_row_bytes(64, 10), 32)
    config = {
        "raw": {"format": "SBGGR10_CSI2P", "size": (64, 8), "stride": stride, "framesize": stride * 8},
        "sensor": {"bit_depth": 10, "output_size": (64, 8)},
        "controls": {"NoiseReductionMode": _NoiseReduction.Fast, "FrameDurationLimits": (33333, 33333)},
        "transform": object(),
        "model": "imx219",
    }
    metadata = {"SensorBlackLevels": BLACK_16, "ExposureTime": np.int64(10000), "ColourGains": (1.5, 2.0)}
    return pack(mosaic, 10, stride), config, metadata, mosaic


def test_npy_dump_round_trip(tmp_path):
    buffer, config, metadata, mosaic = _pi4_capture()
    path = write_picamera2_npy(tmp_path / "white.npy", buffer, config, metadata)
    assert path == tmp_path / "white.npy" and is_npy(path.read_bytes()[:8])
    record = json.loads((tmp_path / "white.json").read_text())
    assert (record["format"], record["version"], record["sensor"]) == ("picamcal-picamera2", 1, "imx219")
    assert record["config"]["raw"]["size"] == [64, 8]
    assert record["config"]["controls"]["NoiseReductionMode"] == "_NoiseReduction.Fast"
    assert record["metadata"]["ExposureTime"] == 10000
    raw = read_picamera2_npy(path)
    np.testing.assert_array_equal(raw.bayer, mosaic)
    assert (raw.pattern, raw.sensor, raw.black_level) == ("BGGR", "imx219", (67.0, 66.0, 65.0, 64.0))
    assert raw.metadata["format"] == "picamera2-npy" and raw.metadata["path"] == str(path)
    assert raw.metadata["exposure_time_s"] == pytest.approx(0.01, rel=1e-12)
    # a uint16 view is saved as given and read the same; a name without .npy gets it, like np.save
    second = write_picamera2_npy(
        tmp_path / "again", _unpacked_buffer(mosaic, 10, 128).view(np.uint16), _config("SBGGR10", 64, 8, 128), metadata
    )
    assert second.name == "again.npy" and (tmp_path / "again.json").exists()
    np.testing.assert_array_equal(read_picamera2_npy(second).bayer, mosaic)
    assert not is_npy(b"II*\x00\x08\x00")


def test_npy_dump_refuses_to_overwrite_or_to_write_an_unreadable_dump(tmp_path):
    buffer, config, metadata, _ = _pi4_capture()
    path = write_picamera2_npy(tmp_path / "a.npy", buffer, config, metadata)
    with pytest.raises(OutputError, match="exists already"):
        write_picamera2_npy(path, buffer, config, metadata, overwrite=False)
    with pytest.raises(RawFormatError, match="stride of 16 bytes is too short"):
        write_picamera2_npy(tmp_path / "b.npy", buffer, {"format": "SBGGR10_CSI2P", "size": (64, 8), "stride": 16})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "a.npy"]


# --- bad input: one RawFormatError, one line, naming the file ---------------------------------------------------


def _one_line(excinfo, where: str) -> str:
    message = str(excinfo.value)
    assert "\n" not in message and message.startswith(f"{where}: ")
    return message


@pytest.mark.parametrize(
    ("config", "message"),
    [
        (_config("SBGGR10_CSI2P", 64, 8, 64), "stride of 64 bytes is too short for 64 pixels at 10 bits"),
        (_config("SBGGR12", 64, 8, 127), "stride of 127 bytes is too short for 64 pixels at 12 bits"),
        (_config("SBGGR10_CSI2P", 64, 16, 96), "smaller than 16 rows x 80 bytes"),
        (_config("SBGGR10_CSI2P", 64, 8, 128), "does not match 8 rows of stride 128"),
        ({**_config("SBGGR10_CSI2P", 64, 8, 96), "framesize": 700}, "framesize of 700 bytes"),
        (_config("YUV420", 64, 8, 96), "unknown raw format 'YUV420'"),
        (_config("SBGGR8_CSI2P", 64, 8, 96), "unknown raw format 'SBGGR8_CSI2P'"),
        (_config("MONO_PISP_COMP1", 64, 8, 96), "MONO_PISP_COMP1 is a monochrome (greyscale) format"),
        (_config("SBGGR10P", 64, 8, 96), "did you mean SBGGR10_CSI2P?"),
        (_config("SBGGR10_CSI2P", 63, 8, 96), "even width and height"),
        ({"format": "SBGGR10_CSI2P", "size": "64x8"}, "'size' must be (width, height)"),
        ({"raw": None}, "'raw' stream is missing"),
        ({"raw": {"format": "SBGGR10", "size": (64, 8)}, "sensor": {"bit_depth": 24}}, "bit_depth of 24"),
    ],
)
def test_bad_configuration_gives_one_clear_error(config, message):
    buffer = np.zeros((8, 96), np.uint8)
    with pytest.raises(RawFormatError) as excinfo:
        from_picamera2(buffer, config, source="frame7")
    assert message in _one_line(excinfo, "frame7")


@pytest.mark.parametrize(
    ("metadata", "message"),
    [
        ({"SensorBlackLevels": (4096, 4096)}, "SensorBlackLevels must be 4 numbers"),
        ({"SensorBlackLevels": "4096"}, "SensorBlackLevels must be 4 numbers"),
        ({"SensorBlackLevels": (4096, -1, 0, 0)}, "outside the 16-bit range"),
        ({"ExposureTime": "fast"}, "ExposureTime must be numeric"),
        ({"AnalogueGain": float("nan")}, "not a finite number"),
        ({"ColourGains": 1.5}, "ColourGains must be 2 numbers"),
        ([("ExposureTime", 1)], "metadata must be a dict"),
    ],
)
def test_bad_metadata_gives_one_clear_error(metadata, message):
    buffer, config = pack(_mosaic(10, height=8, width=64), 10, 96), _config("SBGGR10_CSI2P", 64, 8, 96)
    with pytest.raises(RawFormatError) as excinfo:
        from_picamera2(buffer, config, metadata)
    assert message in _one_line(excinfo, "<picamera2>")


def test_values_beyond_the_bit_depth_are_rejected():
    buffer = _unpacked_buffer(np.full((4, 8), 1024, np.uint16), 16, 32)  # 16-bit data labelled 10-bit
    with pytest.raises(RawFormatError, match="values up to 1024 do not fit the 10 bits of SRGGB10"):
        from_picamera2(buffer, _config("SRGGB10", 8, 4, 32))


def test_bad_dump_files_give_one_clear_error_naming_the_file(tmp_path):
    buffer, config, metadata, _ = _pi4_capture()
    path = write_picamera2_npy(tmp_path / "a.npy", buffer, config, metadata)
    sidecar = tmp_path / "a.json"

    sidecar.rename(tmp_path / "moved.json")
    with pytest.raises(RawFormatError) as excinfo:
        read_picamera2_npy(path)
    assert "no JSON sidecar a.json beside it" in _one_line(excinfo, str(path))
    (tmp_path / "moved.json").rename(sidecar)

    for text, problem in [
        ('{"format": "picamcal-picamera2", "version": 1, "config": ', "corrupt sidecar of a.npy (JSONDecodeError"),
        ('{"format": "other"}', "not a picamcal sidecar of a.npy"),
        ('{"format": "picamcal-picamera2", "version": 9, "config": {}}', "unsupported sidecar of a.npy version 9"),
        ('{"format": "picamcal-picamera2", "version": 1, "config": []}', "'config' and 'metadata' must be objects"),
        ("\udcff", "corrupt sidecar of a.npy"),
    ]:
        sidecar.write_bytes(text.encode("utf-8", "surrogateescape"))
        with pytest.raises(RawFormatError) as excinfo:
            read_picamera2_npy(path)
        assert problem in _one_line(excinfo, str(sidecar)), problem

    for content, problem in [
        (b"", "corrupt .npy file"),
        (b"\x93NUMPY\x01\x00garbage", "corrupt .npy file"),
        (path.read_bytes()[:-10], "truncated .npy"),
    ]:
        bad = tmp_path / "b.npy"
        bad.write_bytes(content)
        with pytest.raises(RawFormatError) as excinfo:
            read_picamera2_npy(bad)
        assert problem in _one_line(excinfo, str(bad)), problem
    np.save(tmp_path / "c.npy", np.zeros((4, 4), np.float32))
    with pytest.raises(RawFormatError, match="float32 array of shape"):
        read_picamera2_npy(tmp_path / "c.npy")
    with pytest.raises(RawFormatError) as excinfo:
        read_picamera2_npy(tmp_path / "missing.npy")
    assert _one_line(excinfo, str(tmp_path / "missing.npy")).endswith("no such file")


# --- fuzzing: RawFormatError or a valid image, never anything else ---------------------------------------------

_FORMATS = [f"S{p}{b}" for p in PATTERNS for b in (8, 10, 12, 14, 16)]
_FORMATS += [f"S{p}{b}_CSI2P" for p in PATTERNS for b in (10, 12, 14)] + [f"{p}_PISP_COMP1" for p in PATTERNS]
_junk = st.one_of(st.none(), st.booleans(), st.floats(), st.text(max_size=5), st.lists(st.integers(), max_size=3))
_sizes = st.integers(-2, 70)
_even = st.integers(1, 32).map(lambda n: 2 * n)


def _mostly(valid, invalid):
    """Valid values three times in four, so that most examples reach the decoders."""
    return st.integers(0, 3).flatmap(lambda choice: valid if choice else invalid)


@st.composite
def _configs(draw):
    stream = {
        "format": draw(_mostly(st.sampled_from(_FORMATS), _junk)),
        "size": draw(_mostly(st.tuples(_even, _even), st.one_of(st.lists(_sizes, max_size=3), _junk))),
    }
    for key in ("stride", "framesize"):
        if draw(st.booleans()):
            stream[key] = draw(_mostly(st.integers(0, 200), st.one_of(st.integers(), _junk)))
    if draw(st.booleans()):
        return stream
    sensor = _mostly(st.fixed_dictionaries({"bit_depth": st.integers(8, 16)}), st.one_of(st.integers(0, 20), _junk))
    return {"raw": stream, "sensor": draw(st.one_of(sensor, st.fixed_dictionaries({"bit_depth": sensor})))}


_metadata = st.dictionaries(
    st.sampled_from(["SensorBlackLevels", "ExposureTime", "AnalogueGain", "ColourGains", "SensorTimestamp", "Lux"]),
    st.one_of(_junk, st.integers(-10, 70000), st.lists(st.integers(-10, 70000), min_size=4, max_size=4)),
)
_arrays = st.one_of(
    hnp.arrays(np.uint8, st.tuples(st.integers(0, 20), st.integers(0, 160))),
    hnp.arrays(np.uint8, st.integers(0, 2000)),
    hnp.arrays(np.uint16, st.tuples(st.integers(0, 20), st.integers(0, 80))),
    hnp.arrays(st.sampled_from([np.uint8, np.float32, np.int16]), hnp.array_shapes(min_dims=0, max_dims=3, max_side=4)),
    st.binary(max_size=100),
    st.none(),
)


@st.composite
def _buffers(draw, config):
    """A random array, or one shaped as the configuration asks (rows of its stride, or 128 bytes), random bytes."""
    stream = config.get("raw", config) if isinstance(config.get("raw", config), dict) else {}
    size, stride = stream.get("size"), stream.get("stride")
    if not draw(st.booleans()) or not isinstance(size, tuple) or not all(type(n) is int for n in size):
        return draw(_arrays)
    stride = stride if type(stride) is int and 0 <= stride <= 200 else 128
    return draw(hnp.arrays(np.uint8, (max(size[1], 0), stride)))


def _check_image(raw):
    assert raw.bayer.dtype == np.uint16 and raw.bayer.ndim == 2
    assert raw.white_level == 2**raw.bit_depth - 1 and int(raw.bayer.max()) <= raw.white_level


@pytest.mark.slow
@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(config=_configs(), metadata=st.one_of(st.none(), _metadata), data=st.data())
def test_fuzz_from_picamera2_raises_only_raw_format_error(config, metadata, data):
    array = data.draw(_buffers(config))
    try:
        raw = _quiet(array, config, metadata, source="fuzz")
    except RawFormatError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("fuzz: ")
    else:
        _check_image(raw)


@settings(max_examples=200, deadline=None)
@given(fmt=st.sampled_from(_FORMATS), data=st.data())
def test_fuzz_any_bytes_in_a_fitting_buffer_give_an_image_or_raw_format_error(fmt, data):
    config = _config(fmt, 16, 4, 48)
    buffer = data.draw(hnp.arrays(np.uint8, (4, 48)))
    try:
        raw = _quiet(buffer, config, data.draw(st.one_of(st.none(), _metadata)), source="fuzz")
    except RawFormatError as exc:  # unpacked values beyond the bit depth, or bad metadata
        assert "\n" not in str(exc) and str(exc).startswith("fuzz: ")
    else:
        _check_image(raw)
        assert raw.bayer.shape == (4, 16)


@settings(max_examples=150, deadline=None)
@given(
    fmt=st.sampled_from(_FORMATS),
    keep_rows=st.integers(0, 7),
    keep_bytes=st.integers(0, 159),
    flat=st.booleans(),
)
def test_fuzz_truncated_buffers_are_rejected(fmt, keep_rows, keep_bytes, flat):
    stride = 160  # enough for 64 pixels in any format
    buffer = np.random.default_rng(0).integers(0, 256, (8, stride), dtype=np.uint8)
    buffer = buffer.ravel()[: keep_rows * stride + keep_bytes] if flat else buffer[:keep_rows, :keep_bytes]
    with pytest.raises(RawFormatError):
        _quiet(buffer, _config(fmt, 64, 8, stride))


def _npy_bytes(array: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.save(out, array)
    return out.getvalue()


_REAL_NPY = _npy_bytes(np.zeros((8, 96), np.uint8))  # fits _config("SBGGR10_CSI2P", 64, 8, 96)


def _sidecar_json(config, metadata, sensor) -> bytes:
    record = {"format": "picamcal-picamera2", "version": 1, "config": config, "metadata": metadata, "sensor": sensor}
    return json.dumps(record).encode()


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    npy=st.one_of(
        st.binary(max_size=300),
        st.binary(max_size=200).map(lambda b: b"\x93NUMPY\x01\x00" + b),
        st.integers(0, len(_REAL_NPY)).map(lambda n: _REAL_NPY[:n]),  # a real header, data truncated
        hnp.arrays(st.sampled_from([np.uint8, np.uint16, np.float64]), hnp.array_shapes(max_dims=3)).map(_npy_bytes),
    ),
    sidecar=st.one_of(
        st.binary(max_size=200),
        st.builds(
            _sidecar_json,
            st.one_of(_configs(), st.just(_config("SBGGR10_CSI2P", 64, 8, 96)), _junk),
            st.one_of(_metadata, _junk),
            st.one_of(st.none(), st.text(max_size=8), _junk),
        ),
    ),
)
@pytest.mark.slow
def test_fuzz_read_picamera2_npy_raises_only_raw_format_error(tmp_path, npy, sidecar):
    path = tmp_path / "fuzz.npy"
    path.write_bytes(npy)
    path.with_suffix(".json").write_bytes(sidecar)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PicamcalWarning)
            raw = read_picamera2_npy(path)
    except RawFormatError as exc:
        assert "\n" not in str(exc) and str(exc).startswith(str(tmp_path))
    else:
        _check_image(raw)


# --- the capture helper, with a stand-in for the camera hardware ------------------------------------------------


class _FakeRequest:
    def __init__(self, array, metadata):
        self.array, self.metadata, self.released = array, metadata, False

    def make_array(self, name):
        assert name == "raw"
        return self.array

    def get_metadata(self):
        return self.metadata

    def release(self):
        self.released = True


class _FakePicamera2:
    """The few attributes of picamera2.Picamera2 that capture_raw uses, as an HQ camera on a Pi 4 reports them."""

    def __init__(self, array, raw_config, metadata):
        self.camera_properties = {"Model": "imx477", "PixelArraySize": (4056, 3040)}
        # (minimum, maximum, default): the maximum is the configured mode's crop, picamera2's crop_limits
        self.camera_controls = {"ScalerCrop": ((0, 0, 64, 16), (1000, 1000, 128, 16), (1000, 1000, 128, 16))}
        self.request = _FakeRequest(array, metadata)
        self.raw_config = raw_config

    def capture_request(self):
        return self.request

    def camera_configuration(self):
        return {"main": {"format": "BGR888", "size": (640, 480)}, "raw": self.raw_config, "sensor": {"bit_depth": 12}}


def test_capture_raw_reads_the_request_and_releases_it():
    mosaic = _mosaic(12, height=8, width=64)
    stride = _aligned(packed_row_bytes(64, 12), 32)
    camera = _FakePicamera2(
        pack(mosaic, 12, stride),
        _config("SRGGB12_CSI2P", 64, 8, stride),
        {"SensorBlackLevels": (4096,) * 4, "ExposureTime": 5000},
    )
    raw = capture_raw(camera)
    assert camera.request.released
    np.testing.assert_array_equal(raw.bayer, mosaic)
    assert (raw.sensor, raw.bit_depth, raw.black_level) == ("imx477", 12, (256.0,) * 4)
    assert raw.metadata["exposure_time_s"] == pytest.approx(0.005, rel=1e-12)
    # Where the mode lies on the sensor, as the camera says: its crop limits on the pixel array, binned 2 x 2 here.
    assert (raw.metadata["sensor_size"], raw.metadata["sensor_crop"]) == ([4056, 3040], [1000, 1000, 128, 16])
    geometry = raw_geometry(raw)
    assert (geometry.binning, geometry.source) == (2, "camera")
    broken = _FakePicamera2(np.zeros((8, 8), np.uint8), _config("SRGGB12_CSI2P", 64, 8, 8), {})
    with pytest.raises(RawFormatError, match="stride of 8 bytes is too short"):
        capture_raw(broken)
    assert broken.request.released


# --- full-size frames (their speed is a benchmark's: benchmarks/run.py, "Reading one raw frame") ------------------


def test_an_8_megapixel_raw10_frame_decodes_exactly():
    width, height = 3280, 2464  # IMX219 full resolution, stride padded to 32 bytes as on a Pi 4
    mosaic = np.random.default_rng(0).integers(0, 1024, (height, width), dtype=np.uint16)
    stride = _aligned(packed_row_bytes(width, 10), 32)
    config = _config("SBGGR10_CSI2P", width, height, stride)
    decoded = from_picamera2(pack(mosaic, 10, stride), config, {"SensorBlackLevels": (4096,) * 4})
    np.testing.assert_array_equal(decoded.bayer, mosaic)


def test_an_8_megapixel_pisp_frame_of_every_code_decodes():
    width, height = 3280, 2464
    stride = _aligned(width, 64)
    buffer = np.random.default_rng(0).integers(0, 256, (height, stride), dtype=np.uint8)  # every mode, many escapes
    config = {"raw": _config("BGGR_PISP_COMP1", width, height, stride), "sensor": {"bit_depth": 10}}
    raw = _quiet(buffer, config, {"SensorBlackLevels": (4096,) * 4})
    assert raw.bayer.shape == (height, width) and int(raw.bayer.max()) <= 1023


@pytest.mark.parametrize("sensor", ["ov5647", "imx219", "imx477", "imx708"])
@pytest.mark.parametrize("pattern", ["RGGB", "GRBG", "GBRG", "BGGR"])
def test_to_picamera2_inverts_from_picamera2(sensor, pattern):
    from picamcal.raw import to_picamera2
    from picamcal.sensors import get_sensor

    bits = get_sensor(sensor).bit_depth
    rng = np.random.default_rng(3)
    raw = RawImage(
        rng.integers(0, 2**bits, (24, 40), dtype=np.uint16),
        pattern,
        (60.0, 61.0, 62.0, 63.0),
        2**bits - 1,
        bits,
        sensor,
        {"exposure_time_s": 0.02, "analogue_gain": 2.0},
    )
    array, config, metadata = to_picamera2(raw)
    assert config["raw"]["format"] == f"S{pattern}{bits}_CSI2P" and config["raw"]["stride"] % 32 == 0
    back = from_picamera2(array, config, metadata)
    np.testing.assert_array_equal(back.bayer, raw.bayer)
    assert back.black_level == raw.black_level  # per site, through R/Gr/Gb/B on the 16-bit scale
    assert (back.pattern, back.sensor, back.bit_depth) == (pattern, sensor, bits)
    assert back.metadata["exposure_time_s"] == pytest.approx(0.02) and back.metadata["analogue_gain"] == 2.0
