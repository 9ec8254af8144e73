"""Headless raw dumps (rpicam-raw -o): every packing round-trips exactly, frames, strides, sensors, bad input, CLI."""

from __future__ import annotations

import json
import re
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from picamcal import PicamcalWarning, RawFormatError, read_raw
from picamcal.raw import RawImage, to_picamera2
from picamcal.raw.headless import default_strides, read_headless
from picamcal.raw.model import PATTERNS, require_black_level
from picamcal.raw.packing import pack
from picamcal.raw.picamera2 import RAW_FORMATS, from_picamera2, parse_raw_format
from test_cli import assert_bad_input, run

# (format suffix, bits): every layout libcamera's raw streams use for Bayer data.
PACKINGS = [("_CSI2P", 10), ("_CSI2P", 12), ("_CSI2P", 14), ("", 8), ("", 10), ("", 12), ("", 16)]
WIDTH, HEIGHT = 44, 6  # 44 pixels: no packing's row is a multiple of 32 bytes, so the stride pads every row


def _mosaic(bits: int, height: int = HEIGHT, width: int = WIDTH, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 2**bits, size=(height, width), dtype=np.uint16)


def _pack_raw14(mosaic: np.ndarray, stride: int) -> np.ndarray:
    """RAW14 byte by byte from the kernel's V4L2_PIX_FMT_SBGGR14P table (the project has no RAW14 packer)."""
    height, width = mosaic.shape
    p = np.zeros((height, -(-width // 4) * 4), np.uint16)
    p[:, :width] = mosaic
    p = p.reshape(height, -1, 4)
    out = np.zeros((height, stride), np.uint8)
    groups = out[:, : p.shape[1] * 7].reshape(height, -1, 7)
    groups[..., :4] = p >> 6
    groups[..., 4] = (p[..., 0] & 0x3F) | (p[..., 1] & 0x3) << 6
    groups[..., 5] = (p[..., 1] >> 2) & 0xF | (p[..., 2] & 0xF) << 4
    groups[..., 6] = (p[..., 2] >> 4) & 0x3 | (p[..., 3] & 0x3F) << 2
    return out


def _frame_bytes(mosaic: np.ndarray, suffix: str, bits: int, stride: int) -> bytes:
    """One frame as the Pi writes it, by the project's packers: pack() for RAW10/12, to_picamera2's layout else."""
    if suffix and bits in (10, 12):
        return pack(mosaic, bits, stride).tobytes()
    if suffix:
        return _pack_raw14(mosaic, stride).tobytes()
    raw = RawImage(mosaic, "RGGB", 0, 2**bits - 1, bits)
    array, config, _ = to_picamera2(raw, packed=False, align=stride)
    assert config["raw"]["stride"] == stride  # align=stride gives exactly that stride (stride >= the row's bytes)
    return array.tobytes()


def _quiet_read(*args, **kwargs) -> RawImage:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PicamcalWarning)
        return read_raw(*args, **kwargs)


# --- every packing, every Bayer order, default and explicit strides ----------------------------------------


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize(("suffix", "bits"), PACKINGS, ids=[f"{b}{s or '_unpacked'}" for s, b in PACKINGS])
@pytest.mark.parametrize("explicit", [False, True], ids=["libcamera-stride", "given-stride"])
def test_every_packing_round_trips_exactly(tmp_path, pattern, suffix, bits, explicit):
    name = f"S{pattern}{bits}{suffix}"
    spec = parse_raw_format(name)
    mosaic = _mosaic(bits)
    # libcamera's stride: 32-byte rows (Pi 4) for packed and narrow formats, 64 (Pi 5) for 16-bit; else any wider.
    stride = spec.row_bytes(WIDTH) + 24 if explicit else default_strides(spec, WIDTH)[0][0]
    path = tmp_path / "dump.raw"
    path.write_bytes(_frame_bytes(mosaic, suffix, bits, stride))
    raw = read_raw(path, raw_format=name.lower(), size=(WIDTH, HEIGHT), stride=stride if explicit else None)
    np.testing.assert_array_equal(raw.bayer, mosaic)  # bit-exact: no tolerance
    assert (raw.pattern, raw.bit_depth, raw.white_level) == (pattern, bits, 2**bits - 1)
    assert raw.metadata["format"] == "headless" and raw.metadata["raw_format"] == name
    assert (raw.metadata["stride"], raw.metadata["frames"], raw.metadata["frame"]) == (stride, 1, 0)
    assert raw.metadata["stride_source"] == ("given" if explicit else default_strides(spec, WIDTH)[0][1])


def test_libcamera_alignments_are_32_on_a_pi4_and_64_on_a_pi5():
    raw10, raw16 = parse_raw_format("SBGGR10_CSI2P"), parse_raw_format("SBGGR16")
    # A 3280-pixel IMX219 row of RAW10 is 4100 bytes: 4128 on a Pi 4 (as its legacy BRCM block has it too).
    assert default_strides(raw10, 3280)[0] == (4128, "libcamera's 32-byte alignment (Pi 4)")
    # A 1456-pixel IMX296 row of 16-bit pixels is 2912 bytes: 2944 on a Pi 5, 2912 on a Pi 4, in that order.
    assert [s for s, _ in default_strides(raw16, 1456)] == [2944, 2912]
    assert [s for s, _ in default_strides(parse_raw_format("RGGB_PISP_COMP1"), 1456)] == [1472, 1456]


@pytest.mark.parametrize(
    ("name", "width", "stride", "source"),
    [
        ("SRGGB10_CSI2P", 64, 128, "64-byte alignment (Pi 5)"),  # 80-byte rows: 96 on a Pi 4, 128 found instead
        ("SRGGB16", 40, 96, "32-byte alignment (Pi 4)"),  # 80-byte rows: 128 on a Pi 5, 96 found instead
        ("SRGGB10_CSI2P", 44, 55, "no padding"),  # another tool's tight rows
    ],
)
def test_the_stride_that_divides_the_file_is_found(tmp_path, name, width, stride, source):
    spec = parse_raw_format(name)
    mosaic = _mosaic(spec.bits, width=width)
    path = tmp_path / "dump.raw"
    path.write_bytes(_frame_bytes(mosaic, "_CSI2P" if spec.packing == "csi2p" else "", spec.bits, stride))
    raw = read_raw(path, raw_format=name, size=(width, HEIGHT))
    np.testing.assert_array_equal(raw.bayer, mosaic)
    assert raw.metadata["stride"] == stride and source in raw.metadata["stride_source"]


def test_pisp_compressed_dumps_use_the_pi5_stride(tmp_path):
    stride = 64  # 24 pixels of PISP_COMP1 are 24 bytes, rounded up to 64 on a Pi 5
    rows = np.random.default_rng(5).integers(0, 256, size=(3, HEIGHT, stride), dtype=np.uint8)
    path = tmp_path / "pisp.raw"
    path.write_bytes(rows.tobytes())
    with pytest.warns(PicamcalWarning, match="lossy"):
        raw = read_raw(path, raw_format="rggb_pisp_comp1", size=(24, HEIGHT), frame=2, sensor="imx708")
    with pytest.warns(PicamcalWarning, match="lossy"):
        same = from_picamera2(
            rows[2],
            {"raw": {"format": "RGGB_PISP_COMP1", "size": (24, HEIGHT), "stride": 64}, "sensor": {"bit_depth": 10}},
        )
    np.testing.assert_array_equal(raw.bayer, same.bayer)  # the dump's third frame, decoded as picamera2's buffer
    assert (raw.metadata["frames"], raw.metadata["stride"], raw.bit_depth) == (3, 64, 10)
    assert raw.metadata["lossy_compression"] == "PISP_COMP1"


# --- frames ----------------------------------------------------------------------------------------------


def test_a_three_frame_dump_gives_frame_k_exactly(tmp_path):
    frames = [_mosaic(12, seed=k) for k in range(3)]
    path = tmp_path / "video.raw"
    path.write_bytes(b"".join(pack(f, 12, 96).tobytes() for f in frames))  # 66-byte rows, 96 on a Pi 4
    for k, expected in enumerate(frames):
        raw = read_raw(path, raw_format="SGRBG12_CSI2P", size=(WIDTH, HEIGHT), frame=k)
        np.testing.assert_array_equal(raw.bayer, expected)
        assert (raw.metadata["frame"], raw.metadata["frames"]) == (k, 3)
    with pytest.raises(
        RawFormatError, match=r"frame 3 is past the end: the file holds 3 frame\(s\) \(give --frame 0 to 2\)"
    ):
        read_raw(path, raw_format="SGRBG12_CSI2P", size=(WIDTH, HEIGHT), frame=3)
    with pytest.raises(RawFormatError, match="frame must be a whole number from 0"):
        read_raw(path, raw_format="SGRBG12_CSI2P", size=(WIDTH, HEIGHT), frame=-1)


def test_only_the_frame_asked_for_is_read(tmp_path):
    # 200 frames of 640x480 16-bit (614400 bytes each, 123 MB) as a sparse file: reading one frame must cost
    # about one frame of memory, never the file. Decoding holds a few copies of one frame; 8 frames is the bound.
    frame_bytes = 1280 * 480
    path = tmp_path / "long.raw"
    with open(path, "wb") as f:
        f.truncate(200 * frame_bytes)
    tracemalloc.start()
    try:
        raw = read_raw(path, raw_format="SBGGR16", size=(640, 480), frame=150, black_level=4096)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert raw.metadata["frames"] == 200 and not raw.bayer.any()
    assert peak < 8 * frame_bytes, peak


# --- sizes that do not fit, format names ------------------------------------------------------------------


def test_a_size_that_does_not_fit_names_both_byte_counts(tmp_path):
    path = tmp_path / "one.raw"
    path.write_bytes(pack(_mosaic(10, height=240, width=320), 10, 416).tobytes())  # 99840 bytes
    with pytest.raises(RawFormatError) as info:
        read_raw(path, raw_format="SBGGR10_CSI2P", size=(320, 242))
    message = str(info.value)
    assert message.startswith(f"{path}: 99840 bytes is not a whole number of 320x242 SBGGR10_CSI2P frames")
    assert "frames of 100672 bytes (stride 416 bytes, libcamera's 32-byte alignment (Pi 4)" in message
    assert "--size" in message and "\n" not in message
    with pytest.raises(RawFormatError, match=r"frames of 101640 bytes \(stride 420 bytes, given\)"):
        read_raw(path, raw_format="SBGGR10_CSI2P", size=(320, 242), stride=420)
    with pytest.raises(RawFormatError, match="a stride of 300 bytes is too short for 320 pixels of SBGGR10_CSI2P"):
        read_raw(path, raw_format="SBGGR10_CSI2P", size=(320, 240), stride=300)
    with pytest.raises(RawFormatError, match="needs its frame size: give --size WIDTHxHEIGHT"):
        read_raw(path, raw_format="SBGGR10_CSI2P")
    with pytest.raises(RawFormatError, match="even width and height"):
        read_raw(path, raw_format="SBGGR10_CSI2P", size=(319, 240))


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("YUV420", r"unknown raw format 'YUV420' \(expected S<order>\{8,10,12,14,16\}, S<order>\{10,12,14\}_CSI2P"),
        ("SBGGR10P", "did you mean SBGGR10_CSI2P?"),  # V4L2's name of the packed format
        ("SBGGR10_CSIP", r"did you mean SBGGR10_CSI2P\?"),  # a typo beside a Bayer order: the format of that order
        # No Bayer order, or a misspelt one: the four formats, never one picked (the order is the data's).
        (
            "RAW10_CSI2P",
            "did you mean SBGGR10_CSI2P, SGBRG10_CSI2P, SGRBG10_CSI2P or SRGGB10_CSI2P: the Bayer order is "
            "part of the format",
        ),
        ("SBGRG12_CSI2P", "did you mean SBGGR12_CSI2P, SGBRG12_CSI2P, SGRBG12_CSI2P or SRGGB12_CSI2P: the Bayer"),
        ("PISP_COMP1", "did you mean BGGR_PISP_COMP1, GBRG_PISP_COMP1, GRBG_PISP_COMP1 or RGGB_PISP_COMP1: "),
        ("SBGGR8_CSI2P", "unknown raw format 'SBGGR8_CSI2P'"),
        ("R10_CSI2P", "R10_CSI2P is a monochrome .greyscale. format: picamcal calibrates colour Bayer sensors"),
        ("r12", "r12 is a monochrome"),
        ("MONO_PISP_COMP1", "no colour crosstalk to unmix"),
    ],
)
def test_unknown_and_monochrome_format_names(tmp_path, name, message):
    path = tmp_path / "dump.raw"
    path.write_bytes(bytes(416 * 6))
    with pytest.raises(RawFormatError, match=message) as info:
        read_raw(path, raw_format=name, size=(320, 6))
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_format_names_are_case_insensitive_and_all_known_names_parse():
    assert {parse_raw_format(n.lower()).name for n in RAW_FORMATS} == set(RAW_FORMATS)
    assert parse_raw_format(" sgbrg16 ") == parse_raw_format("SGBRG16")


