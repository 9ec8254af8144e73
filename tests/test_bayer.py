"""The block average every binning goes through (:func:`picamcal.bayer.block_mean`, :func:`picamcal.bayer.bin_sites`),
against the plain mean of each block, whole and partial, in 2-D and with channels."""

from __future__ import annotations

import numpy as np
import pytest

from picamcal.bayer import bin_sites, block_mean


def _plain_block_mean(values: np.ndarray, block: int) -> np.ndarray:
    rows, cols = range(0, values.shape[0], block), range(0, values.shape[1], block)
    return np.array([[values[y : y + block, x : x + block].mean(axis=(0, 1)) for x in cols] for y in rows])


@pytest.mark.parametrize("shape", [(48, 64), (50, 70), (7, 5), (3, 2), (33, 17, 3)])
@pytest.mark.parametrize("block", [1, 2, 5, 8])
def test_block_mean_is_the_mean_of_each_block_partial_ones_included(shape, block):
    values = np.random.default_rng(0).random(shape) * 1000
    # Sums of up to 64 values in float64: equal to the plain mean to rounding (1e-9 of values up to 1000).
    np.testing.assert_allclose(block_mean(values, block), _plain_block_mean(values, block), rtol=0, atol=1e-9)
    whole = block_mean(values, block, partial=False)
    assert whole.shape[:2] == (shape[0] // block, shape[1] // block)
    np.testing.assert_allclose(whole, _plain_block_mean(values, block)[: whole.shape[0], : whole.shape[1]], atol=1e-9)


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_bin_sites_averages_each_bayer_site_over_each_bin(dtype):
    mosaic = (np.random.default_rng(1).random((70, 90)) * 4000).astype(dtype)
    sites = bin_sites(mosaic, 16)
    assert sites.shape == (5, 6, 4)
    for k, (sy, sx) in enumerate([(0, 0), (0, 1), (1, 0), (1, 1)]):
        plane = mosaic[sy::2, sx::2].astype(np.float64)
        np.testing.assert_allclose(sites[..., k], _plain_block_mean(plane, 8), rtol=0, atol=1e-9)
