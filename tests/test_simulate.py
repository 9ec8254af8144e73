"""Tests of the physical sensor simulator (picamcal.simulate)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.special import ndtr

from picamcal.bayer import bin_sites, sites_to_channels
from picamcal.colour_wheel import WHEEL_POSITIONS
from picamcal.errors import OutputError, PicamcalError
from picamcal.raw import PATTERNS, read_raw, site_channels
from picamcal.references import ROLES
from picamcal.simulate import (
    Optics,
    dust_specks,
    expected_response,
    ground_truth,
    make_camera,
    render,
    simulate_references,
    simulate_run,
    simulate_target,
    wheel_layout,
    wheel_scene,
)
from picamcal.target import target_layout

CORNERS = ((0, 0), (0, -1), (-1, 0), (-1, -1))


@pytest.fixture(scope="module")
def camera():
    return make_camera("imx219", size=(640, 480))


@pytest.fixture(scope="module")
def channel_mixing(camera):
    """Per-bin 3x3 matrices M[channel, primary] of the 640x480 camera (greens averaged), bins of 16."""
    mixing = ground_truth(camera, bin_size=16)["site_mixing"]
    return np.swapaxes(sites_to_channels(np.swapaxes(mixing, -1, -2), camera.pattern), -1, -2)


def _centre_bin(a):
    return a[a.shape[0] // 2, a.shape[1] // 2]


def _corner_mean(a):
    return np.mean([a[c] for c in CORNERS], axis=0)


def _direct_sum(camera, scene):
    """The model written out per pixel and per lenslet (slow; for tiny frames)."""
    o = camera.optics
    h, w = camera.height, camera.width
    colours = site_channels(camera.pattern)
    coeff = np.asarray(o.sensitivity)[:, None] * np.asarray(o.spectral_overlap) * camera.scale
    light = np.array([[coeff[colours[2 * (y % 2) + x % 2]] @ scene[y, x] for x in range(w)] for y in range(h)])
    padded = np.pad(light, 2, mode="reflect")
    cx, cy = (w - 1) / 2, (h - 1) / 2
    k = o.lenslet_shift_corner / math.hypot(cx, cy)
    tx, ty = (o.stack_height * math.tan(math.radians(a)) for a in camera.tilt)
    half = o.photodiode_width / 2

    def box(u, s):
        return ndtr((u + half) / s) - ndtr((u - half) / s)

    out = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            dx, dy = -k * (x - cx) + tx, -k * (y - cy) + ty
            for ny in range(-2, 3):
                for nx in range(-2, 3):
                    s = o.spot_sigma[colours[2 * ((y - ny) % 2) + (x - nx) % 2]]
                    out[y, x] += padded[y - ny + 2, x - nx + 2] * box(nx - dx, s) * box(ny - dy, s)
    return out


@pytest.mark.parametrize("pattern", ["GRBG", "RGGB"])
def test_fast_rendering_equals_the_model_summed_pixel_by_pixel(pattern):
    camera = make_camera("imx219", size=(16, 12), pattern=pattern, tilt=(4.0, -3.0))
    scene = np.random.default_rng(5).random((12, 16, 3)).astype(np.float32)
    direct = _direct_sum(camera, scene)
    # float32 accumulation: relative error ~1e-6 of the largest value.
    np.testing.assert_allclose(expected_response(camera, scene), direct, rtol=0, atol=1e-5 * direct.max())


@pytest.mark.parametrize("amounts", [(1, 1, 1), (1, 0, 0), (0, 0.3, 0.7)])
def test_uniform_scene_fast_path_equals_the_general_path(camera, amounts):
    uniform = expected_response(camera, amounts)
    as_image = expected_response(camera, np.broadcast_to(np.float32(amounts), (480, 640, 3)))
    # The general path works in float32: 1e-5 of the peak is far below a DN.
    np.testing.assert_allclose(as_image, uniform, rtol=0, atol=1e-5 * uniform.max())


@pytest.mark.parametrize("sensor", ["imx219", "imx477", "ov5647"])
def test_brightest_white_pixel_sits_at_the_exposure(sensor):
    camera = make_camera(sensor, size=(320, 240), exposure=0.6)
    white = expected_response(camera, "white")
    assert white.max() == pytest.approx(0.6 * (camera.white_level - camera.black_level), rel=1e-12)
    raw = render(camera, "white", noise=False)
    assert raw.bayer.max() == round(camera.black_level + 0.6 * (camera.white_level - camera.black_level))


@pytest.mark.parametrize("scene", ["white", "red", "black"])
def test_noiseless_render_is_expected_response_quantised(camera, scene):
    raw = render(camera, scene, noise=False)
    expected = expected_response(camera, scene)
    # Rounding to integers is the only difference: at most 0.5 DN (plus float32 rounding).
    assert np.abs(raw.bayer - camera.black_level - expected).max() <= 0.5 + 1e-3


def test_noiseless_target_is_expected_response_quantised(camera):
    raw, layout = simulate_target(camera, noise=False)
    expected = expected_response(camera, wheel_scene(layout))
    assert np.abs(raw.bayer - camera.black_level - expected).max() <= 0.5 + 1e-3
    assert raw.metadata["scene"] == "target"


def test_render_clips_to_the_white_level():
    camera = make_camera("imx219", size=(64, 48))
    raw = render(camera, (3.0, 3.0, 3.0), noise=False)  # three times the exposure: saturates
    assert raw.bayer.max() == camera.white_level
    assert raw.bayer.dtype == np.uint16


def test_render_metadata_and_levels(camera):
    raw = render(make_camera("imx219", size=(64, 48), tilt=(1.0, 2.0)), "green", rng=3)
    assert raw.metadata == {
        "simulated": True,
        "sensor_size": [64, 48],
        "sensor_crop": [0, 0, 64, 48],
        "geometry_source": "file",
        "exposure_time_s": 0.01,
        "analogue_gain": 1.0,
        "tilt_deg": [1.0, 2.0],
        "scene": "green",
    }
    assert (raw.pattern, raw.black_level, raw.white_level, raw.bit_depth, raw.sensor) == (
        "BGGR",
        (64.0, 64.0, 64.0, 64.0),
        1023,
        10,
        "imx219",
    )


def test_white_is_brightest_in_the_centre_and_darker_in_the_corners(camera, channel_mixing):
    white = channel_mixing.sum(-1)
    ratio = _corner_mean(white) / _centre_bin(white)
    # Tuned defaults: green keeps 40-60 % in the corners; red (widest spot) falls off more gently
    # than green and blue; every channel is darker in the corners.
    assert 0.40 <= ratio[1] <= 0.60
    assert 0.40 <= ratio[2] <= 0.65
    assert ratio[1] + 0.2 < ratio[0] < 0.95
    peak = np.unravel_index(np.argmax(white[..., 1]), white.shape[:2])
    assert peak in ((14, 19), (14, 20), (15, 19), (15, 20))  # the four bins around the frame centre


def test_no_lenslet_shift_means_no_vignetting():
    camera = make_camera("imx219", size=(64, 48), optics=Optics(lenslet_shift_corner=0.0))
    white = expected_response(camera, "white")
    for sy in (0, 1):
        for sx in (0, 1):
            plane = white[sy::2, sx::2]
            assert np.ptp(plane) <= 1e-9 * plane.max()


def test_red_light_reaches_green_and_blue_pixels_more_in_the_corners(camera, channel_mixing):
    red = channel_mixing[..., 0]
    centre, corner = _centre_bin(red), _corner_mean(red)
    # Crosstalk grows with the lenslet shift: green and blue pixels see at least 10 % more red light
    # in the corners although the red pixels themselves see less.
    assert corner[1] > 1.1 * centre[1]
    assert corner[2] > 1.1 * centre[2]
    assert corner[0] < centre[0]
    assert corner[1] / corner[0] > 2 * centre[1] / centre[0]


def test_crosstalk_matrices_stay_well_conditioned(camera, channel_mixing):
    cond = np.linalg.cond(channel_mixing)
    assert cond.max() < 20
    assert _corner_mean(cond) > 1.2 * _centre_bin(cond)


def test_corner_colours_are_desaturated(camera, channel_mixing):
    # Saturation of each primary after dividing by the white: (own - largest other) / own.
    normalised = channel_mixing / channel_mixing.sum(-1, keepdims=True)
    own = np.diagonal(normalised, axis1=-2, axis2=-1)
    other = np.max(normalised - 10 * np.eye(3), axis=-2)
    saturation = (own - other) / own
    centre, corner = _centre_bin(saturation), _corner_mean(saturation)
    assert np.all(centre > 0.7)
    assert np.all(corner < 0.8 * centre)
    assert np.all(corner > 0.15)  # still recoverable


@pytest.mark.parametrize("tilt", [(3.0, -2.0), (-4.0, 1.5)])
def test_tilt_moves_the_vignetting_centre_by_t_over_k(tilt):
    camera = make_camera("imx219", size=(640, 480), tilt=tilt)
    optics = camera.optics
    k = optics.lenslet_shift_corner / math.hypot(319.5, 239.5)
    shift = [optics.stack_height * math.tan(math.radians(a)) / k for a in tilt]
    assert camera.vignetting_centre == pytest.approx((319.5 + shift[0], 239.5 + shift[1]), abs=1e-9)
    assert np.sign(shift).tolist() == np.sign(tilt).tolist()
    truth = ground_truth(camera, bin_size=16)["vignetting_centre"]
    np.testing.assert_allclose(truth, camera.vignetting_centre, atol=1e-9)
    # Find the peak of the green site plane of the rendered model by a parabola through the brightest
    # pixel and its neighbours along each axis; it must be within 0.5 px of the prediction.
    white = expected_response(camera, "white")
    plane = white[0::2, 1::2]  # a green site of BGGR: x = 2 j + 1, y = 2 i
    i, j = np.unravel_index(np.argmax(plane), plane.shape)

    def vertex(m, c, p):
        return (m - p) / (2 * (m - 2 * c + p))

    x = 2 * (j + vertex(plane[i, j - 1], plane[i, j], plane[i, j + 1])) + 1
    y = 2 * (i + vertex(plane[i - 1, j], plane[i, j], plane[i + 1, j]))
    assert x == pytest.approx(camera.vignetting_centre[0], abs=0.5)
    assert y == pytest.approx(camera.vignetting_centre[1], abs=0.5)


@pytest.mark.parametrize("sensor", ["imx219", "imx477"])
def test_black_frame_noise_is_the_read_noise(sensor):
    camera = make_camera(sensor, size=(640, 480))
    raw = render(camera, "black", rng=11)
    values = raw.bayer.astype(float)
    read = camera.read_noise_dn
    assert read == pytest.approx(2.0 * 2 ** (camera.bit_depth - 10))
    # Rounding adds 1/12 DN^2; with 307200 samples the std is known to 0.2 %, so 5 % is a firm bound.
    assert values.std() == pytest.approx(math.sqrt(read**2 + 1 / 12), rel=0.05)
    assert values.mean() == pytest.approx(camera.black_level, abs=0.05)


def test_white_frame_noise_is_shot_plus_read_noise(camera):
    raw = render(camera, "white", rng=12)
    expected = expected_response(camera, "white")
    residual = raw.bayer - camera.black_level - expected
    variance = expected.mean() / camera.electrons_per_dn + camera.read_noise_dn**2 + 1 / 12
    # Poisson variance = mean / gain in DN; 307200 samples give the variance to about 0.3 %.
    assert residual.var() == pytest.approx(variance, rel=0.03)
    assert residual.mean() == pytest.approx(0.0, abs=0.05)
    # Brighter pixels are noisier: split at the median of the expected response.
    bright = expected > np.median(expected)
    assert residual[bright].var() > residual[~bright].var()


def test_conversion_gain_scales_with_bit_depth():
    assert make_camera("imx219", size=(8, 8)).electrons_per_dn == 4.0
    assert make_camera("imx477", size=(8, 8)).electrons_per_dn == 1.0


@pytest.mark.parametrize("pattern", PATTERNS)
def test_every_pattern_puts_each_filter_on_its_sites(pattern):
    camera = make_camera("imx219", size=(128, 96), pattern=pattern)
    refs = simulate_references(camera, noise=False)
    for name, letter in (("red", "R"), ("green", "G"), ("blue", "B")):
        raw = refs[name]
        assert raw.pattern == pattern
        centre = bin_sites(raw.black_subtracted(), 32)[1, 2]  # a central bin
        brightest = {i for i, c in enumerate(pattern) if c == letter}
        assert int(np.argmax(centre)) in brightest
        dimmest = max(centre[i] for i in range(4) if i not in brightest)
        assert min(centre[i] for i in brightest) > 2 * dimmest


def test_ground_truth_matches_binned_noiseless_references(camera):
    truth = ground_truth(camera, bin_size=16)
    refs = simulate_references(camera, noise=False)
    assert truth["site_response"].shape == (4, 30, 40, 4)
    assert truth["site_mixing"].shape == (30, 40, 4, 3)
    for i, name in enumerate(("white", "red", "green", "blue")):
        binned = bin_sites(refs[name].black_subtracted(), 16)
        # A bin mean of 64 rounded values is within 0.5 DN of the unrounded mean; on average much closer
        # (about 0.06 DN: neighbouring pixels of a smooth image round alike, so errors do not average out).
        np.testing.assert_allclose(binned, truth["site_response"][i], rtol=0, atol=0.5)
        assert np.abs(binned - truth["site_response"][i]).mean() < 0.15
    np.testing.assert_array_equal(truth["site_response"][0], truth["site_mixing"].sum(-1))
    for primary in range(3):
        np.testing.assert_array_equal(truth["site_response"][1 + primary], truth["site_mixing"][..., primary])


def test_dust_darkens_the_white_by_its_depth():
    camera = make_camera("imx219", size=(320, 240))
    speck = {"x": 100.0, "y": 80.0, "radius": 10.0, "depth": 0.2}
    clean = render(camera, "white", noise=False).black_subtracted()
    dusty = render(camera, "white", noise=False, dust=[speck]).black_subtracted()
    ratio = bin_sites(dusty, 2) / bin_sites(clean, 2)
    # The speck is smooth over the 5x5 lenslet neighbourhood: ratio 1 - depth at its centre (2 %),
    # and 1 - depth * exp(-2) two radii away; untouched far away (a value on a rounding boundary may
    # round the other way: 1 DN).
    assert ratio[40, 50].mean() == pytest.approx(0.8, abs=0.02)
    assert ratio[40, 60].mean() == pytest.approx(1 - 0.2 * math.exp(-2), abs=0.02)
    assert np.abs(dusty[:, 200:] - clean[:, 200:]).max() <= 1
    assert dusty.sum() < clean.sum()


def test_references_carry_dust_on_the_white_only():
    camera = make_camera("imx219", size=(320, 240))
    refs = simulate_references(camera, noise=False, dust=4, seed=2)
    specks = refs["white"].metadata["dust"]
    assert specks == dust_specks(camera, 4, rng=np.random.default_rng(np.random.SeedSequence(2, spawn_key=(5,))))
    assert len(specks) == 4 and all("dust" not in refs[n].metadata for n in ROLES[1:])
    expected = expected_response(camera, "white")
    white = refs["white"].black_subtracted()
    for s in specks:
        assert 4 <= s["radius"] <= 25 and 0.05 <= s["depth"] <= 0.30
        x, y = round(s["x"]), round(s["y"])
        ratio = white[y, x] / expected[y, x]
        # At least the speck's own depth (more where specks overlap), 2 % for rounding and spread.
        assert ratio <= 1 - s["depth"] + 0.02


def test_references_are_reproducible_and_independent():
    camera = make_camera("imx219", size=(64, 48))
    a = simulate_references(camera, seed=4)
    b = simulate_references(camera, seed=4)
    c = simulate_references(camera, seed=5)
    for name in ROLES:
        np.testing.assert_array_equal(a[name].bayer, b[name].bayer)
        assert not np.array_equal(a[name].bayer, c[name].bayer)
    # Each frame has its own noise stream: the black frame's noise is not the white's.
    noise_black = a["black"].black_subtracted().ravel()
    noise_white = (a["white"].black_subtracted() - expected_response(camera, "white")).ravel()
    assert abs(np.corrcoef(noise_black, noise_white)[0, 1]) < 0.1


def test_the_simulated_target_is_the_printable_target_laid_out_on_the_frame():
    layout = wheel_layout(640, 480)
    assert layout == target_layout(640, 480)  # one target: what `picamcal target --size 640x480` writes
    assert json.loads(json.dumps(layout)) == layout
    assert [s["name"] for s in layout["segments"]] == ["red", "yellow", "green", "cyan", "blue", "magenta"]
    assert [s["colour"] for s in layout["segments"]][1] == [1, 1, 0]
    assert [(s["start_deg"], s["end_deg"]) for s in layout["segments"]][-1] == (300, 360)
    wheels = {w["name"]: w for w in layout["wheels"]}
    assert list(wheels) == [name for name, _, _ in WHEEL_POSITIONS]
    assert (wheels["centre"]["x"], wheels["centre"]["y"]) == (319.5, 239.5)
    # 15 % of the width from the right edge; max(15 % of the height, 17 % of the short side) from the bottom.
    assert (wheels["bottom-right"]["x"], wheels["bottom-right"]["y"]) == (543.5, 397.9)
    assert all(w["radius"] == pytest.approx(0.10 * 480) for w in wheels.values())
    assert sorted(f["kind"] for f in layout["fiducials"]) == ["disc", "ring", "ring", "ring", "ring"]
    # The simulator lays the target out on frames too small to print it on.
    assert len(wheel_layout(64, 48)["wheels"]) == 9


def test_wheel_scene_colours_angles_and_areas():
    layout = wheel_layout(640, 480)
    scene = wheel_scene(layout)
    assert scene.shape == (480, 640, 3) and scene.dtype == np.float32
    for wheel in layout["wheels"]:
        cx, cy, r = wheel["x"], wheel["y"], wheel["radius"]
        for seg in layout["segments"]:
            # Screen angles: counter-clockwise from +x with y growing downwards.
            angle = math.radians(seg["start_deg"] + 30)
            x, y = round(cx + 0.6 * r * math.cos(angle)), round(cy - 0.6 * r * math.sin(angle))
            assert scene[y, x].tolist() == seg["colour"]
        # Half of the segments lack each primary: the missing amount is half the disc's area. The 4 x 4 samples
        # of an edge pixel place an edge to 1/8 pixel: a boundary along a pixel row (the 0 and 180 degree rays of
        # a wheel centred 0.1 pixel off a row, as the outer ones are here) is off by up to 1/8 pixel^2 per pixel
        # of its 2 r length, r / 4 in all (0.3 %; measured 0.27 %); the curved rim's errors average out (0.01 %).
        block = scene[round(cy - r) - 2 : round(cy + r) + 3, round(cx - r) - 2 : round(cx + r) + 3]
        deficit = (1 - block).sum(axis=(0, 1))
        np.testing.assert_allclose(deficit, math.pi * r**2 / 2, rtol=0, atol=r / 4)
    for mark in layout["fiducials"]:
        # A black ring (disc) on white: the missing amount is its area in every primary, to 1/32 pixel^2 per
        # pixel of its curved edges (measured 0.004).
        cx, cy, r, hole = mark["x"], mark["y"], mark["radius"], mark.get("hole_radius", 0.0)
        block = scene[round(cy - r) - 2 : round(cy + r) + 3, round(cx - r) - 2 : round(cx + r) + 3]
        deficit = (1 - block).sum(axis=(0, 1))
        np.testing.assert_allclose(deficit, math.pi * (r**2 - hole**2), rtol=0, atol=2 * math.pi * (r + hole) / 32)
        assert scene[round(cy), round(cx)].tolist() == ([1.0] * 3 if hole else [0.0] * 3)
    assert np.all(scene[:5, :5] == 1)
    top = layout["wheels"][2]
    assert top["name"] == "top"
    edge = scene[round(top["y"] + top["radius"]), round(top["x"])]  # the pixel the blue segment's rim crosses
    assert 0 < edge[1] < 1 and edge[2] == 1


@pytest.mark.slow
def test_full_size_imx219_target_renders_the_whole_frame():
    # No timing bound (the project's rule): about 2.5 s on two cores, the figure in the simulator's docstring.
    camera = make_camera("imx219")
    raw, layout = simulate_target(camera, seed=1)
    assert raw.bayer.shape == (2464, 3280) and raw.bayer.dtype == np.uint16
    assert (layout["width"], layout["height"]) == (3280, 2464)
    assert layout == wheel_layout(3280, 2464)
    assert raw.pattern == "BGGR"


@pytest.mark.parametrize("fmt", ["dng", "npz"])
def test_simulate_run_writes_files_that_read_back_bit_exactly(tmp_path, fmt):
    paths = simulate_run(tmp_path / "run", size=(320, 240), seed=7, dust=2, fmt=fmt, pattern="GRBG", tilt=(1, 0))
    assert {p.name for p in paths.values()} == {
        *(f"{n}.{fmt}" for n in (*ROLES, "target")),
        "layout.json",
        "truth.npz",
        "truth.json",
    }
    camera = make_camera("imx219", size=(320, 240), pattern="GRBG", tilt=(1, 0))
    refs = simulate_references(camera, seed=7, dust=2)
    refs["target"] = simulate_target(camera, seed=7)[0]
    for name, raw in refs.items():
        back = read_raw(paths[name])
        np.testing.assert_array_equal(back.bayer, raw.bayer)
        assert (back.pattern, back.black_level, back.white_level, back.sensor) == (
            "GRBG",
            raw.black_level,
            1023,
            "imx219",
        )
        assert back.metadata["scene"] == name and back.metadata["simulated"] is True
    layout = json.loads(paths["layout"].read_text())
    assert layout == wheel_layout(320, 240)
    record = json.loads(paths["truth_json"].read_text())
    assert record["dust"] == refs["white"].metadata["dust"]
    assert (record["sensor"], record["pattern"], record["size"], record["tilt"], record["seed"]) == (
        "imx219",
        "GRBG",
        [320, 240],
        [1.0, 0.0],
        7,
    )
    assert record["optics"]["lenslet_shift_corner"] == camera.optics.lenslet_shift_corner
    truth = ground_truth(camera, bin_size=16)
    with np.load(paths["truth_npz"]) as saved:
        assert int(saved["bin_size"]) == 16
        for key, value in truth.items():
            np.testing.assert_array_equal(saved[key], value)


def test_simulate_run_refuses_to_overwrite(tmp_path):
    simulate_run(tmp_path, size=(64, 48), noise=False, fmt="npz")
    before = (tmp_path / "white.npz").stat().st_mtime_ns
    with pytest.raises(OutputError, match=r"white\.npz"):
        simulate_run(tmp_path, size=(64, 48), fmt="npz")
    assert (tmp_path / "white.npz").stat().st_mtime_ns == before
    simulate_run(tmp_path, size=(64, 48), fmt="npz", overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [f"{n}.npz" for n in (*ROLES, "target")] + ["layout.json", "truth.json", "truth.npz"]
    )


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"pattern": "RGBG"}, "pattern"),
        ({"size": (63, 48)}, "even"),
        ({"exposure": 1.5}, "exposure"),
        ({"optics": None, "sensor": "imx999"}, "unknown sensor"),
    ],
)
def test_make_camera_rejects_bad_settings(kwargs, match):
    with pytest.raises(PicamcalError, match=match):
        make_camera(**kwargs)


def test_render_rejects_a_scene_of_the_wrong_shape(camera):
    with pytest.raises(PicamcalError, match="shape"):
        render(camera, np.ones((10, 10, 3)))
    with pytest.raises(PicamcalError, match="unknown scene"):
        render(camera, "purple")
