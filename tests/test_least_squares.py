"""Calibration from more than three colour references (least squares per bin) and the noise-limited unmixing.

On the fast simulator (three LED primaries, exactly linear), whose ground truth gives the true unmixing field
``U = M_centre inv(M)``.
"""

from __future__ import annotations

import dataclasses
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from picamcal import CalibrationInputError, PicamcalWarning, calibrate, load_calibration
from picamcal.analysis.diagnostics import check_noise_limit, diagnose, noise_limit_cost
from picamcal.bayer import centre_region, sites_to_channels
from picamcal.calibration.fitting import least_squares_unmixing, limit_noise_penalty, penalty_field
from picamcal.raw import RawImage
from picamcal.simulate import ground_truth, make_camera, render, simulate_references

SIZE = (320, 240)
#: Extra references: LED mixtures, none of them a primary.
MIXTURES = {
    "cyan": (0, 1, 1),
    "magenta": (1, 0, 1),
    "yellow": (1, 1, 0),
    "amber": (1, 0.5, 0),
    "teal": (0, 0.6, 1),
    "pink": (1, 0.3, 0.6),
}
DATA = Path(__file__).parent / "data"
METHOD = Path(__file__).resolve().parents[1] / "docs" / "method.md"


@pytest.fixture(scope="module")
def camera():
    return make_camera("imx219", size=SIZE)


@pytest.fixture(scope="module")
def refs(camera):
    return simulate_references(camera, seed=1)


@pytest.fixture(scope="module")
def unbounded(refs):
    return calibrate(**refs)


def true_unmixing(camera) -> np.ndarray:
    """``M_centre inv(M(b))`` from the simulator's noiseless per-bin mixing."""
    mixing = ground_truth(camera)["site_mixing"]  # (nby, nbx, 4 sites, 3 primaries)
    normalised = np.moveaxis(mixing / mixing.sum(-1, keepdims=True), -1, 0)
    m = np.moveaxis(sites_to_channels(normalised, camera.pattern), 0, -1)
    y0, y1, x0, x1 = centre_region(*m.shape[:2])
    return m[y0:y1, x0:x1].reshape(-1, 3, 3).mean(axis=0) @ np.linalg.inv(m)


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def jump(field: np.ndarray) -> float:
    """The largest change of any element between neighbouring bins."""
    return float(max(np.abs(np.diff(field, axis=0)).max(), np.abs(np.diff(field, axis=1)).max()))


# Least squares ----------------------------------------------------------------------------------------


def test_least_squares_of_three_references_is_the_papers_inverse(unbounded):
    # With exactly red, green and blue the fit is exact and must be M_centre inv(M): solving the constrained
    # normal equations in float64 against the stored float32 field leaves float32 rounding only.
    cal = unbounded
    white = cal.site_responses[0].astype(np.float64)
    responses = sites_to_channels(cal.site_responses[1:] / white, cal.pattern)
    centre = responses[:, cal.centre_slices[0], cal.centre_slices[1]].reshape(3, -1, 3).mean(axis=1)
    fitted, residual = least_squares_unmixing(responses, cal.centre_response.T, 1 / (centre**2).sum(-1))
    np.testing.assert_allclose(fitted, cal.unmixing, atol=2e-5)
    assert residual.max() < 1e-5
    np.testing.assert_allclose(fitted.sum(axis=-1), 1.0, atol=1e-12)  # the white is exact


def test_the_weights_make_a_dim_reference_count_as_a_bright_one():
    # The same four references, one of them ten times dimmer: with the brightness weights the fit does not change.
    rng = np.random.default_rng(0)
    m = np.eye(3) + 0.1 * rng.random((50, 3, 3))
    colours = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0.5, 0.5]], float)
    responses = np.einsum("bpq,kq->kbp", m, colours) + 0.01 * rng.normal(size=(4, 50, 3))  # noisy: no exact fit
    dimmed = responses * np.array([1, 1, 1, 0.1])[:, None, None]

    def weights(r):
        return 1 / (r.mean(axis=1) ** 2).sum(-1)

    u, _ = least_squares_unmixing(responses, colours, weights(responses))
    u_dim, _ = least_squares_unmixing(dimmed, colours, weights(dimmed))
    np.testing.assert_allclose(u_dim, u, rtol=1e-9, atol=1e-12)
    unweighted, _ = least_squares_unmixing(dimmed, colours)
    assert np.abs(unweighted - u).max() > 1e-3  # without them the dim one counts 100 times less