# --- sensors and black levels -----------------------------------------------------------------------------


def test_an_unknown_sensor_without_a_black_level_reads_and_is_refused_where_a_level_is_needed(tmp_path):
    mosaic = _mosaic(10, height=8, width=64)
    path = tmp_path / "imx298.raw"
    path.write_bytes(pack(mosaic, 10, 96).tobytes())
    raw = read_raw(path, raw_format="SRGGB10_CSI2P", size=(64, 8), sensor="imx298")
    np.testing.assert_array_equal(raw.bayer, mosaic)
    assert raw.sensor == "imx298" and raw.metadata["sensor_known"] is False
    assert raw.metadata["black_level_source"] == "none" and all(np.isnan(raw.black_level))
    with pytest.raises(RawFormatError, match="no black level") as info:
        require_black_level(raw)
    # The sensor was given: only a level can say its black level, not --sensor (calibrate adds its dark frame).
    message = str(info.value)
    assert message.startswith(str(path)) and "the black level of the imx298, a sensor outside its registry" in message
    assert message.endswith("give --black-level N")  # no dark frame: read_raw's callers may take none
    given = read_raw(path, raw_format="SRGGB10_CSI2P", size=(64, 8), sensor="imx298", black_level=[60, 61, 62, 63])
    require_black_level(given)
    assert given.black_level == (60.0, 61.0, 62.0, 63.0) and given.metadata["black_level_source"] == "given"


