"""uint16 codes straight from the correction (``correct(..., dtype=np.uint16)``), and numba imported only when needed.

The codes must be bit for bit those of ``output.tiff.encode_uint16(correct(...))`` (tolerance 0: the kernel
computes the same float32 value and scales it by a power of two, which is exact, before the same rounding).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import tifffile

from picamcal import calibrate, correct
from picamcal.ckernel import c_available, correct_c
from picamcal.correct import UINT16_WHITE
from picamcal.errors import OutputError
from picamcal.kernels import CorrectionFields, correct_numpy, make_taps, numba_available
from picamcal.output.tiff import encode_uint16, write_tiff
from picamcal.raw import RawImage
from picamcal.simulate import make_camera, simulate_references, simulate_target

needs_numba = pytest.mark.skipif(not numba_available(), reason="numba is not installed")
needs_c = pytest.mark.skipif(not c_available(), reason="the C kernel cannot be compiled here")
ENGINES = ["numpy", "reference", pytest.param("numba", marks=needs_numba), pytest.param("c", marks=needs_c)]
SRC = Path(__file__).resolve().parents[1] / "src"


@pytest.fixture(scope="module")
def scene():
    camera = make_camera("imx477", pattern="GBRG", size=(202, 162))
    cal = calibrate(**simulate_references(camera, seed=1), bin_size=10)
    target, _ = simulate_target(camera, seed=2)
    # Out of range both ways: a third of the rows three times too bright (values over 2.0, clipped to 65535), a
    # third at zero (below black: negative values, clipped to 0).
    bayer = target.bayer.astype(np.int64)
    bayer[:54] = np.minimum(3 * bayer[:54], target.white_level)
    bayer[108:] = 0
    bright = RawImage(bayer.astype(np.uint16), target.pattern, target.black_level, target.white_level, target.bit_depth)
    return cal, bright


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("mode", ["uncorrected", "flat", "centre", "pure"])
def test_codes_are_those_of_encode_uint16_bit_for_bit(scene, engine, mode):
    cal, raw = scene
    codes = correct(raw, cal, mode, engine=engine, dtype=np.uint16)
    expected = encode_uint16(correct(raw, cal, mode, engine=engine))
    assert codes.dtype == np.uint16 and codes.shape == (raw.height, raw.width, 3)  # interleaved, as the TIFF
    np.testing.assert_array_equal(codes, expected)
    # The scene reaches both ends, so the clipping is exercised, and the white sits near its code.
    assert codes.min() == 0 and codes.max() == 65535


def _mosaic_fields(site_gains: list[float]) -> CorrectionFields:
    """Demosaic-only fields (no white, no matrix) with the given constant gain per Bayer site."""
    unused = make_taps(np.zeros(1, np.int64), np.zeros((1, 4)))
    return CorrectionFields(
        black=np.zeros(4, np.float32),
        channels=np.array([0, 1, 1, 2]),
        site_gains=np.array(site_gains, np.float32),
        white=None,
        white_rows=unused,
        matrices=None,
        matrix_rows=unused,
        matrix_cols=unused,
    )


@pytest.mark.parametrize(
    "site_gains",
    [
        [np.nan, 1 / 65536, 1 / 65536, -1 / 65536],  # NaN gives 0; negatives 0; halves of a code round to even
        [np.inf, 1 / 512, 1.0, 1 / 65536],  # infinities and values far over 2.0 give 65535
    ],
)
def test_codes_of_nan_infinity_negatives_and_halves(site_gains):
    mosaic = np.random.default_rng(5).integers(0, 1024, size=(24, 34)).astype(np.uint16)
    fields = _mosaic_fields(site_gains)
    with np.errstate(invalid="ignore"):  # infinity minus infinity in the demosaic: NaN, on purpose
        rgb = correct_numpy(mosaic, fields)
        numpy_codes = correct_numpy(mosaic, fields, code_scale=UINT16_WHITE)
    assert np.isnan(rgb).any() and (rgb < 0).any()
    # value * 32768 = raw / 2 on the sites of gain 1 / 65536: exact halves, where rounding half to even shows.
    assert np.any(np.modf(rgb * UINT16_WHITE)[0] == 0.5)
    expected = encode_uint16(rgb)
    np.testing.assert_array_equal(numpy_codes, expected)
    compiled = []
    if numba_available():
        from picamcal.kernels import correct_numba

        compiled.append(correct_numba)
    if c_available():
        compiled.append(correct_c)
    for kernel in compiled:
        np.testing.assert_array_equal(kernel(mosaic, fields), rgb)  # the same floats first
        np.testing.assert_array_equal(kernel(mosaic, fields, code_scale=UINT16_WHITE), expected)


@pytest.mark.parametrize("engine", ENGINES)
def test_out_takes_the_codes_and_is_reused(scene, engine):
    cal, raw = scene
    out = np.full((raw.height, raw.width, 3), 7, dtype=np.uint16)
    assert correct(raw, cal, "flat", engine=engine, out=out, dtype=np.uint16) is out
    np.testing.assert_array_equal(out, correct(raw, cal, "flat", engine=engine, dtype=np.uint16))
    assert correct(raw, cal, "centre", engine=engine, out=out, dtype=np.uint16) is out  # the same buffer again
    np.testing.assert_array_equal(out, correct(raw, cal, "centre", engine=engine, dtype=np.uint16))


@pytest.mark.parametrize("engine", ENGINES)
def test_wrong_out_is_refused_with_picamcals_error(scene, engine):
    cal, raw = scene
    h, w = raw.height, raw.width
    wrong = [
        np.empty((h, w, 3), np.float32),  # the codes' shape, not their type
        np.empty((3, h, w), np.uint16),  # the codes' type, planar
        np.empty((h, w + 2, 3), np.uint16)[:, :w],  # not contiguous
        np.empty((h, w, 3), np.uint16)[::-1],  # not contiguous either
    ]
    for out in wrong:
        with pytest.raises(OutputError, match=r"out must be .*uint16 .*\(162, 202, 3\)"):
            correct(raw, cal, "flat", engine=engine, out=out, dtype=np.uint16)
    with pytest.raises(OutputError, match="out must be"):
        correct(raw, cal, "flat", engine=engine, out=np.empty((h, w, 3), np.uint16))  # float32 asked for
    with pytest.raises(ValueError, match="dtype"):
        correct(raw, cal, "flat", engine=engine, dtype=np.float64)
    with pytest.raises(ValueError, match="binned"):
        correct(raw, cal, "flat", binned=True, dtype=np.uint16)


@pytest.mark.parametrize(
    "engine", ["numpy", pytest.param("numba", marks=needs_numba), pytest.param("c", marks=needs_c)]
)
def test_codes_need_no_float32_image_at_full_resolution(engine):
    camera = make_camera("imx477", size=(1000, 800))
    cal = calibrate(**simulate_references(camera, seed=1))
    target, _ = simulate_target(camera, seed=2)
    float_bytes = target.height * target.width * 3 * 4
    peaks = {}
    for dtype in (np.float32, np.uint16):
        correct(target, cal, "centre", engine=engine, dtype=dtype)  # compile, and cache the fields
        tracemalloc.start()
        try:
            correct(target, cal, "centre", engine=engine, dtype=dtype)
            peaks[dtype] = tracemalloc.get_traced_memory()[1] / float_bytes
        finally:
            tracemalloc.stop()
    # The codes are half a float32 image, so the peak drops by about half an image (measured, in float32 images:
    # 1.00 -> 0.50 with numba and C; 1.28 -> 0.86 with numpy, which adds one float32 block of 64 rows, large next
    # to this small frame); with a float32 image at full resolution besides, it would rise by half an image instead.
    assert peaks[np.uint16] < peaks[np.float32] - 0.4, peaks
    assert peaks[np.uint16] < (0.9 if engine == "numpy" else 0.52), peaks


def test_write_tiff_takes_the_codes_as_they_are(scene, tmp_path):
    cal, raw = scene
    rgb = correct(raw, cal, "centre")
    codes = correct(raw, cal, "centre", dtype=np.uint16)
    from_codes = write_tiff(tmp_path / "codes.tiff", codes, "uint16-tiff", {"source": "bright.dng"})
    from_rgb = write_tiff(tmp_path / "rgb.tiff", rgb, "uint16-tiff", {"source": "bright.dng"})
    assert from_codes.read_bytes() == from_rgb.read_bytes()  # the same file, metadata included
    np.testing.assert_array_equal(tifffile.imread(from_codes), codes)
    with pytest.raises(ValueError, match="uint16-tiff"):
        write_tiff(tmp_path / "f.tiff", codes, "float32-tiff")


def test_importing_correct_imports_no_numba():
    # In a fresh interpreter: importing the correction and asking whether numba is there must not import it
    # (about 0.2 s): only the numba kernel itself imports it.
    code = "\n".join(
        [
            "import sys, picamcal.correct",
            "available = sys.modules['picamcal.correct'].numba_available()",
            "print(available, 'numba' in sys.modules)",
        ]
    )
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert result.stdout.split() == [str(numba_available()), "False"]


@pytest.mark.usefixtures("no_c_kernel")  # else auto is the C kernel
def test_auto_falls_back_to_numpy_when_an_installed_numba_fails_to_import(scene, monkeypatch):
    cal, raw = scene
    correct_module = sys.modules["picamcal.correct"]
    expected = correct(raw, cal, "centre", engine="numpy", dtype=np.uint16)
    monkeypatch.setattr(correct_module, "numba_available", lambda: True)  # found, as find_spec would say
    monkeypatch.setitem(sys.modules, "numba", None)  # but importing it raises ImportError
    np.testing.assert_array_equal(correct(raw, cal, "centre", dtype=np.uint16), expected)
    with pytest.raises(ImportError):
        correct(raw, cal, "centre", engine="numba")
