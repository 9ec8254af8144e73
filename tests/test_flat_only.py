"""Flat-field calibrations from a white alone: correction, exports, report, several frames per role, and the
errors that point at the fix (centre/pure without unmixing, swapped arguments, unknown black levels)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from picamcal import (
    CalibrationFileError,
    CalibrationInputError,
    PicamcalWarning,
    RawFormatError,
    RawImage,
    calibrate,
    calibrate_in_situ,
    correct,
    load_calibration,
    write_dng,
    write_npz,
)
from picamcal.analysis.metrics import flatness
from picamcal.bayer import bin_sites
from picamcal.calibration import FLAT_ARRAYS, UNMIXING_ARRAYS
from picamcal.export.legacy import apply_legacy_table, legacy_table
from picamcal.export.tuning import export_tuning, load_tuning
from picamcal.raw.model import site_channels
from picamcal.report import write_report
from picamcal.simulate import make_camera, render, simulate_references, simulate_target
from test_cli import assert_bad_input, run
from test_report import BROWSER, open_in_browser

ROOT = Path(__file__).resolve().parents[1]
SIZE = (320, 240)


@pytest.fixture(scope="module")
def camera():
    return make_camera("imx219", size=SIZE)


@pytest.fixture(scope="module")
def clean(camera):
    refs = simulate_references(camera, noise=False)
    return refs, calibrate(refs["white"], black=refs["black"])


@pytest.fixture(scope="module")
def files(camera, tmp_path_factory):
    """A noisy white and dark frame as DNG files, their flat calibration, and a colour-wheel target."""
    folder = tmp_path_factory.mktemp("flat")
    refs = simulate_references(camera, seed=1)
    write_dng(folder / "white.dng", refs["white"])
    write_dng(folder / "black.dng", refs["black"])
    write_dng(folder / "target.dng", simulate_target(camera, seed=2)[0])
    write_dng(folder / "other_white.dng", render(camera, "white", rng=7))
    result = run(
        "calibrate",
        "--white",
        str(folder / "white.dng"),
        "--black",
        str(folder / "black.dng"),
        "--out",
        str(folder / "flat.npz"),
    )
    assert result.returncode == 0, result.stderr
    return folder


def _expected_cv(camera, white: RawImage, frames: int = 1) -> np.ndarray:
    """The CV in bins that shot, read and rounding noise alone give a flat-fielded white, per channel.

    A channel's bin value is the test white's bin mean over the calibration white's, so their relative
    variances add. A site's bin mean averages 64 pixels of variance ``S / g + r**2 + 1/12`` DN^2 (``g``
    electrons per DN); the calibration's also carries the dark frame's ``r**2 + 1/12`` and averages
    ``frames`` whites; the two greens average two sites. The CV over the bins is the RMS of the relative
    standard deviations (the mean is 1 to well within them).
    """
    signal = white.bayer.astype(np.float64) - camera.black_level
    dark = camera.read_noise_dn**2 + 1 / 12
    shot_read = signal / camera.electrons_per_dn + dark
    pixels = (16 // 2) ** 2  # of one site in a 16-pixel bin (the 320 x 240 frame has no partial bins)
    mean = bin_sites(signal, 16)
    relative = bin_sites(shot_read, 16) / pixels / mean**2 * (1 + 1 / frames) + dark / pixels / mean**2
    channels = site_channels(white.pattern)
    return np.array([np.sqrt(np.mean(relative[..., channels == c].mean(-1) / np.sum(channels == c))) for c in range(3)])


def test_a_white_alone_gives_a_flat_calibration_with_only_the_flat_field_arrays(clean, tmp_path):
    _, cal = clean
    assert cal.kind == "flat" and not cal.has_unmixing and cal.modes == ("uncorrected", "flat")
    assert set(cal.to_arrays()) == set(FLAT_ARRAYS) and cal.site_responses.shape[0] == 1
    assert all(getattr(cal, name) is None for name in UNMIXING_ARRAYS) and cal.ill_conditioned_bins == 0
    assert "ill_conditioned_bins" not in cal.to_record()
    back = load_calibration(cal.save(tmp_path / "flat.npz"))
    assert back.kind == "flat" and back.to_record() == cal.to_record() and back.path == tmp_path / "flat.npz"
    with np.load(tmp_path / "flat.npz", allow_pickle=False) as data:
        assert json.loads(str(data["metadata"]))["kind"] == "flat"
        assert set(data.files) == {"metadata", *FLAT_ARRAYS}
    # The flat field is the full calibration's, from the same white: one code path for the shared maths.
    refs, _ = clean
    full = calibrate(**refs)
    assert full.kind == "full" and full.has_unmixing
    for name in FLAT_ARRAYS:
        whole = getattr(full, name)
        np.testing.assert_array_equal(getattr(cal, name), whole[:1] if name == "site_responses" else whole)


def test_flat_calibration_corrects_an_independent_white(camera, clean):
    refs, cal = clean
    # Noiseless: a white at 60 % of the exposure, rounded to DN on its own, comes out flat to 0.02 % in bins
    # (rounding averages out over 64 pixels; what is left is the spline's fit between bin centres) and 0.05 %
    # at full resolution in 16-pixel blocks (demosaicing at the frame edges), against up to 15 % uncorrected.
    dim = render(camera, (0.6, 0.6, 0.6), noise=False)
    assert np.all(flatness(correct(dim, cal, "flat", binned=True)) < 2e-4)
    assert np.all(flatness(correct(dim, cal, "flat"), bin_size=16) < 5e-4)
    assert flatness(correct(dim, cal, "uncorrected", binned=True)).max() > 0.1
    # Noisy: calibrated from one noisy white and dark frame, applied to another noisy white. Measured CV
    # 0.51 %, 0.25 %, 0.37 % (R, G, B); the noise model gives 0.48 %, 0.26 %, 0.37 %. The CV of 300 bins
    # scatters by 1 / sqrt(2 * 300) = 4 % of itself, so 15 % is over three standard errors.
    noisy = simulate_references(camera, seed=1)
    noisy_cal = calibrate(noisy["white"], black=noisy["black"])
    cv = flatness(correct(render(camera, "white", rng=99), noisy_cal, "flat", binned=True))
    np.testing.assert_allclose(cv, _expected_cv(camera, refs["white"]), rtol=0.15)


def test_exports_from_a_flat_calibration_match_the_full_ones(clean):
    refs, cal = clean
    full = calibrate(**refs)
    base = load_tuning(ROOT / "tests" / "data" / "tuning_vc4_imx219.json")
    tuning = export_tuning(cal, base)
    alsc = next(a["rpi.alsc"] for a in tuning["algorithms"] if "rpi.alsc" in a)
    assert alsc["n_iter"] == 0 and len(alsc["luminance_lut"]) == 16 * 12
    # The lens shading depends on the white alone: identical to the full calibration's, to the digit.
    assert tuning == export_tuning(full, base)
    table = legacy_table(cal)
    np.testing.assert_array_equal(table, legacy_table(full))
    # The firmware's bilinear table flattens the white to within its u3.5 steps (1/32) and cell size: the
    # green sites' spread drops from 15 % to under 3 %.
    flat_green = apply_legacy_table(refs["white"], table)[0::2, 1::2]
    assert flat_green.std() / flat_green.mean() < 0.03 < 0.1 < flatness(refs["white"].black_subtracted()[0::2, 1::2])
    with pytest.raises(CalibrationFileError, match=r"no colour unmixing for --ccm .*--unmixing-from JIG\.npz"):
        export_tuning(cal, base, ccm=True)


def test_unmixing_modes_are_one_clear_error(clean, tmp_path):
    refs, cal = clean
    path = cal.save(tmp_path / "flat.npz")
    loaded = load_calibration(path)
    for mode in ("centre", "pure"):
        message = (
            rf"^{re.escape(str(path))}: a flat-field calibration \(white only\) has no colour unmixing for mode "
            rf"{mode}: calibrate with red, green and blue references"
        )
        with pytest.raises(CalibrationFileError, match=message):
            correct(refs["white"], loaded, mode)
    assert loaded.noise_penalty("flat").max() > 1.5  # the vignetting gain at the corners
    np.testing.assert_allclose(loaded.noise_penalty("uncorrected"), 1.0)
    with pytest.raises(CalibrationFileError, match="has no colour unmixing to take"):
        calibrate_in_situ(refs["white"], path)
    # Its unmixing fields are None, and everything that needs them says so in one line naming the file and the fix.
    assert loaded.unmixing is None
    with pytest.raises(CalibrationFileError, match=rf"^{re.escape(str(path))}: .* no colour unmixing for the matrices"):
        loaded.require_unmixing("the matrices")
    with pytest.raises(CalibrationFileError, match="no colour unmixing for mode pure"):
        loaded.matrices("pure")


@pytest.mark.slow
def test_correct_cli_refuses_centre_on_a_flat_calibration_before_any_work(files, tmp_path):
    out = tmp_path / "corrected"
    result = run("correct", str(files / "flat.npz"), str(files / "target.dng"), "--out", str(out), "--mode", "centre")
    assert_bad_input(result, "flat.npz: a flat-field calibration (white only)", "mode centre", "--unmixing-from")
    assert "--white white.dng --unmixing-from JIG.npz" in result.stderr  # the fix, with the user's own white
    assert not out.exists()
    result = run("correct", str(files / "flat.npz"), str(files / "target.dng"), "--out", str(out), "--mode", "flat")
    assert result.returncode == 0, result.stderr
    assert (out / "target.tiff").is_file()
    assert_bad_input(
        run(
            "export-tuning",
            str(files / "flat.npz"),
            "--base",
            str(ROOT / "tests/data/tuning_vc4_imx219.json"),
            "--out",
            str(tmp_path / "t.json"),
            "--ccm",
        ),
        "no colour unmixing for --ccm",
    )
    assert not (tmp_path / "t.json").exists()
    result = run("export-lst", str(files / "flat.npz"), "--out", str(tmp_path / "lst.npy"))
    assert result.returncode == 0, result.stderr
    assert np.load(tmp_path / "lst.npy").shape == (4, 240 // 64 + 1, 320 // 64 + 1)


def test_several_frames_are_averaged_and_their_noise_measured(camera, clean):
    refs, truth = clean
    whites = [render(camera, "white", rng=100 + k) for k in range(4)]
    one = calibrate(whites[0], black=refs["black"])
    four = calibrate(iter(whites), black=refs["black"])  # any iterable: frames are read one at a time

    def rms_error(cal):
        return float(np.sqrt(np.mean((cal.site_white / truth.site_white - 1) ** 2)))

    # Four frames halve the noise of the flat field (measured 1.99); 1200 site-bins give each RMS to 2 %.
    assert rms_error(one) / rms_error(four) == pytest.approx(2.0, rel=0.08)
    info = four.inputs[0]
    assert info["frame_count"] == 4 and len(info["frames"]) == 4 and "frame_count" not in one.inputs[0]
    # One frame's temporal noise against the simulator's model, sqrt(mean(S / g + r^2 + 1/12)) = 11.75 DN:
    # measured 11.77 from 4 frames x 77 000 pixels, good to 0.3 %.
    signal = refs["white"].bayer.astype(np.float64) - camera.black_level
    model = np.sqrt(np.mean(signal / camera.electrons_per_dn + camera.read_noise_dn**2 + 1 / 12))
    assert info["temporal_noise_dn"] == pytest.approx(model, rel=0.02)
    assert info["averaged_noise_dn"] == pytest.approx(info["temporal_noise_dn"] / 2, abs=1e-3)
    # And the averaged flat field corrects an independent white as the noise model says.
    cv = flatness(correct(render(camera, "white", rng=99), four, "flat", binned=True))
    np.testing.assert_allclose(cv, _expected_cv(camera, refs["white"], frames=4), rtol=0.15)


def test_frames_of_one_role_are_checked_one_by_one(camera, clean):
    refs, _ = clean
    white = refs["white"]
    clipped = RawImage(
        np.full_like(white.bayer, 1023), white.pattern, white.black_level, 1023, 10, "imx219", {"path": "white_3.dng"}
    )
    with pytest.raises(CalibrationInputError, match=r"white_3\.dng: white reference is saturated"):
        calibrate([white, white, clipped])
    small = RawImage(white.bayer[:120, :160], white.pattern, white.black_level, 1023, 10, "imx219", {"path": "w2.dng"})
    with pytest.raises(CalibrationInputError, match=r"w2\.dng: size 160x120 differs from the first white frame's"):
        calibrate([white, small])
    with pytest.raises(CalibrationInputError, match="no frames given for the white reference"):
        calibrate([])
    with pytest.raises(CalibrationInputError, match="no blue reference: give red, green and blue references together"):
        calibrate(white, refs["red"], refs["green"])


@pytest.mark.slow
def test_a_folder_of_white_frames_and_a_black(camera, tmp_path):
    folder = tmp_path / "microscope"
    folder.mkdir()
    for k in range(1, 4):
        write_dng(folder / f"white_{k}.dng", render(camera, "white", rng=200 + k))
    write_dng(folder / "black.dng", render(camera, "black", rng=300))
    (folder / "notes.txt").write_text("sample removed, lamp at 70 %")
    out = tmp_path / "cal.npz"
    result = run("calibrate", str(folder), "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "a flat field from the white and the dark frame" in result.stderr  # not "alone": a black was given
    line = next(x for x in result.stderr.splitlines() if x.startswith("white: 3 frames averaged"))
    single, average = (float(v) for v in re.findall(r"([\d.]+) DN", line))
    assert average == pytest.approx(single / np.sqrt(3), abs=0.01) and 10 < single < 14  # 11.75 DN by the model
    cal = load_calibration(out)
    white = cal.inputs[0]
    assert cal.kind == "flat" and [f["name"] for f in white["frames"]] == ["white_1.dng", "white_2.dng", "white_3.dng"]
    assert all(len(f["sha256"]) == 64 for f in white["frames"])
    assert cal.black_level_source == "dark frame"
    # The same frames named on the command line (--white a b c) give the same calibration.
    frames = [str(folder / f"white_{k}.dng") for k in range(1, 4)]
    result = run(
        "calibrate", "--white", *frames, "--black", str(folder / "black.dng"), "--out", str(tmp_path / "b.npz")
    )
    assert result.returncode == 0, result.stderr
    np.testing.assert_array_equal(load_calibration(tmp_path / "b.npz").site_white, cal.site_white)
    # Only some colours: one line, nothing written.
    result = run("calibrate", "--white", frames[0], "--red", frames[1], "--out", str(tmp_path / "c.npz"))
    assert_bad_input(result, "no green or blue reference: give red, green and blue references together, or none")
    assert not (tmp_path / "c.npz").exists()


@pytest.mark.slow
def test_swapped_arguments_are_named_as_such(files, tmp_path):
    white = simulate_references(make_camera("imx219", size=SIZE), noise=False)["white"]
    write_npz(tmp_path / "frame.npz", white)
    np.save(tmp_path / "frame.npy", white.bayer)
    (tmp_path / "dump.raw").write_bytes(white.bayer.tobytes())
    from PIL import Image

    Image.new("RGB", (8, 8)).save(tmp_path / "photo.png")
    Image.new("RGB", (8, 8)).save(tmp_path / "photo.jpg")
    for image, what in [
        (files / "target.dng", "a raw image"),
        (tmp_path / "frame.npz", "a raw image"),
        (tmp_path / "frame.npy", "a raw image"),
        (tmp_path / "dump.raw", "a raw image"),
        (tmp_path / "photo.png", "an image"),
        (tmp_path / "photo.jpg", "an image"),
    ]:
        with pytest.raises(CalibrationFileError, match=rf"{re.escape(image.name)}: this is {what}, not a calibration"):
            load_calibration(image)
    result = run("correct", str(files / "target.dng"), str(files / "flat.npz"), "--out", str(tmp_path / "o"))
    assert_bad_input(
        result,
        "target.dng: this is a raw image, not a calibration (the calibration comes first: "
        "picamcal correct CALIBRATION IMAGE...)",
    )
    assert "pickle" not in result.stderr and not (tmp_path / "o").exists()
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(CalibrationFileError, match=r"notes\.txt: not a picamcal calibration file") as caught:
        load_calibration(tmp_path / "notes.txt")
    assert "pickle" not in str(caught.value)


@pytest.mark.slow
def test_calibrate_prints_the_verdicts_that_need_a_look(tmp_path):
    camera = make_camera("imx219", size=(640, 480))  # the dust check needs about 30 x 40 bins
    dusty = simulate_references(camera, seed=2, dust=3)
    write_dng(tmp_path / "dusty.dng", dusty["white"])
    write_dng(tmp_path / "clean.dng", simulate_references(camera, seed=4)["white"])
    result = run("calibrate", "--white", str(tmp_path / "dusty.dng"), "--out", str(tmp_path / "d.npz"))
    assert result.returncode == 0, result.stderr
    looks = [line for line in result.stderr.splitlines() if line.startswith("needs a look: ")]
    assert len(looks) == 1 and looks[0].startswith("needs a look: dust: 3 dark specks in the white reference")
    result = run("calibrate", "--white", str(tmp_path / "clean.dng"), "--out", str(tmp_path / "c.npz"))
    assert result.returncode == 0 and "needs a look" not in result.stderr, result.stderr
    assert result.stderr.count("\n") == 1  # "wrote ..." and nothing more when every check passes


@pytest.mark.slow
def test_report_of_a_flat_calibration(files, tmp_path):
    cal = load_calibration(files / "flat.npz")
    index = write_report(cal, tmp_path / "report", test_images=[files / "target.dng"])
    html = index.read_text()
    record = json.loads((tmp_path / "report" / "report.json").read_text())
    assert [c["name"] for c in record["checks"]] == ["vignetting_centre", "dust", "exposure"]
    assert set(record["test_images"][0]["analysis"]) == {"uncorrected", "flat"}
    assert "has no colour unmixing" in html and "unmixing_grid" not in html
    images = html.count("<img ")
    assert images == 5 + 2 * 3  # five flat-field figures; image, wheels and polar plot for uncorrected and flat
    assert all((tmp_path / "report" / src).is_file() for src in re.findall(r"<img src='([^']+)'", html))
    result = run("report", str(files / "flat.npz"), "--out", str(tmp_path / "cli-report"))
    assert result.returncode == 0, result.stderr
    if BROWSER is None:
        pytest.skip("no browser: Debian's chromium is installed by .ci/run (apt-get install chromium)")
    assert f'data-images="{images}/{images}"' in open_in_browser(index)


def _without_black_level(raw: RawImage) -> RawImage:
    """The frame as a headless dump of an unknown sensor gives it: black level unknown (NaN)."""
    return RawImage(raw.bayer, raw.pattern, (np.nan,) * 4, raw.white_level, raw.bit_depth, None, {"path": "dump.raw"})


def test_unknown_black_levels_are_taken_from_the_dark_frame(camera, clean):
    refs, known = clean
    white, dark = _without_black_level(refs["white"]), _without_black_level(refs["black"])
    cal = calibrate(white, black=dark)
    # The noiseless dark frame is exactly the simulator's 64 DN, so the fields match those made with it.
    assert cal.black_level == (64.0,) * 4 and cal.black_level_source == "dark frame"
    np.testing.assert_allclose(cal.site_white, known.site_white, rtol=1e-6)
    dim = render(camera, (0.6, 0.6, 0.6), noise=False)
    for binned in (True, False):
        np.testing.assert_allclose(
            correct(_without_black_level(dim), cal, "flat", binned=binned),
            correct(dim, cal, "flat", binned=binned),
            rtol=1e-6,
        )
    # Without a dark frame there is no black level to take: the standard one-line error, naming the file.
    with pytest.raises(RawFormatError, match=r"dump\.raw: no black level: .*--black-level N, --sensor NAME or a dark"):
        calibrate(white)
    # A calibration whose references gave their level (64 DN) lends it to an image that gives none, with a warning.
    without_dark = calibrate(refs["white"])
    assert without_dark.black_level_source == "references"
    for binned in (True, False):
        with pytest.warns(PicamcalWarning, match=r"corrected with the calibration's, 64 DN \(from its references\)"):
            lent = correct(_without_black_level(dim), without_dark, "flat", binned=binned)
        np.testing.assert_allclose(lent, correct(dim, without_dark, "flat", binned=binned), rtol=1e-6)


def test_old_full_files_load_and_flat_files_are_validated(clean, tmp_path):
    refs, _ = clean
    full = calibrate(**refs)
    path = full.save(tmp_path / "old.npz")
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    record = json.loads(str(arrays.pop("metadata")))

    def rewrite(name, meta, **contents):
        np.savez(tmp_path / name, metadata=np.array(json.dumps(meta)), **contents)
        return tmp_path / name

    old = {k: v for k, v in record.items() if k not in ("kind", "black_level_source")}  # as files before them
    assert load_calibration(rewrite("a.npz", old, **arrays)).kind == "full"
    flat_arrays = {k: v for k, v in arrays.items() if k in FLAT_ARRAYS}
    flat_arrays["site_responses"] = arrays["site_responses"][:1]
    assert load_calibration(rewrite("b.npz", {**record, "kind": "flat"}, **flat_arrays)).kind == "flat"
    with pytest.raises(CalibrationFileError, match="a flat calibration holds 'unmixing'"):
        load_calibration(rewrite("c.npz", {**record, "kind": "flat"}, **flat_arrays, unmixing=arrays["unmixing"]))
    with pytest.raises(CalibrationFileError, match=r"'site_responses' has shape \(4, 15, 20, 4\), expected \(1, "):
        load_calibration(
            rewrite("d.npz", {**record, "kind": "flat"}, **{**flat_arrays, "site_responses": arrays["site_responses"]})
        )
    with pytest.raises(CalibrationFileError, match="lacks the array 'crosstalk'"):
        load_calibration(rewrite("e.npz", record, **{**flat_arrays, "site_responses": arrays["site_responses"]}))
    with pytest.raises(CalibrationFileError, match="unknown calibration kind 'half'"):
        load_calibration(rewrite("f.npz", {**record, "kind": "half"}, **arrays))


@pytest.mark.slow
def test_calibration_file_doc_examples_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text = (ROOT / "docs" / "calibration-file.md").read_text()
    namespace: dict = {}
    for block in re.findall(r"```python\n(.*?)```", text, re.DOTALL):
        exec(compile(block, "docs/calibration-file.md", "exec"), namespace)
    for line in "".join(re.findall(r"```bash\n(.*?)```", text, re.DOTALL)).strip().splitlines():
        result = run(*line.split()[1:], cwd=tmp_path)
        assert result.returncode == 0, (line, result.stderr)


@pytest.mark.slow
def test_analyse_with_a_flat_calibration_compares_the_modes_it_has(files, tmp_path):
    result = run(
        "analyse", str(files / "target.dng"), "--calibration", str(files / "flat.npz"), "--out", str(tmp_path / "a")
    )
    assert result.returncode == 0, result.stderr
    analysis = json.loads((tmp_path / "a" / "target_analysis.json").read_text())["analysis"]
    assert set(analysis) == {"uncorrected", "flat"}
