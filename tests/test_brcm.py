"""Legacy JPEG+raw (BRCM) files: hand-packed blocks read exactly, the writer checked by LibRaw, bad files rejected.

The hand-made files here are packed by the test's own per-pixel loop (FORMATS.md section 2), not by
``picamcal.raw.packing``, so a wrong bit order in the library cannot cancel out.
"""

from __future__ import annotations

import io
import struct
import tracemalloc
from datetime import timedelta

import numpy as np
import pytest
import rawpy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image, TiffImagePlugin

from picamcal.errors import OutputError, RawFormatError
from picamcal.raw import RawImage
from picamcal.raw.brcm import is_jpeg, read_brcm, write_brcm
from picamcal.sensors import SENSORS

HEADER = 32768
FIELDS_AT = 0xB0
FIELDS = "<32s4H6I2H2B"  # name, width, height, padding_right, padding_down, 6 unused, transform, format, order, bits
ORDERS = {0: "RGGB", 1: "GBRG", 2: "BGGR", 3: "GRBG"}
BAYER_FORMAT = {10: 3, 12: 4}

# (sensor, width, height) -> (padding_right, stride): worked out by hand from the stride formula of FORMATS.md.
LAYOUT = {
    ("ov5647", 2592, 1944): (0, 3264),
    ("ov5647", 1920, 1080): (24, 2432),
    ("ov5647", 1296, 972): (0, 1632),
    ("ov5647", 1296, 730): (0, 1632),
    ("ov5647", 640, 480): (24, 832),
    ("imx219", 3280, 2464): (0, 4128),
    ("imx219", 1920, 1080): (24, 2432),
    ("imx219", 1640, 1232): (0, 2080),
    ("imx219", 1640, 922): (0, 2080),
    ("imx219", 1280, 720): (24, 1632),
    ("imx219", 640, 480): (24, 832),
    ("imx477", 4056, 3040): (0, 6112),
    ("imx477", 2028, 1520): (0, 3072),
    ("imx477", 2028, 1080): (0, 3072),
    ("imx477", 1012, 760): (0, 1280),
}
MODES = [(s.name, m) for s in SENSORS.values() for m in s.legacy_modes]
MODE_IDS = [f"{name}-{m.width}x{m.height}" for name, m in MODES]
SMALL = {"ov5647": (640, 480), "imx219": (640, 480), "imx477": (1012, 760)}


def stride_formula(padded_width: int, bits: int) -> int:
    nbytes = (padded_width * 5 + 3) // 4 if bits == 10 else ((padded_width + 1) // 2) * 3
    return (nbytes + 31) // 32 * 32


def hand_pack(values: list[int], bits: int) -> bytes:
    """CSI-2 packing, one group of pixels at a time, exactly as FORMATS.md words it."""
    out = bytearray()
    if bits == 10:
        for g in range(0, len(values), 4):
            p0, p1, p2, p3 = values[g : g + 4]
            out += bytes([p0 >> 2, p1 >> 2, p2 >> 2, p3 >> 2])
            out.append((p0 & 3) | (p1 & 3) << 2 | (p2 & 3) << 4 | (p3 & 3) << 6)
    else:
        for g in range(0, len(values), 2):
            p0, p1 = values[g : g + 2]
            out += bytes([p0 >> 4, p1 >> 4, (p0 & 0xF) | (p1 & 0xF) << 4])
    return bytes(out)


def row_values(row: int, width: int, bits: int) -> list[int]:
    """Edge values (0-3, the top four, alternating bits, the middle) at every position mod 4, then a ramp."""
    top = (1 << bits) - 1
    special = [0, 1, 2, 3, top, top - 1, top - 2, top - 3, 0x155 & top, 0x2AA & top, 1 << (bits - 1), top >> 1]
    special = special[row % 4 :] + special[: row % 4]
    ramp = [(row * 97 + col * 13) % (top + 1) for col in range(width)]
    return special + ramp[len(special) :]


