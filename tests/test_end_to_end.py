"""The paper's method end to end on the physical simulator, scored on frames the calibration never saw.

Every test calibrates on one simulated set of references and corrects other frames: a white of another seed or
brightness, and a scene of colour patches mixed from the primaries in proportions no reference has. What the
corrected frame should be comes from the simulator alone: the amounts of the primaries it rendered, its noiseless
response (:func:`~picamcal.simulate.expected_response`) and its per-bin mixing
(:func:`~picamcal.simulate.ground_truth`), never from picamcal's calibrate or correct functions.
"""

from __future__ import annotations

import numpy as np
import pytest

from picamcal import calibrate, correct
from picamcal.simulate import expected_response, ground_truth, make_camera, render, simulate_references

SIZE = (640, 480)
BIN = 16  # the calibration's default bin edge
CALIBRATION_SEED, WHITE_SEED, SCENE_SEED = 1, 101, 202
#: Held-out colours: mixtures of the primaries that no reference shows (orange, teal, violet, olive, ...).
PALETTE = np.array(
    [(0.8, 0.3, 0.1), (0.2, 0.7, 0.4), (0.3, 0.2, 0.9), (0.6, 0.6, 0.1), (0.1, 0.5, 0.6), (0.7, 0.2, 0.6), (0.45,) * 3]
)
CELL, MARGIN = 40, 6  # patch edge and the border left out of its mean (demosaicing blurs edges by a few pixels)


# ---- the simulator's truth -----------------------------------------------------------------------------------


def _channels(sites: np.ndarray, pattern: str) -> np.ndarray:
    """Per-site values (..., 4, ...) on axis -1 averaged into R, G, B (the two greens averaged)."""
    channel = np.array(["RGB".index(c) for c in pattern])
    return np.stack([sites[..., channel == c].mean(-1) for c in range(3)], axis=-1)