def test_extra_references_on_the_exact_simulator_give_the_three_reference_field(camera):
    # Noiseless and exactly three-primary: every mixture is fitted exactly, so the least-squares field equals the
    # three-reference one up to the 1-DN quantisation of the references (~2e-3 at the darkest corner).
    refs = simulate_references(camera, noise=False)
    three = calibrate(**refs)
    extras = {name: render(camera, amounts, noise=False) for name, amounts in MIXTURES.items()}
    least = calibrate(**refs, colours=extras)
    assert np.abs(least.unmixing - three.unmixing).max() < 3e-3
    assert np.abs(least.unmixing - true_unmixing(camera)).max() < 3e-3
    fit = {i["role"]: i["fit_residual"] for i in least.inputs if "fit_residual" in i}
    assert list(fit) == ["red", "green", "blue", *(f"colour_{n}" for n in MIXTURES)]
    assert max(fit.values()) < 1e-3  # a 3x3 fits LED mixtures to quantisation
    np.testing.assert_allclose(least.unmixing @ np.ones(3), 1.0, atol=1e-5)  # the white stays exact
    # pure and crosstalk stay consistent: pure = Cx U, M = inv(U) M_centre, so pure = inv(M).
    np.testing.assert_allclose(least.pure_unmixing, least.colour_response_inverse @ least.unmixing, atol=1e-5)
    np.testing.assert_allclose(
        least.pure_unmixing @ least.crosstalk, np.broadcast_to(np.eye(3), (15, 20, 3, 3)), atol=1e-4
    )