def jpeg(model: str | None = "RP_imx219", *, exposure=None, iso=None, maker_note=None, stamp=None) -> bytes:
    exif = Image.Exif()
    exif[271] = "RaspberryPi"
    if model is not None:
        exif[272] = model
    sub = exif.get_ifd(0x8769)
    if exposure is not None:  # a RATIONAL, as the firmware writes it (a bare tuple would be written as two LONGs)
        sub[33434] = TiffImagePlugin.IFDRational(*exposure)
    if iso is not None:
        sub[34855] = iso
    if maker_note is not None:
        sub[37500] = maker_note
    if stamp is not None:
        sub[36867] = stamp
    out = io.BytesIO()
    Image.new("RGB", (64, 48), (90, 120, 60)).save(out, "JPEG", exif=exif)
    return out.getvalue()


def hand_block(sensor: str, mode, *, order: int = 2, name: str = "", **overrides) -> tuple[bytes, np.ndarray]:
    """A BRCM block with hand-packed rows 0-3 and the last two; stride padding 0xFF and spare rows 0xEE."""
    padding, stride = LAYOUT[(sensor, mode.width, mode.height)]
    rows = (mode.block_size - HEADER) // stride
    fields = {
        "width": mode.width,
        "height": mode.height,
        "padding_right": padding,
        "format": 33,
        "bayer_format": BAYER_FORMAT[mode.bit_depth],
    }
    fields.update(overrides)
    header = bytearray(HEADER)
    header[:5] = b"BRCMo" if sensor == "imx477" else b"BRCM\x00"
    struct.pack_into(
        FIELDS,
        header,
        FIELDS_AT,
        name.encode(),
        fields["width"],
        fields["height"],
        fields["padding_right"],
        0,
        *[0] * 6,
        0,
        fields["format"],
        order,
        fields["bayer_format"],
    )
    pixels = np.zeros((rows, stride), np.uint8)
    used = mode.width * mode.bit_depth // 8
    pixels[:, used:] = 0xFF
    pixels[mode.height :] = 0xEE
    expected = np.zeros((mode.height, mode.width), np.uint16)
    for r in (0, 1, 2, 3, mode.height - 2, mode.height - 1):
        values = row_values(r, mode.width, mode.bit_depth)
        pixels[r, :used] = np.frombuffer(hand_pack(values, mode.bit_depth), np.uint8)
        expected[r] = values
    return bytes(header) + pixels.tobytes(), expected


def small_mode(sensor: str):
    width, height = SMALL[sensor]
    return next(m for m in SENSORS[sensor].legacy_modes if (m.width, m.height) == (width, height))


def random_raw(sensor: str, mode, pattern: str = "BGGR", seed: int = 0, **meta) -> RawImage:
    rng = np.random.default_rng(seed)
    bayer = rng.integers(0, 1 << mode.bit_depth, size=(mode.height, mode.width), dtype=np.uint16)
    bayer[0, :8] = [0, 1, 2, 3, (1 << mode.bit_depth) - 1, (1 << mode.bit_depth) - 2, 0x155, 0x2AA]
    top = (1 << mode.bit_depth) - 1
    return RawImage(bayer, pattern, (0.0,) * 4, top, mode.bit_depth, sensor, dict(meta))


def libraw_pattern(rp) -> str:
    desc = rp.color_desc.decode()
    return "".join(desc[i] for i in rp.raw_pattern.ravel())


# --- the test's own packer and layout table agree with FORMATS.md --------------------------------------------


def test_hand_packer_follows_the_documented_bit_order():
    # RAW10: bytes 0-3 the 8 MSBs; byte 4 pixel 0 in bits 1:0 ... pixel 3 in bits 7:6.
    assert hand_pack([0x3FF, 0x000, 0x155, 0x2AA], 10) == bytes([0xFF, 0x00, 0x55, 0xAA, 0b10_01_00_11])
    # RAW12: bytes 0-1 the 8 MSBs; byte 2 low nibble pixel 0, high nibble pixel 1.
    assert hand_pack([0xABC, 0x123], 12) == bytes([0xAB, 0x12, 0x3C])


@pytest.mark.parametrize(("sensor", "mode"), MODES, ids=MODE_IDS)
def test_layout_table_reproduces_the_registry_block_size(sensor, mode):
    padding, stride = LAYOUT[(sensor, mode.width, mode.height)]
    assert stride_formula(mode.width + padding, mode.bit_depth) == stride
    rows, rest = divmod(mode.block_size - HEADER, stride)
    assert rest == 0 and rows >= mode.height


