"""Processed (ISP output) images: reading, undoing the tone curve, and correcting only what the ISP did not."""

from __future__ import annotations

import json

import numpy as np
import png
import pytest
import tifffile
from PIL import Image

from picamcal import PicamcalError, RawFormatError, calibrate, correct, load_calibration
from picamcal.analysis.metrics import encode_srgb, wheel_figures
from picamcal.batch import BatchOptions, run_batch
from picamcal.correct import correct_processed
from picamcal.export.isp import apply_tuning, processed_inputs
from picamcal.export.tuning import load_tuning, stock_tuning_path
from picamcal.raw.processed import linearise, read_processed, tuning_gamma_curve
from picamcal.simulate import make_camera, simulate_references, simulate_target

TUNING = {
    "version": 2.0,
    "target": "bcm2835",
    "algorithms": [{"rpi.contrast": {"gamma_curve": [0, 0, 16384, 40000, 65535, 65535]}}],
}


def _srgb16(linear: np.ndarray) -> np.ndarray:
    v = np.clip(linear, 0, 1)
    return np.round(65535 * np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)).astype(np.uint16)


def test_linearise_encodings(tmp_path):
    v = np.linspace(0, 1, 11)
    np.testing.assert_allclose(linearise(v, "linear"), v, atol=1e-7)
    np.testing.assert_allclose(linearise(v, "gamma:2.2"), v**2.2, rtol=1e-5)
    srgb = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(linearise(srgb, "srgb"), v, atol=1e-6)  # the sRGB curve undone exactly
    path = tmp_path / "tuning.json"
    path.write_text(json.dumps(TUNING))
    np.testing.assert_allclose(linearise(np.array([40000 / 65535, 1.0]), f"tuning:{path}"), [16384 / 65535, 1.0])
    for bad in ("gamma:x", "gamma:50", "log", "tuning:"):
        with pytest.raises(PicamcalError):
            linearise(v, bad)


def test_real_tuning_curves_are_invertible():
    from pathlib import Path

    files = sorted((Path(__file__).resolve().parent / "data" / "libcamera-tuning").glob("*/*.json"))
    assert len(files) == 8  # vc4 and pisp, four sensors each
    for path in files:
        linear, encoded = tuning_gamma_curve(path)
        assert linear[0] == 0 and linear[-1] == pytest.approx(1.0, abs=1e-4)
        assert np.all(np.diff(encoded) >= 0)


def test_reads_jpeg_png8_png16_and_tiff(tmp_path):
    rng = np.random.default_rng(0)
    data16 = rng.integers(0, 65536, (12, 16, 3), dtype=np.uint16)
    with open(tmp_path / "a.png", "wb") as f:
        png.Writer(16, 12, bitdepth=16, greyscale=False).write(f, data16.reshape(12, -1))
    tifffile.imwrite(tmp_path / "a.tiff", data16, photometric="rgb")
    Image.fromarray((data16 >> 8).astype(np.uint8)).save(tmp_path / "b.png")
    Image.fromarray((data16 >> 8).astype(np.uint8)).save(tmp_path / "c.jpg", quality=95)
    for name, bits in (("a.png", 16), ("a.tiff", 16), ("b.png", 8)):
        image = read_processed(tmp_path / name, "linear")
        expected = data16 / 65535 if bits == 16 else (data16 >> 8) / 255
        np.testing.assert_allclose(image.rgb, expected, atol=1e-6)  # every bit of a 16-bit PNG survives
        assert image.bit_depth == bits
    jpeg = read_processed(tmp_path / "c.jpg", "linear")
    assert jpeg.metadata["format"] == "jpeg" and jpeg.rgb.shape == (12, 16, 3)


def test_bad_processed_files(tmp_path):
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(RawFormatError, match="empty file"):
        read_processed(tmp_path / "empty.png")
    (tmp_path / "junk.jpg").write_bytes(b"\xff\xd8\xff not really")
    with pytest.raises(RawFormatError, match=r"junk\.jpg: (cannot decode|not an image)"):
        read_processed(tmp_path / "junk.jpg")
    tifffile.imwrite(tmp_path / "grey.tiff", np.zeros((4, 4), np.uint16))
    with pytest.raises(RawFormatError, match="expected an RGB image"):
        read_processed(tmp_path / "grey.tiff")


@pytest.fixture(scope="module")
def isp():
    """A simulated camera, its calibration, and the flat-fielded linear target as an ISP with our table gives it."""
    camera = make_camera("imx219", size=(640, 480))
    cal = calibrate(**simulate_references(camera, noise=False))
    target, layout = simulate_target(camera, noise=False)
    return cal, target, layout


def test_unmixing_a_processed_image_matches_the_raw_correction(isp, tmp_path):
    cal, target, layout = isp
    flat = correct(target, cal, "flat")  # what the ISP outputs with the exported table and frozen gains
    with open(tmp_path / "isp.png", "wb") as f:  # 16-bit sRGB, as a careful user would save it
        png.Writer(640, 480, bitdepth=16, greyscale=False).write(f, _srgb16(flat / 1.2).reshape(480, -1))
    processed = read_processed(tmp_path / "isp.png", "srgb")
    rgb = correct_processed(processed, cal, "centre") * 1.2
    # 16-bit encoding costs almost nothing: the corner wheels match the centre as well as from raw.
    assert wheel_figures(rgb, layout)["max_delta_e"] < 1.0
    assert wheel_figures(correct_processed(processed, cal, "flat") * 1.2, layout)["max_delta_e"] > 5


