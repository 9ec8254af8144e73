"""The paper's method end to end on the physical simulator: what the issue asks the correction to show."""

from __future__ import annotations

import numpy as np
import pytest

from picamcal import calibrate, correct
from picamcal.analysis.metrics import flatness, wheel_figures
from picamcal.bayer import sites_to_channels
from picamcal.calibrate import centre_region
from picamcal.simulate import ground_truth, make_camera, render, simulate_references, simulate_target

SIZE = (640, 480)


@pytest.fixture(scope="module", params=[("imx219", "BGGR"), ("imx477", "GRBG")], ids=lambda p: p[0])
def noiseless(request):
    sensor, pattern = request.param
    camera = make_camera(sensor, pattern=pattern, size=SIZE)
    refs = simulate_references(camera, noise=False)
    target, layout = simulate_target(camera, noise=False)
    return camera, refs, target, layout, calibrate(**refs)


def _true_fields(camera, bin_size=16):
    truth = ground_truth(camera, bin_size=bin_size)
    mixing = truth["site_mixing"]  # (nby, nbx, 4 sites, 3 primaries), DN per unit primary
    white = mixing.sum(-1)
    per_site = np.moveaxis(mixing / white[..., None], -1, 0)  # (3 primaries, nby, nbx, 4 sites)
    m = np.moveaxis(sites_to_channels(per_site, camera.pattern), 0, -1)  # (nby, nbx, channel, primary)
    y0, y1, x0, x1 = centre_region(*m.shape[:2])
    m_centre = m[y0:y1, x0:x1].reshape(-1, 3, 3).mean(0)
    return sites_to_channels(white, camera.pattern), m, m_centre @ np.linalg.inv(m)


def test_calibration_recovers_the_true_flat_field_and_unmixing(noiseless):
    camera, _, _, _, cal = noiseless
    white, m, u = _true_fields(camera)
    # Only quantisation to integer DN separates the files from the model: 0.3 % on the flat field,
    # 0.01 on the matrix elements (which reach ~2 in the corners).
    np.testing.assert_allclose(cal.white, white, rtol=3e-3)
    np.testing.assert_allclose(cal.crosstalk, m, atol=5e-3)
    np.testing.assert_allclose(cal.unmixing, u, atol=1e-2)
    assert cal.condition_number.max() < 20 and cal.meta["ill_conditioned_bins"] == 0


def test_calibration_recovers_the_truth_with_noise_to_within_noise():
    camera = make_camera("imx219", size=SIZE)
    cal = calibrate(**simulate_references(camera, noise=True, seed=4))
    _, _, u = _true_fields(camera)
    # Shot and read noise over 64 pixels per site and bin, amplified by inverting M: measured 0.004 mean and
    # 0.03 at the 99th percentile over the 40 x 30 bins and 9 elements (elements reach 2.3 in the corners).
    error = np.abs(cal.unmixing - u)
    assert error.mean() < 0.01
    assert np.percentile(error, 99) < 0.05


def test_flat_mode_makes_white_uniform_to_half_a_percent(noiseless):
    _, refs, _, _, cal = noiseless
    for binned in (True, False):
        white = correct(refs["white"], cal, "flat", binned=binned)
        cv = flatness(white, bin_size=None if binned else 16)
        assert np.all(cv < 0.005), cv
    uncorrected = flatness(correct(refs["white"], cal, "balance", binned=True))
    # Vignetting: the uncorrected white is far from flat (the simulated red falls off least, as in the paper).
    assert uncorrected.max() > 0.1 and uncorrected.min() > 0.02


def test_centre_mode_brings_every_corner_wheel_within_one_delta_e(noiseless):
    _, _, target, layout, cal = noiseless
    figures = {mode: wheel_figures(correct(target, cal, mode), layout) for mode in ("balance", "flat", "centre")}
    for name, wheel in figures["centre"]["wheels"].items():
        assert max(wheel["delta_e"]) < 1.0, (name, wheel["delta_e"])
    assert figures["centre"]["mean_saturation_ratio"] == pytest.approx(1.0, abs=0.03)
    # Uncorrected and flat-field-only are far off: the corners are dark and desaturated.
    assert figures["balance"]["max_delta_e"] > 8
    assert figures["flat"]["max_delta_e"] > 5
    assert figures["flat"]["mean_saturation_ratio"] < 0.85


def test_pure_mode_unmixes_the_primaries(noiseless):
    _, refs, _, _, cal = noiseless
    for index, name in enumerate(("red", "green", "blue")):
        pure = correct(refs[name], cal, "pure", binned=True)
        expected = np.eye(3)[index]
        np.testing.assert_allclose(pure, np.broadcast_to(expected, pure.shape), atol=0.01)


def test_noise_penalty_matches_noise_measured_on_simulated_frames():
    # Read noise only: dark frames of the simulated sensor, corrected with a noiseless calibration.
    camera = make_camera("imx219", size=(160, 120))
    cal = calibrate(**simulate_references(camera, noise=False), bin_size=8)
    rng = np.random.default_rng(11)
    frames = [render(camera, (0.0, 0.0, 0.0), noise=True, rng=rng) for _ in range(300)]
    noise = {mode: np.std([correct(f, cal, mode, binned=True) for f in frames], axis=0) for mode in ("flat", "centre")}
    ys, xs = cal.centre_slices
    reference = noise["flat"][ys, xs].reshape(-1, 3).mean(0)  # each channel's noise at the centre, flat field only
    # A binned green averages twice as many pixels as red or blue, hence the relative input noise.
    for mode in ("flat", "centre"):
        predicted = cal.noise_penalty(mode, channel_noise=(1.0, 2**-0.5, 1.0))
        ratio = noise[mode] / reference / predicted
        # 300 frames give each bin's std to ~4 %; the median over bins must agree within 10 %, and 95 % of bins
        # within the sampling spread.
        assert abs(np.median(ratio) - 1) < 0.10, (mode, np.median(ratio))
        assert np.mean(np.abs(ratio - 1) < 0.15) > 0.95
    assert cal.noise_penalty("centre").max() > 1.5  # the test would be empty if unmixing cost nothing


def test_a_tilted_sensor_still_calibrates_and_corrects():
    camera = make_camera("imx219", size=SIZE, tilt=(3.0, -2.0))
    cal = calibrate(**simulate_references(camera, noise=False))
    target, layout = simulate_target(camera, noise=False)
    assert wheel_figures(correct(target, cal, "centre"), layout)["max_delta_e"] < 1.0


def test_full_resolution_flat_field_has_no_block_edges(noiseless):
    _, refs, _, _, cal = noiseless
    white = correct(refs["white"], cal, "flat")[..., 1]
    # The corrected white's column profile must have no steps or kinks: the cubic splines give at most
    # 6e-5 per column and 1e-4 in second differences here, while a nearest-bin field jumps by 2e-2 and a
    # bilinear one kinks by 1e-2 at bin centres and the edges.
    profile = white.mean(axis=0)
    assert np.abs(np.diff(profile)).max() < 5e-4
    assert np.abs(np.diff(profile, 2)).max() < 5e-4
    assert np.abs(white - 1).max() < 0.03  # every pixel, edges and corners included
