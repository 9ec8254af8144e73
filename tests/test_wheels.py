"""Tests of picamcal.analysis.wheels: finding the colour wheels, comparing them, and the paper's figures."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

from picamcal import calibrate, correct
from picamcal.analysis.metrics import wheel_figures
from picamcal.analysis.wheels import analyse, find_wheels, polar_plot, wheel_crops
from picamcal.errors import PicamcalError
from picamcal.modes import Mode
from picamcal.raw.model import site_channels
from picamcal.simulate import make_camera, simulate_references, simulate_target, wheel_scene
from picamcal.target import render_target, target_layout

SMALL = (640, 480)
MODES = tuple(mode.value for mode in Mode)
TARGET_NAMES = {"centre", "top-left", "top", "top-right", "left", "right", "bottom-left", "bottom", "bottom-right"}


def uncorrected(raw) -> np.ndarray:
    """A quick uncorrected linear RGB image of a raw frame: each 2x2 site's channels, repeated over it.

    Much faster than demosaicing a 12-megapixel frame, and as vignetted; balanced on the white at the
    middle of the left edge. Its channels are up to a pixel out of register, which moves the wheels by at
    most half a pixel.
    """
    mosaic = raw.black_subtracted()
    rgb = np.zeros((mosaic.shape[0] // 2, mosaic.shape[1] // 2, 3), dtype=np.float32)
    for site, channel in enumerate(site_channels(raw.pattern)):
        rgb[..., channel] += mosaic[site // 2 :: 2, site % 2 :: 2] / (2.0 if channel == 1 else 1.0)
    rgb = rgb.repeat(2, axis=0).repeat(2, axis=1)
    middle = rgb.shape[0] // 2
    return rgb / rgb[middle - 8 : middle + 8, :16].reshape(-1, 3).mean(axis=0)


def errors(found: dict, truth: dict) -> tuple[float, float]:
    """Largest centre error and radius error over the wheels, as fractions of the true radius."""
    assert {w["name"] for w in found["wheels"]} == {w["name"] for w in truth["wheels"]}
    expected = {w["name"]: w for w in truth["wheels"]}
    centre, radius = 0.0, 0.0
    for wheel in found["wheels"]:
        true = expected[wheel["name"]]
        centre = max(centre, math.hypot(wheel["x"] - true["x"], wheel["y"] - true["y"]) / true["radius"])
        radius = max(radius, abs(wheel["radius"] / true["radius"] - 1))
    return centre, radius


@pytest.fixture(scope="module")
def calibrated():
    """A simulated 640 x 480 camera and its noiseless calibration."""
    camera = make_camera("imx219", size=SMALL)
    return camera, calibrate(**simulate_references(camera, noise=False))


@pytest.fixture(scope="module")
def corrected(calibrated):
    """The simulator's target at 640 x 480, noiseless, corrected in every mode, and its layout."""
    camera, cal = calibrated
    raw, layout = simulate_target(camera, noise=False)
    return {mode: correct(raw, cal, mode) for mode in MODES}, layout


# --- without a layout -------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("sensor", ["ov5647", "imx219", "imx477", "imx708"])
@pytest.mark.parametrize("size", [None, SMALL], ids=["full", "640x480"])
def test_finds_the_simulator_wheels_at_every_sensor_size(sensor, size):
    raw, truth = simulate_target(make_camera(sensor, size=size), noise=False)
    found = find_wheels(uncorrected(raw))
    assert (found["width"], found["height"]) == (raw.width, raw.height)
    centre, radius = errors(found, truth)
    # Measured: centres within 0.14 % of the radius at full size and 0.7 % at 640 x 480 (most of it the
    # half-pixel misregistration of the quick demosaic); radii within 0.2 % and 0.85 %.
    assert centre < 0.01 and radius < 0.015, (centre, radius)
    for wheel in found["wheels"]:
        assert not wheel["mirrored"] and abs(wheel["rotation_deg"]) < 0.5, wheel


def test_finds_the_wheels_in_every_correction_mode_with_vignetting_and_noise(calibrated):
    camera, cal = calibrated
    raw, truth = simulate_target(camera, noise=True, seed=2)
    for mode in MODES:
        found = find_wheels(correct(raw, cal, mode))
        centre, radius = errors(found, truth)
        # Measured: centres within 0.4 % of the radius, radii within 0.35 %, rotations within 0.11 degree.
        assert centre < 0.01 and radius < 0.01, (mode, centre, radius)
        assert max(abs(w["rotation_deg"]) for w in found["wheels"]) < 0.5
        assert found["method"] == "detected" and found["wheels"][0]["name"] == "centre"


