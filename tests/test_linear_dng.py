"""Corrected images as LinearRaw DNGs: the file's samples and colour tags, exiftool, and raw editors that render the
centre's colour as the corrected image has it.

The editors run for real (Debian: darktable, rawtherapee); a test that needs a missing one is skipped with its
reason.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import tifffile

import picamcal
from picamcal.errors import OutputError, RawFormatError
from picamcal.raw import RawImage, write_linear_dng
from picamcal.raw.dng.linear import WHITE_CODE
from picamcal.simulate import make_camera, simulate_references
from test_dng import D50, GAINS, IMX219_CCM, SRGB_TO_XYZ, exiftool_problems, need
from test_dng_gainmap import render

SIZE = (640, 480)  # RawTherapee refuses tiny frames


@pytest.fixture(scope="module")
def simulated() -> tuple[dict[str, RawImage], picamcal.Calibration]:
    refs = simulate_references(make_camera("imx219", size=SIZE), seed=2)
    return refs, picamcal.calibrate(**refs)


def centre_mean(rgb: np.ndarray) -> np.ndarray:
    """R, G, B means over the central 80 x 80 px."""
    h, w = rgb.shape[:2]
    return rgb[h // 2 - 40 : h // 2 + 40, w // 2 - 40 : w // 2 + 40].reshape(-1, 3).mean(axis=0)


def chromaticity(rgb: np.ndarray) -> np.ndarray:
    return rgb / rgb.sum()


def ccm_patch() -> tuple[np.ndarray, dict, np.ndarray]:
    """A uniform patch of white-balanced camera RGB that the imx219's CCM makes linear sRGB (0.6, 0.3, 0.1)."""
    target = np.array([0.6, 0.3, 0.1])
    camera = np.linalg.solve(IMX219_CCM, target)
    rgb = np.broadcast_to(0.8 * camera / camera.max(), (SIZE[1], SIZE[0], 3))
    meta = {"colour_gains": list(GAINS), "colour_correction_matrix": IMX219_CCM.ravel().tolist(), "iso": 200}
    return rgb, meta, target


# --- the file -----------------------------------------------------------------------------------------------------


def test_samples_tags_and_colour_matrices(tmp_path, simulated):
    refs, cal = simulated
    red = refs["red"]
    rgb = picamcal.correct(red, cal, "centre")
    path = write_linear_dng(tmp_path / "red.dng", rgb, metadata=red.metadata, sensor=red.sensor)
    with tifffile.TiffFile(path) as tif:
        page = tif.pages.first
        tags = {tag.code: tag.value for tag in page.tags}
        samples = page.asarray()
    assert samples.dtype == np.uint16 and samples.shape == (SIZE[1], SIZE[0], 3)
    # 1.0 (the white reference) at 16384, rounded; below 0 clipped to 0.
    np.testing.assert_array_equal(samples, np.rint(np.clip(rgb * WHITE_CODE, 0, 65535)).astype(np.uint16))
    assert tags[262] == 34892 and tags[277] == 3 and tuple(tags[258]) == (16, 16, 16)  # LinearRaw, 3 x 16 bits
    assert tags[50717] == (65535, 65535, 65535) and tags[50728] == (1, 1, 1, 1, 1, 1)  # WhiteLevel, AsShotNeutral
    assert tags[50730] == (2, 1)  # BaselineExposure +2 EV: the white reference shown at full scale
    assert json.loads(tags[270])["picamcal"]["white_code"] == WHITE_CODE
    color = np.array(tags[50721], float).reshape(9, 2)
    color = (color[:, 0] / color[:, 1]).reshape(3, 3)
    forward = np.array(tags[50964], float).reshape(9, 2)
    forward = (forward[:, 0] / forward[:, 1]).reshape(3, 3)
    # The simulator has no CCM: the image's RGB is linear sRGB. ColorMatrix1 takes the D65 white (sRGB's) to the
    # neutral 1 1 1; ForwardMatrix1 takes 1 1 1 to D50 and the image's green to sRGB green adapted to D50.
    np.testing.assert_allclose(color @ SRGB_TO_XYZ @ np.ones(3), np.ones(3), atol=1e-5)
    np.testing.assert_allclose(forward @ np.ones(3), D50, atol=2e-4)
    np.testing.assert_allclose(forward @ [0, 1, 0], [0.3851, 0.7169, 0.0971], atol=2e-4)


