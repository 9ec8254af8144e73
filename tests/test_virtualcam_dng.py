"""picamera2's DNGs: written on the virtual camera as a Pi writes them, and read by picamcal from both picamera2
generations (issue 31).

picamera2 writes DNGs through PiDNG (``Helpers.save_dng``). Since 0.3.28 it gives PiDNG the sensor's name as the
DNG's Model and, since 0.3.32, a file object to write into, which only Raspberry Pi OS's PiDNG takes; the virtual
camera gives picamera2 that interface over the PiDNG the ``virtual-camera`` extra installs (PyPI's 4.0.9:
:mod:`picamcal.virtualcam.raspios_pidng`). Earlier picamera2 DNGs (and picamera2 with PyPI's PiDNG on a Pi) have
the Model "PiDNG / PiCamera2" and name no sensor.

The tests that run picamera2 start a Python under ``picamcal virtual-camera`` (several seconds each: slow).
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from picamcal import PicamcalWarning, load_calibration, read_raw
from test_virtualcam_picamera2 import run_script

needs_picamera2 = pytest.mark.skipif(
    importlib.util.find_spec("picamera2") is None or importlib.util.find_spec("pidng") is None,
    reason="picamera2 and PiDNG are not installed (pip install 'picamcal[virtual-camera]')",
)
rawpy = pytest.importorskip("rawpy")

#: sRGB's linear RGB to XYZ (D65), by which a DNG's ColorMatrix1 (XYZ to camera) is made from the IPA's colour
#: matrix (camera to sRGB) and the white balance's gains: ColorMatrix1 = inverse(M_srgb_to_xyz . CCM . diag(gains)).
SRGB_TO_XYZ = np.array(
    [[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]]
)

CAPTURE = """
import json, warnings
import numpy as np
from picamera2 import Picamera2
from picamcal.raw import from_picamera2

warnings.simplefilter("ignore")  # picamcal's note that the Pi 5's compressed raw is lossy
picam2 = Picamera2()
picam2.configure(picam2.create_still_configuration(raw={}))
picam2.start()
with picam2.captured_request() as request:
    request.save_dng("request.dng")
    config, metadata = request.config["raw"], request.get_metadata()
    picam2.helpers.save_dng(request.make_buffer("raw"), metadata, config, "helpers.dng")
    np.save("raw.npy", from_picamera2(request.make_array("raw"), config, metadata).bayer)
picam2.capture_file("refs/white.dng", name="raw")
model = picam2.camera_properties["Model"]
picam2.close()
keys = ("SensorBlackLevels", "ColourCorrectionMatrix", "ColourGains")
json.dump({"format": config["format"], "model": model,
           "metadata": {k: metadata[k] for k in keys}}, open("capture.json", "w"))
"""

FAIL_THEN_CAPTURE = """
import sys, time
from picamera2 import Picamera2

picam2 = Picamera2()
picam2.configure(picam2.create_preview_configuration(raw={}))
picam2.start()
try:
    picam2.capture_file("missing/white.dng", name="raw")
except OSError as exc:
    print("failed:", type(exc).__name__)
start = time.monotonic()
raw = picam2.capture_array("raw")
picam2.capture_file("white.dng", name="raw")
print("captured again:", raw.shape, f"{time.monotonic() - start:.3f} s")
# A still configuration has one buffer, and the failed job kept it (picamera2 releases a job's request only when
# the job succeeds), on a Pi as here: stopping the camera gives it back.
picam2.switch_mode(picam2.create_still_configuration(raw={}))
try:
    picam2.capture_file("missing/white.dng", name="raw")
except OSError as exc:
    print("failed:", type(exc).__name__)
time.sleep(7)  # the camera, every request held, warns once that no frame can come
picam2.stop()
picam2.start()
print("after a restart:", picam2.capture_array("raw").shape)
picam2.close()
"""


def colour_matrix(ccm: list[float], gains: list[float]) -> np.ndarray:
    """The ColorMatrix1 a Pi's picamera2 writes for a frame of this colour matrix and these gains."""
    return np.linalg.inv(SRGB_TO_XYZ @ np.reshape(ccm, (3, 3)) @ np.diag([gains[0], 1.0, gains[1]])).ravel()


