"""Tests of picamcal.analysis.metrics: colour differences, wheel sampling and figures, flatness and previews."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from PIL import Image

from picamcal.analysis.metrics import (
    delta_e2000,
    delta_e2000_lab,
    encode_srgb,
    flatness,
    hue_saturation,
    linear_to_lab,
    save_preview,
    segment_colours,
    wheel_figures,
)
from picamcal.bayer import bin_centres
from picamcal.errors import PicamcalError

SEGMENTS = [
    ("red", [1.0, 0.0, 0.0]),
    ("yellow", [1.0, 1.0, 0.0]),
    ("green", [0.0, 1.0, 0.0]),
    ("cyan", [0.0, 1.0, 1.0]),
    ("blue", [0.0, 0.0, 1.0]),
    ("magenta", [1.0, 0.0, 1.0]),
]
COLOURS = np.array([colour for _, colour in SEGMENTS])
WIDTH, HEIGHT, RADIUS = 300, 220, 45.0


def make_layout() -> dict:
    """A layout in the simulator's format: six 60-degree segments, a centre wheel and four corner wheels."""
    margin = RADIUS + 8.0
    wheels = [
        ("centre", (WIDTH - 1) / 2, (HEIGHT - 1) / 2),
        ("top-left", margin, margin),
        ("top-right", WIDTH - 1 - margin, margin),
        ("bottom-left", margin, HEIGHT - 1 - margin),
        ("bottom-right", WIDTH - 1 - margin, HEIGHT - 1 - margin),
    ]
    return {
        "width": WIDTH,
        "height": HEIGHT,
        "segments": [
            {"name": name, "colour": colour, "start_deg": 60 * k, "end_deg": 60 * (k + 1)}
            for k, (name, colour) in enumerate(SEGMENTS)
        ],
        "wheels": [{"name": name, "x": x, "y": y, "radius": RADIUS} for name, x, y in wheels],
    }


