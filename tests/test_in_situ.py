"""In-situ calibration: a white through the user's optics combined with the unmixing measured in the jig."""

from __future__ import annotations

import numpy as np
import pytest

from picamcal import CalibrationInputError, calibrate, calibrate_in_situ, correct
from picamcal.analysis.metrics import flatness, wheel_figures
from picamcal.calibration import UNMIXING_ARRAYS
from picamcal.raw import RawImage
from picamcal.simulate import make_camera, render, simulate_references, simulate_target


def _through_optics(raw: RawImage) -> RawImage:
    """The same frame seen through optics that add their own smooth vignetting (a cos^4-like fall to ~65 %)."""
    y, x = np.mgrid[0 : raw.height, 0 : raw.width]
    r2 = ((x - raw.width / 2) ** 2 + (y - raw.height / 2) ** 2) / (raw.width / 2) ** 2
    black = np.asarray(raw.black_level).reshape(2, 2)
    black_map = np.tile(black, (raw.height // 2, raw.width // 2))
    signal = (raw.bayer - black_map) / (1 + 0.35 * r2) ** 2
    bayer = np.clip(np.round(signal + black_map), 0, raw.white_level).astype(np.uint16)
    return RawImage(bayer, raw.pattern, raw.black_level, raw.white_level, raw.bit_depth, raw.sensor, dict(raw.metadata))


@pytest.fixture(scope="module")
def jig_and_optics():
    camera = make_camera("imx219", size=(640, 480))
    jig = calibrate(**simulate_references(camera, noise=False))
    optics_white = _through_optics(simulate_references(camera, noise=False, seed=1)["white"])
    target, layout = simulate_target(camera, noise=False)
    return jig, optics_white, _through_optics(target), layout


def test_in_situ_keeps_the_jigs_unmixing_and_takes_the_new_flat_field(jig_and_optics):
    jig, optics_white, target, layout = jig_and_optics
    cal = calibrate_in_situ(optics_white, jig)
    # The jig's colour response and unmixing, unchanged: the in-situ calibration is the jig's with a new white.
    for name in UNMIXING_ARRAYS:
        np.testing.assert_array_equal(getattr(cal, name), getattr(jig, name), err_msg=name)
    np.testing.assert_allclose(cal.site_white, cal.site_responses[0], rtol=1e-6)  # the new white's flat field
    ratios = cal.site_responses[1:] / cal.site_responses[0], jig.site_responses[1:] / jig.site_responses[0]
    np.testing.assert_allclose(*ratios, rtol=1e-5)  # the jig's colour responses, relative to its white, kept
    assert np.all(flatness(correct(optics_white, cal, "flat", binned=True)) < 0.002)
    # The jig's own flat field does not know the optics: a white through them stays far from flat.
    assert np.all(flatness(correct(optics_white, jig, "flat", binned=True)) > 0.05)
    assert wheel_figures(correct(target, cal, "centre"), layout)["max_delta_e"] < 1.0
    assert cal.provenance["in_situ"]["unmixing_from"]["role"] == "unmixing"
    assert [i["role"] for i in cal.inputs] == ["white", "unmixing"]


def test_in_situ_from_files_records_the_jig(tmp_path, jig_and_optics):
    jig, optics_white, *_ = jig_and_optics
    path = jig.save(tmp_path / "jig.npz")
    cal = calibrate_in_situ(optics_white, path)
    assert cal.provenance["in_situ"]["unmixing_from"]["name"] == "jig.npz"
    assert len(cal.provenance["in_situ"]["unmixing_from"]["sha256"]) == 64


def test_in_situ_white_must_fit_the_jig(jig_and_optics):
    jig, optics_white, *_ = jig_and_optics
    smaller = RawImage(
        optics_white.bayer[:240, :320],
        optics_white.pattern,
        optics_white.black_level,
        1023,
        10,
        "imx219",
        {"path": "small.dng"},
    )
    with pytest.raises(
        CalibrationInputError,
        match=r"small\.dng: the white does not fit the jig calibration: size 320x240, .* is for 640x480",
    ):
        calibrate_in_situ(smaller, jig)


@pytest.mark.slow
def test_in_situ_from_the_command_line(tmp_path, jig_and_optics):
    from picamcal import load_calibration
    from picamcal.raw import write_dng
    from test_cli import run

    jig, optics_white, *_ = jig_and_optics
    jig.save(tmp_path / "jig.npz")
    write_dng(tmp_path / "white.dng", optics_white)
    result = run(
        "calibrate",
        "--white",
        str(tmp_path / "white.dng"),
        "--unmixing-from",
        str(tmp_path / "jig.npz"),
        "--out",
        str(tmp_path / "cal.npz"),
    )
    assert result.returncode == 0, result.stderr
    np.testing.assert_allclose(load_calibration(tmp_path / "cal.npz").unmixing, jig.unmixing, atol=1e-5)
    folder = tmp_path / "microscope"
    folder.mkdir()
    write_dng(folder / "white.dng", optics_white)
    result = run(
        "calibrate", str(folder), "--unmixing-from", str(tmp_path / "jig.npz"), "--out", str(tmp_path / "cal2.npz")
    )
    assert result.returncode == 0, result.stderr


@pytest.mark.slow
def test_in_situ_averages_several_white_frames(tmp_path, jig_and_optics):
    from picamcal import load_calibration
    from picamcal.raw import write_dng
    from test_cli import assert_bad_input, run

    jig, optics_white, *_ = jig_and_optics
    camera = make_camera("imx219", size=(640, 480))
    frames = [_through_optics(render(camera, "white", rng=k)) for k in range(3)]
    cal = calibrate_in_situ(frames, jig)
    np.testing.assert_allclose(cal.unmixing, jig.unmixing, atol=1e-5)  # the jig's unmixing, whatever the white
    white = cal.inputs[0]
    assert white["frame_count"] == 3 and white["averaged_noise_dn"] < white["temporal_noise_dn"] / 1.7
    # Averaged noisy frames flatten the noiseless white through the optics to their noise (0.3 % in bins).
    assert np.all(flatness(correct(optics_white, cal, "flat", binned=True)) < 0.004)
    jig.save(tmp_path / "jig.npz")
    for k, frame in enumerate(frames, 1):
        write_dng(tmp_path / f"white_{k}.dng", frame)
    names = [str(tmp_path / f"white_{k}.dng") for k in (1, 2, 3)]
    result = run(
        "calibrate", "--white", *names, "--unmixing-from", str(tmp_path / "jig.npz"), "--out", str(tmp_path / "c.npz")
    )
    assert result.returncode == 0, result.stderr
    assert "white: 3 frames averaged" in result.stderr
    assert load_calibration(tmp_path / "c.npz").inputs[0]["frame_count"] == 3
    result = run(
        "calibrate",
        "--white",
        names[0],
        "--red",
        names[1],
        "--unmixing-from",
        str(tmp_path / "jig.npz"),
        "--out",
        str(tmp_path / "d.npz"),
    )
    assert_bad_input(result, "--unmixing-from takes the colours from the jig calibration: drop --red")