@needs_picamera2
@pytest.mark.slow
@pytest.mark.parametrize("platform", ["pisp", "vc4"])
def test_picamera2_writes_a_dng_as_a_pi_writes_it_and_picamcal_calibrates_it(tmp_path, platform):
    (tmp_path / "refs").mkdir()
    result = run_script(tmp_path, CAPTURE, "--size", "640x480", "--platform", platform)
    assert result.returncode == 0, result.stderr
    captured = json.loads((tmp_path / "capture.json").read_text())
    metadata = captured["metadata"]
    bayer = np.load(tmp_path / "raw.npy")
    # The Pi 5 gives its compressed raw decompressed to 16 bits, the Pi 4 the sensor's 12.
    bits = 16 if platform == "pisp" else 12
    assert (captured["format"], captured["model"]) == (
        {"pisp": "BGGR_PISP_COMP1", "vc4": "SBGGR12_CSI2P"}[platform],
        "imx477",
    )
    for name in ("request.dng", "helpers.dng"):
        path = tmp_path / name
        raw = read_raw(path)
        # As a Pi writes it: the sensor's name as Model, its black level (the IPA's 16-bit levels at the DNG's bit
        # depth), the raw stream's Bayer order (the HQ camera flipped: BGGR) and the colour matrix of the frame.
        assert (raw.metadata["model"], raw.sensor, raw.pattern, raw.bit_depth) == ("imx477", "imx477", "BGGR", bits)
        assert raw.black_level == tuple(float(b >> (16 - bits)) for b in metadata["SensorBlackLevels"])
        # PiDNG writes each entry as a rational over 10000, truncated: 1e-4 apart at most.
        expected = colour_matrix(metadata["ColourCorrectionMatrix"], metadata["ColourGains"])
        np.testing.assert_allclose(raw.metadata["color_matrix1"], expected, atol=1.01e-4)
        # The samples exactly as captured, read by picamcal and by LibRaw.
        np.testing.assert_array_equal(raw.bayer, bayer)
        with rawpy.imread(str(path)) as libraw:
            np.testing.assert_array_equal(libraw.raw_image_visible, bayer)
            assert list(libraw.black_level_per_channel) == list(raw.black_level)
    # picamcal calibrate takes the white picamera2 wrote with no option.
    calibrated = subprocess.run(
        [sys.executable, "-m", "picamcal", "calibrate", "refs"], capture_output=True, text=True, cwd=tmp_path
    )
    assert calibrated.returncode == 0, calibrated.stderr
    assert load_calibration(tmp_path / "calibration.npz").sensor == "imx477"


@needs_picamera2
@pytest.mark.slow
@pytest.mark.parametrize("platform", ["pisp", "vc4"])
def test_a_capture_after_a_failing_capture_job_completes(tmp_path, platform):
    result = run_script(tmp_path, FAIL_THEN_CAPTURE, "--size", "640x480", "--platform", platform)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == 4 and lines[0] == lines[2] == "failed: FileNotFoundError", result.stdout
    assert lines[1].startswith("captured again: (480, ") and lines[3].startswith("after a restart: (480, ")
    assert read_raw(tmp_path / "white.dng").sensor == "imx477"
    # While the one buffer was held, the virtual camera said why no frame came, once; with two it never starved.
    starved = [line for line in result.stderr.splitlines() if "no request queued" in line]
    assert len(starved) == 1 and "failed picamera2 capture job" in starved[0], result.stderr


# -- the DNGs of both picamera2 generations, written by the installed PiDNG as picamera2 calls it -----------------