@pytest.mark.parametrize(
    ("sensor", "name", "bits", "black"),
    [
        ("imx219", "SBGGR10_CSI2P", 10, 64.0),  # imx219.json 4096 on the 16-bit scale
        ("IMX477", "SRGGB12_CSI2P", 12, 256.0),  # imx477.json 4096
        ("imx296", "SRGGB10_CSI2P", 10, 60.0),  # imx296.json 3840
        ("imx708_wide", "SRGGB10_CSI2P", 10, 64.0),  # picamera2's model of the wide Camera Module 3
    ],
)
def test_a_registry_sensor_gives_its_black_level(tmp_path, sensor, name, bits, black):
    path = tmp_path / "dump.raw"
    stride = default_strides(parse_raw_format(name), WIDTH)[0][0]
    path.write_bytes(_frame_bytes(_mosaic(bits), "_CSI2P", bits, stride))
    raw = read_raw(path, raw_format=name, size=(WIDTH, HEIGHT), sensor=sensor)
    assert raw.black_level == (black,) * 4 and raw.metadata["black_level_source"] == "registry"
    assert raw.metadata["sensor_known"] is True and raw.sensor == sensor.lower().removesuffix("_wide")


def test_a_pi5_16_bit_dump_of_a_known_sensor_is_shifted_to_its_bit_depth(tmp_path):
    mosaic = _mosaic(12)
    raw16 = RawImage(mosaic << 4, "RGGB", 0, 65535, 16)  # the Pi 5 front end writes 12 bits left-justified
    array, _, _ = to_picamera2(raw16, packed=False, align=64)
    path = tmp_path / "pi5.raw"
    path.write_bytes(array.tobytes())
    raw = read_raw(path, raw_format="SRGGB16", size=(WIDTH, HEIGHT), sensor="imx477")
    np.testing.assert_array_equal(raw.bayer, mosaic)  # exact: the low 4 bits are zero
    assert (raw.bit_depth, raw.black_level[0]) == (12, 256.0)
    unknown = read_raw(path, raw_format="SRGGB16", size=(WIDTH, HEIGHT))
    np.testing.assert_array_equal(unknown.bayer, mosaic << 4)  # no sensor, no bit depth: kept at 16 bits
    assert unknown.bit_depth == 16