def test_documented_full_resolution_layouts():
    # FORMATS.md: IMX219 full stores 2480 rows of 4128 bytes; HQ 3056 rows of 6112 bytes.
    assert LAYOUT[("imx219", 3280, 2464)][1] == 4128 and (10270208 - HEADER) // 4128 == 2480
    assert LAYOUT[("imx477", 4056, 3040)][1] == 6112 and (18711040 - HEADER) // 6112 == 3056


# --- reading hand-made files ------------------------------------------------------------------------------------


@pytest.mark.parametrize(("sensor", "mode"), MODES, ids=MODE_IDS)
def test_hand_packed_block_reads_exactly(tmp_path, sensor, mode):
    block, expected = hand_block(sensor, mode)
    path = tmp_path / "hand.jpg"
    path.write_bytes(jpeg(SENSORS[sensor].legacy_model) + block)
    raw = read_brcm(path)
    np.testing.assert_array_equal(raw.bayer, expected)
    assert raw.bayer.dtype == np.uint16
    assert (raw.sensor, raw.pattern, raw.bit_depth) == (sensor, "BGGR", mode.bit_depth)
    assert raw.white_level == (1 << mode.bit_depth) - 1
    assert raw.metadata["format"] == "brcm" and raw.metadata["path"] == str(path)
    assert raw.metadata["legacy_mode"]["block_size"] == mode.block_size


@pytest.mark.parametrize(("code", "pattern"), ORDERS.items())
def test_every_bayer_order_code_of_the_header(tmp_path, code, pattern):
    block, _ = hand_block("imx219", small_mode("imx219"), order=code)
    path = tmp_path / "order.jpg"
    path.write_bytes(jpeg("RP_imx219") + block)
    assert read_brcm(path).pattern == pattern


@pytest.mark.parametrize(
    ("sensor", "width", "height", "black"),
    [
        ("ov5647", 640, 480, 16.0),
        ("imx219", 640, 480, 64.0),
        ("imx477", 4056, 3040, 256.0),
        ("imx477", 1012, 760, 64.0),
    ],
)
def test_black_level_comes_from_the_registry_at_the_mode_depth(tmp_path, sensor, width, height, black):
    mode = next(m for m in SENSORS[sensor].legacy_modes if (m.width, m.height) == (width, height))
    path = write_brcm(tmp_path / "x.jpg", random_raw(sensor, mode))
    raw = read_brcm(path)
    assert raw.sensor == sensor and raw.black_level == (black,) * 4


@pytest.mark.parametrize(
    ("model", "sensor"),
    [
        ("RP_ov5647", "ov5647"),
        ("ov5647", "ov5647"),
        ("RP_OV5647", "ov5647"),
        ("RP_testc", "ov5647"),
        ("RP_imx219", "imx219"),
    ],
)
def test_exif_model_tells_ov5647_from_imx219_in_a_shared_block_size(tmp_path, model, sensor):
    block, expected = hand_block(sensor, small_mode(sensor))  # 640x480: 445440 bytes for both sensors
    path = tmp_path / "shared.jpg"
    path.write_bytes(jpeg(model) + block)
    raw = read_brcm(path)
    assert raw.sensor == sensor and raw.metadata["model"] == model
    np.testing.assert_array_equal(raw.bayer, expected)


def test_header_size_tells_ov5647_from_imx219_in_a_shared_block_size(tmp_path):
    # 1233920 bytes is OV5647 1296x730 and IMX219 1280x720: the header decides, whatever EXIF says.
    mode = next(m for m in SENSORS["ov5647"].legacy_modes if m.width == 1296 and m.height == 730)
    block, _ = hand_block("ov5647", mode)
    path = tmp_path / "x.jpg"
    path.write_bytes(jpeg(None) + block)
    assert read_brcm(path).sensor == "ov5647"


def test_old_hq_model_name(tmp_path):
    mode = next(m for m in SENSORS["imx477"].legacy_modes if (m.width, m.height) == (2028, 1080))
    block, expected = hand_block("imx477", mode)
    path = tmp_path / "hq.jpg"
    path.write_bytes(jpeg("imx477") + block)
    raw = read_brcm(path)
    assert (raw.sensor, raw.black_level[0]) == ("imx477", 256.0)
    np.testing.assert_array_equal(raw.bayer, expected)


def test_bare_block_uses_the_header_name_when_there_is_no_exif(tmp_path):
    block, expected = hand_block("imx219", small_mode("imx219"), name="imx219")
    path = tmp_path / "block.raw"
    path.write_bytes(block)
    raw = read_brcm(path)
    assert raw.sensor == "imx219" and raw.metadata["header_name"] == "imx219"
    np.testing.assert_array_equal(raw.bayer, expected)