def pidng_dng(path: Path, bayer: np.ndarray, model: str | None, black_level: bool = True) -> Path:
    """A DNG as picamera2's ``save_dng`` makes it with PiDNG: of an unpacked 10-bit RGGB frame, the IMX477's 16-bit
    black levels in the metadata; with ``model`` the later picamera2's (the sensor's name as Model), without it the
    earlier's; without ``black_level`` the tag left out, as some PiDNG files have it."""
    from pidng.camdefs import Picamera2Camera
    from pidng.core import PICAM2DNG
    from pidng.dng import Tag

    from picamcal.virtualcam.raspios_pidng import with_file_output, with_model

    height, width = bayer.shape
    config = {"format": "SRGGB10", "size": (width, height), "stride": 2 * width, "framesize": 2 * width * height}
    metadata = {
        "SensorBlackLevels": (4096,) * 4,
        "ColourGains": (1.8, 1.5),
        "ColourCorrectionMatrix": (1.6, -0.4, -0.2, -0.3, 1.5, -0.2, 0.0, -0.5, 1.5),
        "ExposureTime": 10000,
        "AnalogueGain": 1.0,
        "DigitalGain": 1.0,
        "SensorTimestamp": 1,
    }
    camera = with_model(Picamera2Camera)(config, metadata, *([model] if model else []))
    if not black_level:
        for tag in (Tag.BlackLevel, Tag.BlackLevelRepeatDim):
            del camera.tags.__tags__[tag]
    converter = with_file_output(PICAM2DNG)(camera)
    converter.options(compress=False)
    with open(path, "wb") as file:
        converter.convert(bayer.astype("<u2").view(np.uint8), file=file)
    return path


@pytest.fixture(scope="module")
def frame() -> np.ndarray:
    """A 10-bit frame of the HQ camera's 1332x990 mode (no other sensor has it) whose darkest pixel is 73 DN."""
    return np.random.default_rng(1).integers(73, 1000, (990, 1332)).astype(np.uint16)


@needs_picamera2
def test_picamcal_reads_the_dngs_of_both_picamera2_generations(tmp_path, frame):
    earlier, later = (
        pidng_dng(tmp_path / "earlier.dng", frame, None),
        pidng_dng(tmp_path / "later.dng", frame, "imx477"),
    )
    with pytest.warns(
        PicamcalWarning, match="frames of 1332x990 that do not name their sensor are taken as the imx477"
    ):
        first = read_raw(earlier)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PicamcalWarning)  # the sensor's name: nothing to guess, nothing to say
        second = read_raw(later)
    assert (first.metadata["model"], first.sensor, first.metadata["sensor_source"]) == (
        "PiDNG / PiCamera2",
        "imx477",
        "size",
    )
    assert (second.metadata["model"], second.sensor, "sensor_source" in second.metadata) == ("imx477", "imx477", False)
    for raw, path in ((first, earlier), (second, later)):
        assert (raw.pattern, raw.bit_depth, raw.black_level) == ("RGGB", 10, (64.0,) * 4)  # 4096 >> 6
        np.testing.assert_array_equal(raw.bayer, frame)
        with rawpy.imread(str(path)) as libraw:
            np.testing.assert_array_equal(libraw.raw_image_visible, frame)


@needs_picamera2
def test_a_pidng_dng_without_black_level_takes_its_sensors_told_by_size_and_says_so(tmp_path, frame):
    path = pidng_dng(tmp_path / "white.dng", frame, None, black_level=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        raw = read_raw(path)
    said = [str(w.message) for w in caught]
    # Not "no pixel is darker than 73 DN ... pass --black-level 73": the IMX477's 64 DN at 10 bits, said so.
    assert (raw.sensor, raw.black_level, raw.metadata["black_level_source"]) == ("imx477", (64.0,) * 4, "registry")
    # The sensor told by its size (that warning is read_raw's) and the black level taken from it, both said.
    assert said[-1] == (
        "DNGs of the imx477 without a BlackLevel tag are taken at the sensor's black level, 64 DN at 10 bits (not "
        "the DNG default, 0): give --black-level N if theirs is another"
    )
    assert len(said) == 2 and "1332x990" in said[0] and "imx477" in said[0]
    # The same file named by its model, and the level given: the sensor's name or the level given wins, quietly.
    named = pidng_dng(tmp_path / "named.dng", frame, "imx477", black_level=False)
    with pytest.warns(PicamcalWarning, match="DNGs of the imx477 without a BlackLevel tag"):
        assert read_raw(named).black_level == (64.0,) * 4
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert read_raw(path, black_level=70).black_level == (70.0,) * 4