def test_a_reference_a_3x3_cannot_fit_shows_in_its_fit_residual(camera, refs):
    # An "extra" whose colour changes across the frame (cyan on the left half, amber on the right) is no single
    # colour: no per-bin matrix maps it onto its centre colour. Its fit error is the largest, and being a least-
    # squares compromise it spoils the others' too. Measured: 0.0012 - 0.0031 without it (noise); with it 0.34
    # for it and 0.09 - 0.15 for the others.
    scene = np.zeros((SIZE[1], SIZE[0], 3))
    scene[:, : SIZE[0] // 2] = (0, 1, 1)
    scene[:, SIZE[0] // 2 :] = (1, 0.5, 0)
    cyan = render(camera, (0, 1, 1), rng=5)

    def fit(extras):
        return {i["role"]: i["fit_residual"] for i in calibrate(**refs, colours=extras).inputs if "fit_residual" in i}

    assert max(fit({"cyan": cyan}).values()) < 0.005
    spoilt = fit({"cyan": cyan, "changing": render(camera, scene, rng=6)})
    assert max(spoilt, key=spoilt.get) == "colour_changing" and spoilt["colour_changing"] > 0.25
    assert min(spoilt.values()) > 0.05


def test_ill_conditioned_bins_are_filled_with_extras_too(camera, refs):
    red = refs["red"].bayer.copy()
    red[:16, :16] = refs["white"].bayer[:16, :16]  # one bin where "red" is white: M is singular there
    broken = {**refs, "red": dataclasses.replace(refs["red"], bayer=red)}
    with pytest.warns(PicamcalWarning, match="1 of 300 bins have an ill-conditioned"):
        cal = calibrate(**broken, colours={"cyan": render(camera, (0, 1, 1), rng=5)})
    assert cal.ill_conditioned_bins == 1 and cal.ill_conditioned[0, 0]
    assert any(np.array_equal(cal.unmixing[0, 0], cal.unmixing[y, x]) for y, x in ((0, 1), (1, 0), (1, 1)))
    assert np.isfinite(cal.unmixing).all() and np.isfinite(cal.pure_unmixing).all()


@pytest.mark.parametrize("seed", [1, 2])
def test_more_references_average_the_noise_down(camera, seed):
    # With shot and read noise, six LED mixtures besides red, green and blue bring the unmixing field's RMS error
    # against the ground truth to 0.68 - 0.71 of the three-reference error (seeds 0 - 3; three frames of each
    # primary instead, the same number of frames, give 0.70 - 0.80). The white's noise, common to every
    # reference, is what is left. 0.8 leaves room for the seed.
    refs = simulate_references(camera, seed=seed)
    extras = {name: render(camera, a, rng=100 * seed + i) for i, (name, a) in enumerate(MIXTURES.items())}
    truth = true_unmixing(camera)
    three = rms(calibrate(**refs).unmixing, truth)
    nine = rms(calibrate(**refs, colours=extras).unmixing, truth)
    assert nine < 0.8 * three


# Noise-limited unmixing -------------------------------------------------------------------------------


def test_a_bound_that_binds_nowhere_changes_nothing(refs, unbounded):
    worst = float(unbounded.noise_penalty("centre").max())  # 3.62 on this camera
    cal = calibrate(**refs, max_noise_penalty=worst + 0.05)
    np.testing.assert_array_equal(cal.unmixing, unbounded.unmixing)
    np.testing.assert_array_equal(cal.pure_unmixing, unbounded.pure_unmixing)
    assert cal.noise_limit["bins_over_bound"] == cal.noise_limit["limited_bins"] == 0
    assert cal.noise_limit["max_residual_crosstalk"] == 0


@pytest.mark.parametrize("bound", [3.5, 3.0, 2.5, 2.0, 1.8])
def test_the_bound_holds_everywhere_and_the_field_stays_smooth(refs, unbounded, bound):
    cal = calibrate(**refs, max_noise_penalty=bound)
    # The bound is aimed 1e-5 below and stored in float32 (rounding 6e-8): never over it.
    assert cal.noise_penalty("centre").max() <= bound
    assert cal.noise_penalty("centre").max() > bound * (1 - 1e-4)  # and met, not overshot: the weakest blend
    # The blend is smooth across bins: no neighbouring bins differ more than in the unbounded field.
    assert jump(cal.unmixing) <= jump(unbounded.unmixing)
    np.testing.assert_allclose(cal.unmixing @ np.ones(3), 1.0, atol=1e-5)  # the white stays exact
    np.testing.assert_array_equal(cal.crosstalk, unbounded.crosstalk)  # M stays what was measured


def test_the_colour_cost_grows_as_the_bound_falls(refs, unbounded):
    # 320 x 240 (300 bins), unbounded worst penalty 3.62: over 3.5 in 4 bins, over 2.0 in 58 (binds in many).
    bounds = [3.5, 3.0, 2.5, 2.0, 1.8]
    cals = [calibrate(**refs, max_noise_penalty=b) for b in bounds]
    over = [c.noise_limit["bins_over_bound"] for c in cals]
    leak = [c.noise_limit["max_residual_crosstalk"] for c in cals]
    delta_e = [float(noise_limit_cost(c).max()) for c in cals]
    mean_delta_e = [float(noise_limit_cost(c).mean()) for c in cals]
    assert over == sorted(over) and over[0] == 4 and over[-2] == 58
    assert leak == sorted(leak) and delta_e == sorted(delta_e) and mean_delta_e == sorted(mean_delta_e)
    # Measured: worst-bin CIEDE2000 on saturated primaries 0.74, 4.0, 7.7, 12.1, 14.3 (0.1 either way: noise).
    np.testing.assert_allclose(delta_e, [0.74, 4.0, 7.7, 12.1, 14.3], atol=0.15)
    assert float(noise_limit_cost(unbounded).max()) < 1e-3  # the full unmixing leaves no crosstalk
    # The residual crosstalk is lambda (Cx M - I): its per-bin largest leak is what the record summarises.
    residual = cals[2].residual_crosstalk()
    largest = np.abs(residual * (1 - np.eye(3))).max(axis=(-1, -2))
    assert largest.max() == pytest.approx(cals[2].noise_limit["max_residual_crosstalk"], abs=1e-5)


def test_the_blend_is_the_weakest_per_bin():
    # One bin at 60 % of the centre's white: the blend weight found meets the bound exactly, and a weaker one fails.
    m = np.array([[0.8, 0.15, 0.05], [0.15, 0.7, 0.15], [0.05, 0.15, 0.8]])
    u = np.linalg.inv(m)[None, None]
    white, centre = np.full((1, 1, 3), 60.0), np.full(3, 100.0)
    limited, blend = limit_noise_penalty(u, white, centre, 2.5)
    assert penalty_field(limited, white, centre).max() == pytest.approx(2.5 * (1 - 1e-5), rel=1e-9)
    weaker = u + 0.99 * blend[..., None, None] * (np.eye(3) - u)
    assert penalty_field(weaker, white, centre).max() > 2.5


def test_the_check_and_the_record_show_the_bound(refs):
    cal = calibrate(**refs, max_noise_penalty=2.5)
    checks = diagnose(cal)
    assert checks[-1].name == "noise_limit" and checks[-1].verdict == "warn"  # CIEDE2000 7.7 > 2 at the worst bin
    assert "bounded at 2.5x" in checks[-1].summary and "CIEDE2000 7.68" in checks[-1].summary
    assert check_noise_limit(calibrate(**refs, max_noise_penalty=3.5)).verdict == "pass"  # 0.74


# Files ------------------------------------------------------------------------------------------------


def test_a_calibration_with_extras_and_a_bound_loads_back_the_same(refs, camera, tmp_path):
    extras = {name: render(camera, a, rng=i) for i, (name, a) in enumerate(list(MIXTURES.items())[:2])}
    cal = calibrate(**refs, colours=extras, max_noise_penalty=2.5)
    back = load_calibration(cal.save(tmp_path / "cal.npz"))
    assert back.to_record() == cal.to_record()
    for name, array in cal.to_arrays().items():
        np.testing.assert_array_equal(getattr(back, name), array)
    assert back.noise_limit == cal.noise_limit and back.noise_limit["max_noise_penalty"] == 2.5
    assert [i["role"] for i in back.inputs] == [
        "white",
        "red",
        "green",
        "blue",
        "colour_cyan",
        "colour_magenta",
        "black",
    ]
    assert back.noise_penalty("centre").max() <= 2.5


def test_a_calibration_written_before_extras_and_bounds_still_loads():
    # Written by picamcal at commit 14e86b9 (before this change) from simulate_references(make_camera("imx219",
    # size=(128, 96)), seed=4); today's calibrate of the same references gives the same arrays bit for bit.
    old = load_calibration(DATA / "calibration_before_issue13.npz")
    assert old.kind == "full" and old.noise_limit is None and "noise_limit" not in old.to_record()
    assert float(np.abs(old.residual_crosstalk()).max()) < 1e-5
    new = calibrate(**simulate_references(make_camera("imx219", size=(128, 96)), seed=4))
    for name, array in old.to_arrays().items():
        np.testing.assert_array_equal(getattr(new, name), array)


def test_a_corrupt_noise_limit_record_is_refused(refs, tmp_path):
    cal = calibrate(**refs, max_noise_penalty=3.0)
    provenance = {**cal.to_record(), "noise_limit": {"max_noise_penalty": 0.5}}
    provenance = {k: v for k, v in provenance.items() if k in ("inputs", "noise_limit")}
    with pytest.raises(CalibrationInputError, match=r"noise_limit'\.max_noise_penalty"):
        dataclasses.replace(cal, provenance=provenance)


# Bad input (library) ----------------------------------------------------------------------------------


def _renamed(raw: RawImage, name: str) -> RawImage:
    return dataclasses.replace(raw, metadata={**raw.metadata, "path": name})


def test_bad_extra_references_are_refused_naming_the_file(refs, camera):
    cyan = _renamed(render(camera, (0, 1, 1), rng=3), "colour_cyan.dng")
    with pytest.raises(CalibrationInputError, match="extra colour references need the colour unmixing"):
        calibrate(refs["white"], colours={"cyan": cyan})
    with pytest.raises(CalibrationInputError, match="not a name of letters, digits and '-'"):
        calibrate(**refs, colours={"cy an": cyan})
    with pytest.raises(CalibrationInputError, match="two colour references are named cyan"):
        calibrate(**refs, colours={"cyan": cyan, "CYAN": cyan})
    teal = _renamed(cyan, "colour_teal.dng")
    with pytest.raises(
        CalibrationInputError,
        match=r"colour_teal.dng: the colour_teal reference is identical to the "
        r"colour_cyan reference",
    ):
        calibrate(**refs, colours={"cyan": cyan, "teal": teal})
    small = _renamed(dataclasses.replace(cyan, bayer=cyan.bayer[:, :160]), "colour_small.dng")
    with pytest.raises(CalibrationInputError, match=r"colour_small.dng: size 160x240 differs from the white"):
        calibrate(**refs, colours={"small": small})
    dim = _renamed(render(camera, (0, 0.05, 0.05), rng=4), "colour_dim.dng")
    with pytest.raises(CalibrationInputError, match=r"colour_dim.dng: colour_dim reference is too dark"):
        calibrate(**refs, colours={"dim": dim})


@pytest.mark.parametrize("bound", [0.5, float("nan"), float("inf"), -1.0])
def test_a_bound_out_of_range_is_refused(refs, bound):
    with pytest.raises(CalibrationInputError, match=r"out of range \(--max-noise-penalty\)"):
        calibrate(**refs, max_noise_penalty=bound)


def test_a_bound_below_the_flat_fields_own_penalty_or_without_colours_is_refused(refs):
    with pytest.raises(CalibrationInputError, match=r"1.2 is below the flat field's own worst noise penalty 1.77"):
        calibrate(**refs, max_noise_penalty=1.2)
    with pytest.raises(CalibrationInputError, match=r"noise-penalty bound .* need the colour unmixing"):
        calibrate(refs["white"], max_noise_penalty=3.0)


# The examples of docs/method.md ----------------------------------------------------------------------


@pytest.mark.slow  # about 10 s: two simulated calibration sets and three commands
def test_the_method_pages_examples_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    text = METHOD.read_text()
    for block in re.findall(r"```python\n(.*?)```", text, re.DOTALL):
        exec(compile(block, "docs/method.md", "exec"), {})
    printed = capsys.readouterr().out
    assert "('colour_pink', " in printed and " 2.5   21  129  22.9 %  7.68  0.58" in printed  # the table's row
    for line in re.findall(r"```bash\n(.*?)```", text, re.DOTALL)[0].strip().splitlines():
        words = shlex.split(line)
        command = [sys.executable, *words[1:]] if words[0] == "python3" else [sys.executable, "-m", *words]
        result = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, (line, result.stderr)
    assert load_calibration(tmp_path / "bounded.npz").noise_limit["max_noise_penalty"] == 2.5
