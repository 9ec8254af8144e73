"""Live unmixing (picamcal.live): the same codes as correct_processed on the same frame, in place, in every
picamera2 byte order, through a stand-in for picamera2's request and MappedArray; bad streams refused at start-up."""

from __future__ import annotations

import re
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

import picamcal
from picamcal.correct import correct_processed
from picamcal.errors import CalibrationFileError, PicamcalError, PicamcalWarning
from picamcal.export.isp import apply_tuning, calibration_colour_gains, processed_inputs
from picamcal.export.tuning import export_tuning, load_tuning, stock_tuning_path
from picamcal.kernels import numba_available
from picamcal.live import STREAM_FORMATS, LiveStreamError, LiveUnmixer, stream_format, tone_curve_tables
from picamcal.raw.processed import linearise
from picamcal.simulate import make_camera, simulate_references, simulate_target

ROOT = Path(__file__).resolve().parents[1]
ENGINES = ["numpy"] + (["numba"] if numba_available() else [])
STREAM = (160, 120)  # a half-size stream of the 320 x 240 simulated sensor, as the ISP scales its output


@pytest.fixture(scope="module")
def setup():
    """A simulated calibration, the tuning exported from it (adaptive contrast off), and one ISP output frame."""
    camera = make_camera("imx219", size=(320, 240))
    refs = simulate_references(camera, seed=1)
    cal = picamcal.calibrate(**refs)
    tuning = export_tuning(cal, load_tuning(stock_tuning_path("imx219", "pisp")), ccm=True)
    for algorithm in tuning["algorithms"]:
        if "rpi.contrast" in algorithm:
            algorithm["rpi.contrast"]["ce_enable"] = 0
    gains = calibration_colour_gains(cal)
    target, _ = simulate_target(camera, seed=2)
    linear = apply_tuning(target, tuning, colour_gains=gains, ccm=True)
    linear = linear.reshape(120, 2, 160, 2, 3).mean(axis=(1, 3))  # the ISP's 2 x 2 downscale
    curve = _gamma_curve(tuning)
    rgb = np.clip(np.floor(np.interp(np.clip(linear, 0, 1), *curve) * 255 + 0.5), 0, 255).astype(np.uint8)
    return {"cal": cal, "tuning": tuning, "gains": gains, "rgb": rgb, "curve": curve, "refs": refs}


def _gamma_curve(tuning) -> tuple[np.ndarray, np.ndarray]:
    """(linear, encoded) points of the tuning's rpi.contrast curve, independently of picamcal.live."""
    section = next(a["rpi.contrast"] for a in tuning["algorithms"] if "rpi.contrast" in a)
    curve = np.asarray(section["gamma_curve"], dtype=np.float64) / 65535.0
    return curve[0::2], curve[1::2]


def reference_codes(setup, rgb: np.ndarray) -> np.ndarray:
    """correct_processed on the decoded frame, encoded with the exact inverse curve and rounded: the file path."""
    linear_points, encoded_points = setup["curve"]
    decoded = np.interp(rgb.astype(np.float32) / 255.0, encoded_points, linear_points).astype(np.float32)
    inputs = processed_inputs(setup["tuning"], setup["cal"], decoded, colour_gains=setup["gains"])
    corrected = correct_processed(decoded, setup["cal"], "centre", **inputs)
    encoded = np.interp(np.clip(corrected, 0, 1), linear_points, encoded_points)
    return np.clip(np.floor(encoded * 255 + 0.5), 0, 255).astype(np.uint8)


def pack(rgb: np.ndarray, name: str) -> np.ndarray:
    """An (H, W, 3) R, G, B image in a picamera2 format's byte order (written here from the manual's table)."""
    order = {"RGB888": "BGR", "BGR888": "RGB", "XBGR8888": "RGBX", "XRGB8888": "BGRX"}[name]
    frame = np.full((*rgb.shape[:2], len(order)), 77, np.uint8)  # 77: a padding byte the unmixer must not touch
    for at, channel in enumerate(order):
        if channel != "X":
            frame[..., at] = rgb[..., "RGB".index(channel)]
    return frame


def unpack(frame: np.ndarray, name: str) -> np.ndarray:
    order = {"RGB888": "BGR", "BGR888": "RGB", "XBGR8888": "RGBX", "XRGB8888": "BGRX"}[name]
    return np.stack([frame[..., order.index(channel)] for channel in "RGB"], axis=-1)


@pytest.fixture(scope="module")
def prepared(setup):
    """One unmixer per engine for RGB888 (the field and tables are the same for every format)."""
    return {
        engine: LiveUnmixer.prepare(
            setup["cal"], STREAM, "RGB888", tuning=setup["tuning"], colour_gains=setup["gains"], engine=engine
        )
        for engine in ENGINES
    }