def test_exif_metadata_is_read(tmp_path):
    note = (
        b"ev=-1 mlux=-1 exp=62998 ag=556 focus=255 gain_r=1.128 gain_b=2.546 greenness=3 "
        b"ccm=6022,-2314,394,-936,4728,310,300,-4324,8126,0,0,0 md=0 tg=262 262 oth=0 0 b=0 f=262 262 fi=0"
    )
    head = jpeg("RP_imx219", exposure=(62998, 1000000), iso=220, maker_note=note, stamp="2018:10:20 18:10:01")
    block, _ = hand_block("imx219", small_mode("imx219"))
    path = tmp_path / "meta.jpg"
    path.write_bytes(head + block)
    meta = read_brcm(path).metadata
    assert meta["make"] == "RaspberryPi" and meta["model"] == "RP_imx219"
    assert meta["exposure_time_s"] == pytest.approx(0.062998, rel=1e-9)
    assert meta["iso"] == 220
    assert meta["analogue_gain"] == pytest.approx(556 / 256)  # the firmware's ag is Q8
    assert meta["colour_gains"] == pytest.approx([1.128, 2.546])
    assert meta["timestamp"] == "2018:10:20 18:10:01"
    assert meta["legacy_mode"] == {"modes": [7], "width": 640, "height": 480, "bit_depth": 10, "block_size": 445440}


def test_a_jpeg_whose_exif_pillow_cannot_parse_still_reads(tmp_path):
    plain = io.BytesIO()
    Image.new("L", (32, 24), 100).save(plain, "JPEG")
    garbage = b"Exif\x00\x00MM\x00*\xff\xff\xff\xf0" + bytes(range(256)) * 2
    app1 = b"\xff\xe1" + struct.pack(">H", len(garbage) + 2) + garbage
    data = plain.getvalue()
    mode = next(m for m in SENSORS["imx219"].legacy_modes if (m.width, m.height) == (1640, 922))
    block, expected = hand_block("imx219", mode)
    path = tmp_path / "bad_exif.jpg"
    path.write_bytes(data[:2] + app1 + data[2:] + block)
    raw = read_brcm(path)
    np.testing.assert_array_equal(raw.bayer, expected)
    assert raw.sensor == "imx219" and "model" not in raw.metadata


# --- writing: read back by read_brcm and by LibRaw ---------------------------------------------------------------


@pytest.mark.parametrize(("sensor", "mode"), MODES, ids=MODE_IDS)
def test_write_then_read_is_bit_exact_by_read_brcm_and_libraw(tmp_path, sensor, mode):
    raw = random_raw(sensor, mode, "GRBG", exposure_time_s=0.02, analogue_gain=2.0)
    path = write_brcm(tmp_path / "w.jpg", raw)
    data = path.read_bytes()
    assert data[-mode.block_size :].startswith(b"BRCM") and is_jpeg(data[:4])
    back = read_brcm(path)
    np.testing.assert_array_equal(back.bayer, raw.bayer)
    assert (back.pattern, back.sensor, back.bit_depth) == ("GRBG", sensor, mode.bit_depth)
    assert back.metadata["exposure_time_s"] == pytest.approx(0.02)
    assert back.metadata["iso"] == 200 and back.metadata["analogue_gain"] == 2.0
    with rawpy.imread(str(path)) as rp:  # LibRaw finds the block from the EXIF Model and its own size table
        np.testing.assert_array_equal(rp.raw_image_visible, raw.bayer)
        assert libraw_pattern(rp) == "GRBG"


@pytest.mark.parametrize("sensor", ["ov5647", "imx219", "imx477"])
@pytest.mark.parametrize("pattern", list(ORDERS.values()))
def test_every_pattern_survives_writing(tmp_path, sensor, pattern):
    raw = random_raw(sensor, small_mode(sensor), pattern, seed=3)
    path = write_brcm(tmp_path / "p.jpg", raw)
    assert read_brcm(path).pattern == pattern
    with rawpy.imread(str(path)) as rp:
        assert libraw_pattern(rp) == pattern
        np.testing.assert_array_equal(rp.raw_image_visible, raw.bayer)