def _true_fields(camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The simulator's per-bin white W (nby, nbx, 3), crosstalk M (nby, nbx, channel, primary), white-normalised as
    the paper's, and M_centre (3, 3), its mean over the central ninth."""
    mixing = ground_truth(camera, bin_size=BIN)["site_mixing"]  # (nby, nbx, 4 sites, 3 primaries), DN per amount
    white = mixing.sum(-1)
    m = _channels(np.moveaxis(mixing / white[..., None], -1, -2), camera.pattern)  # (nby, nbx, primary, channel)
    m = np.swapaxes(m, -1, -2)
    return _channels(white, camera.pattern), m, _centre(m).reshape(-1, 3, 3).mean(0)


def _centre(values: np.ndarray) -> np.ndarray:
    """The central ninth of a bin grid (the middle third in each axis): the region the paper calls the centre."""
    nby, nbx = values.shape[:2]
    return values[nby // 3 : 2 * nby // 3, nbx // 3 : 2 * nbx // 3]


def _pixel_channels(camera) -> np.ndarray:
    """The colour channel (0 R, 1 G, 2 B) of every pixel of the camera's mosaic."""
    site = (np.arange(camera.height)[:, None] % 2) * 2 + np.arange(camera.width)[None, :] % 2
    return np.array(["RGB".index(c) for c in camera.pattern])[site]


def _noise_floor(camera) -> np.ndarray:
    """The coefficient of variation over bins of a flat-fielded white expected from noise alone, per channel.

    A bin's corrected value is the ratio of two independent bin means of a white (the held-out frame's and the
    calibration's): each pixel has shot noise of ``S / electrons_per_dn`` and read noise of ``read_noise_dn``
    (DN^2), so the ratio's relative variance is twice the bin mean's.
    """
    signal = expected_response(camera, "white")
    variance = signal / camera.electrons_per_dn + camera.read_noise_dn**2
    return np.sqrt(np.mean(2 * _bin_sums(camera, variance) / _bin_sums(camera, signal) ** 2, axis=(0, 1)))


def _bin_sums(camera, values: np.ndarray) -> np.ndarray:
    """Sums of a per-pixel map over each bin's pixels of each colour channel: (nby, nbx, 3)."""
    channel = _pixel_channels(camera)
    nby, nbx = camera.height // BIN, camera.width // BIN
    return np.stack([np.where(channel == c, values, 0).reshape(nby, BIN, nbx, BIN).sum((1, 3)) for c in range(3)], -1)


def _bin_means(camera, amounts) -> np.ndarray:
    """The simulator's noiseless mean response (DN above black) of each bin and channel to uniform ``amounts``."""
    count = _bin_sums(camera, np.ones((camera.height, camera.width)))
    return _bin_sums(camera, expected_response(camera, amounts)) / count


def _patch_scene(camera) -> np.ndarray:
    """Amounts of the primaries of each CELL x CELL patch (ny, nx, 3): the palette, each colour in every region."""
    ny, nx = camera.height // CELL, camera.width // CELL
    return PALETTE[(3 * np.arange(ny)[:, None] + np.arange(nx)[None, :]) % len(PALETTE)]


def _patch_means(image: np.ndarray) -> np.ndarray:
    ny, nx = image.shape[0] // CELL, image.shape[1] // CELL
    inner = image[: ny * CELL, : nx * CELL].reshape(ny, CELL, nx, CELL, 3)[:, MARGIN:-MARGIN, :, MARGIN:-MARGIN]
    return inner.mean((1, 3))


def _corners(ny: int, nx: int) -> np.ndarray:
    """The 2 x 2 patches in each corner of the frame, where vignetting and crosstalk are worst."""
    mask = np.zeros((ny, nx), dtype=bool)
    for ys in (slice(0, 2), slice(ny - 2, ny)):
        for xs in (slice(0, 2), slice(nx - 2, nx)):
            mask[ys, xs] = True
    return mask


def _colour_errors(camera, cal, noise: bool) -> dict[str, np.ndarray]:
    """Relative error of every patch of a held-out scene, per mode, against the simulator's truth.

    ``pure`` must give the rendered amounts themselves; the other modes aim at the colour the same amounts have
    at the centre of the sensor, ``M_centre @ amounts`` (the white reference being 1.0 in every channel).
    """
    amounts = _patch_scene(camera)
    scene = np.repeat(np.repeat(amounts, CELL, axis=0), CELL, axis=1)
    frame = render(camera, scene, noise=noise, rng=SCENE_SEED)
    at_centre = amounts @ _true_fields(camera)[2].T
    errors = {}
    for mode in ("uncorrected", "flat", "centre", "pure"):
        truth = amounts if mode == "pure" else at_centre
        patches = _patch_means(correct(frame, cal, mode))
        errors[mode] = np.linalg.norm(patches - truth, axis=-1) / np.linalg.norm(truth, axis=-1)
    return errors


# ---- fixtures: calibrations made on references of CALIBRATION_SEED only -----------------------------------------


@pytest.fixture(scope="module", params=[("imx219", "BGGR"), ("imx477", "GRBG")], ids=lambda p: p[0])
def camera(request):
    sensor, pattern = request.param
    return make_camera(sensor, pattern=pattern, size=SIZE)


@pytest.fixture(scope="module")
def noiseless_cal(camera):
    return calibrate(**simulate_references(camera, noise=False))


@pytest.fixture(scope="module")
def noisy_cal(camera):
    return calibrate(**simulate_references(camera, noise=True, seed=CALIBRATION_SEED))


# ---- the calibration against the simulator's fields -------------------------------------------------------------


def test_calibration_recovers_the_true_flat_field_and_unmixing(camera, noiseless_cal):
    white, m, m_centre = _true_fields(camera)
    u = m_centre @ np.linalg.inv(m)  # the unmixing of the ``centre`` mode, U = M_centre M^-1
    # Only quantisation to integer DN separates the files from the model: 0.3 % on the flat field,
    # 0.01 on the matrix elements (which reach ~2 in the corners).
    np.testing.assert_allclose(noiseless_cal.white, white, rtol=3e-3)
    np.testing.assert_allclose(noiseless_cal.crosstalk, m, atol=5e-3)
    np.testing.assert_allclose(noiseless_cal.unmixing, u, atol=1e-2)
    assert noiseless_cal.condition_number.max() < 20


def test_calibration_recovers_the_truth_with_noise_to_within_noise():
    camera = make_camera("imx219", size=SIZE)
    cal = calibrate(**simulate_references(camera, noise=True, seed=4))
    _, m, m_centre = _true_fields(camera)
    u = m_centre @ np.linalg.inv(m)
    # Shot and read noise over 64 pixels per site and bin, amplified by inverting M: measured 0.004 mean and
    # 0.03 at the 99th percentile over the 40 x 30 bins and 9 elements (elements reach 2.3 in the corners).
    error = np.abs(cal.unmixing - u)
    assert error.mean() < 0.01
    assert np.percentile(error, 99) < 0.05


# ---- a held-out white ------------------------------------------------------------------------------------------


def test_flat_field_flattens_a_held_out_white_down_to_its_noise(camera, noisy_cal):
    white = render(camera, "white", noise=True, rng=WHITE_SEED)
    flat = correct(white, noisy_cal, "flat", binned=True)
    cv = flat.std(axis=(0, 1)) / flat.mean(axis=(0, 1))
    floor = _noise_floor(camera)
    # What is left is the noise of the two frames and nothing else: the spread over 1200 bins estimates the floor
    # to ~2 %, so 15 % above it would be a residual flat-field error of half the noise (measured 0.99-1.02).
    assert np.all(cv < 1.15 * floor) and np.all(cv > 0.85 * floor), (cv, floor)
    uncorrected = correct(white, noisy_cal, "uncorrected", binned=True)
    # Vignetting: uncorrected, the same frame varies by 3 % (red falls off least, as in the paper) to 15 %.
    assert np.all(uncorrected.std(axis=(0, 1)) / uncorrected.mean(axis=(0, 1)) > 5 * floor)


def test_flat_field_flattens_a_dimmer_white_at_full_resolution_without_block_edges(camera, noiseless_cal):
    # Half the exposure of the references: a flat field that forgot the black level or were not linear would
    # show here, where the calibration's own white would be flat by construction.
    half = render(camera, (0.5, 0.5, 0.5), noise=False)
    binned = correct(half, noiseless_cal, "flat", binned=True) / 0.5
    # Rounding to integer DN moves a bin's mean by at most 0.5 DN, in this frame and in the calibration's white
    # (where the field is flat across a bin, as at the centre, every pixel rounds the same way and it does not
    # average out): measured 0.24 % at most, within the bound everywhere.
    bound = 0.5 / _bin_means(camera, (0.5, 0.5, 0.5)) + 0.5 / _bin_means(camera, (1.0, 1.0, 1.0))
    assert np.all(np.abs(binned - 1) <= bound), np.abs(binned - 1).max()
    green = correct(half, noiseless_cal, "flat")[..., 1] / 0.5
    # Every pixel, edges and corners included: the rounding of one pixel (0.5 DN in >= 110 DN, 0.45 %) and the
    # splines between bin centres (measured 0.36 % at most).
    assert np.abs(green - 1).max() < 0.01
    # The column profile has no steps or kinks: the cubic splines give at most 6e-5 per column and 1e-4 in second
    # differences here, while a nearest-bin field jumps by 2e-2 and a bilinear one kinks by 1e-2 at bin centres.
    profile = green.mean(axis=0)
    assert np.abs(np.diff(profile)).max() < 5e-4
    assert np.abs(np.diff(profile, 2)).max() < 5e-4


# ---- a held-out colour scene -----------------------------------------------------------------------------------


def test_held_out_colours_noiseless_are_restored_to_the_quantisation_floor(camera, noiseless_cal):
    errors = _colour_errors(camera, noiseless_cal, noise=False)
    # Only the references' rounding to integer DN separates the calibration from the model: 1 DN in ~300,
    # amplified up to ~4x by the unmixing in the corners, averaged over a bin (measured at most 0.2 %).
    assert errors["centre"].max() < 0.005, errors["centre"].max()
    assert errors["pure"].max() < 0.005, errors["pure"].max()


def test_held_out_colours_are_restored_at_the_corners_and_modes_order_as_physics_says(camera, noisy_cal):
    errors = _colour_errors(camera, noisy_cal, noise=True)
    corners = _corners(*errors["centre"].shape)
    # The calibration's own noise (about 0.4 % per bin on each reference's ratio to the white) amplified by the
    # unmixing, up to 4x in the corners; the held-out frame's noise averages out over a patch's 784 pixels.
    # Measured: corner mean 0.5-0.7 %, corner max 1.0-2.6 %, everywhere 3 % at most.
    for mode in ("centre", "pure"):
        assert errors[mode][corners].mean() < 0.015, (mode, errors[mode][corners].mean())
        assert errors[mode].max() < 0.05, (mode, errors[mode].max())
    # Physics orders the modes in every corner patch: uncorrected keeps vignetting and the colour cast (measured
    # 35 % mean), flat removes those but not the crosstalk that desaturates colours (15 %), centre removes both.
    # A grey has nothing to desaturate: there flat is as right as centre, to within the same noise.
    grey = (_patch_scene(camera).std(axis=-1) == 0) & corners
    colour = corners & ~grey
    assert np.all(errors["uncorrected"][corners] > errors["flat"][corners])
    assert np.all(errors["flat"][colour] > errors["centre"][colour])
    assert grey.any() and errors["flat"][grey].max() < 0.015
    assert errors["uncorrected"][corners].mean() > 0.25
    assert errors["flat"][corners].mean() > 0.10
    # The centre is where M_centre is measured: there flat and centre agree with the truth alike.
    middle = _centre(errors["flat"])
    assert middle.mean() < 0.01 and _centre(errors["centre"]).mean() < 0.01


def test_a_tilted_sensor_still_calibrates_and_restores_held_out_colours():
    camera = make_camera("imx219", size=SIZE, tilt=(3.0, -2.0))
    cal = calibrate(**simulate_references(camera, noise=True, seed=CALIBRATION_SEED))
    errors = _colour_errors(camera, cal, noise=True)
    corners = _corners(*errors["centre"].shape)
    # The tilt moves the vignetting centre off the frame's; the calibration follows it (same noise as above).
    assert errors["centre"][corners].mean() < 0.015 and errors["centre"].max() < 0.05
    assert errors["flat"][corners].mean() > 5 * errors["centre"][corners].mean()


# ---- noise -----------------------------------------------------------------------------------------------------


def test_noise_penalty_matches_noise_measured_on_simulated_frames():
    # Read noise only: dark frames of the simulated sensor, corrected with a noiseless calibration.
    camera = make_camera("imx219", size=(160, 120))
    cal = calibrate(**simulate_references(camera, noise=False), bin_size=8)
    rng = np.random.default_rng(11)
    frames = [render(camera, (0.0, 0.0, 0.0), noise=True, rng=rng) for _ in range(300)]
    noise = {mode: np.std([correct(f, cal, mode, binned=True) for f in frames], axis=0) for mode in ("flat", "centre")}
    reference = _centre(noise["flat"]).reshape(-1, 3).mean(0)  # each channel's noise at the centre, flat field only
    # A binned green averages twice as many pixels as red or blue, hence the relative input noise.
    for mode in ("flat", "centre"):
        predicted = cal.noise_penalty(mode, channel_noise=(1.0, 2**-0.5, 1.0))
        ratio = noise[mode] / reference / predicted
        # 300 frames give each bin's std to ~4 %; the median over bins must agree within 10 %, and 95 % of bins
        # within the sampling spread.
        assert abs(np.median(ratio) - 1) < 0.10, (mode, np.median(ratio))
        assert np.mean(np.abs(ratio - 1) < 0.15) > 0.95
    assert cal.noise_penalty("centre").max() > 1.5  # the test would be empty if unmixing cost nothing
