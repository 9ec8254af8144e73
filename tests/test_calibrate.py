"""The paper's maths on an exactly known linear sensor model (tests/conftest.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import linear_mixing, render_linear
from picamcal import CalibrationInputError, PicamcalWarning, calibrate, correct
from picamcal.bayer import bin_sites, centre_region, sites_to_channels
from picamcal.calibrate import REFUSE_CONDITION, REFUSE_WHITE_FRACTION, invert_3x3
from picamcal.raw import RawImage


def test_invert_3x3_matches_numpy_on_random_stacks():
    rng = np.random.default_rng(0)
    m = rng.normal(size=(500, 3, 3)) + 3 * np.eye(3)
    inverse, det = invert_3x3(m)
    np.testing.assert_allclose(inverse, np.linalg.inv(m), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(det, np.linalg.det(m), rtol=1e-10)


def test_invert_3x3_keeps_float32():
    m = (np.random.default_rng(1).normal(size=(100, 3, 3)) + 3 * np.eye(3)).astype(np.float32)
    inverse, _ = invert_3x3(m)
    assert inverse.dtype == np.float32
    np.testing.assert_allclose(inverse, np.linalg.inv(m.astype(np.float64)), rtol=1e-4, atol=1e-5)


def test_invert_3x3_singular_gives_non_finite():
    inverse, det = invert_3x3(np.ones((3, 3)))
    assert det == 0 and not np.isfinite(inverse).any()


@given(st.lists(st.floats(-10, 10, allow_nan=False), min_size=9, max_size=9))
def test_invert_3x3_property(values):
    m = np.array(values).reshape(3, 3)
    inverse, det = invert_3x3(m)
    if abs(det) > 1e-3 and np.linalg.cond(m) < 1e6:
        np.testing.assert_allclose(m @ inverse, np.eye(3), atol=1e-6)


def test_centre_region_is_the_central_ninth():
    # The paper's 2019 code took rows 4/9 to the bottom edge; this must be the middle third in each axis.
    assert centre_region(154, 205) == (51, 102, 68, 136)
    assert centre_region(9, 9) == (3, 6, 3, 6)
    assert centre_region(2, 2) == (0, 1, 0, 1)  # at least one bin each way, however small the grid


def test_the_calibration_records_the_central_ninth_it_unmixed_to(linear_refs):
    cal = calibrate(**linear_refs)
    assert cal.centre_region == centre_region(*cal.bins) == (4, 8, 5, 10)  # 12 x 16 bins of 16 pixels
    m = cal.crosstalk[cal.centre_slices].reshape(-1, 3, 3).mean(axis=0)
    np.testing.assert_allclose(cal.centre_response, m, rtol=1e-6)  # M_centre is M's mean over that region


def test_white_maps_to_one_and_centre_unmixing_is_identity(linear_refs):
    cal = calibrate(**linear_refs)
    ys, xs = cal.centre_slices
    centre_u = cal.unmixing[ys, xs].mean(axis=(0, 1))
    # The mean of U over the centre region is M_c @ mean(inv(M)); with smooth M it is the identity to 1e-3.
    np.testing.assert_allclose(centre_u, np.eye(3), atol=2e-3)
    for mode in ("flat", "centre", "pure"):
        binned = correct(linear_refs["white"], cal, mode, binned=True)
        # Exact by construction (M @ 1 = 1 per bin): float32 rounding only.
        np.testing.assert_allclose(binned, 1.0, atol=1e-5)


def test_recovers_the_true_mixing_field(linear_refs):
    cal = calibrate(**linear_refs)
    pattern = linear_refs["white"].pattern
    mixing = linear_mixing(192, 256, pattern)  # (H, W, primary) for the pixel's own channel
    site_mix = np.stack([bin_sites(mixing[..., p], 16) for p in range(3)], axis=-1)  # (nby, nbx, 4, 3)
    white = site_mix.sum(-1)
    m_true = np.moveaxis(sites_to_channels(np.moveaxis(site_mix / white[..., None], -1, 0), pattern), 0, -1)
    # True M already has M @ 1 = 1 (white is the sum of the primaries); quantisation to integer DN is the only error.
    np.testing.assert_allclose(cal.crosstalk, m_true, atol=2e-3)
    true_white = sites_to_channels(white * 700, pattern)
    np.testing.assert_allclose(cal.white, true_white, rtol=3e-3)
    u_true = m_true[cal.centre_slices].reshape(-1, 3, 3).mean(0) @ np.linalg.inv(m_true)
    np.testing.assert_allclose(cal.unmixing, u_true, atol=1e-2)


@settings(max_examples=15, deadline=None)
@given(st.tuples(*[st.floats(0.0, 1.0)] * 3).filter(lambda a: sum(a) > 0.3))
def test_unmixing_a_mixed_colour_gives_it_back(amounts):
    # A uniform field of any mix of the primaries: `pure` returns the amounts, `centre` the centre's colour,
    # in every bin. 12-bit quantisation of the darkest corner limits the agreement to ~1e-2.
    pattern = "GBRG"
    mixing = linear_mixing(96, 128, pattern)
    refs = {
        name: RawImage(render_linear(mixing, a, scale=3000, black=256, bits=12), pattern, (256,) * 4, 4095, 12)
        for name, a in {"white": (1, 1, 1), "red": (1, 0, 0), "green": (0, 1, 0), "blue": (0, 0, 1)}.items()
    }
    cal = calibrate(**refs, bin_size=8)
    image = RawImage(render_linear(mixing, amounts, scale=3000, black=256, bits=12), pattern, (256,) * 4, 4095, 12)
    pure = correct(image, cal, "pure", binned=True)
    np.testing.assert_allclose(pure, np.broadcast_to(amounts, pure.shape), atol=1.5e-2)
    centre = correct(image, cal, "centre", binned=True)
    np.testing.assert_allclose(centre, np.broadcast_to(cal.centre_response @ amounts, centre.shape), atol=1.5e-2)


def test_black_frame_is_used_when_given(linear_refs):
    refs = dict(linear_refs)
    offset = refs["black"].bayer.astype(np.int32) + 5  # the dark frame sits 5 DN above the files' black level
    refs = {
        k: RawImage(
            np.clip(r.bayer.astype(np.int32) + 5, 0, 1023).astype(np.uint16),
            r.pattern,
            r.black_level,
            1023,
            10,
            "imx219",
        )
        for k, r in refs.items()
    }
    assert offset.min() == 69
    with_black = calibrate(**refs)
    without = calibrate(**{k: v for k, v in refs.items() if k != "black"})
    # With the dark frame the 5 DN offset is removed exactly; without it, it biases the white.
    np.testing.assert_allclose(with_black.white, calibrate(**linear_refs).white, rtol=1e-6)
    assert np.all(without.white > with_black.white + 4.9)
    assert with_black.provenance["black_frame"] and not without.provenance["black_frame"]
    assert (with_black.black_level_source, without.black_level_source) == ("dark frame", "references")


def test_smoothing_reduces_noise_in_the_fields(linear_refs):
    rng = np.random.default_rng(3)
    noisy = {
        k: RawImage(
            np.clip(r.bayer + rng.normal(0, 8, r.bayer.shape), 0, 1023).astype(np.uint16),
            r.pattern,
            r.black_level,
            1023,
            10,
        )
        for k, r in linear_refs.items()
    }

    def roughness(u):  # bin-to-bin jitter: what smoothing removes, and what the paper says indicates dirt
        return np.abs(np.diff(u, n=2, axis=1)).mean()

    clean = roughness(calibrate(**linear_refs).unmixing)  # the field's own curvature
    rough = roughness(calibrate(**noisy).unmixing) - clean
    smooth = roughness(calibrate(**noisy, smoothing=1.5).unmixing) - clean
    assert smooth < 0.3 * rough


def _with(raw: RawImage, **changes) -> RawImage:
    fields = {
        "bayer": raw.bayer,
        "pattern": raw.pattern,
        "black_level": raw.black_level,
        "white_level": raw.white_level,
        "bit_depth": raw.bit_depth,
        "sensor": raw.sensor,
        "metadata": dict(raw.metadata),
    }
    fields.update(changes)
    return RawImage(**fields)


def test_bad_references_are_refused_with_the_file_named(linear_refs):
    refs = dict(linear_refs)
    with pytest.raises(CalibrationInputError, match=r"<red>: size 128x192 differs"):
        calibrate(**{**refs, "red": _with(refs["red"], bayer=refs["red"].bayer[:, :128])})
    with pytest.raises(CalibrationInputError, match=r"<green>: Bayer pattern .* differs"):
        other = "GRBG" if refs["green"].pattern != "GRBG" else "RGGB"
        calibrate(**{**refs, "green": _with(refs["green"], pattern=other)})
    saturated = _with(refs["white"], bayer=np.minimum(refs["white"].bayer.astype(np.int32) * 3, 1023).astype(np.uint16))
    with pytest.raises(CalibrationInputError, match="<white>: white reference is saturated"):
        calibrate(**{**refs, "white": saturated})
    dark = _with(refs["white"], bayer=(64 + (refs["white"].bayer - 64) // 40).astype(np.uint16))
    refused = rf"<white>: white reference is too dark: .* \(at least {100 * REFUSE_WHITE_FRACTION:.0f} % needed\)"
    with pytest.raises(CalibrationInputError, match=refused):
        calibrate(**{**refs, "white": dark})
    with pytest.raises(CalibrationInputError, match=r"<white>: black frame .* not darker"):
        calibrate(**{**refs, "black": _with(refs["white"])})
    with pytest.raises(CalibrationInputError, match="bin size must be an even"):
        calibrate(**refs, bin_size=15)


def test_colourless_references_are_refused(linear_refs):
    refs = dict(linear_refs)
    grey = {k: refs["white"] for k in ("red", "green", "blue")}
    with pytest.raises(CalibrationInputError, match=rf"do not separate the colours: .*> {REFUSE_CONDITION:g}\)"):
        calibrate(refs["white"], **grey)


def test_a_few_ill_conditioned_bins_are_filled_and_reported(linear_refs):
    refs = dict(linear_refs)
    red = refs["red"].bayer.copy()
    red[:16, :16] = refs["white"].bayer[:16, :16]  # one bin where "red" is white: M is singular there
    with pytest.warns(PicamcalWarning, match="1 of 192 bins have an ill-conditioned"):
        cal = calibrate(**{**refs, "red": _with(refs["red"], bayer=red)})
    assert cal.ill_conditioned[0, 0] and cal.ill_conditioned.sum() == 1
    assert cal.ill_conditioned_bins == 1 and cal.to_record()["ill_conditioned_bins"] == 1
    neighbours = [cal.unmixing[0, 1], cal.unmixing[1, 0], cal.unmixing[1, 1]]
    assert any(np.array_equal(cal.unmixing[0, 0], n) for n in neighbours)