def test_written_12_bit_block_alone_is_read_by_libraw(tmp_path):
    mode = next(m for m in SENSORS["imx477"].legacy_modes if (m.width, m.height) == (2028, 1080))
    raw = random_raw("imx477", mode, "RGGB", seed=5)
    block = write_brcm(tmp_path / "hq.jpg", raw).read_bytes()[-mode.block_size :]
    bare = tmp_path / "hq.raw"
    bare.write_bytes(block)
    with rawpy.imread(str(bare)) as rp:
        np.testing.assert_array_equal(rp.raw_image_visible, raw.bayer)
        assert libraw_pattern(rp) == "RGGB"
    np.testing.assert_array_equal(read_brcm(bare).bayer, raw.bayer)


def test_written_header_and_exif(tmp_path):
    mode = next(m for m in SENSORS["imx219"].legacy_modes if (m.width, m.height) == (1920, 1080))
    path = write_brcm(tmp_path / "h.jpg", random_raw("imx219", mode, "BGGR"))
    data = path.read_bytes()
    block = data[-mode.block_size :]
    fields = struct.unpack_from(FIELDS, block, FIELDS_AT)
    width, height, padding = fields[1:4]
    fmt, order, bayer_format = fields[-3:]
    assert (width, height, padding, fmt, order, bayer_format) == (1920, 1080, 24, 33, 2, 3)
    with Image.open(io.BytesIO(data[: -mode.block_size])) as preview:
        preview.load()
        exif = preview.getexif()
        assert max(preview.size) <= 320
    assert (exif[271], exif[272]) == ("RaspberryPi", "RP_imx219")

    hq = next(m for m in SENSORS["imx477"].legacy_modes if (m.width, m.height) == (4056, 3040))
    block = write_brcm(tmp_path / "hq.jpg", random_raw("imx477", hq)).read_bytes()[-hq.block_size :]
    assert block[:5] == b"BRCMo" and struct.unpack_from(FIELDS, block, FIELDS_AT)[-1] == 4


def test_a_read_file_writes_back_identically(tmp_path):
    block, _ = hand_block("ov5647", small_mode("ov5647"), order=1, name="ov5647")
    source = tmp_path / "a.jpg"
    source.write_bytes(jpeg("RP_ov5647", exposure=(1, 100), iso=150) + block)
    raw = read_brcm(source)
    again = read_brcm(write_brcm(tmp_path / "b.jpg", raw))
    np.testing.assert_array_equal(again.bayer, raw.bayer)
    assert (again.sensor, again.pattern, again.metadata["header_name"]) == ("ov5647", "GBRG", "ov5647")


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        (RawImage(np.zeros((2592, 4608), np.uint16), "RGGB", (64,) * 4, 1023, 10, "imx708"), "no legacy"),
        (RawImage(np.zeros((100, 100), np.uint16), "BGGR", (64,) * 4, 1023, 10, "imx219"), "not a legacy raw mode"),
        (RawImage(np.zeros((480, 640), np.uint16), "BGGR", (64,) * 4, 4095, 12, "imx219"), "not a legacy raw mode"),
        (RawImage(np.zeros((480, 640), np.uint16), "BGGR", (64,) * 4, 1023, 10, None), "known sensor"),
        (RawImage(np.full((480, 640), 1024, np.uint16), "BGGR", (64,) * 4, 1023, 10, "imx219"), "do not fit"),
    ],
)
def test_write_rejects_what_has_no_legacy_mode(tmp_path, raw, message):
    with pytest.raises(RawFormatError, match=message):
        write_brcm(tmp_path / "x.jpg", raw)
    assert list(tmp_path.iterdir()) == []


