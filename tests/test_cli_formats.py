"""Every command with every raw format, `picamcal inspect`, metadata overrides and processed images, via subprocess."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from picamcal import load_calibration, read_raw
from picamcal.raw import override, write_dng
from test_cli import assert_bad_input, run

# Every test runs the command line several times (a second or more each) on a 640 x 480 run: the fast loop leaves
# them out; tests/test_brcm.py, test_dng.py, test_picamera2.py and test_processed.py test the formats quickly.
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def brcm_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("brcm") / "run"
    result = run("simulate", "--out", str(out), "--format", "brcm", "--size", "640x480", "--seed", "5")
    assert result.returncode == 0, result.stderr
    return out


def test_calibrate_and_correct_legacy_jpeg_raw_files(brcm_run, tmp_path):
    cal = tmp_path / "cal.npz"
    assert run("calibrate", str(brcm_run), "--out", str(cal)).returncode == 0
    inputs = load_calibration(cal).inputs
    assert {i["format"] for i in inputs} == {"brcm"}  # the calibration records where each reference came from
    result = run("correct", str(cal), str(brcm_run / "target.jpg"), "--out", str(tmp_path / "out"))
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "out" / "target.tiff").exists()


def test_mixed_formats_in_one_calibration(brcm_run, tmp_path):
    npz = tmp_path / "red.npz"
    from picamcal import write_npz

    write_npz(npz, read_raw(brcm_run / "red.jpg"))
    result = run(
        "calibrate",
        f"--white={brcm_run / 'white.jpg'}",
        f"--red={npz}",
        f"--green={brcm_run / 'green.jpg'}",
        f"--blue={brcm_run / 'blue.jpg'}",
        "--out",
        str(tmp_path / "cal.npz"),
    )
    assert result.returncode == 0, result.stderr
    formats = {i["role"]: i["format"] for i in load_calibration(tmp_path / "cal.npz").inputs}
    assert formats == {"white": "brcm", "red": "npz", "green": "brcm", "blue": "brcm"}


def test_inspect_table_and_json(brcm_run, tmp_path):
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "photo.png")
    result = run("inspect", str(brcm_run / "white.jpg"), str(tmp_path / "photo.png"), "--json")
    assert result.returncode == 0, result.stderr
    raw, processed = json.loads(result.stdout)
    assert raw["format"] == "brcm" and raw["sensor"] == "imx219" and raw["pattern"] == "BGGR"
    assert raw["bit_depth"] == 10 and raw["black_level"] == [64.0] * 4 and raw["white_level"] == 1023
    assert raw["exposure_time_s"] == pytest.approx(0.01) and raw["warnings"] == []
    assert processed["format"] == "processed png" and processed["raw"] is False
    table = run("inspect", str(brcm_run / "white.jpg"))
    assert "brcm" in table.stdout and "imx219" in table.stdout and "640x480" in table.stdout


def test_lying_metadata_is_reported_and_overridden(brcm_run, tmp_path):
    folder = tmp_path / "pidng"
    folder.mkdir()
    for role in ("white", "red", "green", "blue"):
        write_dng(folder / f"{role}.dng", override(read_raw(brcm_run / f"{role}.jpg"), pattern="GBRG", black_level=0))
    result = run("inspect", str(folder / "white.dng"))
    assert "greens sit on the other diagonal" in result.stdout and "--black-level 64" in result.stdout
    # Believing the file mixes up the colours: the warnings say why, and the calibration refuses.
    warned = run("calibrate", str(folder), "--out", str(tmp_path / "bad.npz"))
    # The warnings are folded into the one error line.
    assert_bad_input(warned, "warning(s):", "--pattern")
    assert not (tmp_path / "bad.npz").exists()
    fixed = run(
        "calibrate", str(folder), "--out", str(tmp_path / "good.npz"), "--pattern", "BGGR", "--black-level", "64"
    )
    assert fixed.returncode == 0 and "warning" not in fixed.stderr
    good = load_calibration(tmp_path / "good.npz")
    # The same references read with their true metadata (and, like the lying copies, no dark frame).
    reference = run(
        "calibrate",
        *[f"--{r}={brcm_run / f'{r}.jpg'}" for r in ("white", "red", "green", "blue")],
        "--out",
        str(tmp_path / "ref.npz"),
    )
    assert reference.returncode == 0
    np.testing.assert_allclose(good.unmixing, load_calibration(tmp_path / "ref.npz").unmixing, atol=1e-6)


def test_correct_processed_images(brcm_run, tmp_path):
    cal = tmp_path / "cal.npz"
    assert run("calibrate", str(brcm_run), "--out", str(cal)).returncode == 0
    from picamcal import correct, load_calibration
    from picamcal.analysis.metrics import encode_srgb

    flat = correct(read_raw(brcm_run / "target.jpg"), load_calibration(cal), "flat")
    Image.fromarray(encode_srgb(flat)).save(tmp_path / "isp.png")
    result = run(
        "correct",
        str(cal),
        str(tmp_path / "isp.png"),
        "--processed",
        "--input-encoding",
        "srgb",
        "--out",
        str(tmp_path / "out"),
    )
    assert result.returncode == 0, result.stderr
    import tifffile

    assert tifffile.imread(tmp_path / "out" / "isp.tiff").shape == (480, 640, 3)
    assert_bad_input(
        run(
            "correct",
            str(cal),
            str(tmp_path / "isp.png"),
            "--processed",
            "--input-encoding",
            "log",
            "--out",
            str(tmp_path / "o2"),
        ),
        "unknown input encoding 'log'",
    )


def test_bad_raw_inputs(brcm_run, tmp_path):
    refs = [f"--{r}={brcm_run / f'{r}.jpg'}" for r in ("red", "green", "blue")]
    out = tmp_path / "cal.npz"
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "plain.jpg")
    assert_bad_input(
        run("calibrate", f"--white={tmp_path / 'plain.jpg'}", *refs, "--out", str(out)),
        "plain.jpg",
        "no raw (BRCM) block",
    )
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "plain.png")
    assert_bad_input(
        run("calibrate", f"--white={tmp_path / 'plain.png'}", *refs, "--out", str(out)),
        "plain.png",
        "a PNG image, not a raw image",
    )
    data = (brcm_run / "white.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    assert_bad_input(run("calibrate", f"--white={tmp_path / 'cut.jpg'}", *refs, "--out", str(out)), "cut.jpg")
    inspected = run("inspect", str(tmp_path / "cut.jpg"))  # its JPEG preview still decodes: say why it is not raw
    assert inspected.returncode == 0 and "processed jpeg" in inspected.stdout and "not raw:" in inspected.stdout
    # One file named that cannot be read is one error line, as in every other command (a folder is listed: exit 1).
    assert_bad_input(run("inspect", str(tmp_path / "nothing.dng")), "nothing.dng: no such file")
    assert not out.exists()


def test_every_format_gives_the_same_calibration(tmp_path):
    # One simulated run (same seed) written in every format: the mosaics are identical, so must the calibrations be.
    unmixing = {}
    for fmt in ("dng", "brcm", "npy", "npz"):
        folder = tmp_path / fmt
        assert (
            run("simulate", "--out", str(folder), "--format", fmt, "--size", "640x480", "--seed", "9").returncode == 0
        )
        result = run("calibrate", str(folder), "--out", str(tmp_path / f"{fmt}.npz"))
        assert result.returncode == 0, result.stderr
        cal = load_calibration(tmp_path / f"{fmt}.npz")
        assert {i["format"] for i in cal.inputs} == {fmt if fmt != "npy" else "picamera2-npy"}
        unmixing[fmt] = cal.unmixing
        suffix = {"dng": ".dng", "brcm": ".jpg", "npy": ".npy", "npz": ".npz"}[fmt]
        listed = run("inspect", str(folder / f"target{suffix}"), "--json")
        assert json.loads(listed.stdout)[0]["raw"] is True
    for fmt, u in unmixing.items():
        np.testing.assert_array_equal(u, unmixing["dng"], err_msg=fmt)


def test_demo_runs_on_legacy_jpeg_raw_files(tmp_path):
    result = run("demo", "--out", str(tmp_path / "demo"), "--format", "brcm", "--size", "640x480")
    assert result.returncode == 0, result.stderr
    figures = json.loads((tmp_path / "demo" / "figures.json").read_text())
    assert figures["format"] == "brcm" and figures["modes"]["centre"]["max_delta_e"] < 1.0
    assert (tmp_path / "demo" / "raw" / "white.jpg").exists()
