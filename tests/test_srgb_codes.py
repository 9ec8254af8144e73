"""sRGB codes straight from the correction kernels (``correct(..., encoding=srgb_encoding(...))``) and from a float
image (``encode_srgb``), against the sRGB formats' definition as picamcal computed it before the kernels made them.

Tolerances:

- kernel codes against :func:`picamcal.output.colour.encode_srgb` of the same engine's float32 image: 0. Both take
  the same float32 values through the same float32 colour matrix product and the same table, exact to the
  transfer function for that product (the C kernel, numba and numpy alike).
- against the definition computed in float64 (``old_encode_srgb``, a copy of what ``encode_srgb`` did before): one
  code. The only difference is the colour matrix's product in float32 rather than float64, a relative error of a
  few 1e-7, which moves a value across a code's threshold only when it lies that close to one: measured on the
  scene below, in every engine, mode and white level, at most 1 code in 98 000 differs at 8 bits and 1 in 1 300 at
  16 bits (MOSTLY_EXACT allows ten and two and a half times that); where the product is exact (the identity
  matrix, a white level of 1) the codes are the definition's exactly.
"""

from __future__ import annotations

import sys
import tracemalloc

import numpy as np
import pytest
from PIL import Image

from conftest import run_measured, simulated_calibration
from picamcal import calibrate, correct, load_calibration, read_raw
from picamcal.ckernel import c_available, encode_image
from picamcal.kernels import encode_table, numba_available
from picamcal.output import write_corrected
from picamcal.output.colour import ColourMatrix, camera_to_srgb, encode_srgb, srgb_encoding
from picamcal.raw import RawImage
from picamcal.simulate import make_camera, simulate_references, simulate_target
from test_output import provenance, read_png16

needs_numba = pytest.mark.skipif(not numba_available(), reason="numba is not installed")
needs_c = pytest.mark.skipif(not c_available(), reason="the C kernel cannot be compiled here")
ENGINES = ["numpy", "reference", pytest.param("numba", marks=needs_numba), pytest.param("c", marks=needs_c)]
IMAGE_ENGINES = ["numpy", pytest.param("numba", marks=needs_numba), pytest.param("c", marks=needs_c)]
#: A camera matrix with strong crosstalk to undo, rows summing to 1, as libcamera's CCMs are.
CCM = ColourMatrix([[1.9, -0.6, -0.3], [-0.4, 1.7, -0.3], [0.1, -0.8, 1.7]], "a test matrix")
#: The least share of codes equal to the float64 definition's (see the module's docstring).
MOSTLY_EXACT = {8: 0.9999, 16: 0.998}