def test_centre_and_radius_are_exact_on_the_ideal_scene():
    _, truth = simulate_target(make_camera("imx219", size=SMALL), noise=False)
    centre, radius = errors(find_wheels(wheel_scene(truth)), truth)
    # Without a camera the only error is the anti-aliased rim: measured 0.0002 % and 0.02 %.
    assert centre < 0.002 and radius < 0.003


def test_mirrored_and_turned_images_give_mirrored_and_turned_wheels_named_by_image_position(corrected):
    image = corrected[0]["uncorrected"]
    flipped = find_wheels(image[:, ::-1])
    # Mirrored left to right = mirrored top to bottom, then turned by 180 degrees.
    assert all(w["mirrored"] and abs(abs(w["rotation_deg"]) - 180) < 0.5 for w in flipped["wheels"])
    positions = {w["name"]: (w["x"], w["y"]) for w in flipped["wheels"]}
    assert positions["top-left"][0] < positions["top-right"][0]
    assert flipped["segments"][0]["start_deg"] == pytest.approx(120.0, abs=0.5)  # red now 120 to 180

    turned = find_wheels(np.rot90(image))  # a quarter turn counter-clockwise
    assert all(not w["mirrored"] and abs(w["rotation_deg"] - 90) < 0.5 for w in turned["wheels"])
    centre = next(w for w in turned["wheels"] if w["name"] == "centre")
    assert (centre["x"], centre["y"]) == pytest.approx((239.5, 319.5), abs=0.3)


def test_an_image_without_wheels_raises():
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:480, 0:640]
    vignetted_white = (1 - 0.5 * ((x - 320) ** 2 + (y - 240) ** 2) / 400**2)[..., None] * [0.9, 0.55, 0.55]
    with pytest.raises(PicamcalError, match="no colour wheels found in the image"):
        find_wheels(vignetted_white + rng.normal(0, 0.01, vignetted_white.shape))
    # A disc of a single colour is round and saturated but not a wheel: its hue does not turn.
    disc = np.ones((480, 640, 3))
    disc[np.hypot(x - 320, y - 240) < 60] = [1.0, 0.0, 0.0]
    with pytest.raises(PicamcalError, match="no colour wheels found in the image"):
        find_wheels(disc)


def test_a_malformed_image_is_refused():
    with pytest.raises(PicamcalError, match=r"\(h, w, 3\)"):
        find_wheels(np.ones((100, 100)))


# --- with a target layout ---------------------------------------------------------------------------------


