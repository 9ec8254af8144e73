"""The fused correction kernels: numba and numpy agree with each other and with the plain reference.

Tolerances, on images whose white reference is 1.0:

- numba vs numpy: 1e-6. Both do the same float32 operations in the same order (they are equal to
  the bit on this machine; a compiler may still contract or reorder one operation, a few ulp).
- fused vs reference: 2e-5. The interpolant is the same spline (its B-spline form is checked
  against the dense matrices to 1e-12 below); what differs is float32 against the reference's float64
  in the spline evaluation and in colour-demosaicing's convolutions (measured: at most 3.6e-6).
"""

from __future__ import annotations

import dataclasses
import importlib
import sys
import tracemalloc
import warnings

import numpy as np
import pytest

from picamcal import PicamcalWarning, calibrate, correct
from picamcal.bayer import bin_centres
from picamcal.ckernel import c_available, correct_c
from picamcal.correct import CLIPPED_WARNING_FRACTION, correction_fields, demosaic, malvar_demosaic
from picamcal.errors import OutputError
from picamcal.interpolate import interpolation_matrix, spline_coefficients, spline_knots, spline_taps, upsample
from picamcal.kernels import CorrectionFields, correct_numpy, make_taps, numba_available
from picamcal.modes import Mode
from picamcal.raw import PATTERNS, RawImage
from picamcal.simulate import make_camera, simulate_references, simulate_target

MODES = tuple(Mode)
NUMBA_VS_NUMPY = 1e-6
FUSED_VS_REFERENCE = 2e-5

correct_module = importlib.import_module("picamcal.correct")  # the package's `correct` is the function
needs_numba = pytest.mark.skipif(not numba_available(), reason="numba is not installed")
needs_c = pytest.mark.skipif(not c_available(), reason="the C kernel cannot be compiled here")


def _scene(sensor: str, pattern: str, size: tuple[int, int], bin_size: int = 16):
    camera = make_camera(sensor, pattern=pattern, size=size)
    cal = calibrate(**simulate_references(camera, seed=1), bin_size=bin_size)
    target, _ = simulate_target(camera, seed=2)
    return cal, target


#: The Raspberry Pi camera modules' sensors: the kernels know nothing of sensors, only of bit depths and sizes.
KERNEL_SENSORS = ("ov5647", "imx219", "imx477", "imx708")


@pytest.fixture(scope="module", params=[(s, p) for s in KERNEL_SENSORS for p in PATTERNS], ids="-".join)
def small(request):
    """A 200 x 160 frame of every sensor in every Bayer order, with its calibration."""
    return _scene(*request.param, size=(200, 160))


@pytest.mark.parametrize("mode", MODES)
def test_numpy_path_matches_the_reference(small, mode):
    cal, target = small
    fused = correct(target, cal, mode, engine="numpy")
    reference = correct(target, cal, mode, engine="reference")
    assert fused.dtype == np.float32 and fused.shape == (160, 200, 3)
    np.testing.assert_allclose(fused, reference, rtol=0, atol=FUSED_VS_REFERENCE)


@needs_numba
@pytest.mark.parametrize("mode", MODES)
def test_numba_kernel_matches_the_numpy_path(small, mode):
    cal, target = small
    fused = correct(target, cal, mode, engine="numba")
    np.testing.assert_allclose(fused, correct(target, cal, mode, engine="numpy"), rtol=0, atol=NUMBA_VS_NUMPY)
    np.testing.assert_allclose(fused, correct(target, cal, mode, engine="reference"), rtol=0, atol=FUSED_VS_REFERENCE)


@pytest.mark.parametrize(
    ("sensor", "size", "bin_size"),
    [
        ("imx477", (1000, 800), 16),  # a larger frame, with a partial last bin column
        ("imx219", (202, 162), 10),  # bins of 10: knot intervals that start at odd pixels; size 2 mod 4
        ("ov5647", (40, 24), 16),  # 3 x 2 bins: the natural splines of interpolation_matrix
        ("imx708", (32, 16), 16),  # one row of two bins: constant along y, linear along x
    ],
)
@pytest.mark.parametrize("mode", ["flat", "pure"])
def test_engines_agree_on_other_geometries(sensor, size, bin_size, mode):
    cal, target = _scene(sensor, "GRBG", size, bin_size)
    reference = correct(target, cal, mode, engine="reference")
    fused = correct(target, cal, mode, engine="numpy")
    np.testing.assert_allclose(fused, reference, rtol=0, atol=FUSED_VS_REFERENCE)
    if numba_available():
        np.testing.assert_allclose(correct(target, cal, mode, engine="numba"), fused, rtol=0, atol=NUMBA_VS_NUMPY)


