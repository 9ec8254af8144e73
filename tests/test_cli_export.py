"""export-tuning, export-lst, apply-tuning and correct --processed --tuning through real subprocesses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import png
import pytest
import tifffile

from picamcal.bayer import bin_sites
from picamcal.export.tuning import TuningError, stock_tuning_path
from test_cli import assert_bad_input, run

DATA = Path(__file__).parent / "data"
VC4 = DATA / "tuning_vc4_imx219.json"
PISP = DATA / "tuning_pisp_imx219.json"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export")
    assert run("simulate", "--out", str(out / "sim"), "--size", "640x480", "--no-noise").returncode == 0
    assert run("calibrate", str(out / "sim"), "--out", str(out / "cal.npz")).returncode == 0
    return out


@pytest.mark.slow
def test_export_and_apply_tuning(run_dir, tmp_path):
    for base in (VC4, PISP):
        out = tmp_path / f"{base.stem}.json"
        before = base.read_bytes()
        result = run(
            "export-tuning",
            str(run_dir / "cal.npz"),
            "--base",
            str(base),
            "--out",
            str(out),
            "--ccm",
            "--ct",
            "5000",
            "--luminance-strength",
            "0.9",
        )
        assert result.returncode == 0, result.stderr
        assert base.read_bytes() == before
        tuning = json.loads(out.read_text())
        alsc = next(a["rpi.alsc"] for a in tuning["algorithms"] if "rpi.alsc" in a)
        assert alsc["calibrations_Cr"][0]["ct"] == 5000 and alsc["luminance_strength"] == 0.9
        image = tmp_path / f"{base.stem}.tiff"
        result = run("apply-tuning", str(out), str(run_dir / "sim" / "white.dng"), "--out", str(image))
        assert result.returncode == 0, result.stderr
        rgb = tifffile.imread(image)
        assert rgb.shape == (480, 640, 3) and rgb.dtype == np.float32
        green = bin_sites(rgb[..., 1], 16).mean(-1)
        assert green.std() / green.mean() < 0.02  # luminance strength 0.9 leaves a tenth of the vignetting


@pytest.mark.slow
def test_export_lst(run_dir, tmp_path):
    result = run("export-lst", str(run_dir / "cal.npz"), "--out", str(tmp_path / "lst.npy"))
    assert result.returncode == 0, result.stderr
    table = np.load(tmp_path / "lst.npy")
    assert table.shape == (4, 480 // 64 + 1, 640 // 64 + 1) and table.dtype == np.uint8 and table.min() >= 32


@pytest.mark.slow
def test_correct_processed_with_the_tuning_it_was_taken_with(run_dir, tmp_path):
    from picamcal import read_raw
    from picamcal.export.isp import apply_tuning
    from picamcal.export.tuning import load_tuning
    from picamcal.raw.processed import tuning_gamma_curve

    # A camera without a colour matrix: a CCM would push the saturated wheel colours out of gamut, where the
    # camera clips them for good (the library test covers undoing a CCM).
    base = json.loads(VC4.read_text())
    base["algorithms"] = [a for a in base["algorithms"] if "rpi.ccm" not in a]
    (tmp_path / "base.json").write_text(json.dumps(base))
    tuning_path = tmp_path / "tuning.json"
    result = run(
        "export-tuning",
        str(run_dir / "cal.npz"),
        "--base",
        str(tmp_path / "base.json"),
        "--out",
        str(tuning_path),
        "--sensor",
        "imx219",
    )
    assert result.returncode == 0, result.stderr
    tuning = load_tuning(tuning_path)
    # The ISP without colour gains (the simulated files carry their true white's): the test derives its own.
    isp_white = apply_tuning(read_raw(run_dir / "sim" / "white.dng"), tuning, colour_gains=(1.0, 1.0))
    white = isp_white[200:280, 260:380].reshape(-1, 3).mean(0)
    linear = apply_tuning(
        read_raw(run_dir / "sim" / "target.dng"),
        tuning,
        colour_gains=(white[1] / white[0], white[1] / white[2]),
    )
    x, y = tuning_gamma_curve(tuning_path)  # the camera's own tone curve, as it would encode its output
    encoded = np.round(65535 * np.interp(np.clip(linear / linear.max(), 0, 1), x, y)).astype(np.uint16)
    with open(tmp_path / "isp.png", "wb") as f:
        png.Writer(640, 480, bitdepth=16, greyscale=False).write(f, encoded.reshape(480, -1))
    result = run(
        "correct",
        str(run_dir / "cal.npz"),
        str(tmp_path / "isp.png"),
        "--processed",
        "--tuning",
        str(tuning_path),
        "--out",
        str(tmp_path / "out"),
    )
    assert result.returncode == 0, result.stderr
    from picamcal.analysis.metrics import wheel_figures

    layout = json.loads((run_dir / "sim" / "layout.json").read_text())
    assert wheel_figures(tifffile.imread(tmp_path / "out" / "isp.tiff"), layout)["max_delta_e"] < 1.0


@pytest.mark.slow
def test_bad_inputs(run_dir, tmp_path):
    cal = str(run_dir / "cal.npz")
    bad = tmp_path / "v1.json"
    bad.write_text(json.dumps({"rpi.alsc": {}}))
    assert_bad_input(
        run("export-tuning", cal, "--base", str(bad), "--out", str(tmp_path / "o.json")), "v1.json", "not a version 2"
    )
    other = tmp_path / "imx477.json"
    other.write_text(VC4.read_text())
    assert_bad_input(
        run("export-tuning", cal, "--base", str(other), "--out", str(tmp_path / "o.json")),
        "calibration is for the imx219, the base tuning file for the imx477",
    )
    with pytest.raises(TuningError, match=r"ships no stock tuning file for the imx585: .*--base"):
        stock_tuning_path("imx585", "pisp")  # a registry sensor Raspberry Pi ships no tuning file for
    (tmp_path / "no").write_text("a file where --out needs a folder")  # missing folders are made; a file is not
    assert_bad_input(
        run("export-tuning", cal, "--base", str(VC4), "--out", str(tmp_path / "no" / "such" / "o.json")),
        "o.json",
        "a file is in the way",
    )
    assert_bad_input(
        run("export-tuning", cal, "--base", str(VC4), "--out", str(VC4), "--overwrite"),
        "is an input of this command",
    )
    assert not (tmp_path / "o.json").exists()
    assert_bad_input(
        run("apply-tuning", str(bad), str(run_dir / "sim" / "white.dng"), "--out", str(tmp_path / "a.tiff")),
        "not a version 2",
    )
    assert_bad_input(
        run(
            "apply-tuning",
            str(VC4),
            str(run_dir / "sim" / "white.dng"),
            "--out",
            str(tmp_path / "a.tiff"),
            "--sensor-size",
            "3280x2464",
        ),
        "--sensor-crop",
    )
    assert not (tmp_path / "a.tiff").exists()


@pytest.mark.slow
def test_export_tuning_without_a_base_uses_the_bundled_stock_files(run_dir, tmp_path):
    from picamcal.export.tuning import BUNDLED_TUNING_DIR, check_tuning

    out = tmp_path / "tuning"
    result = run("export-tuning", str(run_dir / "cal.npz"), "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["imx219_pisp.json", "imx219_vc4.json"]
    for name, target, cells in (("vc4", "bcm2835", 16 * 12), ("pisp", "pisp", 32 * 32)):
        tuning = json.loads((out / f"imx219_{name}.json").read_text())
        stock = json.loads((BUNDLED_TUNING_DIR / name / "imx219.json").read_text())
        assert check_tuning(tuning) == target
        alsc = next(a["rpi.alsc"] for a in tuning["algorithms"] if "rpi.alsc" in a)
        assert alsc["n_iter"] == 0 and len(alsc["calibrations_Cr"][0]["table"]) == cells
        # Every other algorithm is the stock file's, in its order.
        assert [a for a in tuning["algorithms"] if "rpi.alsc" not in a] == [
            a for a in stock["algorithms"] if "rpi.alsc" not in a
        ]
    one = tmp_path / "pi5.json"
    assert run("export-tuning", str(run_dir / "cal.npz"), "--out", str(one), "--target", "PiSP").returncode == 0
    assert json.loads(one.read_text())["target"] == "pisp"


@pytest.mark.slow
def test_export_tuning_bad_targets(run_dir, tmp_path):
    cal = str(run_dir / "cal.npz")
    assert_bad_input(run("export-tuning", cal, "--out", str(tmp_path / "x"), "--target", "vc-4"), "did you mean vc4")
    assert_bad_input(run("export-tuning", cal, "--out", str(tmp_path / "both.json")), "folder")
    assert not any(tmp_path.iterdir())