def with_format(unmixer: LiveUnmixer, name: str) -> LiveUnmixer:
    return LiveUnmixer(unmixer.size, stream_format(name), unmixer.field, unmixer.curve, unmixer.engine)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("name", list(STREAM_FORMATS))
def test_live_codes_equal_correct_processed_on_the_same_frame(setup, prepared, engine, name):
    # The decoding table is read_processed's own, the field is correct_processed's composed (float32 rounding,
    # below 1e-6 in linear value), and the encoding is the exact rounding: so the codes are those of the file
    # path but where that rounding puts a value on the other side of a code's edge. At most 1 code, in under
    # 1 value in 10000 (none on this frame).
    unmixer = with_format(prepared[engine], name)
    frame = pack(setup["rgb"], name)
    expected = reference_codes(setup, setup["rgb"])
    assert unmixer.apply(frame) is frame  # in place
    got = unpack(frame, name)
    difference = np.abs(got.astype(int) - expected)
    assert difference.max() <= 1 and np.count_nonzero(difference) <= expected.size // 10000
    assert np.count_nonzero(got != setup["rgb"]) > got.size // 2  # it did unmix: most codes moved
    if STREAM_FORMATS[name].bytes_per_pixel == 4:
        assert np.all(frame[..., 3] == 77)  # the padding byte is left as it was


@pytest.mark.skipif(not numba_available(), reason="numba is not installed")
def test_numba_and_numpy_give_the_same_codes_on_padded_rows(setup, prepared):
    # picamera2's rows are padded to the stride: the frame is a view with a row step above width * 3.
    # And with parallel=True, numba's threads share the rows.
    width, height = STREAM
    numba = prepared["numba"]
    threaded = LiveUnmixer(numba.size, numba.format, numba.field, numba.curve, "numba", parallel=True)
    buffers = []
    for unmixer in (numba, threaded, prepared["numpy"]):
        buffer = np.full((height, width * 3 + 64), 9, np.uint8)
        frame = buffer[:, : width * 3].reshape(height, width, 3)
        frame[...] = pack(setup["rgb"], "RGB888")
        unmixer.apply(frame)
        buffers.append(buffer)
    np.testing.assert_array_equal(buffers[0], buffers[2])
    np.testing.assert_array_equal(buffers[1], buffers[2])
    assert np.all(buffers[0][:, width * 3 :] == 9)  # the padding is not written


def test_the_tone_tables_round_exactly():
    # The table's guess moved up to the edges is the code whose interval holds the value, for every value (the
    # edges themselves and the float32 just below them included); and that code is round(255 * srgb(v)) but within
    # 1e-4 code of a rounding edge, where linearise's float32 decoding of the edge decides.
    curve = tone_curve_tables("srgb")
    inner = curve.edges[1:-1]
    values = np.concatenate([np.linspace(-0.1, 1.1, 200001, dtype=np.float32), inner, np.nextafter(inner, -1)])
    top = curve.encode.size - 1
    code = curve.encode[np.clip(values * np.float32(top), 0, top).astype(np.intp)].astype(np.intp)
    while np.any(up := values >= curve.edges[code + 1]):
        code += up
    np.testing.assert_array_equal(code, np.searchsorted(curve.edges, values, side="right") - 1)
    v = np.clip(values.astype(np.float64), 0, 1)
    exact = 255 * np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    clear = np.abs(exact - np.floor(exact) - 0.5) > 1e-4
    assert np.count_nonzero(clear) > 190000
    np.testing.assert_array_equal(code[clear], np.floor(exact + 0.5)[clear])
    assert np.array_equal(curve.decode, linearise(np.arange(256, dtype=np.float32) / 255.0, "srgb"))


