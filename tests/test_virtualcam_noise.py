"""The virtual camera's sensor noise is the sensor model's (picamcal.virtualcam.frames): shot noise with the Poisson
variance at the optics' conversion gain and read noise, both amplified by the analogue gain, then rounding; each
frame's own, and the same wherever the flips put a pixel."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from picamcal.raw.model import site_channels
from picamcal.sensors import black_level_at, get_sensor
from picamcal.simulate import Optics
from picamcal.virtualcam.frames import REFERENCE_EXPOSURE_US, Scene, VirtualSensor
from picamcal.virtualcam.modes import scaled_spec, sensor_spec

FRAMES = 8
EXPOSURE_US, GAIN = 8000.0, 2.0


@pytest.fixture(scope="module")
def sensor() -> VirtualSensor:
    # The colour wheel: every level from the dark ring to 0.4 of the white level (none clipped), in all channels.
    return VirtualSensor(scaled_spec(sensor_spec("imx477"), (320, 240)), Scene("wheel"), seed=4, brightness=0.25)


@pytest.mark.parametrize("flips", [(False, False), (True, True), (True, False)])
def test_each_bayer_channels_noise_has_the_sensor_models_mean_and_variance(sensor, flips):
    mode = sensor.spec.modes[-1]  # the full 320 x 240 array, 12 bits
    bits = mode.bit_depth
    optics = Optics()
    black = black_level_at(get_sensor("imx477"), bits)
    electrons_per_dn = optics.electrons_per_dn * 2.0 ** (10 - bits)  # at the mode's bit depth
    read_dn = optics.read_noise_dn * 2.0 ** (bits - 10)
    fraction = sensor.brightness * EXPOSURE_US / REFERENCE_EXPOSURE_US * GAIN
    signal = sensor._rendered(mode).oriented(*flips).astype(np.float64) * fraction  # the noiseless DN above black
    # Shot noise (Poisson: the signal's electrons) and read noise, amplified by the gain; rounding adds 1/12 DN^2.
    variance = signal * GAIN / electrons_per_dn + (read_dn * GAIN) ** 2 + 1 / 12
    frames = np.stack([sensor.capture(mode, EXPOSURE_US, GAIN, n, *flips) for n in range(FRAMES)]).astype(np.float64)
    assert frames.max() < (1 << bits) - 1 and frames.min() > 0  # nothing clipped: the model holds everywhere
    z = (frames - black - signal) / np.sqrt(variance)
    channels = site_channels(sensor.order(*flips))
    for channel in range(3):
        sites = [divmod(site, 2) for site in range(4) if channels[site] == channel]
        values = np.concatenate([z[:, sy::2, sx::2].ravel() for sy, sx in sites])
        n = values.size  # 8 frames of 19 200 (red, blue) or 38 400 (green) pixels
        # Unit normal deviates: the mean within 5 standard errors of 0, the variance within 5 of 1.
        assert abs(values.mean()) < 5 / np.sqrt(n), (channel, values.mean())
        assert abs(values.var() - 1) < 5 * np.sqrt(2 / n), (channel, values.var())
    # Each frame draws its own noise: consecutive frames' deviates are uncorrelated (5 standard errors).
    for a, b in itertools.pairwise(z):
        assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 5 / np.sqrt(a.size)
    # The same frame number gives the same frame (a run is reproducible from its seed).
    np.testing.assert_array_equal(sensor.capture(mode, EXPOSURE_US, GAIN, 3, *flips), frames[3])


def test_the_flips_mirror_the_noiseless_frame(sensor):
    mode = sensor.spec.modes[-1]
    upright = sensor.capture(mode, EXPOSURE_US, GAIN, 0, noise=False)
    for hflip, vflip in ((True, True), (True, False), (False, True), (False, False)):
        mirrored = upright[:: -1 if vflip else 1, :: -1 if hflip else 1]
        np.testing.assert_array_equal(sensor.capture(mode, EXPOSURE_US, GAIN, 0, hflip, vflip, noise=False), mirrored)


def test_the_compiled_readout_makes_the_numpy_paths_frames(sensor, monkeypatch):
    pytest.importorskip("numba")
    from picamcal.virtualcam import frames

    mode = sensor.spec.modes[-1]
    compiled = [sensor.capture(mode, EXPOSURE_US, GAIN, 5, *flips) for flips in ((True, True), (False, False))]
    monkeypatch.setattr(frames, "_compiled_readout", lambda: None)
    for frame, flips in zip(compiled, ((True, True), (False, False)), strict=True):
        np.testing.assert_array_equal(frame, sensor.capture(mode, EXPOSURE_US, GAIN, 5, *flips))