def test_a_monochrome_sensor_is_refused(tmp_path):
    path = tmp_path / "ov9281.raw"
    path.write_bytes(bytes(96 * HEIGHT))
    with pytest.raises(RawFormatError, match="the OV9281 is a monochrome sensor"):
        read_raw(path, raw_format="SBGGR10_CSI2P", size=(WIDTH, HEIGHT), sensor="ov9281")


def test_the_bayer_order_can_be_overridden(tmp_path):
    path = tmp_path / "dump.raw"
    path.write_bytes(pack(_mosaic(10), 10, 64).tobytes())
    raw = read_raw(path, raw_format="SRGGB10_CSI2P", size=(WIDTH, HEIGHT), pattern="BGGR", black_level=64)
    assert (raw.pattern, raw.metadata["declared_pattern"], raw.black_level[0]) == ("BGGR", "RGGB", 64.0)


# --- nothing but RawFormatError, whatever the input ----------------------------------------------------------

_NAMES = st.one_of(
    st.sampled_from([*RAW_FORMATS, "R10_CSI2P", "MONO_PISP_COMP1", "YUV420", "SBGGR10P", "", "S", "BGGR"]),
    st.text(max_size=12),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    content=st.binary(min_size=0, max_size=1500),
    name=_NAMES,
    size=st.one_of(st.none(), st.tuples(st.integers(-4, 40), st.integers(-4, 12))),
    stride=st.one_of(st.none(), st.integers(-8, 200)),
    frame=st.one_of(st.none(), st.integers(-2, 6)),
    sensor=st.one_of(st.none(), st.sampled_from(["imx219", "imx477", "imx298", "ov9281", "imx708_wide", ""])),
)
def test_random_dumps_raise_only_raw_format_errors(tmp_path, content, name, size, stride, frame, sensor):
    path = tmp_path / "fuzz.raw"
    path.write_bytes(content)
    try:
        raw = _quiet_read(path, raw_format=name, size=size, stride=stride, frame=frame, sensor=sensor)
    except RawFormatError as exc:
        assert "\n" not in str(exc) and str(exc).startswith(str(path))
    else:
        assert raw.bayer.shape == (size[1], size[0]) and raw.metadata["frames"] * raw.metadata["stride"] * size[
            1
        ] == len(content)