def test_write_does_not_overwrite_when_told_not_to(tmp_path):
    raw = random_raw("imx219", small_mode("imx219"))
    path = write_brcm(tmp_path / "x.jpg", raw)
    with pytest.raises(OutputError):
        write_brcm(path, raw, overwrite=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.jpg"]


def test_a_full_imx219_file_reads_back_exactly(tmp_path):
    # Its speed is a benchmark's (benchmarks/run.py, "Reading one raw frame"), never a test's.
    mode = SENSORS["imx219"].legacy_modes[0]
    raw = random_raw("imx219", mode)
    np.testing.assert_array_equal(read_brcm(write_brcm(tmp_path / "full.jpg", raw)).bayer, raw.bayer)


# --- bad files: always a one-line RawFormatError naming the file --------------------------------------------


def _small_file(**overrides) -> bytes:
    block, _ = hand_block("imx219", small_mode("imx219"), **overrides)
    return jpeg("RP_imx219") + block


BAD_FILES = {
    "empty": (b"", "empty file"),
    "jpeg without block": (jpeg("RP_imx219"), "no raw (BRCM) block, not a raw image (DNG, JPEG+raw"),
    "unknown block size": (_small_file() + bytes(32), "block of 445472 bytes (header 640x480) matches no known"),
    "truncated": (_small_file()[:-1000], "truncated file"),
    "truncated in header": (_small_file()[: len(jpeg("RP_imx219")) + 1000], "truncated file"),
    "header size disagrees": (_small_file(width=1000), "header says 1000x480, but a 445440-byte block is a 640x480"),
    "huge header size": (_small_file(width=65535, height=65535), "header says 65535x65535"),
    "unknown bayer code": (_small_file(order=7), "unknown Bayer order code 7"),
    "stride inconsistent": (_small_file(padding_right=200), "inconsistent raw layout"),
    "bit depth disagrees": (_small_file(bayer_format=4), "12-bit samples"),
    "random bytes": (bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8)), "not a legacy raw"),
    "ambiguous sensor": (jpeg(None) + hand_block("imx219", small_mode("imx219"))[0], "cannot tell"),
}


@pytest.mark.parametrize("case", BAD_FILES)
def test_bad_file_gives_one_line_raw_format_error_naming_it(tmp_path, case):
    content, message = BAD_FILES[case]
    path = tmp_path / "bad.jpg"
    path.write_bytes(content)
    with pytest.raises(RawFormatError) as info:
        read_brcm(path)
    assert info.value.path == str(path) and str(path) in str(info.value)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(RawFormatError, match="no such file"):
        read_brcm(tmp_path / "nope.jpg")
    with pytest.raises(RawFormatError, match="directory"):
        read_brcm(tmp_path)


# --- fuzzing: damaged files never raise anything but RawFormatError, quickly and without large allocations ------

VALID = _small_file()
JPEG_LENGTH = len(jpeg("RP_imx219"))
FUZZ = settings(
    max_examples=100,
    deadline=timedelta(seconds=2),
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
EXIF_START = b"\xff\xd8\xff\xe1\x00\x10Exif\x00\x00"
PEAK_LIMIT = 16 << 20  # a valid 640x480 read needs ~2 MB; a header-driven allocation would be far larger


def _read_damaged(path, content: bytes) -> None:
    path.write_bytes(content)
    tracemalloc.start()
    try:
        raw = read_brcm(path)
    except RawFormatError as exc:
        assert exc.path == str(path)
    else:
        assert raw.bayer.shape == (480, 640)
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert peak < PEAK_LIMIT


@FUZZ
@given(length=st.integers(0, len(VALID) - 1))
def test_fuzz_truncation(tmp_path, length):
    _read_damaged(tmp_path / "t.jpg", VALID[:length])


@FUZZ
@given(
    changes=st.lists(
        st.tuples(st.one_of(st.integers(0, FIELDS_AT + 80), st.integers(0, HEADER - 1)), st.integers(0, 255)),
        min_size=1,
        max_size=8,
    )
)
def test_fuzz_header_corruption(tmp_path, changes):
    data = bytearray(VALID)
    for offset, value in changes:
        data[JPEG_LENGTH + offset] = value
    _read_damaged(tmp_path / "h.jpg", bytes(data))


@FUZZ
@given(changes=st.lists(st.tuples(st.integers(0, JPEG_LENGTH - 1), st.integers(0, 255)), min_size=1, max_size=8))
def test_fuzz_jpeg_corruption(tmp_path, changes):
    data = bytearray(VALID)
    for offset, value in changes:
        data[offset] = value
    _read_damaged(tmp_path / "j.jpg", bytes(data))


@FUZZ
@given(
    prefix=st.sampled_from([b"", b"\xff\xd8\xff", b"BRCM", b"\xff\xd8\xff\xe1\x00\x10Exif\x00\x00"]), rest=st.binary()
)
def test_fuzz_random_bytes(tmp_path, prefix, rest):
    _read_damaged(tmp_path / "r.jpg", prefix + rest)
