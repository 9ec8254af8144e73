"""Output formats: every format written and read back with the expected values, colour matrices, the CLI."""

from __future__ import annotations

import io
import json
import re
import shutil
import subprocess
import sys
import warnings
import zlib
from pathlib import Path

import colour
import numpy as np
import png
import pytest
import tifffile
from PIL import Image, ImageCms

from picamcal import PicamcalWarning, __version__, read_raw
from picamcal.export.isp import tuning_ccm
from picamcal.export.tuning import load_tuning
from picamcal.output import (
    NO_MATRIX,
    OUTPUT_FORMATS,
    SRGB_TO_XYZ_D65,
    UINT16_WHITE,
    XYZ_D50_TO_SRGB,
    ColourMatrix,
    camera_to_srgb,
    color_matrix_to_srgb,
    encode_srgb,
    forward_matrix_to_srgb,
    output_bytes,
    write_corrected,
    write_rgb_tiff,
)
from picamcal.raw.picamera2 import to_picamera2, write_picamera2_npy
from picamcal.raw.processed import read_processed
from test_cli import assert_bad_input, run

ROOT = Path(__file__).resolve().parents[1]
TUNING = ROOT / "tests" / "data" / "libcamera-tuning" / "pisp" / "imx219.json"
SUFFIXES = {
    "float32-tiff": ".tiff",
    "uint16-tiff": ".tiff",
    "srgb-png": ".png",
    "srgb-png16": ".png",
    "srgb-jpeg": ".jpg",
}
#: A camera matrix with strong crosstalk to undo, rows summing to 1 (white-preserving), as libcamera's CCMs are.
CCM = np.array([[1.9, -0.6, -0.3], [-0.4, 1.7, -0.3], [0.1, -0.8, 1.7]])


def cctf(linear) -> np.ndarray:
    """The sRGB encoding by colour-science: an independent implementation of IEC 61966-2-1."""
    return np.asarray(colour.cctf_encoding(np.asarray(linear, dtype=float), function="sRGB"))


def patches() -> np.ndarray:
    """A 64 x 96 image of six flat 32 x 32 patches (JPEG blocks never straddle two): white, grey, colours."""
    values = [[1.0, 1.0, 1.0], [0.25, 0.25, 0.25], [0.6, 0.3, 0.2], [0.2, 0.5, 0.3], [1.5, 1.5, 1.5], [0.0, 0.0, 0.0]]
    rgb = np.empty((64, 96, 3), np.float32)
    for k, value in enumerate(values):
        row, column = divmod(k, 3)
        rgb[32 * row : 32 * row + 32, 32 * column : 32 * column + 32] = value
    return rgb