def test_read_headless_is_what_read_raw_calls(tmp_path):
    path = tmp_path / "dump.bin"
    path.write_bytes(pack(_mosaic(10), 10, 64).tobytes())
    direct = read_headless(path, "SRGGB10_CSI2P", (WIDTH, HEIGHT), black_level=64)
    through = read_raw(path, raw_format="SRGGB10_CSI2P", size=(WIDTH, HEIGHT), black_level=64)
    np.testing.assert_array_equal(direct.bayer, through.bayer)
    assert direct.metadata == through.metadata


# --- the command line ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dumps(tmp_path_factory) -> Path:
    """The simulator's IMX219 references at 320x240, each as rpicam-raw would dump it (SBGGR10_CSI2P, stride 416).

    The sensor is not named anywhere: as far as picamcal can tell, an unknown sensor.
    """
    from picamcal.simulate import make_camera, simulate_references, simulate_target

    folder = tmp_path_factory.mktemp("dumps")
    camera = make_camera("imx219", size=(320, 240))
    frames = {**simulate_references(camera, seed=4), "target": simulate_target(camera, seed=5)[0]}
    for role, raw in frames.items():
        assert raw.pattern == "BGGR" and raw.bit_depth == 10
        (folder / f"{role}.raw").write_bytes(pack(raw.bayer, 10, 416).tobytes())
    video = [frames["target"].bayer, frames["white"].bayer, frames["black"].bayer]
    (folder / "video.raw").write_bytes(b"".join(pack(b, 10, 416).tobytes() for b in video))
    return folder


HEADLESS = ("--raw-format", "SBGGR10_CSI2P", "--size", "320x240")
DUMPS = ("white", "red", "green", "blue", "black", "target", "video")


