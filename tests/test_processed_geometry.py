"""Where a processed image lies on the sensor (issue 30, item 3), on small simulated cameras: the ISP's gains taken
for the sensor mode and sampled at the ScalerCrop, the stream mapped through the mode (crop, binning, flips) into the
calibration's image, and what is refused. The same paths through the real picamera2 are tests/test_live_modes.py and
tests/test_processed_modes.py."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from picamcal import calibrate, correct
from picamcal.correct import correct_processed
from picamcal.errors import CalibrationFileError, PicamcalError
from picamcal.export.isp import (
    isp_gains_for_image,
    lens_shading_gains,
    processed_geometry,
    processed_inputs,
)
from picamcal.export.tuning import load_tuning, stock_tuning_path
from picamcal.geometry import SensorMode, default_scaler_crop, named_mode
from picamcal.raw.processed import ProcessedImage
from picamcal.simulate import make_camera, simulate_references, simulate_target


@pytest.fixture(scope="module")
def tuning():
    return load_tuning(stock_tuning_path("imx219", "pisp"))


@pytest.fixture(scope="module")
def small():
    camera = make_camera("imx219", size=(320, 240))
    cal = calibrate(**simulate_references(camera, seed=1))
    target, _ = simulate_target(camera, seed=2)
    return cal, target


def test_the_whole_mode_at_its_own_size_gets_the_modes_own_gains(tuning):
    # The stream is the mode's image itself: its pixels are the mode's, so are its gains (to float32 rounding).
    mode = SensorMode.full(640, 480, binning=2)
    stream = isp_gains_for_image(tuning, mode, (320, 240))
    np.testing.assert_allclose(stream, lens_shading_gains(tuning, 320, 240, mode=mode), rtol=0, atol=1e-6)


def test_a_zoom_takes_the_modes_gains_where_it_lies(tuning):
    # libcamera computes the tables for the mode and the ISP crops after them: a 2x zoom at the zoom's own scale
    # shows the mode's pixels 80.. and 60.. and their gains. Taking the ScalerCrop for the mode's crop (the bug) made
    # new tables over the zoom, normalised there (2.9 % off here with the stock tables; with the exported ones of the
    # issue's run the white's centre came out R/G 1.7).
    mode = SensorMode.full(640, 480, binning=2)
    whole = lens_shading_gains(tuning, 320, 240, mode=mode)
    zoom = isp_gains_for_image(tuning, mode, (160, 120), scaler_crop=(160, 120, 320, 240))
    np.testing.assert_allclose(zoom, whole[60:180, 80:240], rtol=0, atol=1e-6)
    as_a_mode = lens_shading_gains(tuning, 160, 120, mode=SensorMode(640, 480, (160, 120, 320, 240), binning=2))
    assert np.abs(as_a_mode / zoom - 1).max() > 0.02  # what the bug applied


def test_a_scaler_crop_outside_the_mode_or_the_sensor_is_one_line(tuning):
    mode = SensorMode(640, 480, (132, 134, 374, 210))
    with pytest.raises(PicamcalError, match=r"^ScalerCrop 0,0,640,480 lies outside the sensor mode's crop \(the "):
        isp_gains_for_image(tuning, mode, (374, 210), scaler_crop=(0, 0, 640, 480))
    with pytest.raises(PicamcalError, match=r"^ScalerCrop 600,0,100,100 lies outside the 640x480 sensor$"):
        isp_gains_for_image(tuning, mode, (100, 100), scaler_crop=(600, 0, 100, 100))


def test_libcameras_default_crop_for_a_stream_of_another_aspect_ratio():
    # boundedToAspectRatio, centredTo, scaleIspCrop in libcamera's integers (the virtual camera's metadata agrees:
    # tests/test_processed_modes.py).
    binned = named_mode("imx219", "1640x1232")
    assert default_scaler_crop(binned, (1640, 1232)) == (0, 0, 3280, 2464)
    assert default_scaler_crop(binned, (1920, 1080)) == (0, 310, 3280, 1844)
    assert default_scaler_crop(binned, (1000, 1000)) == (408, 0, 2464, 2464)


def test_a_zoomed_image_is_corrected_as_that_part_of_the_whole(small):
    cal, target = small
    flat = correct(target, cal, "flat")  # a camera whose lens shading came from cal
    whole = correct_processed(flat, cal, "centre")
    zoom = correct_processed(flat[60:180, 80:240], cal, "centre", crop=(80, 60, 160, 120))
    # The same pixels, each with its own bin's unmixing (the spline through the bin centres is the same function
    # however the image is cut; 1e-4 is float32 rounding of values near 1).
    np.testing.assert_allclose(zoom, whole[60:180, 80:240], rtol=0, atol=1e-4)
    misplaced = correct_processed(flat[60:180, 80:240], cal, "centre")  # taken for the whole sensor, scaled
    assert np.abs(misplaced - whole[60:180, 80:240]).max() > 0.05  # measured 0.136: the unmixing of other bins


def test_a_mirrored_camera_mode_maps_the_fields_mirrored(small):
    # The camera runs mirrored (hflip), the calibration was not: image column u is the calibration's 319 - u.
    cal, target = small
    flat = correct(target, cal, "flat")
    straight = correct_processed(flat, cal, "centre")
    mirrored = SensorMode(320, 240, (0, 0, 320, 240), hflip=True)
    got = correct_processed(flat[:, ::-1], cal, "centre", sensor_mode=mirrored)
    np.testing.assert_allclose(got, straight[:, ::-1], rtol=0, atol=1e-4)
    unflipped = correct_processed(flat[:, ::-1], cal, "centre")
    assert np.abs(unflipped - straight[:, ::-1]).max() > 0.01  # the flip matters: measured 0.029, and 1e-4 above


def test_a_stream_outside_the_calibrations_area_is_one_line_naming_the_image(small):
    cal, _ = small
    cropped = dataclasses.replace(cal, geometry=SensorMode(640, 480, (160, 120, 320, 240)))
    image = ProcessedImage(np.ones((240, 320, 3), np.float32), "linear", 8, {"path": "frame.png"})
    with pytest.raises(CalibrationFileError) as caught:
        correct_processed(image, cropped, "centre", sensor_mode=SensorMode.full(640, 480, binning=2))
    assert str(caught.value) == (
        "frame.png: image does not match the calibration: it shows the sensor area 640x480 at (0, 0), outside the "
        "calibration's 320x240 at (160, 120): calibrate in a mode that covers it (a full-sensor or binned mode covers "
        "every mode)"
    )
    with pytest.raises(PicamcalError, match=r"^frame.png: sensor crop \[600, 0, 100, 100\] lies outside the 320x240"):
        correct_processed(image, cal, "centre", crop=(600, 0, 100, 100))


@pytest.fixture(scope="module")
def imx219_binned_by_4():
    """A calibration of the whole IMX219 read 4 x 4 binned (820 x 616), so that the registry's modes apply to it."""
    cal = calibrate(**simulate_references(make_camera("imx219", size=(820, 616)), seed=1))
    return dataclasses.replace(cal, geometry=SensorMode.full(3280, 2464, binning=4, source="given"))