def test_processed_8_bit_jpeg_quality_still_improves(isp, tmp_path):
    cal, target, layout = isp
    Image.fromarray(encode_srgb(correct(target, cal, "flat"))).save(tmp_path / "isp.jpg", quality=92)
    processed = read_processed(tmp_path / "isp.jpg", "srgb")
    before = wheel_figures(processed.rgb, layout)["max_delta_e"]
    after = wheel_figures(correct_processed(processed, cal, "centre"), layout)["max_delta_e"]
    # JPEG compression and 8 bits limit what unmixing can restore, but it must still remove most of the error.
    assert after < 0.35 * before, (before, after)


def test_residual_flat_from_a_processed_white_and_a_colour_matrix(isp):
    cal, target, layout = isp
    camera_white = simulate_references(make_camera("imx219", size=(640, 480)), noise=False)["white"]
    ccm = np.array([[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [-0.1, -0.5, 1.6]])
    # An ISP that applied only colour balance (no lens shading) and then a colour matrix.
    isp_target = np.einsum("pq,yxq->yxp", ccm, correct(target, cal, "uncorrected"))
    isp_white = np.einsum("pq,yxq->yxp", ccm, correct(camera_white, cal, "uncorrected"))
    rgb = correct_processed(isp_target, cal, "centre", white=isp_white, ccm=ccm)
    rgb = np.einsum("pq,yxq->yxp", np.linalg.inv(ccm), rgb)  # back to camera colours to compare with raw
    assert wheel_figures(rgb, layout)["max_delta_e"] < 1.5


def test_scaled_image_maps_to_the_sensor(isp):
    cal, target, layout = isp
    flat = correct(target, cal, "flat")
    half = flat.reshape(240, 2, 320, 2, 3).mean(axis=(1, 3))  # the ISP's half-size output
    half_layout = json.loads(json.dumps(layout))
    half_layout.update(width=320, height=240)
    for wheel in half_layout["wheels"]:
        wheel.update(x=(wheel["x"] + 0.5) / 2 - 0.5, y=(wheel["y"] + 0.5) / 2 - 0.5, radius=wheel["radius"] / 2)
    assert wheel_figures(correct_processed(half, cal, "centre"), half_layout)["max_delta_e"] < 1.0


def test_processed_geometry_errors(isp):
    cal, *_ = isp
    with pytest.raises(PicamcalError, match="aspect ratios differ"):
        correct_processed(np.ones((100, 100, 3), np.float32), cal)
    with pytest.raises(PicamcalError, match="outside"):
        correct_processed(np.ones((48, 64, 3), np.float32), cal, crop=(600, 0, 64, 48))
    with pytest.raises(PicamcalError, match="white reference is"):
        correct_processed(np.ones((48, 64, 3), np.float32), cal, white=np.ones((24, 32, 3)))


def test_the_library_recipe_gives_what_the_batch_writes_for_a_processed_image(tmp_path):
    """``processed_inputs`` is the recipe ``correct --processed --tuning`` applies: the same float32 values."""
    camera = make_camera("imx219", size=(320, 240))
    calibrate(**simulate_references(camera, seed=2)).save(tmp_path / "cal.npz")
    cal = load_calibration(tmp_path / "cal.npz")
    tuning_path = stock_tuning_path("imx219", "pisp")
    tuning = load_tuning(tuning_path)
    # An ISP's half-size output: the tuning file's lens shading and CCM, its own tone curve, 16-bit PNG.
    isp = (
        apply_tuning(simulate_target(camera, seed=3)[0], tuning, ccm=True).reshape(120, 2, 160, 2, 3).mean(axis=(1, 3))
    )
    linear, encoded = tuning_gamma_curve(tuning_path)
    codes = np.round(65535 * np.interp(np.clip(isp / isp.max(), 0, 1), linear, encoded)).astype(np.uint16)
    with open(tmp_path / "isp.png", "wb") as f:
        png.Writer(160, 120, bitdepth=16, greyscale=False).write(f, codes.reshape(120, -1))

    options = BatchOptions(out_dir=tmp_path / "out", processed=True, tuning=tuning_path, workers=0)
    result = run_batch(tmp_path / "cal.npz", [tmp_path / "isp.png"], options)
    assert result.done == [tmp_path / "isp.png"] and not result.failed
    image = read_processed(tmp_path / "isp.png", f"tuning:{tuning_path}")
    library = correct_processed(image, cal, "centre", **processed_inputs(tuning, cal, image))
    # Bit for bit: one recipe, in the library, used by the batch (a copy that drifted would differ in the gains).
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "out" / "isp.tiff"), library)
    # And the recipe matters: without the tuning file's gains and CCM a typical pixel is off by about a quarter
    # (measured: median 24 %); 5 % leaves room for other simulations while still catching an ignored recipe.
    plain = correct_processed(image, cal, "centre")
    assert np.median(np.abs(library - plain) / np.maximum(np.abs(plain), 1e-3)) > 0.05