@pytest.mark.parametrize("height", [200, 162, 40, 20, 12])
@pytest.mark.parametrize("site", [None, 0, 1])
def test_local_spline_is_the_cubic_spline_of_interpolation_matrix(height, site):
    from scipy.interpolate import CubicSpline

    def scipys(centres, positions):  # the cubic spline interpolation_matrix stands for, by scipy
        if centres.size == 1:
            return np.ones((positions.size, 1))
        bc = "not-a-knot" if centres.size > 3 else "natural"
        return CubicSpline(centres, np.eye(centres.size), axis=0, bc_type=bc)(positions)

    width = 4056
    cy, cx = bin_centres(height, 16, site), bin_centres(width, 16, site)
    field = np.random.default_rng(height).normal(size=(cy.size, cx.size))
    y, x = np.arange(height), np.arange(width)
    for centres, positions in ((cy, y), (cx, x)):  # every pixel, the outer half-bins extrapolated
        np.testing.assert_allclose(
            interpolation_matrix(centres, positions), scipys(centres, positions), rtol=0, atol=1e-12
        )
    dense = upsample(field, scipys(cy, y), scipys(cx, x))
    coefficients = spline_coefficients(field, cy, cx)
    (iy, wy), (ix, wx) = spline_taps(spline_knots(cy), y), spline_taps(spline_knots(cx), x)
    rows = np.einsum("ya,yac->yc", wy, coefficients[iy[:, None] + np.arange(4)])
    local = np.einsum("yxb,xb->yx", rows[:, ix[:, None] + np.arange(4)], wx)
    # The same piecewise cubic in another basis: agreement to double rounding (values are ~1).
    np.testing.assert_allclose(local, dense, rtol=0, atol=1e-12)


@pytest.mark.parametrize("n", [2, 3, 4, 5, 9, 154, 254])
@pytest.mark.parametrize("spacing", ["bins", "uneven"])
def test_spline_coefficients_are_scipys_interpolating_splines(n, spacing):
    from scipy.interpolate import make_interp_spline

    def scipys(centres, values, axis):
        bc = "not-a-knot" if centres.size > 3 else "natural"
        spline = make_interp_spline(centres, values, k=3, bc_type=bc, axis=axis)
        return spline.t, np.moveaxis(spline.c, 0, axis)

    rng = np.random.default_rng(n)
    cy = 8.0 + 16 * np.arange(n) if spacing == "bins" else np.cumsum(rng.uniform(4, 40, n))
    cx = np.cumsum(rng.uniform(4, 40, 6))
    field = rng.normal(1, 0.3, size=(n, 6, 3))
    knots, along_y = scipys(cy, field, 0)
    np.testing.assert_array_equal(spline_knots(cy), knots)
    # The same system, solved by LU instead of scipy's banded LU: equal to double rounding (values are ~1).
    np.testing.assert_allclose(spline_coefficients(field, cy, cx), scipys(cx, along_y, 1)[1], rtol=0, atol=1e-12)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_kernel_demosaic_is_malvar_he_cutler_with_colour_demosaicings_borders(pattern):
    mosaic = np.random.default_rng(3).integers(0, 1024, size=(22, 30)).astype(np.uint16)
    unused = make_taps(np.zeros(1, np.int64), np.zeros((1, 4)))
    fields = CorrectionFields(
        black=np.zeros(4, np.float32),
        channels=np.array(["RGB".index(c) for c in pattern]),
        site_gains=np.ones(4, np.float32),
        white=None,
        white_rows=unused,
        matrices=None,
        matrix_rows=unused,
        matrix_cols=unused,
    )
    expected = demosaic(mosaic.astype(np.float32), pattern)
    # Exact, borders included: on integers below 2**10 every partial sum is a multiple of 1/16 below
    # 2**13, which float32 holds exactly, as it does colour-demosaicing's float64 result.
    np.testing.assert_array_equal(correct_numpy(mosaic, fields), expected)
    if numba_available():
        from picamcal.kernels import correct_numba

        np.testing.assert_array_equal(correct_numba(mosaic, fields), correct_numpy(mosaic, fields))


@pytest.mark.parametrize("pattern", PATTERNS)
def test_malvar_demosaic_is_colour_demosaicings_without_importing_it(pattern):
    # apply_tuning and analyse demosaic with the kernels' arithmetic alone: the reference's result, exactly on
    # integers, to float32 rounding on gains (rows in several blocks, borders included).
    rng = np.random.default_rng(4)
    integers = rng.integers(0, 1024, size=(22, 30)).astype(np.float32)
    np.testing.assert_array_equal(malvar_demosaic(integers, pattern, block_rows=8), demosaic(integers, pattern))
    floats = (rng.random((130, 96)) * 3).astype(np.float32)
    np.testing.assert_allclose(malvar_demosaic(floats, pattern, block_rows=16), demosaic(floats, pattern), atol=2e-6)


@pytest.fixture(scope="module")
def larger():
    return _scene("imx477", "RGGB", (1000, 800))


@pytest.mark.usefixtures("no_c_kernel")  # else auto is the C kernel
def test_auto_falls_back_to_numpy_when_numba_cannot_be_imported(larger, monkeypatch):
    cal, target = larger
    expected = correct(target, cal, "centre", engine="numpy")
    monkeypatch.setitem(sys.modules, "numba", None)  # import numba now raises ImportError
    correct_module.numba_available.cache_clear()
    try:

        def no_numba(*args, **kwargs):
            raise AssertionError("the numba kernel ran without numba")

        monkeypatch.setattr(correct_module, "correct_numba", no_numba)
        assert not correct_module.numba_available()
        np.testing.assert_array_equal(correct(target, cal, "centre"), expected)
        monkeypatch.undo()
        monkeypatch.setitem(sys.modules, "numba", None)
        with pytest.raises(ImportError):
            correct(target, cal, "centre", engine="numba")
    finally:
        correct_module.numba_available.cache_clear()


