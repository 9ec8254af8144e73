"""`picamcal correct --output-format dng-gainmap | linear-dng`: DNG outputs for raw editors, through the batch."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
import rawpy
import tifffile
from tests.test_cli import assert_bad_input, run

import picamcal
from picamcal.raw import flat_field_gain_map, read_gain_map
from picamcal.raw.dng.linear import WHITE_CODE
from picamcal.simulate import simulate_run


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("dng-out")
    paths = simulate_run(folder / "sim", "imx219", size=(320, 240), seed=3)
    cal = picamcal.calibrate(**{role: paths[role] for role in ("white", "red", "green", "blue", "black")})
    cal.save(folder / "cal.npz")
    return folder, paths


def test_gainmap_keeps_the_mosaic_and_carries_the_calibrations_flat_field(files, tmp_path):
    folder, paths = files
    result = run("correct", str(folder / "cal.npz"), str(paths["target"]), "--output-format", "dng-gainmap",
                 "--out", str(tmp_path / "out"), "--workers", "0")  # fmt: skip
    assert result.returncode == 0, result.stderr
    out = tmp_path / "out" / "target.dng"
    with rawpy.imread(str(out)) as written, rawpy.imread(str(paths["target"])) as source:
        assert np.array_equal(written.raw_image, source.raw_image)  # LibRaw reads the mosaic unchanged
    expected = flat_field_gain_map(picamcal.load_calibration(folder / "cal.npz"))
    assert read_gain_map(out) == expected
    if shutil.which("exiftool"):
        validation = subprocess.run(["exiftool", "-validate", "-warning", "-a", str(out)], capture_output=True,
                                    text=True, check=True)  # fmt: skip
        assert "Validate                        : OK" in validation.stdout, validation.stdout


@pytest.mark.parametrize("mode", ["centre", "pure"])
def test_linear_dng_holds_the_corrected_image(files, tmp_path, mode):
    folder, paths = files
    result = run("correct", str(folder / "cal.npz"), str(paths["target"]), "--output-format", "linear-dng",
                 "--mode", mode, "--out", str(tmp_path / "out"), "--workers", "0")  # fmt: skip
    assert result.returncode == 0, result.stderr
    codes = tifffile.imread(tmp_path / "out" / "target.dng")
    expected = picamcal.correct(picamcal.read_raw(paths["target"]), picamcal.load_calibration(folder / "cal.npz"),
                                mode)  # fmt: skip
    # 16-bit codes with the white at WHITE_CODE: the image to within half a code where it is not clipped.
    inside = (expected >= 0) & (expected * WHITE_CODE < 65535)
    assert np.abs(codes / WHITE_CODE - expected)[inside].max() <= 0.5 / WHITE_CODE + 1e-6


def test_dng_outputs_refuse_what_they_cannot_hold(files, tmp_path):
    folder, paths = files
    cal, target = str(folder / "cal.npz"), str(paths["target"])
    assert_bad_input(run("correct", cal, target, "--output-format", "dng-gainmap", "--binned", "--out",
                         str(tmp_path / "a")), "--output-format", "--binned")  # fmt: skip
    assert_bad_input(run("correct", cal, target, "--output-format", "linear-dng", "--zarr", str(tmp_path / "s.zarr")),
                     "zarr")  # fmt: skip
    assert not (tmp_path / "a").exists() and not (tmp_path / "s.zarr").exists()


def test_a_flat_field_beyond_the_opcodes_gains_is_refused_before_any_work(files, tmp_path):
    import dataclasses

    folder, paths = files
    cal = picamcal.load_calibration(folder / "cal.npz")
    nby, nbx = cal.site_white.shape[:2]
    y, x = np.meshgrid(np.linspace(-1, 1, nby), np.linspace(-1, 1, nbx), indexing="ij")
    falloff = 1 / (1 + 20 * (x**2 + y**2))  # corners 41 times darker than the centre: over the 16 opcodes carry
    vignetted = dataclasses.replace(cal, site_white=(cal.site_white * falloff[..., None]).astype(np.float32))
    vignetted.save(tmp_path / "vignetted.npz")
    result = run("correct", str(tmp_path / "vignetted.npz"), str(paths["target"]), "--output-format", "dng-gainmap",
                 "--out", str(tmp_path / "out"))  # fmt: skip
    assert_bad_input(result, "vignetted.npz", "gain")
    assert not (tmp_path / "out").exists()