def draw_wheels(layout: dict, colours: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """Draw each wheel with hard edges (by pixel centre) on a mid-grey background; colours per wheel optional."""
    ys, xs = np.mgrid[0 : layout["height"], 0 : layout["width"]].astype(float)
    image = np.full((layout["height"], layout["width"], 3), 0.5)
    for wheel in layout["wheels"]:
        dx, dy = xs - wheel["x"], ys - wheel["y"]
        inside = np.hypot(dx, dy) < wheel["radius"]
        angle = np.degrees(np.arctan2(-dy, dx))
        wheel_colours = COLOURS if colours is None else colours[wheel["name"]]
        for k, segment in enumerate(layout["segments"]):
            span = (segment["end_deg"] - segment["start_deg"]) % 360
            in_segment = inside & ((angle - segment["start_deg"]) % 360 < span)
            image[in_segment] = wheel_colours[k]
    return image


def vignetting(height: int, width: int) -> np.ndarray:
    """A smooth radial fall-off to 40 % in the corners, shape (height, width, 1)."""
    ys, xs = np.mgrid[0:height, 0:width].astype(float)
    r2 = ((xs - (width - 1) / 2) ** 2 + (ys - (height - 1) / 2) ** 2) / (
        ((width - 1) / 2) ** 2 + ((height - 1) / 2) ** 2
    )
    return (1.0 - 0.6 * r2)[..., np.newaxis]


def bin_image(image: np.ndarray, bin_size: int) -> np.ndarray:
    """Mean over square bins from the top-left, keeping partial bins (written out plainly, as a reference)."""
    nby, nbx = -(-image.shape[0] // bin_size), -(-image.shape[1] // bin_size)
    out = np.empty((nby, nbx, image.shape[2]))
    for i in range(nby):
        for j in range(nbx):
            block = image[i * bin_size : (i + 1) * bin_size, j * bin_size : (j + 1) * bin_size]
            out[i, j] = block.reshape(-1, image.shape[2]).mean(axis=0)
    return out


# --- colour conversions ---------------------------------------------------------------------------------


def test_white_is_lightness_100_and_neutral():
    # the L*a*b* white is the XYZ of RGB (1, 1, 1), so white is exact up to rounding (tolerance 1e-3 as specified)
    np.testing.assert_allclose(linear_to_lab([1.0, 1.0, 1.0]), [100.0, 0.0, 0.0], atol=1e-3)


def test_black_is_lightness_0_and_grey_is_neutral():
    np.testing.assert_allclose(linear_to_lab([0.0, 0.0, 0.0]), [0.0, 0.0, 0.0], atol=1e-9)
    # any grey is neutral: a* = b* = 0 up to float rounding
    np.testing.assert_allclose(linear_to_lab([0.3, 0.3, 0.3])[1:], [0.0, 0.0], atol=1e-9)


def test_linear_to_lab_keeps_leading_shape():
    assert linear_to_lab(np.ones((4, 5, 3))).shape == (4, 5, 3)


def test_linear_to_lab_rejects_wrong_last_axis():
    with pytest.raises(PicamcalError, match="3 components"):
        linear_to_lab(np.ones((4, 2)))


@pytest.mark.parametrize(
    ("lab_a", "lab_b", "published"),
    [
        # Sharma, Wu & Dalal (2005), Table 1, pairs 1, 7, 17, 25 and 34
        ([50.0, 2.6772, -79.7751], [50.0, 0.0, -82.7485], 2.0425),
        ([50.0, 0.0, 0.0], [50.0, -1.0, 2.0], 2.3669),
        ([50.0, 2.5, 0.0], [73.0, 25.0, -18.0], 27.1492),
        ([60.2574, -34.0099, 36.2677], [60.4626, -34.1751, 39.4387], 1.2644),
        ([22.7233, 20.0904, -46.6940], [23.0331, 14.9730, -42.5619], 2.0373),
    ],
)
def test_delta_e2000_lab_matches_sharma_test_data(lab_a, lab_b, published):
    # published to 4 decimals: rounding alone allows 5e-5, so 1e-4 is a strict check
    assert float(delta_e2000_lab(lab_a, lab_b)) == pytest.approx(published, abs=1e-4)


def test_lab_and_delta_e2000_are_colour_sciences():
    """The numpy conversions against the colour-science functions they stand for (colour-science is installed with
    colour-demosaicing): L*a*b* within 1e-9, CIEDE2000 within 1e-9, neutral, black and identical pairs included."""
    colour = pytest.importorskip("colour")
    from colour.utilities import domain_range_scale

    rng = np.random.default_rng(5)
    rgb = rng.random((5000, 3)) * 1.3 - 0.05
    rgb[:3] = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.004, 0.004, 0.004]]  # black, white, a grey below (6/29)**3
    space = colour.RGB_COLOURSPACES["sRGB"]
    with domain_range_scale("reference"):
        white = colour.XYZ_to_xy(space.matrix_RGB_to_XYZ @ np.ones(3))
        expected = colour.XYZ_to_Lab(colour.RGB_to_XYZ(rgb, space), white)
        lab_a, lab_b = linear_to_lab(rgb), linear_to_lab(rng.permutation(rgb))
        lab_b[:500] = lab_a[:500]  # identical
        lab_a[500:600, 1:] = lab_b[550:650, 1:] = 0  # neutral on one side, both sides
        difference = colour.delta_E(lab_a, lab_b, method="CIE 2000")
    np.testing.assert_allclose(linear_to_lab(rgb), expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(delta_e2000_lab(lab_a, lab_b), difference, rtol=0, atol=1e-9)


def test_delta_e2000_identical_colours_is_zero_and_broadcasts():
    colours = np.array([[0.2, 0.4, 0.6], [1.0, 0.0, 0.0], [0.01, 0.02, 0.005]])
    np.testing.assert_array_equal(delta_e2000(colours, colours), np.zeros(3))
    assert delta_e2000(colours, [0.5, 0.5, 0.5]).shape == (3,)


@settings(max_examples=50, deadline=None)
@given(
    arrays(np.float64, (2, 3), elements=st.floats(0.0, 1.0)),
)
def test_delta_e2000_is_symmetric_and_zero_on_the_diagonal(pair):
    a, b = pair
    # CIEDE2000 is symmetric in exact arithmetic; 1e-9 allows for float rounding in the hue terms
    assert float(delta_e2000(a, b)) == pytest.approx(float(delta_e2000(b, a)), abs=1e-9)
    assert float(delta_e2000(a, a)) == 0.0
    assert float(delta_e2000(a, b)) >= 0.0


def test_hue_of_primaries_increases_red_green_blue():
    hue, saturation = hue_saturation(np.eye(3))
    # CIE h_ab of the sRGB primaries is about 40, 136 and 306 degrees
    assert hue[0] < hue[1] < hue[2]
    np.testing.assert_allclose(hue, [40.0, 136.0, 306.3], atol=0.5)
    assert np.all(saturation > 1.0)


def test_saturation_is_zero_for_grey_nan_for_black_and_falls_on_mixing_with_grey():
    _, saturation = hue_saturation([[0.5, 0.5, 0.5], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.8, 0.2, 0.2]])
    assert saturation[0] == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(saturation[1])
    assert saturation[3] < saturation[2]