def linear_from_srgb(encoded: np.ndarray) -> np.ndarray:
    v = encoded / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def photograph(layout: dict, homography: np.ndarray, size: tuple[int, int], *, seed: int = 0) -> np.ndarray:
    """The rendered target seen through a known homography: blurred, vignetted, tinted and noisy."""
    screen = linear_from_srgb(render_target(layout))
    width, height = size
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    back = np.linalg.inv(homography) @ np.stack([x.ravel(), y.ravel(), np.ones(x.size)])
    lx, ly = (back[:2] / back[2]).reshape(2, height, width)
    image = np.stack([ndimage.map_coordinates(screen[..., c], [ly, lx], order=1, cval=0.1) for c in range(3)], axis=-1)
    image = ndimage.gaussian_filter(image, (1.0, 1.0, 0))
    r2 = ((x - width / 2) ** 2 + (y - height / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)
    image *= (1 - 0.5 * r2)[..., None] * [0.9, 1.0, 0.8]
    return image + np.random.default_rng(seed).normal(0, 0.005, image.shape)


def homography(angle_deg: float, scale: float, perspective: tuple[float, float], *, mirror: bool = False):
    """Layout (960 x 540, centred) to an 800 x 600 image: scale, mirror, turn, perspective, shift."""
    a = math.radians(angle_deg)
    centre = np.array([[1, 0, -479.5], [0, 1, -269.5], [0, 0, 1]])
    turn = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    stretch = np.diag([-scale if mirror else scale, scale, 1.0])
    tilt = np.array([[1, 0, 0], [0, 1, 0], [perspective[0], perspective[1], 1]])
    shift = np.array([[1, 0, 402], [0, 1, 297], [0, 0, 1]])
    return shift @ tilt @ turn @ stretch @ centre


def mapped_truth(layout: dict, h: np.ndarray) -> dict:
    """The layout's wheels through h: centre, and radius as the mean distance of the mapped rim from it."""
    wheels = []
    angles = np.radians(np.arange(0, 360, 2))
    for wheel in layout["wheels"]:
        x, y, r = wheel["x"], wheel["y"], wheel["radius"]
        points = h @ np.stack([x + r * np.cos(angles), y - r * np.sin(angles), np.ones_like(angles)])
        centre = h @ [x, y, 1.0]
        cx, cy = centre[:2] / centre[2]
        radius = np.mean(np.hypot(points[0] / points[2] - cx, points[1] / points[2] - cy))
        wheels.append({"name": wheel["name"], "x": cx, "y": cy, "radius": radius})
    return {"wheels": wheels}


@pytest.mark.parametrize(
    ("angle", "perspective", "mirror"),
    [(3.0, (1e-4, -5e-5), False), (183.0, (-1e-4, 5e-5), False), (-10.0, (0.0, 1e-4), True)],
    ids=["upright", "upside-down", "mirrored"],
)
def test_finds_the_wheels_through_the_fiducials_of_a_warped_target(angle, perspective, mirror):
    layout = target_layout(960, 540)
    h = homography(angle, 0.75, perspective, mirror=mirror)
    found = find_wheels(photograph(layout, h, (800, 600)), layout=layout)
    assert found["method"] == "fiducials" and {w["name"] for w in found["wheels"]} == TARGET_NAMES
    centre, radius = errors(found, mapped_truth(layout, h))
    # Measured: centres within 0.2 % of the radius, radii within 0.03 %, marks fitted to 0.03 pixel.
    assert centre < 0.01 and radius < 0.01, (centre, radius)
    assert found["fit_rms_px"] < 0.2
    np.testing.assert_allclose(np.asarray(found["homography"]), h / h[2, 2], rtol=0.02, atol=2e-3)
    assert all(w["mirrored"] == mirror for w in found["wheels"])


def test_the_mapped_segments_sample_the_right_colours():
    layout = target_layout(960, 540)
    h = homography(183.0, 0.75, (-1e-4, 5e-5))
    image = photograph(layout, h, (800, 600))
    found = find_wheels(image, layout=layout)
    result = analyse({"photo": image}, found)["photo"]
    for name, wheel in result["wheels"].items():
        red, yellow, green, cyan, blue, magenta = np.asarray(wheel["colours"])
        # Each segment's strongest channels are the ones its colour has, however the target is turned.
        assert red.argmax() == 0 and green.argmax() == 1 and blue.argmax() == 2, name
        assert min(yellow[:2]) > 2 * yellow[2] and min(cyan[1:]) > 2 * cyan[0] and min(magenta[::2]) > 2 * magenta[1]


@pytest.mark.parametrize(("angle", "scale"), [(-12.0, 0.75), (5.0, 0.4)], ids=["tilted", "small-in-the-dark"])
def test_the_target_without_its_layout_gets_the_names_of_its_positions(angle, scale):
    layout = target_layout(960, 540)
    # Beyond the screen the photograph is dark (a tenth of the white).
    found = find_wheels(photograph(layout, homography(angle, scale, (0.0, 0.0)), (800, 600)))
    assert found["method"] == "detected"
    assert {w["name"] for w in found["wheels"]} == TARGET_NAMES
    # The homography turns y-down coordinates by the angle: counter-clockwise on screen by minus the angle.
    assert all(abs(w["rotation_deg"] + angle) < 0.5 for w in found["wheels"])


def test_a_layout_that_does_not_match_the_image_raises():
    layout = target_layout(960, 540)
    image = photograph(layout, homography(3.0, 0.75, (0.0, 0.0)), (800, 600))
    with pytest.raises(PicamcalError, match="the layout does not match the image"):
        find_wheels(np.ones((600, 800, 3)), layout=layout)  # no fiducials at all
    with pytest.raises(PicamcalError, match="the layout does not match the image"):
        find_wheels(image, layout=target_layout(540, 540))  # another target's proportions
    shuffled = json.loads(json.dumps(layout))
    colours = [segment["colour"] for segment in shuffled["segments"]]
    for segment, colour in zip(shuffled["segments"], colours[1:] + colours[:1], strict=True):
        segment["colour"] = colour
    with pytest.raises(PicamcalError, match="the layout does not match the image"):
        find_wheels(image, layout=shuffled)  # the fiducials fit, but the colours are a segment out


def test_the_simulated_target_is_found_through_its_fiducials_in_every_mode(calibrated):
    camera, cal = calibrated
    raw, truth = simulate_target(camera, noise=True, seed=4)
    for mode in MODES:
        found = find_wheels(correct(raw, cal, mode), layout=truth)
        assert found["method"] == "fiducials" and {w["name"] for w in found["wheels"]} == TARGET_NAMES
        # The frame is the layout, seen through lenslets that move the light towards the centre by up to
        # lenslet_shift_corner (0.5 pixel) at the corners: the homography moves the frame's corners by at most
        # that (measured 0.30 to 0.48 pixel) and its centre by well under a pixel (measured 0.03); the five marks
        # fit it to 0.016 pixel or better.
        assert found["fit_rms_px"] < 0.1, (mode, found["fit_rms_px"])
        h = np.asarray(found["homography"])
        points = np.array([[0, 0, 1], [639, 0, 1], [0, 479, 1], [639, 479, 1], [319.5, 239.5, 1]]).T
        mapped = h @ points
        moved = np.hypot(*(mapped[:2] / mapped[2] - points[:2]))
        assert moved[:4].max() < camera.optics.lenslet_shift_corner + 0.1 and moved[4] < 0.1, (mode, moved)
        centre, radius = errors(found, truth)
        assert centre < 0.01 and radius < 0.01, (mode, centre, radius)


def test_a_layout_without_fiducials_names_the_wheels_found(corrected):
    images, truth = corrected
    plain = {key: value for key, value in truth.items() if key != "fiducials"}
    found = find_wheels(images["uncorrected"], layout=plain)
    assert found["method"] == "layout-names"
    centre, radius = errors(found, truth)
    assert centre < 0.01 and radius < 0.01
    moved = json.loads(json.dumps(plain))
    moved["wheels"][1]["x"] += moved["wheels"][1]["radius"]
    with pytest.raises(PicamcalError, match="the layout does not match the image"):
        find_wheels(images["uncorrected"], layout=moved)


# --- analysis and figures ---------------------------------------------------------------------------------


def test_analyse_matches_wheel_figures_on_the_true_layout(corrected):
    images, truth = corrected
    found = find_wheels(images["uncorrected"])
    result = analyse(images, found)
    assert set(result) == set(MODES)
    json.dumps(result)
    # The paper's recommended correction leaves every wheel within one CIEDE2000 of the centre's.
    assert result["centre"]["summary"]["max_delta_e"] < 1.0
    uncorrected_summary = result["uncorrected"]["summary"]
    assert uncorrected_summary["max_delta_e"] > 8 and uncorrected_summary["mean_saturation_ratio"] < 0.8
    for mode in MODES:
        expected = wheel_figures(images[mode], truth)
        summary = result[mode]["summary"]
        # Sampled at the found wheels rather than the true ones: measured within 0.01.
        assert summary["max_delta_e"] == pytest.approx(expected["max_delta_e"], abs=0.2)
        assert summary["mean_delta_e"] == pytest.approx(expected["mean_delta_e"], abs=0.2)
        assert summary["mean_saturation_ratio"] == pytest.approx(expected["mean_saturation_ratio"], abs=0.01)
        for name, wheel in expected["wheels"].items():
            np.testing.assert_allclose(result[mode]["figures"][name]["delta_e"], wheel["delta_e"], atol=0.2)
    centre = result["centre"]["wheels"]["centre"]
    assert len(centre["colours"]) == 6 and len(centre["hue_deg"]) == 6 and len(centre["saturation"]) == 6


def test_analyse_refuses_an_image_of_another_size(corrected):
    images, truth = corrected
    with pytest.raises(PicamcalError, match="640 x 480"):
        analyse({"half": images["centre"][::2, ::2]}, truth)


def test_polar_plot_and_wheel_crops_write_pngs(corrected, tmp_path):
    images = corrected[0]
    found = find_wheels(images["uncorrected"])
    result = analyse(images, found)
    polar = polar_plot(result["uncorrected"], tmp_path / "polar.png", title="uncorrected")
    crops = wheel_crops(images["uncorrected"], found, tmp_path / "crops.png")
    for path in (polar, crops):
        with Image.open(path) as picture:
            assert picture.format == "PNG" and picture.width > 200 and picture.height > 200
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crops.png", "polar.png"]