def test_ccm_and_pure_mode_matrices(tmp_path, simulated):
    # With the camera's CCM C, the image (white-balanced camera RGB) maps to XYZ as M_sRGB C; in mode pure the
    # image's RGB is first taken back to the camera's by M_centre (to_camera).
    rgb, meta, _ = ccm_patch()
    cal = simulated[1]
    for to_camera in (None, cal.centre_response):
        path = write_linear_dng(tmp_path / "patch.dng", rgb, metadata=meta, sensor="imx219", to_camera=to_camera)
        tags = {tag.code: tag.value for tag in tifffile.TiffFile(path).pages.first.tags}
        color = np.array(tags[50721], float).reshape(9, 2)
        color = (color[:, 0] / color[:, 1]).reshape(3, 3)
        t = np.eye(3) if to_camera is None else to_camera
        np.testing.assert_allclose(color @ SRGB_TO_XYZ @ IMX219_CCM @ t, np.eye(3), atol=2e-5)
        assert tags[34665]  # the EXIF IFD, with the ISO
        assert picamcal.__version__ in tags[305]


def test_exiftool_validates_it(tmp_path, simulated):
    need("exiftool")
    refs, cal = simulated
    rgb = picamcal.correct(refs["white"], cal, "flat")
    assert exiftool_problems(write_linear_dng(tmp_path / "white.dng", rgb, metadata=refs["white"].metadata)) == []
    assert exiftool_problems(write_linear_dng(tmp_path / "bare.dng", rgb)) == []


# --- the editors -----------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("editor", ["darktable-cli", "rawtherapee-cli"])
def test_raw_editors_render_the_centre_colour(tmp_path, simulated, editor):
    # The simulated red, green and white references corrected (mode centre), and a patch whose colour comes from
    # the imx219's CCM, developed with the editor's defaults: the rgb chromaticity of the centre (undoing sRGB's
    # curve) matches the corrected image's (for the simulator, whose CCM is the identity, its RGB is linear sRGB)
    # or the CCM's target within 0.006. Measured: darktable 4.2 within 0.0022 (the saturated red; its own colour
    # processing), RawTherapee 5.9 within 0.0004.
    if shutil.which(editor) is None:
        pytest.skip(f"needs {editor} (Debian: {editor.removesuffix('-cli')})")
    refs, cal = simulated
    cases = {}
    for role in ("red", "green", "white"):
        rgb = picamcal.correct(refs[role], cal, "centre")
        cases[role] = (rgb, refs[role].metadata, centre_mean(rgb))
    patch, meta, target = ccm_patch()
    cases["ccm"] = (patch, meta, target)
    for name, (rgb, metadata, expected) in cases.items():
        source = write_linear_dng(tmp_path / f"{name}.dng", rgb, metadata=metadata, sensor="imx219")
        rendered = centre_mean(render(editor, source, tmp_path / f"{name}.tif", tmp_path))
        np.testing.assert_allclose(chromaticity(rendered), chromaticity(expected), atol=0.006, err_msg=name)


# --- bad input ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("rgb", "to_camera", "message"),
    [
        (np.zeros((4, 4)), None, r"an \(H, W, 3\) RGB image, not an array of shape \(4, 4\)"),
        (np.zeros((4, 4, 4)), None, r"not an array of shape \(4, 4, 4\)"),
        (np.full((4, 4, 3), np.nan), None, "not finite"),
        (np.zeros((4, 4, 3)), np.zeros((3, 3)), "to_camera must be an invertible 3 x 3 matrix"),
        (np.zeros((4, 4, 3)), np.eye(2), "to_camera must be an invertible 3 x 3 matrix"),
    ],
)
def test_bad_images_are_refused_in_one_line_and_nothing_is_written(tmp_path, rgb, to_camera, message):
    with pytest.raises(OutputError, match=message) as info:
        write_linear_dng(tmp_path / "out.dng", rgb, to_camera=to_camera)
    assert str(info.value).startswith(str(tmp_path / "out.dng")) and "\n" not in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_bad_colour_metadata_is_refused_and_existing_files_are_kept(tmp_path):
    with pytest.raises(RawFormatError, match="colour_gains must be 2 finite numbers"):
        write_linear_dng(tmp_path / "out.dng", np.zeros((4, 4, 3)), metadata={"colour_gains": [1.0]})
    assert list(tmp_path.iterdir()) == []
    kept = tmp_path / "kept.dng"
    kept.write_bytes(b"mine")
    with pytest.raises(OutputError):
        write_linear_dng(kept, np.zeros((4, 4, 3)), overwrite=False)
    assert kept.read_bytes() == b"mine"