@pytest.mark.skipif(not numba_available(), reason="numba is not installed")
@pytest.mark.parametrize(("encoding", "one_step"), [("srgb", True), ("imx477", True), ("gamma:2.2", False)])
def test_the_numba_kernel_rounds_exactly_at_every_edge_and_table_step(encoding, one_step):
    # On the sRGB curve and the Pi's gamma curves one comparison settles each code (the kernel without a loop); on
    # gamma 2.2, steeper than a code a table step near black, the kernel goes up edge by edge. Either way each value
    # gets the code whose interval holds it: the values are the edges, the float32 on either side of them, and the
    # table steps' bounds and their neighbours, taken through the kernel as one channel of a unit matrix.
    from picamcal.live.stream import _one_step

    tuning = load_tuning(stock_tuning_path("imx477", "pisp")) if encoding == "imx477" else None
    curve = tone_curve_tables(None if tuning else encoding, tuning)
    assert _one_step(curve) is one_step
    top = curve.encode.size - 1
    inner = curve.edges[1:-1]
    steps = (np.arange(top + 2) / top).astype(np.float32)
    values = np.concatenate(
        [inner, np.nextafter(inner, -1), np.nextafter(inner, 2), steps, np.nextafter(steps, -1), np.nextafter(steps, 2)]
    )
    values = np.concatenate([values, np.linspace(-0.1, 1.1, 100 * 256 - values.size % 256, dtype=np.float32)])
    height = -(-values.size // 256)
    values = np.resize(values, height * 256).astype(np.float32)
    field = np.zeros((height, 256, 9), np.float32)
    field[..., 0] = values.reshape(height, 256)  # red out = value x decoded 255 (exactly 1.0)
    assert curve.decode[255] == 1.0
    frame = np.full((height, 256, 3), 255, np.uint8)
    LiveUnmixer((256, height), STREAM_FORMATS["BGR888"], field, curve, "numba").apply(frame)
    expected = np.clip(np.searchsorted(curve.edges, values, side="right") - 1, 0, 255)
    np.testing.assert_array_equal(frame[..., 0].ravel(), expected)


def test_srgb_stream_without_a_tuning_is_only_unmixed(setup):
    # No tuning: the stream is taken as flat already, sRGB encoded, no colour matrix; a mid grey of the white
    # reference's colour stays grey at the centre, where U is near the identity (within 2 codes: U's own error).
    unmixer = LiveUnmixer.prepare(setup["cal"], STREAM, "BGR888", engine="numpy")
    frame = np.full((STREAM[1], STREAM[0], 3), 118, np.uint8)
    unmixer.apply(frame)
    assert np.all(np.abs(frame[50:70, 70:90].astype(int) - 118) <= 2)


class FakeMappedArray:
    """picamera2's MappedArray for a stand-in request: the buffer as (h, stride) rows cut to (h, w, bytes per pixel),
    as picamera2.request.MappedArray reshapes the RGB formats (a view on the buffer, so writes reach it)."""

    def __init__(self, request: FakeRequest, stream: str) -> None:
        self.request, self.stream = request, stream
        self.array: np.ndarray | None = None

    def __enter__(self) -> FakeMappedArray:
        config = self.request.config[self.stream]
        (w, h), stride = config["size"], config["stride"]
        step = 4 if config["format"].startswith("X") else 3
        rows = self.request.buffers[self.stream][: h * stride].reshape(h, stride)
        self.array = rows[:, : w * step].reshape(h, w, step)
        self.request.mapped += 1
        return self

    def __exit__(self, *exc: object) -> None:
        self.array = None


class FakeRequest:
    """What a picamera2 CompletedRequest gives a pre_callback: ``config`` per stream and the buffers behind it."""

    def __init__(self, frame: np.ndarray, name: str, stride_padding: int = 64) -> None:
        height, width, step = frame.shape
        stride = width * step + stride_padding
        buffer = np.zeros(height * stride, np.uint8)
        buffer.reshape(height, stride)[:, : width * step] = frame.reshape(height, width * step)
        self.config = {"main": {"format": name, "size": (width, height), "stride": stride}}
        self.buffers = {"main": buffer}
        self.mapped = 0

    def frame(self) -> np.ndarray:
        config = self.config["main"]
        (w, h), stride = config["size"], config["stride"]
        step = 4 if config["format"].startswith("X") else 3
        return self.buffers["main"].reshape(h, stride)[:, : w * step].reshape(h, w, step)


@pytest.mark.parametrize("name", ["XBGR8888", "RGB888"])
def test_the_callback_unmixes_the_request_buffer_in_place(setup, prepared, name):
    engine = ENGINES[-1]
    base = prepared[engine]
    unmixer = LiveUnmixer(base.size, stream_format(name), base.field, base.curve, engine, mapped_array=FakeMappedArray)
    request = FakeRequest(pack(setup["rgb"], name), name)
    before = request.buffers["main"].copy()
    unmixer.callback(request)
    unmixer.callback(FakeRequest(pack(setup["rgb"], name), name))  # the second frame: no new check, same work
    assert request.mapped == 1
    got = unpack(request.frame(), name)
    assert np.abs(got.astype(int) - reference_codes(setup, setup["rgb"])).max() <= 1
    width, height = STREAM
    step = STREAM_FORMATS[name].bytes_per_pixel
    padding = before.reshape(height, -1)[:, width * step :]
    np.testing.assert_array_equal(request.buffers["main"].reshape(height, -1)[:, width * step :], padding)


def test_the_callback_keeps_a_stream_of_another_size_as_its_error_and_never_raises(setup, prepared, caplog):
    # picamera2 calls it in its camera thread, where an exception would stop the camera (or abort Qt).
    unmixer = LiveUnmixer(
        (160, 120),
        STREAM_FORMATS["RGB888"],
        prepared["numpy"].field,
        prepared["numpy"].curve,
        "numpy",
        mapped_array=FakeMappedArray,
    )
    request = FakeRequest(np.zeros((480, 640, 3), np.uint8), "RGB888")
    before = request.buffers["main"].copy()
    unmixer.callback(request)
    unmixer.callback(request)  # later frames pass through, with no second line
    assert isinstance(unmixer.error, LiveStreamError)
    assert str(unmixer.error) == (
        "the main stream is 640x480 RGB888, but the unmixer was prepared for 160x120 RGB888: "
        'prepare it with size=(640, 480), format="RGB888"'
    )
    assert [record.getMessage() for record in caplog.records] == [f"{unmixer.error}; the frames pass through unmixed"]
    assert request.mapped == 0 and np.array_equal(request.buffers["main"], before)


def test_a_stream_of_another_byte_order_is_refused_by_its_configuration(prepared):
    # RGB888 and BGR888 frames have the same shape: only the configuration tells them apart.
    with pytest.raises(LiveStreamError, match="prepared for 160x120 RGB888"):
        prepared["numpy"].check_config({"main": {"format": "BGR888", "size": (160, 120), "stride": 480}})


@pytest.mark.parametrize(
    ("shape", "dtype"),
    [((240, 320, 3), np.uint8), ((120, 160, 4), np.uint8), ((120, 160, 3), np.uint16), ((120, 160), np.uint8)],
)
def test_frames_that_do_not_match_are_refused_naming_the_prepared_stream(prepared, shape, dtype):
    frame = np.zeros(shape, dtype)
    with pytest.raises(LiveStreamError, match=r"is not a 160x120 RGB888 frame, shape \(120, 160, 3\) uint8"):
        prepared["numpy"].apply(frame)
    assert not frame.any()


def test_read_only_and_unpacked_frames_are_refused(prepared):
    frame = np.zeros((120, 160, 3), np.uint8)
    frame.flags.writeable = False
    with pytest.raises(LiveStreamError, match="read-only"):
        prepared["numpy"].apply(frame)
    with pytest.raises(LiveStreamError, match="not packed in rows"):
        prepared["numpy"].apply(np.zeros((120, 160, 6), np.uint8)[..., ::2])


def test_unknown_formats_are_refused_at_prepare(setup):
    with pytest.raises(LiveStreamError, match=r"format YUV420: configure the stream as RGB888, BGR888, XBGR8888"):
        LiveUnmixer.prepare(setup["cal"], STREAM, "YUV420")
    with pytest.raises(LiveStreamError, match=r"RGB88 \(did you mean RGB888\?\)"):
        LiveUnmixer.prepare(setup["cal"], STREAM, "RGB88")


@pytest.mark.parametrize("size", [(0, 120), (160.5, 120), ("a", "b"), (200_000, 200_000)])
def test_bad_sizes_are_refused_at_prepare(setup, size):
    with pytest.raises(LiveStreamError, match="stream"):
        LiveUnmixer.prepare(setup["cal"], size, "RGB888")


def test_a_flat_calibration_is_refused_at_prepare(setup):
    flat = picamcal.calibrate(setup["refs"]["white"], black=setup["refs"]["black"])
    with pytest.raises(CalibrationFileError, match="has no colour unmixing for live unmixing"):
        LiveUnmixer.prepare(flat, STREAM, "RGB888")
    with pytest.raises(PicamcalError, match="mode flat has no unmixing to apply live"):
        LiveUnmixer.prepare(setup["cal"], STREAM, "RGB888", mode="flat")


def test_a_crop_of_another_aspect_ratio_is_refused_at_prepare(setup):
    with pytest.raises(PicamcalError, match="aspect ratios differ"):
        LiveUnmixer.prepare(setup["cal"], STREAM, "RGB888", crop=(0, 0, 320, 120))


def test_adaptive_contrast_is_warned_about(setup):
    tuning = export_tuning(setup["cal"], load_tuning(stock_tuning_path("imx219", "pisp")))
    with pytest.warns(PicamcalWarning, match="ce_enable"):
        LiveUnmixer.prepare(setup["cal"], STREAM, "RGB888", tuning=tuning, engine="numpy")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        LiveUnmixer.prepare(setup["cal"], STREAM, "RGB888", tuning=setup["tuning"], engine="numpy")


def test_the_docs_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text = (ROOT / "docs" / "live.md").read_text()
    blocks = [textwrap.dedent(b) for b in re.findall(r"```python\n(.*?)```", text, re.DOTALL)]
    assert blocks
    namespace: dict = {}
    exec(compile(blocks[0], "docs/live.md", "exec"), namespace)
    assert namespace["difference"] <= 1