@pytest.mark.slow
def test_cli_inspect_shows_the_frame_count(dumps):
    result = run("inspect", str(dumps / "video.raw"), *HEADLESS, "--json")
    assert result.returncode == 0, result.stderr
    (record,) = json.loads(result.stdout)
    assert (record["format"], record["frames"], record["width"], record["pattern"]) == ("headless", 3, 320, "BGGR")
    table = run("inspect", str(dumps / "video.raw"), *HEADLESS, "--frame", "2", "--sensor", "imx219")
    assert table.returncode == 0 and "frames" in table.stdout and "headless" in table.stdout


@pytest.mark.slow
def test_cli_calibrate_and_correct_headless_dumps_of_an_unknown_sensor(dumps, tmp_path):
    refs = [f"--{role}={dumps / f'{role}.raw'}" for role in ("white", "red", "green", "blue", "black")]
    cal = tmp_path / "cal.npz"
    # The dark frame gives the black level the dumps do not carry.
    result = run("calibrate", *refs, *HEADLESS, "--out", str(cal))
    assert result.returncode == 0, result.stderr
    out = tmp_path / "out"
    result = run("correct", str(cal), str(dumps / "target.raw"), *HEADLESS, "--black-level", "64", "--out", str(out))
    assert result.returncode == 0, result.stderr
    image = tifffile.imread(out / "target.tiff")
    assert image.shape == (240, 320, 3) and np.isfinite(image).all()
    # A folder gives its .raw files; frame 0 of the video is the target, and the registry's IMX219 black level is
    # the 64 given above: the same numbers (float32 maths on the same inputs, so compared exactly).
    folder = tmp_path / "folder"
    result = run("correct", str(cal), str(dumps), *HEADLESS, "--sensor", "imx219", "--out", str(folder))
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in folder.glob("*.tiff")) == [f"{s}.tiff" for s in sorted(DUMPS)]
    np.testing.assert_array_equal(tifffile.imread(folder / "target.tiff"), image)
    np.testing.assert_array_equal(tifffile.imread(folder / "video.tiff"), image)


@pytest.mark.parametrize(
    ("extra", "fragments"),
    [
        (("--raw-format", "SBGGR10_CSI2P", "--size", "320x242"), ["white.raw", "99840 bytes", "100672 bytes"]),
        (("--raw-format", "SBGGR10", "--size", "320x240"), ["white.raw", "153600 bytes", "--raw-format"]),
        (("--raw-format", "BAYER10", "--size", "320x240"), ["white.raw", "unknown raw format 'BAYER10'", "S<order>"]),
        (("--raw-format", "R10_CSI2P", "--size", "320x240"), ["white.raw", "monochrome"]),
        (
            ("--raw-format", "SBGGR10_CSI2P", "--size", "320x240", "--frame", "1"),
            ["white.raw", "past the end", "its only frame is --frame 0"],
        ),
    ],
)
@pytest.mark.slow
def test_cli_bad_headless_input_is_one_line_and_writes_nothing(dumps, tmp_path, extra, fragments):
    cal = tmp_path / "cal.npz"
    refs = [f"--{role}={dumps / f'{role}.raw'}" for role in ("white", "red", "green", "blue")]
    assert_bad_input(run("calibrate", *refs, *extra, "--out", str(cal)), *fragments)
    assert not cal.exists() and not list(tmp_path.iterdir())


@pytest.mark.slow
def test_cli_unknown_sensor_without_a_black_level_is_refused(dumps, tmp_path):
    cal = tmp_path / "cal.npz"
    refs = [f"--{role}={dumps / f'{role}.raw'}" for role in ("white", "red", "green", "blue")]
    result = run("calibrate", *refs, *HEADLESS, "--sensor", "imx298", "--out", str(cal))
    assert_bad_input(result, "white.raw", "no black level", "imx298, a sensor outside its registry", "--black FILE")
    assert "or --sensor" not in result.stderr  # it was given
    assert not cal.exists()


def test_the_docs_example_runs(tmp_path, monkeypatch):
    text = (Path(__file__).resolve().parents[1] / "docs" / "formats.md").read_text()
    section = text[text.index("## Headless raw dumps") : text.index("## The sensor registry")]
    (block,) = re.findall(r"```python\n(.*?)```", section, re.DOTALL)
    monkeypatch.chdir(tmp_path)
    exec(compile(block, "docs/formats.md", "exec"), {})
    assert (tmp_path / "white.raw").stat().st_size == 2 * 416 * 240