# --- wheel sampling -------------------------------------------------------------------------------------


def test_segment_colours_recovers_drawn_colours():
    layout = make_layout()
    colours = segment_colours(draw_wheels(layout), layout)
    assert list(colours) == [wheel["name"] for wheel in layout["wheels"]]
    for wheel_colours in colours.values():
        # every sampled pixel has exactly the drawn colour, so the median is exact
        np.testing.assert_allclose(wheel_colours, COLOURS, atol=1e-6)


def test_segment_colours_of_vignetted_wheels_is_colour_times_median_vignetting():
    layout = make_layout()
    shading = vignetting(HEIGHT, WIDTH)
    colours = segment_colours(draw_wheels(layout) * shading, layout)
    grey = segment_colours(np.repeat(shading, 3, axis=2), layout)
    for name, wheel_colours in colours.items():
        # within a segment the colour is constant, so the median of colour x shading is colour x median(shading)
        np.testing.assert_allclose(wheel_colours, COLOURS * grey[name], atol=1e-12)
    # and the corners really are darker than the centre
    assert np.all(grey["top-left"] < 0.9 * grey["centre"])


@pytest.mark.parametrize("bin_size", [4, 8])
def test_segment_colours_of_binned_image_with_partial_bins(bin_size):
    layout = make_layout()
    assert WIDTH % 8 and HEIGHT % 8  # 300 x 220: the last 8-pixel bins are partial
    image = draw_wheels(layout)
    binned = bin_image(image, bin_size)
    centres = (bin_centres(HEIGHT, bin_size), bin_centres(WIDTH, bin_size))
    colours = segment_colours(binned, layout, centres=centres)
    for wheel_colours in colours.values():
        # only the few bins straddling a segment edge are mixed, and the median ignores them: exact to 1e-6
        np.testing.assert_allclose(wheel_colours, COLOURS, atol=1e-6)


def test_segment_colours_of_binned_vignetted_image_matches_full_resolution():
    layout = make_layout()
    image = draw_wheels(layout) * vignetting(HEIGHT, WIDTH)
    full = segment_colours(image, layout)
    binned = segment_colours(bin_image(image, 4), layout, pixel_scale=4)
    for name in full:
        # the shading varies by under 2 % across a bin; medians over different samples of the same smooth
        # field agree to within 1 % of full scale
        np.testing.assert_allclose(binned[name], full[name], atol=0.01)


def test_pixel_scale_and_explicit_centres_agree_for_whole_bins():
    layout = make_layout()
    binned = bin_image(draw_wheels(layout) * vignetting(HEIGHT, WIDTH), 4)  # 300 x 220 divide by 4
    by_scale = segment_colours(binned, layout, pixel_scale=4)
    by_centres = segment_colours(binned, layout, centres=(bin_centres(HEIGHT, 4), bin_centres(WIDTH, 4)))
    for name in by_scale:
        np.testing.assert_array_equal(by_scale[name], by_centres[name])


def test_segment_colours_handles_segment_wrapping_through_zero():
    layout = make_layout()
    for segment in layout["segments"]:  # rotate by -30 degrees: red now covers [330, 30)
        segment["start_deg"] = (segment["start_deg"] - 30) % 360
        segment["end_deg"] = (segment["end_deg"] - 30) % 360
    colours = segment_colours(draw_wheels(layout), layout)
    np.testing.assert_allclose(colours["centre"], COLOURS, atol=1e-6)