def srgb_transfer64(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1's encoding in float64, as picamcal.output.colour.srgb_transfer is."""
    return np.where(
        linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(np.maximum(linear, 0.0031308), 1 / 2.4) - 0.055
    )


def old_encode_srgb(rgb: np.ndarray, matrix: np.ndarray, white_level: float, bits: int) -> np.ndarray:
    """What ``encode_srgb`` computed before the kernels made the codes: the product in float64, then the curve."""
    with np.errstate(invalid="ignore"):  # 0 times infinity: NaN, which gives 0
        linear = np.asarray(rgb, dtype=float) @ (white_level * np.asarray(matrix, dtype=float)).T
    linear = np.fmin(np.fmax(linear, 0.0), 1.0)  # NaN gives 0; infinities clip
    return np.rint((2**bits - 1) * srgb_transfer64(linear)).astype(np.uint8 if bits == 8 else np.uint16)


@pytest.fixture(scope="module")
def scene():
    camera = make_camera("imx477", pattern="GBRG", size=(202, 162))
    cal = calibrate(**simulate_references(camera, seed=1), bin_size=10)
    target, _ = simulate_target(camera, seed=2)
    # Out of range both ways: a third of the rows three times too bright, a third at zero (below black).
    bayer = target.bayer.astype(np.int64)
    bayer[:54] = np.minimum(3 * bayer[:54], target.white_level)
    bayer[108:] = 0
    bright = RawImage(bayer.astype(np.uint16), target.pattern, target.black_level, target.white_level, target.bit_depth)
    return cal, bright


def assert_within_one_code_and_mostly_exact(codes: np.ndarray, expected: np.ndarray, bits: int) -> None:
    difference = np.abs(codes.astype(np.int64) - expected)
    assert difference.max() <= 1, difference.max()
    assert np.mean(difference == 0) >= MOSTLY_EXACT[bits], np.mean(difference == 0)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("mode", ["uncorrected", "flat", "centre", "pure"])
@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("white_level", [0.8, 1.7])
def test_kernel_codes_are_encode_srgb_of_the_float_image_and_within_a_code_of_before(
    scene, engine, mode, bits, white_level
):
    cal, raw = scene
    encoding = srgb_encoding(CCM, white_level=white_level, bits=bits)
    codes = correct(raw, cal, mode, engine=engine, encoding=encoding)
    assert codes.dtype == (np.uint8 if bits == 8 else np.uint16) and codes.shape == (raw.height, raw.width, 3)
    rgb = correct(raw, cal, mode, engine=engine)
    np.testing.assert_array_equal(codes, encode_srgb(rgb, CCM, white_level=white_level, bits=bits))
    assert_within_one_code_and_mostly_exact(codes, old_encode_srgb(rgb, CCM.matrix, white_level, bits), bits)
    # The scene reaches both ends and many codes between (the matrix mixes the channels: no two alike).
    assert codes.min() == 0 and codes.max() == 2**bits - 1 and np.unique(codes).size > min(200, 2**bits // 4)


@pytest.mark.parametrize("engine", IMAGE_ENGINES)
@pytest.mark.parametrize("bits", [8, 16])
def test_values_at_every_codes_threshold_give_the_definitions_code(engine, bits):
    # With the identity matrix and a white level of 1 the product is exact in float32: every code must then be the
    # definition's, also for the values one float32 either side of each threshold (where any slip would show).
    top = 2**bits - 1
    wanted = np.arange(1, top + 1)

    def code(bit_patterns: np.ndarray) -> np.ndarray:
        values = bit_patterns.astype(np.int32).view(np.float32)
        return old_encode_srgb(np.repeat(values[:, None], 3, 1), np.eye(3), 1.0, bits)[:, 0]

    # The smallest float32 whose code reaches each code, by bisection over the bit patterns (ordered as the values).
    low, high = np.zeros(top, np.int64), np.full(top, np.float32(1).view(np.int32), np.int64)
    while np.any(high - low > 1):
        middle = (low + high) // 2
        reached = code(middle) >= wanted
        high, low = np.where(reached, middle, high), np.where(reached, low, middle)
    values = (high[:, None] + np.arange(-2, 3)).astype(np.int32).view(np.float32).ravel()
    values = np.concatenate([values, np.float32([0, 1, 1e-30, 0.0031308])])
    rgb = np.repeat(values[None, :, None], 3, axis=2)
    got = encode_image(rgb, table=srgb_encoding(white_level=1.0, bits=bits), engine=engine)
    np.testing.assert_array_equal(got, old_encode_srgb(rgb, np.eye(3), 1.0, bits))


@pytest.mark.parametrize("engine", IMAGE_ENGINES)
def test_nan_infinities_negatives_and_overrange_give_the_ends(engine):
    # Grey pixels: NaN, -inf and negatives give 0, values past the white's headroom the top code; an infinite red
    # gives the top code in red and 0 elsewhere (0 times infinity is NaN in the others' products), as before.
    grey = np.float32([np.nan, -np.inf, -1.0, 0.0, 1e9, 1.25, 1.0])
    rgb = np.concatenate([np.repeat(grey[None, :, None], 3, axis=2), np.float32([[[np.inf, 0, 0]]])], axis=1)
    for bits in (8, 16):
        top, white = 2**bits - 1, round((2**bits - 1) * float(srgb_transfer64(np.array(0.8))))
        got = encode_image(rgb, table=srgb_encoding(bits=bits), engine=engine)
        assert got[0, :-1, 0].tolist() == [0, 0, 0, 0, top, top, white]
        assert got[0, -1].tolist() == [top, 0, 0]
        np.testing.assert_array_equal(got, old_encode_srgb(rgb, np.eye(3), 0.8, bits))


@pytest.mark.parametrize("engine", IMAGE_ENGINES)
def test_a_float64_image_is_encoded_as_its_float32_values_strip_by_strip(engine):
    rgb = np.random.default_rng(3).random((40, 30, 3)) * 1.3
    encoding = srgb_encoding(CCM, bits=8)
    expected = encode_table(rgb.astype(np.float32), encoding, np.empty(rgb.shape, np.uint8))
    np.testing.assert_array_equal(encode_image(rgb, table=encoding, engine=engine), expected)
    np.testing.assert_array_equal(encode_image(rgb[:, ::2], table=encoding, engine=engine), expected[:, ::2])


@pytest.mark.parametrize(
    "engine", ["numpy", pytest.param("numba", marks=needs_numba), pytest.param("c", marks=needs_c)]
)
def test_codes_need_no_float32_image_at_full_resolution(engine):
    camera = make_camera("imx477", size=(1000, 800))
    cal = calibrate(**simulate_references(camera, seed=1))
    target, _ = simulate_target(camera, seed=2)
    float_bytes = target.height * target.width * 3 * 4
    encoding = srgb_encoding(bits=8)
    peaks = {}
    for name, options in (("float32", {}), ("srgb8", {"encoding": encoding})):
        correct(target, cal, "centre", engine=engine, **options)  # compile, and cache the fields
        tracemalloc.start()
        try:
            correct(target, cal, "centre", engine=engine, **options)
            peaks[name] = tracemalloc.get_traced_memory()[1] / float_bytes
        finally:
            tracemalloc.stop()
    # uint8 codes are a quarter of a float32 image (measured, in float32 images: 1.00 -> 0.25 with C, 1.01 -> 0.26
    # with numba; numpy 1.28 -> 0.61, which adds blocks of 64 rows and their temporaries, large next to this small
    # frame); with a float32 image at full resolution besides, it would rise by three quarters of an image instead.
    assert peaks["srgb8"] < peaks["float32"] - 0.6, peaks
    assert peaks["srgb8"] < (0.7 if engine == "numpy" else 0.3), peaks


@pytest.mark.parametrize("engine", ENGINES)
def test_out_takes_the_codes_and_is_reused(scene, engine):
    cal, raw = scene
    encoding = srgb_encoding(CCM, bits=8)
    out = np.full((raw.height, raw.width, 3), 7, dtype=np.uint8)
    assert correct(raw, cal, "flat", engine=engine, out=out, encoding=encoding) is out
    np.testing.assert_array_equal(out, correct(raw, cal, "flat", engine=engine, encoding=encoding))
    assert correct(raw, cal, "centre", engine=engine, out=out, dtype=np.uint8, encoding=encoding) is out


def test_dtype_and_encoding_must_agree(scene):
    cal, raw = scene
    with pytest.raises(ValueError, match="this encoding's codes are uint8, not uint16"):
        correct(raw, cal, "flat", dtype=np.uint16, encoding=srgb_encoding(bits=8))
    with pytest.raises(ValueError, match=r"uint8 with an encoding \(picamcal.output.colour.srgb_encoding\)"):
        correct(raw, cal, "flat", dtype=np.uint8)
    with pytest.raises(ValueError, match="binned"):
        correct(raw, cal, "flat", binned=True, encoding=srgb_encoding())
    with pytest.raises(ValueError, match="bits is 8 or 16"):
        srgb_encoding(bits=12)


@pytest.mark.parametrize("output_format", ["srgb-png", "srgb-png16", "srgb-jpeg"])
def test_files_from_the_codes_are_the_files_from_the_float_image(scene, tmp_path, output_format):
    cal, raw = scene
    bits = 16 if output_format == "srgb-png16" else 8
    encoding = srgb_encoding(CCM, bits=bits)
    codes = correct(raw, cal, "centre", encoding=encoding)
    rgb = correct(raw, cal, "centre")
    suffix = ".jpg" if output_format == "srgb-jpeg" else ".png"
    options = {"colour_matrix": CCM, "white_level": 0.8}
    from_codes = write_corrected(tmp_path / f"codes{suffix}", codes, output_format, {"source": "x.dng"}, **options)
    from_rgb = write_corrected(tmp_path / f"rgb{suffix}", rgb, output_format, {"source": "x.dng"}, **options)
    assert from_codes.read_bytes() == from_rgb.read_bytes()  # the same pixels and the same metadata
    if output_format == "srgb-png16":
        pixels = read_png16(from_codes)[0]
    else:
        pixels = np.asarray(Image.open(from_codes))
    if output_format != "srgb-jpeg":  # lossless: the pixels are the codes, within a code of before
        np.testing.assert_array_equal(pixels, codes)
        assert_within_one_code_and_mostly_exact(pixels, old_encode_srgb(rgb, CCM.matrix, 0.8, bits), bits)


def test_codes_of_the_wrong_type_are_refused(tmp_path):
    with pytest.raises(ValueError, match="srgb-png is written from uint8 codes or a float image, not uint16"):
        write_corrected(tmp_path / "a.png", np.zeros((4, 4, 3), np.uint16), "srgb-png")
    with pytest.raises(ValueError, match="srgb-png16 is written from uint16 codes or a float image, not uint8"):
        write_corrected(tmp_path / "b.png", np.zeros((4, 4, 3), np.uint8), "srgb-png16")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("output_format", ["srgb-png", "srgb-png16"])
def test_a_batch_writes_the_kernels_codes_within_a_code_of_before(cli, tmp_path, output_format):
    # picamcal correct asks the kernel for the codes (no float image): the file's pixels are encode_srgb of the
    # float32 correction, bit for bit, with the DNG's own colour matrix recorded as before.
    refs, cal_path = simulated_calibration(tmp_path, (200, 160), seed=4)
    status, errors, _ = cli(
        "correct",
        cal_path,
        refs["target"],
        "--out",
        tmp_path / "out",
        "--workers",
        "0",
        "--output-format",
        output_format,
    )
    assert status == 0, errors
    written = tmp_path / "out" / "target.png"
    bits = 16 if output_format == "srgb-png16" else 8
    pixels = read_png16(written)[0] if bits == 16 else np.asarray(Image.open(written))
    raw = read_raw(refs["target"])
    rgb = correct(raw, load_calibration(cal_path), "centre")
    matrix = camera_to_srgb(raw.metadata)
    np.testing.assert_array_equal(pixels, encode_srgb(rgb, matrix, bits=bits))
    assert_within_one_code_and_mostly_exact(pixels, old_encode_srgb(rgb, matrix.matrix, 0.8, bits), bits)
    info = provenance(written)
    assert info["colour_matrix_source"] == matrix.source and info["white_code"] == (231 if bits == 8 else 59396)


@pytest.mark.slow
def test_one_frame_to_srgb_jpeg_peaks_no_higher_than_to_uint16_tiff(tmp_path):
    # A full-size 8 MP frame, corrected by the command line in one process: the JPEG's uint8 codes come from the
    # kernel (a quarter of a float32 image), where the float32 image and its encoding took 308 MiB before, against
    # uint16-tiff's 133 MiB (measured: 131 and 134 MiB now).
    refs, cal_path = simulated_calibration(tmp_path, (3280, 2464), seed=5)
    peaks = {}
    for output_format in ("uint16-tiff", "srgb-jpeg"):
        command = [sys.executable, "-c", "from picamcal.cli import main; main()", "correct", str(cal_path)]
        command += [str(refs["target"]), "--out", str(tmp_path / output_format), "--workers", "0"]
        status, errors, peaks[output_format] = run_measured(*command, "--output-format", output_format)
        assert status == 0, errors
    assert peaks["srgb-jpeg"] <= peaks["uint16-tiff"], {name: peak / 2**20 for name, peak in peaks.items()}