def test_an_image_of_a_cropped_modes_size_is_refused_until_its_mode_is_said(imx219_binned_by_4):
    cal = imx219_binned_by_4
    image = ProcessedImage(np.ones((480, 640, 3), np.float32), "linear", 8, {"path": "frame.png"})
    with pytest.raises(PicamcalError) as caught:
        processed_geometry(cal, image)
    assert str(caught.value) == (
        "frame.png: a 640x480 image may come from the imx219's 640x480 mode (the 1280x960 area at (1000, 752)) or "
        "show the calibration's whole area, scaled: say which with --sensor-mode 640x480, or --sensor-crop "
        "X,Y,WIDTH,HEIGHT (the sensor area it shows: picamera2's ScalerCrop)"
    )
    mode, crop = processed_geometry(cal, image, sensor_mode=named_mode("imx219", "640x480"))
    assert (mode.crop, mode.binning, crop) == ((1000, 752, 1280, 960), 2, (1000, 752, 1280, 960))
    assert processed_geometry(cal, image, crop=(0, 0, 3280, 2464))[1] == (0, 0, 3280, 2464)  # the whole, said
    assert processed_geometry(cal, np.ones((308, 410, 3)))[1] == (0, 0, 3280, 2464)  # a size no cropped mode has


def test_the_record_of_apply_tuning_places_the_image(imx219_binned_by_4, tuning):
    cal = imx219_binned_by_4
    mode = named_mode("imx219", "1920x1080")
    record = {"tuning": "t.json", "ccm": True, "sensor_mode": mode.to_record(), "scaler_crop": list(mode.crop)}
    image = ProcessedImage(np.ones((1080, 1920, 3), np.float32), "linear", 32, {"path": "isp.tiff", "picamcal": record})
    inputs = processed_inputs(tuning, cal, image)
    assert inputs["sensor_mode"].area() == mode.area() and inputs["crop"] == (680, 692, 1920, 1080)
    broken = ProcessedImage(image.rgb, "linear", 32, {"path": "isp.tiff", "picamcal": {**record, "sensor_mode": [1]}})
    with pytest.raises(PicamcalError, match=r"^isp.tiff: its recorded sensor_mode is not a sensor mode \("):
        processed_inputs(tuning, cal, broken)