def test_segment_colours_rejects_wheel_outside_image():
    layout = make_layout()
    image = draw_wheels(layout)[:, : WIDTH // 2 + 40]  # cropped: the right-hand wheels are cut off
    with pytest.raises(PicamcalError, match="does not fit"):
        segment_colours(image, layout)
    with pytest.raises(PicamcalError, match=r"'top-right'.*outside the image"):
        segment_colours(image, layout, centres=(np.arange(HEIGHT), np.arange(image.shape[1])))


def test_segment_colours_rejects_binned_image_without_scale():
    layout = make_layout()
    with pytest.raises(PicamcalError, match="pixel_scale"):
        segment_colours(bin_image(draw_wheels(layout), 4), layout)


def test_segment_colours_rejects_image_too_coarse_for_sectors():
    layout = make_layout()
    # bins of 30 pixels on wheels of radius 45: about a dozen bin centres per wheel, so some sectors are empty
    coarse = bin_image(draw_wheels(layout), 30)
    with pytest.raises(PicamcalError, match="has no pixels"):
        segment_colours(coarse, layout, centres=(bin_centres(HEIGHT, 30), bin_centres(WIDTH, 30)))


def test_segment_colours_rejects_margin_wider_than_segment():
    layout = make_layout()
    with pytest.raises(PicamcalError, match="margin_deg"):
        segment_colours(draw_wheels(layout), layout, margin_deg=30)


# --- wheel figures --------------------------------------------------------------------------------------


def test_wheel_figures_of_identical_wheels_are_zero_and_json_serialisable():
    layout = make_layout()
    figures = wheel_figures(draw_wheels(layout), layout)
    json.dumps(figures)
    assert figures["segments"] == [name for name, _ in SEGMENTS]
    assert sorted(figures["wheels"]) == ["bottom-left", "bottom-right", "top-left", "top-right"]
    assert figures["max_delta_e"] == 0.0
    assert figures["mean_delta_e"] == 0.0
    # identical colours: ratio and shift exact up to float rounding
    assert figures["mean_saturation_ratio"] == pytest.approx(1.0, abs=1e-12)
    for wheel in figures["wheels"].values():
        assert len(wheel["delta_e"]) == 6
        np.testing.assert_allclose(wheel["hue_shift_deg"], 0.0, atol=1e-9)


def test_wheel_figures_detect_desaturated_corners():
    layout = make_layout()
    washed = 0.6 * COLOURS + 0.4 * 0.5  # 40 % mid-grey mixed in, as crosstalk does to the corners
    colours = {wheel["name"]: washed for wheel in layout["wheels"]}
    colours["centre"] = COLOURS
    figures = wheel_figures(draw_wheels(layout, colours), layout)
    # a 40 % grey mix is far beyond a just-noticeable difference (about 1) for saturated primaries
    assert figures["max_delta_e"] > 10.0
    assert figures["mean_delta_e"] > 5.0
    assert figures["mean_saturation_ratio"] < 0.8
    for wheel in figures["wheels"].values():
        assert max(wheel["saturation_ratio"]) < 1.0
        assert wheel["max_delta_e"] == pytest.approx(figures["max_delta_e"])


def test_wheel_figures_hue_shift_is_signed_and_wrapped():
    layout = make_layout()
    # rotate every corner colour's hue a little by swapping in a neighbouring mix
    shifted = np.roll(COLOURS, 1, axis=0) * 0.15 + COLOURS * 0.85
    colours = {wheel["name"]: shifted for wheel in layout["wheels"]}
    colours["centre"] = COLOURS
    figures = wheel_figures(draw_wheels(layout, colours), layout)
    shifts = np.array(figures["wheels"]["top-left"]["hue_shift_deg"])
    assert np.all(shifts >= -180.0) and np.all(shifts < 180.0)
    # mixing in the previous segment's colour moves every hue clockwise (towards lower hue): red takes magenta,
    # whose hue is just below 360, so red's shift must wrap to a small negative number rather than near +360
    assert np.all(shifts < 0.0)
    assert shifts[0] > -60.0


def test_wheel_figures_needs_a_centre_wheel():
    layout = make_layout()
    layout["wheels"] = [wheel for wheel in layout["wheels"] if wheel["name"] != "centre"]
    with pytest.raises(PicamcalError, match="centre"):
        wheel_figures(draw_wheels(layout), layout)


# --- flatness -------------------------------------------------------------------------------------------


def test_flatness_of_constant_is_zero():
    # zero up to the rounding of the mean of 63 copies of a number not exact in binary
    assert flatness(np.full((7, 9), 0.3)) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(flatness(np.full((7, 9, 3), [0.2, 0.5, 1.0])), np.zeros(3), atol=1e-12)


def test_flatness_of_ramp_matches_analytic_value():
    a, b, width = 1.0, 0.01, 50
    plane = np.tile(a + b * np.arange(width), (10, 1))
    # a ramp a + b x over x = 0..n-1 has mean a + b (n - 1) / 2 and population std b sqrt((n^2 - 1) / 12)
    expected = b * np.sqrt((width**2 - 1) / 12) / (a + b * (width - 1) / 2)
    assert flatness(plane) == pytest.approx(expected, rel=1e-12)
    # binned by 5 (whole bins), the bin means are a ramp of 10 steps of 5 b
    expected_binned = 5 * b * np.sqrt((10**2 - 1) / 12) / (a + b * (width - 1) / 2)
    assert flatness(plane, bin_size=5) == pytest.approx(expected_binned, rel=1e-12)


def test_flatness_is_per_channel_and_includes_partial_edge_bins():
    image = np.ones((10, 10, 3))
    image[:, 9, 1] = 3.0  # only the last column of green differs
    cv = flatness(image, bin_size=4)  # bins of columns 0-3, 4-7, 8-9: the last partial bin averages to 2
    expected = np.std([1, 1, 2] * 3) / np.mean([1, 1, 2] * 3)
    np.testing.assert_allclose(cv, [0.0, expected, 0.0], rtol=1e-12)


def test_flatness_rejects_non_positive_mean():
    with pytest.raises(PicamcalError, match="positive mean"):
        flatness(np.zeros((4, 4)))


@pytest.mark.parametrize("bin_size", [0, 2.5, -4])
def test_flatness_rejects_a_bin_size_that_is_not_a_whole_number_of_pixels(bin_size):
    with pytest.raises(PicamcalError, match="bin size must be a whole number of pixels >= 1"):
        flatness(np.ones((8, 8)), bin_size=bin_size)


@settings(max_examples=50, deadline=None)
@given(
    arrays(np.float64, (6, 5), elements=st.floats(0.1, 10.0)),
    st.floats(1e-3, 1e3),
    st.sampled_from([None, 2, 3]),
)
def test_flatness_is_scale_invariant(plane, scale, bin_size):
    # the coefficient of variation is dimensionless; 1e-9 allows for float rounding
    assert flatness(plane * scale, bin_size=bin_size) == pytest.approx(flatness(plane, bin_size=bin_size), rel=1e-9)


# --- sRGB previews --------------------------------------------------------------------------------------


def test_encode_srgb_reference_points():
    encoded = encode_srgb(np.array([[[0.0, 1.0, 0.0031308]]]))
    assert encoded.dtype == np.uint8
    # 0.0031308 is the knee of the sRGB curve: 12.92 x 0.0031308 x 255 = 10.3
    assert encoded.tolist() == [[[0, 255, 10]]]


def test_encode_srgb_clips_scales_and_blackens_nan():
    encoded = encode_srgb(np.array([-0.5, 2.0, np.nan, 0.5]), exposure=2.0)
    assert encoded.tolist() == [0, 255, 0, 255]


def test_save_preview_caps_size_and_writes_png(tmp_path):
    target = tmp_path / "preview.png"
    linear = np.full((300, 130, 3), [0.18, 0.5, 1.0])
    assert save_preview(target, linear, max_size=64) == target
    with Image.open(target) as picture:
        assert picture.format == "PNG"
        assert picture.mode == "RGB"
        # factor ceil(300 / 64) = 5: 300 / 5 = 60 rows, ceil(130 / 5) = 26 columns
        assert picture.size == (26, 60)
        assert picture.getpixel((0, 0)) == (118, 188, 255)
    assert [p.name for p in tmp_path.iterdir()] == ["preview.png"]  # no temporary file left behind


def test_save_preview_averages_in_linear_light(tmp_path):
    target = tmp_path / "checker.png"
    checker = np.zeros((4, 4, 3))
    checker[::2, ::2] = checker[1::2, 1::2] = 1.0
    save_preview(target, checker, max_size=2)
    with Image.open(target) as picture:
        # the mean of black and white is linear 0.5, which sRGB encodes as 188, not 128
        assert picture.getpixel((1, 1)) == (188, 188, 188)


def test_save_preview_keeps_small_images(tmp_path):
    target = tmp_path / "small.png"
    save_preview(target, np.ones((5, 7, 3)), max_size=1024)
    with Image.open(target) as picture:
        assert picture.size == (7, 5)