@pytest.mark.parametrize("engine", ["numpy", pytest.param("numba", marks=needs_numba)])
def test_no_full_resolution_field_is_allocated(larger, engine):
    cal, target = larger
    output_bytes = target.height * target.width * 3 * 4
    correct(target, cal, "centre", engine=engine)  # compile, and cache the fields
    tracemalloc.start()
    try:
        correct(target, cal, "centre", engine=engine)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # The output plus a few rows (measured 1.01 with numba, 1.28 with numpy, 8.5 for the reference): one
    # full-resolution 3x3 field alone would be 3 outputs, a full-resolution gain mosaic a third of one.
    assert peak < 1.5 * output_bytes, peak / output_bytes
    fields = correction_fields(cal, "centre", target.height, target.width)
    arrays = [a for value in fields for a in (value if isinstance(value, tuple) else [value]) if a is not None]
    assert sum(a.nbytes for a in arrays) < 0.1 * output_bytes


def test_out_receives_the_result_and_is_checked(larger):
    cal, target = larger
    out = np.full((target.height, target.width, 3), np.nan, dtype=np.float32)
    for engine in ("auto", "numpy", "reference"):
        assert correct(target, cal, "flat", engine=engine, out=out) is out
        np.testing.assert_allclose(out, correct(target, cal, "flat", engine="reference"), atol=FUSED_VS_REFERENCE)
    with pytest.raises(OutputError, match="out must be"):
        correct(target, cal, "flat", engine="numpy", out=out[:, :-2])
    with pytest.raises(OutputError, match="out must be"):
        correct(target, cal, "flat", engine="reference", out=out[:, :-2])
    with pytest.raises(ValueError, match="binned"):
        correct(target, cal, "flat", binned=True, out=out)
    with pytest.raises(ValueError, match="unknown engine"):
        correct(target, cal, "flat", engine="cuda")


def test_cached_fields_belong_to_one_calibration_value():
    cal, target = _scene("imx219", "BGGR", (64, 48))
    before = correct(target, cal, "centre", engine="numpy")
    # A changed calibration is a new value: the fields kept for the old one are not used for it.
    halved = dataclasses.replace(cal, unmixing=cal.unmixing * np.float32(0.5))
    np.testing.assert_allclose(correct(target, halved, "centre", engine="numpy"), before * 0.5, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(correct(target, cal, "centre", engine="numpy"), before)
    with pytest.raises(ValueError, match="read-only"):
        cal.unmixing[:] *= 2  # nothing can change the value the cache was computed from


def test_black_level_is_per_site():
    pattern = "BGGR"
    cal, target = _scene("imx219", pattern, (64, 48))
    shifted = RawImage(target.bayer + np.uint16(3), pattern, tuple(b + 3 for b in target.black_level), 1023, 10)
    np.testing.assert_allclose(
        correct(shifted, cal, "centre", engine="numpy"), correct(target, cal, "centre", engine="numpy"), atol=1e-6
    )


@pytest.mark.parametrize(
    "engine", ["numpy", "reference", pytest.param("numba", marks=needs_numba), pytest.param("c", marks=needs_c)]
)
@pytest.mark.parametrize("share", [0.3, 0.005])
def test_clipped_pixels_are_warned_of_from_every_engine_the_c_kernel_counting_as_it_reads(engine, share):
    # The C kernel counts the samples at the white level as it reads the mosaic (no pass of its own over the frame):
    # the same count as numpy's, so the same warning, naming the file, and none for a few highlights (0.5 %).
    cal, target = _scene("imx219", "RGGB", (120, 80))
    bayer = target.bayer.copy()
    bayer[np.random.default_rng(1).random(bayer.shape) < share] = target.white_level
    clipped = dataclasses.replace(target, bayer=bayer, metadata={**target.metadata, "path": "scan.dng"})
    expected = int(np.count_nonzero(bayer >= target.white_level))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        correct(clipped, cal, "centre", engine=engine)
    ours = [w for w in caught if issubclass(w.category, PicamcalWarning)]
    messages = [str(w.message) for w in ours]
    if share < CLIPPED_WARNING_FRACTION:
        assert messages == []
    else:
        assert messages == [
            f"scan.dng: {100 * expected / bayer.size:.3g} % of its pixels are at the white level "
            f"(1023): clipped, they cannot be corrected; reduce the exposure"
        ]
        assert ours[0].filename == __file__  # said where correct was called
    if engine == "c":
        count = np.zeros(1, np.int64)
        fields = correction_fields(cal, "centre", target.height, target.width)
        correct_c(bayer, fields, clipped=(target.white_level, count))
        assert count[0] == expected