def centres(image: np.ndarray) -> np.ndarray:
    """The centre pixel of each patch of :func:`patches`, shape (6, 3)."""
    return np.array([image[32 * (k // 3) + 16, 32 * (k % 3) + 16] for k in range(6)], dtype=float)


def expected_srgb(rgb: np.ndarray, matrix: np.ndarray, bits: int) -> np.ndarray:
    """Written from the format's definition: matrix, white at linear 0.8, clip, sRGB curve, round."""
    linear = np.clip(0.8 * rgb @ np.asarray(matrix).T, 0.0, 1.0)
    return np.rint(cctf(linear) * (2**bits - 1))


def read_png16(path: Path) -> tuple[np.ndarray, dict[bytes, bytes]]:
    """pypng: the 16-bit pixels (H, W, 3) and the metadata chunks."""
    chunks = {kind: data for kind, data in png.Reader(filename=str(path)).chunks() if kind != b"IDAT"}
    width, height, rows, info = png.Reader(filename=str(path)).asDirect()
    assert info["bitdepth"] == 16 and info["planes"] == 3
    return np.vstack([np.asarray(row, dtype=np.uint16) for row in rows]).reshape(height, width, 3), chunks


def provenance(path: Path) -> dict:
    """The picamcal metadata of any output, read the way a user would, with the format's own reader."""
    if path.suffix == ".tiff":
        with tifffile.TiffFile(path) as tif:
            text = tif.pages[0].description
    elif path.suffix == ".png":
        text = Image.open(path).info["picamcal"]
    else:
        text = Image.open(path).getexif()[0x010E]
    return json.loads(text)["picamcal"]


def assert_srgb_profile(icc: bytes) -> None:
    profile = ImageCms.ImageCmsProfile(io.BytesIO(icc))
    assert profile.profile.xcolor_space.strip() == "RGB"
    assert "sRGB" in ImageCms.getProfileDescription(profile)


# ---------------------------------------------------------------------------------------------- formats
def test_float32_tiff_holds_the_values_exactly_with_the_description_as_before(tmp_path):
    rgb = patches()
    rgb[0, 0] = [-0.25, 3.5, np.nan]  # nothing is clipped or replaced in float32
    write_corrected(tmp_path / "a.tiff", rgb, "float32-tiff", {"source": "a.dng", "mode": "centre"})
    with tifffile.TiffFile(tmp_path / "a.tiff") as tif:
        back = tif.asarray()
        assert json.loads(tif.pages[0].description) == {"picamcal": {"source": "a.dng", "mode": "centre"}}
        assert tif.pages[0].tags["Software"].value == f"picamcal {__version__}"
    np.testing.assert_array_equal(back, rgb)  # bit for bit, NaN included
    write_rgb_tiff(tmp_path / "b.tiff", rgb, {"source": "a.dng", "mode": "centre"}, compression="zstd")
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "b.tiff"), rgb)


def test_uint16_tiff_is_one_16_bit_rgb_image_with_its_scale_recorded(tmp_path):
    rgb = patches()
    rgb[0, :5] = [[0.123456, 1.999, 2.5], [-0.1, np.nan, 0.5], [1 / 3, 2 / 3, 1.0], [1e-6, 0.99999, 1.00001], [0, 0, 0]]
    write_corrected(tmp_path / "u.tiff", rgb, "uint16-tiff", {"source": "u.dng"}, compression="zstd")
    with tifffile.TiffFile(tmp_path / "u.tiff") as tif:
        assert len(tif.pages) == 1 and not tif.is_imagej
        page = tif.pages.first
        codes = tif.asarray()
    # One interleaved RGB image, as the float32 TIFF is, with the same tags: no colour profile in either.
    assert (page.shape, page.dtype, page.photometric, page.planarconfig) == ((64, 96, 3), np.uint16, 2, 1)
    assert 34675 not in page.tags and page.tags["Software"].value == f"picamcal {__version__}"
    info = json.loads(page.description)["picamcal"]
    scale = info["scale"]
    assert scale == UINT16_WHITE == 32768 and info["output_format"] == "uint16-tiff" and info["source"] == "u.dng"
    assert info["encoding"] == "linear: value = code / 32768 (the white reference at 32768)"
    expected = np.clip(np.rint(np.nan_to_num(rgb.astype(float), nan=0.0) * scale), 0, 65535)
    np.testing.assert_array_equal(codes, expected)  # exact: round(value * scale), clipped
    assert codes[16, 16].tolist() == [32768] * 3  # the white reference
    assert codes[0, 0].tolist() == [4045, 65503, 65535]  # 0.123456 and 1.999 in range, 2.5 clipped


def test_uint16_tiff_read_back_as_a_processed_image_is_the_linear_values(tmp_path):
    rgb = patches()
    path = write_corrected(tmp_path / "u.tiff", rgb, "uint16-tiff", {"source": "u.dng"})
    image = read_processed(path)  # the default encoding is sRGB: the file's record says linear, code / 32768
    assert image.encoding == "linear" and image.metadata["picamcal"]["scale"] == UINT16_WHITE
    # Within half a code (quantisation); 1.5 clips at 65535 / 32768 = 1.99997, well above it.
    np.testing.assert_allclose(image.rgb, rgb, atol=0.5 / UINT16_WHITE)


def test_uint16_tiff_is_read_as_one_16_bit_rgb_image_by_other_readers(tmp_path):
    path = write_corrected(tmp_path / "u.tiff", patches(), "uint16-tiff", {"source": "u.dng"})
    # Pillow has no 16-bit RGB mode: it opens the file as one RGB image, in 8 bits.
    with Image.open(path) as image:
        assert (image.mode, image.size, getattr(image, "n_frames", 1)) == ("RGB", (96, 64), 1)
    if shutil.which("tiffinfo") is None:
        pytest.skip("libtiff's tiffinfo is not installed (Debian: libtiff-tools)")
    info = subprocess.run(["tiffinfo", str(path)], capture_output=True, text=True, check=True).stdout
    assert info.count("TIFF Directory") == 1 and "Bits/Sample: 16" in info and "Samples/Pixel: 3" in info
    assert "Photometric Interpretation: RGB color" in info and "Planar Configuration: single image plane" in info


def test_imagemagick_identifies_uint16_tiff_as_one_16_bit_rgb_image(tmp_path):
    identify = shutil.which("identify")
    if identify is None:
        pytest.skip("ImageMagick's identify is not installed (Debian: imagemagick; .ci/run installs it)")
    rgb = patches()
    for compression in (None, "zstd"):
        path = write_corrected(tmp_path / f"u-{compression}.tiff", rgb, "uint16-tiff", compression=compression)
        if compression:  # ImageMagick's libtiff may lack zstd: then it says so, and the plain file is the check
            probe = subprocess.run([identify, str(path)], capture_output=True, text=True)
            if probe.returncode != 0:
                continue
        result = subprocess.run(
            [identify, "-format", "%n %z %[colorspace] %[channels] %w %h\n", str(path)],
            capture_output=True,
            text=True,
            check=True,
        )
        # One image (%n), 16 bits (%z), in an RGB colour space (ImageMagick calls untagged RGB sRGB), 3 channels.
        count, depth, space, channels, width, height = result.stdout.split()
        assert (count, depth, width, height) == ("1", "16", "96", "64"), result.stdout
        assert space in ("sRGB", "RGB") and channels.startswith(("srgb", "rgb")) and "a" not in channels[3:]
        # And the codes it reads are the file's: the white patch at 32768, the grey (0.25) at 8192.
        pixel = subprocess.run(
            [
                identify,
                "-format",
                " ".join(f"%[fx:round(65535*p{{{x},16}}.{c})]" for x in (16, 48) for c in "rgb"),
                path,
            ],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        assert pixel.split() == ["32768", "32768", "32768", "8192", "8192", "8192"], pixel


@pytest.mark.parametrize("bits", [8, 16])
def test_srgb_png_puts_the_white_at_its_stated_level_through_the_matrix(tmp_path, bits):
    output_format = "srgb-png" if bits == 8 else "srgb-png16"
    matrix = ColourMatrix(CCM, "a test matrix")
    path = tmp_path / "s.png"
    write_corrected(path, patches(), output_format, {"source": "s.dng"}, colour_matrix=matrix)
    if bits == 8:
        image = Image.open(path)
        assert image.mode == "RGB"
        codes, icc = np.asarray(image), image.info["icc_profile"]
    else:
        codes, chunks = read_png16(path)
        name, _, compressed = chunks[b"iCCP"].partition(b"\x00")
        assert name == b"sRGB" and compressed[0] == 0  # deflate
        icc = zlib.decompress(compressed[1:])
        assert Image.open(path).info["icc_profile"] == icc  # Pillow finds it too
        assert b"sRGB" not in chunks  # a PNG with iCCP has no sRGB chunk
    assert_srgb_profile(icc)
    info = provenance(path)
    white = 231 if bits == 8 else 59396  # round(255 or 65535 * cctf(0.8)): 231.11, 59396.45
    assert info["white_code"] == white and info["white_level"] == 0.8
    assert info["colour_matrix_source"] == "a test matrix" and info["picamcal_version"] == __version__
    np.testing.assert_allclose(info["colour_matrix"], CCM, atol=1e-6)  # rows sum to 1 already: kept
    got = centres(codes)
    assert got[0].tolist() == [white] * 3  # white stays neutral through any white-preserving matrix
    assert got[4].tolist() == [2**bits - 1] * 3 and got[5].tolist() == [0] * 3  # 1.5 clips; black is 0
    # The exact codes: colours through the matrix, the grey, the white.
    np.testing.assert_array_equal(got, expected_srgb(centres(patches()), CCM, bits))


def test_srgb_jpeg_is_within_jpeg_error_and_carries_profile_and_provenance(tmp_path):
    path = tmp_path / "j.jpg"
    write_corrected(path, patches(), "srgb-jpeg", {"source": "j.dng"}, colour_matrix=ColourMatrix(CCM, "test"))
    image = Image.open(path)
    assert image.format == "JPEG" and image.mode == "RGB"
    assert_srgb_profile(image.info["icc_profile"])
    exif = image.getexif()
    assert exif[0x0131] == f"picamcal {__version__}"
    info = provenance(path)
    assert (info["source"], info["output_format"], info["white_code"]) == ("j.dng", "srgb-jpeg", 231)
    # Flat 32 x 32 patches at quality 95, 4:4:4: only the YCbCr round trip and the DC quantisation (step 2 at
    # quality 95) move a code, by at most 2.
    np.testing.assert_allclose(centres(np.asarray(image)), expected_srgb(centres(patches()), CCM, 8), atol=2)


def test_a_matrix_is_normalised_so_that_white_stays_neutral(tmp_path):
    unnormalised = CCM * np.array([[2.0], [0.5], [1.3]])  # a matrix that would tint white
    matrix = ColourMatrix(unnormalised, "scaled")
    np.testing.assert_allclose(matrix.matrix, CCM, atol=1e-12)
    assert encode_srgb(np.ones((1, 1, 3)), matrix).ravel().tolist() == [231, 231, 231]
    with pytest.raises(ValueError, match="cannot be normalised"):
        ColourMatrix([[1, -1, 0], [0, 1, 0], [0, 0, 1]], "takes white to black in red")


def test_the_sRGB_outputs_are_the_same_bytes_every_time(tmp_path):
    """The profile's creation date is fixed: workers and reruns write identical files."""
    for output_format in ("srgb-png", "srgb-png16", "srgb-jpeg"):
        a, b = tmp_path / f"a-{output_format}", tmp_path / f"b-{output_format}"
        write_corrected(a, patches(), output_format, {"source": "x"})
        write_corrected(b, patches(), output_format, {"source": "x"})
        assert a.read_bytes() == b.read_bytes()


def test_every_format_refuses_to_replace_a_file_unless_told(tmp_path):
    for output_format in OUTPUT_FORMATS:
        path = tmp_path / f"x{SUFFIXES[output_format]}"
        path.write_bytes(b"keep")
        with pytest.raises(Exception, match="exists already"):
            write_corrected(path, patches(), output_format)
        assert path.read_bytes() == b"keep"
        write_corrected(path, patches(), output_format, overwrite=True)
        assert path.read_bytes() != b"keep"
    with pytest.raises(ValueError, match="zstd"):
        write_corrected(tmp_path / "y.png", patches(), "srgb-png", compression="zstd")
    assert not (tmp_path / "y.png").exists()


def test_output_bytes_is_the_uncompressed_size():
    shape = (3040, 4056, 3)
    assert output_bytes("float32-tiff", shape) == 4056 * 3040 * 12  # 148 MB, as the batch always reserved
    assert output_bytes("uint16-tiff", shape) == output_bytes("srgb-png16", shape) == 4056 * 3040 * 6
    assert output_bytes("srgb-png", shape) == output_bytes("srgb-jpeg", shape) == 4056 * 3040 * 3


# ---------------------------------------------------------------------------------------------- colour matrices
def test_the_d50_to_srgb_matrix_agrees_with_colour_science():
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    adapt = colour.adaptation.matrix_chromatic_adaptation_VonKries(
        colour.xy_to_XYZ(srgb.whitepoint),
        colour.xy_to_XYZ(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D50"]),
        transform="Bradford",
    )
    from_colour = srgb.matrix_XYZ_to_RGB @ np.linalg.inv(adapt)
    # Lindbloom's whitepoints (from tabulated XYZ) and colour-science's (from xy chromaticities) differ in the
    # 4th decimal; the matrices agree to that.
    np.testing.assert_allclose(XYZ_D50_TO_SRGB, from_colour, atol=2e-3)
    np.testing.assert_allclose(np.linalg.inv(SRGB_TO_XYZ_D65), srgb.matrix_XYZ_to_RGB, atol=2e-3)


def test_dng_matrices_give_the_camera_to_srgb_matrix_they_encode():
    # A camera whose white-balanced RGB is inv(CCM) @ sRGB: its ForwardMatrix is sRGB->XYZ(D50) @ CCM.
    forward = np.linalg.inv(XYZ_D50_TO_SRGB) @ CCM
    np.testing.assert_allclose(forward_matrix_to_srgb(forward), CCM, atol=1e-9)
    from_fm = camera_to_srgb({"forward_matrix1": forward.ravel().tolist()})
    np.testing.assert_allclose(from_fm.matrix, CCM, atol=1e-9)
    assert "ForwardMatrix1" in from_fm.source
    # Its ColorMatrix (XYZ -> camera, before white balance by the neutral n): diag(n) inv(CCM) XYZ->sRGB.
    neutral = np.array([0.5, 1.0, 0.7])
    color = np.diag(neutral) @ np.linalg.inv(CCM) @ np.linalg.inv(SRGB_TO_XYZ_D65)
    np.testing.assert_allclose(color_matrix_to_srgb(color), CCM, atol=1e-9)
    from_cm = camera_to_srgb({"color_matrix1": color.ravel().tolist()})
    np.testing.assert_allclose(from_cm.matrix, CCM, atol=1e-9)
    assert "ColorMatrix1" in from_cm.source
    # ForwardMatrix1 comes before ColorMatrix1; identity placeholders are passed over.
    both = {"color_matrix1": np.eye(3).ravel().tolist(), "forward_matrix1": forward.ravel().tolist()}
    assert "ForwardMatrix1" in camera_to_srgb(both).source
    placeholders = {"color_matrix1": np.eye(3).ravel().tolist(), "forward_matrix1": np.eye(3).ravel().tolist()}
    assert camera_to_srgb(placeholders).source == NO_MATRIX


def test_a_singular_color_matrix_is_passed_over_with_a_warning():
    with pytest.warns(PicamcalWarning, match="color_matrix1 is not usable"):
        chosen = camera_to_srgb({"color_matrix1": [1, 2, 3, 2, 4, 6, 0, 0, 1], "path": "x.dng"})
    assert chosen.source == NO_MATRIX
    np.testing.assert_array_equal(chosen.matrix, np.eye(3))


def test_the_tuning_file_comes_first_at_the_images_colour_temperature():
    tuning = load_tuning(TUNING)
    metadata = {"colour_correction_matrix": CCM.ravel().tolist(), "colour_temperature": 3000.0}
    chosen = camera_to_srgb(metadata, tuning, tuning_path=TUNING)
    ccm = tuning_ccm(tuning, 3000.0)
    np.testing.assert_allclose(chosen.matrix, ccm / ccm.sum(axis=1, keepdims=True), atol=1e-12)
    assert chosen.source == "imx219.json rpi.ccm at 3000 K"
    assert not np.allclose(chosen.matrix, camera_to_srgb({"colour_temperature": 6500.0}, tuning).matrix, atol=1e-3)
    # Without the tuning file, the image's own CCM; without a temperature, the tuning file's default.
    np.testing.assert_allclose(camera_to_srgb(metadata).matrix, CCM, atol=1e-12)
    assert re.fullmatch(r"the tuning file rpi\.ccm at \d+ K", camera_to_srgb({}, tuning).source)
    with pytest.raises(Exception, match=r"has no rpi\.ccm"):
        camera_to_srgb({}, {"version": 2.0, "algorithms": []}, tuning_path="bare.json")


# ---------------------------------------------------------------------------------------------- the CLI


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A small simulated run and its calibration, made through the CLI."""
    root = tmp_path_factory.mktemp("outputs")
    result = run("simulate", "--size", "320x240", "--out", str(root / "sim"), "--seed", "3")
    assert result.returncode == 0, result.stderr
    result = run("calibrate", str(root / "sim"), "--out", str(root / "cal.npz"))
    assert result.returncode == 0, result.stderr
    return root


@pytest.mark.slow
@pytest.mark.parametrize("output_format", OUTPUT_FORMATS)
def test_correct_writes_each_format_skips_on_rerun_and_overwrites(run_dir, tmp_path, output_format):
    sim, out = run_dir / "sim", tmp_path / "out"
    args = ("correct", str(run_dir / "cal.npz"), str(sim / "white.dng"), str(sim / "target.dng"), "--out", str(out))
    result = run(*args, "--output-format", output_format.upper(), "--workers", "0")  # case-insensitive
    assert result.returncode == 0, result.stderr
    suffix = SUFFIXES[output_format]
    assert sorted(p.name for p in out.iterdir()) == [f"target{suffix}", f"white{suffix}"]
    white = out / f"white{suffix}"
    info = provenance(white)
    assert (info["source"], info["calibration"], info["mode"]) == ("white.dng", "cal.npz", "centre")
    # The white reference corrected by its own calibration is flat at 1.0 up to its noise (a few % per pixel);
    # its median is 1.0 within 0.5 %, which each format's stated scale turns into codes.
    if output_format == "float32-tiff":
        np.testing.assert_allclose(np.median(tifffile.imread(white), axis=(0, 1)), 1.0, atol=0.005)
    elif output_format == "uint16-tiff":
        median = np.median(tifffile.imread(white), axis=(0, 1)) / info["scale"]
        np.testing.assert_allclose(median, 1.0, atol=0.005)
    else:
        codes = read_png16(white)[0] if output_format == "srgb-png16" else np.asarray(Image.open(white))
        assert info["white_code"] == (59396 if output_format == "srgb-png16" else 231)
        # 0.5 % in linear light is 0.2 % in sRGB code near the white: 0.5 code of 231 (JPEG: 1 more).
        tolerance = {"srgb-png": 0.5, "srgb-jpeg": 1.5, "srgb-png16": 0.002 * 59396}[output_format]
        np.testing.assert_allclose(np.median(codes, axis=(0, 1)), info["white_code"], atol=tolerance)
        # picamcal's simulated DNGs carry the ForwardMatrix1 of a camera with sRGB primaries.
        assert "ForwardMatrix1" in info["colour_matrix_source"]
        np.testing.assert_allclose(info["colour_matrix"], np.eye(3), atol=2e-3)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    again = run(*args, "--output-format", output_format, "--workers", "0")
    assert again.returncode == 0 and "skipped 2" in again.stderr, again.stderr  # the console is stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    forced = run(*args, "--output-format", output_format, "--workers", "0", "--overwrite")
    assert forced.returncode == 0 and "wrote 2" in forced.stderr, forced.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # the same bytes as the first run
    (out / f"target{suffix}").write_bytes(b"somebody else's file")  # not picamcal's: --overwrite leaves it alone
    refused = run(*args, "--output-format", output_format, "--workers", "0", "--overwrite")
    assert_bad_input(refused, f"target{suffix}", "picamcal wrote")
    assert (out / f"target{suffix}").read_bytes() == b"somebody else's file"


@pytest.mark.slow
def test_bad_output_combinations_are_one_line_and_write_nothing(run_dir, tmp_path):
    cal, target = str(run_dir / "cal.npz"), str(run_dir / "sim" / "target.dng")
    result = run("correct", cal, target, "--zarr", str(tmp_path / "s.zarr"), "--output-format", "srgb-png")
    assert_bad_input(result, "zarr stack holds float32 only", "srgb-png")
    result = run("correct", cal, target, "--out", str(tmp_path / "o"), "--output-format", "srgb-png",
                 "--compression", "zstd")  # fmt: skip
    assert_bad_input(result, "compression zstd is for the TIFF formats", "srgb-png")
    result = run("correct", cal, target, "--out", str(tmp_path / "o"), "--tuning", str(TUNING))
    assert_bad_input(result, "--tuning", "srgb-png")
    result = run("correct", cal, target, "--out", str(tmp_path / "o"), "--tuning", str(TUNING),
                 "--output-format", "srgb-png", "--mode", "pure")  # fmt: skip
    assert_bad_input(result, "mode pure", str(TUNING))
    result = run("correct", cal, target, "--out", str(tmp_path / "o"), "--output-format", "srgb-pgn")
    assert_bad_input(result, "did you mean srgb-png")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_a_tuning_file_or_the_images_own_ccm_colours_the_srgb_output(run_dir, tmp_path):
    """The sRGB output is exactly the float32 output through the recorded matrix, for each matrix source."""
    cal = str(run_dir / "cal.npz")
    raw = read_raw(run_dir / "sim" / "target.dng")
    array, config, metadata = to_picamera2(raw)
    metadata["ColourCorrectionMatrix"] = CCM.ravel().tolist()
    dump = write_picamera2_npy(tmp_path / "dump.npy", array, config, metadata, sensor=raw.sensor)
    linear = tmp_path / "linear"
    assert run("correct", cal, str(dump), "--out", str(linear), "--workers", "0").returncode == 0
    rgb = tifffile.imread(linear / "dump.tiff")
    for name, extra, source, matrix in (
        ("own", (), "the image's ColourCorrectionMatrix (libcamera's CCM at capture)", CCM),
        ("tuning", ("--tuning", str(TUNING)), None, None),
    ):
        out = tmp_path / name
        result = run("correct", cal, str(dump), "--out", str(out), "--output-format", "srgb-png", "--workers", "0",
                     *extra)  # fmt: skip
        assert result.returncode == 0, result.stderr
        info = provenance(out / "dump.png")
        if matrix is None:  # the tuning file's, at its default colour temperature (the dump records none)
            tuning = load_tuning(TUNING)
            assert info["colour_matrix_source"].startswith("imx219.json rpi.ccm at ")
            ct = float(info["colour_matrix_source"].split(" at ")[1].removesuffix(" K"))
            matrix = tuning_ccm(tuning, ct)
        else:
            assert info["colour_matrix_source"] == source
        matrix = matrix / matrix.sum(axis=1, keepdims=True)
        np.testing.assert_allclose(info["colour_matrix"], matrix, atol=1e-6)
        codes = np.asarray(Image.open(out / "dump.png")).astype(float)
        # Recomputed from the float32 output in float64: the same codes, but for values that fall within
        # rounding error of a half code (at most a few pixels, by at most 1).
        difference = np.abs(codes - expected_srgb(rgb.astype(float), matrix, 8))
        assert difference.max() <= 1 and (difference > 0).mean() < 1e-3


@pytest.mark.slow
def test_pure_mode_and_processed_inputs_are_encoded_without_a_matrix(run_dir, tmp_path):
    cal, target = str(run_dir / "cal.npz"), str(run_dir / "sim" / "target.dng")
    result = run("correct", cal, target, "--out", str(tmp_path / "pure"), "--mode", "pure",
                 "--output-format", "srgb-png", "--workers", "0")  # fmt: skip
    assert result.returncode == 0, result.stderr
    info = provenance(tmp_path / "pure" / "target.png")
    assert info["colour_matrix"] == np.eye(3).tolist() and "mode pure" in info["colour_matrix_source"]
    processed = tmp_path / "processed.png"
    Image.fromarray(np.full((240, 320, 3), 200, np.uint8)).save(processed)
    result = run("correct", cal, str(processed), "--processed", "--mode", "uncorrected", "--out", str(tmp_path / "p"),
                 "--output-format", "srgb-png", "--workers", "0")  # fmt: skip
    assert result.returncode == 0, result.stderr
    info = provenance(tmp_path / "p" / "processed.png")
    assert info["colour_matrix"] == np.eye(3).tolist() and "processed" in info["colour_matrix_source"]
    assert info["input_encoding"] == "srgb"
    # uncorrected mode on a processed image changes nothing: sRGB 200 is linear 0.578, at 0.8 of it: code 181.
    assert np.asarray(Image.open(tmp_path / "p" / "processed.png"))[120, 160].tolist() == [181] * 3


# ---------------------------------------------------------------------------------------------- docs
@pytest.mark.slow
def test_the_examples_in_docs_outputs_md_run(tmp_path, monkeypatch):
    text = (ROOT / "docs" / "outputs.md").read_text()
    monkeypatch.chdir(tmp_path)
    for line in re.findall(r"```bash\n(.*?)```", text, re.DOTALL)[0].strip().splitlines():
        command = line.replace("picamcal ", f"{sys.executable} -c 'from picamcal.cli import main; main()' ", 1)
        result = subprocess.run(command, shell=True, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, (line, result.stderr)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PicamcalWarning)
        for block in re.findall(r"```python\n(.*?)```", text, re.DOTALL):
            exec(compile(block, "docs/outputs.md", "exec"), {})
    assert Image.open("target.png").info["icc_profile"] and tifffile.imread("target.tiff").shape[-1] == 3
