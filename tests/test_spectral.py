"""The spectral simulator: physics that can fail, the floor of a target, and the accuracy of each workflow.

Everything runs on 320 x 240 cameras without noise unless a test says otherwise: the figures are the model's
systematic errors (noise adds what :meth:`picamcal.Calibration.noise_penalty` says), measured with picamcal's own
``calibrate``, ``correct`` and wheel analysis. The measured values quoted in the comments come from
``measure_workflow`` at this size; 640 x 480 gives the same to within 0.05 (the optics scale with the frame).
"""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from picamcal import calibrate, read_raw
from picamcal.bayer import centre_region, sites_to_channels
from picamcal.cli import main
from picamcal.simulate import WORKFLOWS, make_spectral_camera, measure_workflow, simulate_spectral_run
from picamcal.simulate.spectra import WAVELENGTHS, jig_led, monitor_primaries, sensitivities
from picamcal.simulate.spectral import bin_responses
from picamcal.simulate.spectral_accuracy import floor_residual
from picamcal.simulate.spectral_scenes import jig_source, monitor_source, spectral_references, target_scene

SIZE = (320, 240)


def _channel_bins(camera, spectra) -> np.ndarray:
    """Noiseless bin responses per channel (K, nby, nbx, 3)."""
    return sites_to_channels(bin_responses(camera, spectra), camera.pattern)


def _corners(field: np.ndarray) -> np.ndarray:
    """The 2 x 2 bins in each corner of a bin grid, stacked: (16, ...)."""
    return np.concatenate(
        [
            field[ys, xs].reshape(4, *field.shape[2:])
            for ys in (slice(0, 2), slice(-2, None))
            for xs in (slice(0, 2), slice(-2, None))
        ]
    )


def _unmixing(camera, source) -> np.ndarray:
    return calibrate(**spectral_references(camera, source, noise=False)).unmixing


# ---- the spectra ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("sensor", ["imx219", "imx477", "ov5647", "imx708"])
def test_sensitivities_peak_in_the_order_of_the_filters_and_overlap(sensor):
    s = sensitivities(sensor)
    peaks = WAVELENGTHS[s.argmax(axis=1)]
    # Published curves: blue 450-465, green 525-540, red 595-610 nm.
    assert 445 <= peaks[2] <= 470 and 525 <= peaks[1] <= 545 and 595 <= peaks[0] <= 615, peaks
    # The filters overlap: green sees a tenth or more of its peak at the red LED's line and at the blue LED's.
    green = s[1] / s[1].max()
    assert green[WAVELENGTHS == 625][0] > 0.05 and green[WAVELENGTHS == 465][0] > 0.1


def test_led_lines_are_narrow_and_monitor_primaries_broad():
    def fwhm(spectrum):
        return 5.0 * np.count_nonzero(spectrum >= spectrum.max() / 2)

    led = [fwhm(line) for line in jig_led()]
    monitor = [fwhm(p) for p in monitor_primaries()[:3]]
    # WS2812 lines 15-35 nm wide on the 5 nm grid (measured red 15, green 35, blue 25); the monitor's red and green
    # are its backlight's broad phosphor band cut by dye filters (measured 55 and 65 nm), its blue the backlight's
    # narrow pump (20 nm).
    assert max(led) <= 40, led
    assert monitor[0] >= 3 * led[0] and monitor[1] >= 1.5 * led[1] and monitor[2] <= 30, (led, monitor)


# ---- physics that can fail -----------------------------------------------------------------------------------


def test_an_led_primary_reproduces_the_three_primary_vignetting():
    camera = make_spectral_camera("imx219", size=SIZE)
    own = _channel_bins(camera, jig_source().basis[:3])  # (LED, nby, nbx, channel)
    centre = own[:, 7, 10]
    corner = own[:, 0, 0]
    ratio = np.array([corner[k, k] / centre[k, k] for k in range(3)])  # each channel under its own LED
    # Vignetting falls towards the corners in every channel, red most gently (its spot is widest): measured red
    # 0.94, green 0.41, blue 0.19. The fast simulator gives 0.89 / 0.52 / 0.53 under its white.
    assert np.all(ratio < 0.97), ratio
    assert ratio[0] > ratio[1] + 0.3 and ratio[0] > ratio[2] + 0.3, ratio
    # And it falls monotonically along the diagonal (centre to corner), for each LED in its own channel.
    diagonal = np.array([own[k, 7 - i, 10 - i, k] for k in range(3) for i in range(8)]).reshape(3, 8)
    assert np.all(np.diff(diagonal[1:], axis=1) < 0)


def test_crosstalk_depends_on_the_spectrum_through_the_wavelength_dependent_spot():
    camera = make_spectral_camera("imx219", size=SIZE)
    difference = np.abs(_unmixing(camera, jig_source()) - _unmixing(camera, monitor_source()))
    y0, y1, x0, x1 = centre_region(*difference.shape[:2])
    # Both unmixing fields are the identity at the centre (to 0.04 per element, measured), but in the corners the
    # monitor's broad primaries and the LED's lines see different spots: the elements differ by 0.24 on average
    # and up to 0.68 (measured). A per-bin 3 x 3 measured with the LEDs is not the one a monitor's colours need.
    assert difference[y0:y1, x0:x1].max() < 0.06
    assert _corners(difference).mean() > 0.15 and _corners(difference).max() > 0.4
    # Without the carriers' diffusion (the spot then grows only as lambda) the difference is ten times smaller
    # (measured 0.027 mean): it is the wavelength dependence of the spot that makes it.
    optical = make_spectral_camera("imx219", size=SIZE, spot_diffusion=0.0)
    control = np.abs(_unmixing(optical, jig_source()) - _unmixing(optical, monitor_source()))
    assert _corners(control).mean() < _corners(difference).mean() / 4


def test_a_short_lens_gives_a_different_vignetting_and_crosstalk_field():
    none = make_spectral_camera("imx219", size=SIZE)
    short = make_spectral_camera("imx219", size=SIZE, lens="short")
    white = jig_source().spectrum("white")
    fall = [_channel_bins(c, white)[0, 0, 0] / _channel_bins(c, white)[0, 7, 10] for c in (none, short)]
    # The lens's chief rays undo most of the lenslet shift: the green corner keeps 0.79 of the centre instead of
    # 0.41 (measured), and the crosstalk matrices' off-diagonal sum in the corner drops from 1.75 to 1.37.
    assert fall[1][1] > fall[0][1] + 0.25, fall
    m = [calibrate(**spectral_references(c, jig_source(), noise=False)).crosstalk[0, 0] for c in (none, short)]
    off = [float(x.sum() - np.trace(x)) for x in m]
    assert off[1] < off[0] - 0.2, off


# ---- the floor -----------------------------------------------------------------------------------------------


def test_the_floor_is_zero_on_a_target_of_the_calibrations_own_primaries():
    camera = make_spectral_camera("imx219", size=SIZE)
    cal = calibrate(**spectral_references(camera, jig_source(), noise=False))
    # At the bin level a 3 x 3 is exact for colours mixed from the calibration's own three spectra: only float
    # rounding is left (measured 2e-12).
    assert floor_residual(camera, cal, target_scene(camera, "led"))["max_delta_e"] < 1e-6
    led = measure_workflow("jig", "led", noise=False, modes=("centre",))
    # On the corrected image the floor keeps what demosaicing and interpolating bin fields cost (measured 0.13
    # mean; the fast simulator's target gives 0.06), and the jig calibration reaches it.
    assert led["floor"]["mean_delta_e"] < 0.2
    assert led["modes"]["centre"]["mean_delta_e"] < led["floor"]["mean_delta_e"] + 0.05


@pytest.mark.parametrize("target", ["monitor", "print"])
def test_the_floor_is_above_zero_and_below_the_jig_calibration(target):
    result = measure_workflow("jig", target, noise=False, modes=("centre",))
    # Inks (eight Neugebauer primaries) and a monitor's bluish black leak are not three spectra: some of each
    # target's colours no 3 x 3 can reach (bin level, measured mean 6e-5 for the monitor, 0.10 for the print).
    assert result["floor_residual"]["mean_delta_e"] > (1e-5 if target == "monitor" else 0.05)
    # And a calibration with the LEDs stays well above the floor (measured 1.18 against 0.10 on the monitor, 0.99
    # against 0.16 on the print).
    assert result["floor"]["mean_delta_e"] < 0.25
    assert result["modes"]["centre"]["mean_delta_e"] > 3 * result["floor"]["mean_delta_e"]


@pytest.mark.parametrize("workflow", ["screen", "sheets-print"])
def test_references_in_the_targets_own_spectra_bring_the_centre_mode_within_0_3_of_the_floor(workflow):
    calibration, target, lens = WORKFLOWS[workflow]
    result = measure_workflow(calibration, target, lens, noise=False, modes=("centre",))
    # The issue: the centre mode within 0.3 CIEDE2000 (mean) of the floor on monitor and print targets, with the
    # remedy it names: references whose spectra match the target's (the monitor's full-screen colours; for a print,
    # sheets of paper, overprints and inks from the same printer, a least-squares fit over the eight). Measured
    # 0.15 against 0.10 (monitor) and 0.20 against 0.16 (print); the LEDs leave 1.18 and 0.99 (the test above).
    assert result["modes"]["centre"]["mean_delta_e"] - result["floor"]["mean_delta_e"] <= 0.3, result


@pytest.mark.parametrize("calibration", ["jig", "screen"])
def test_the_processed_path_through_the_emulated_isp_scores_as_the_raw_path(calibration):
    raw = measure_workflow(calibration, "monitor", noise=False, modes=("centre",))
    isp = measure_workflow(calibration, "monitor", noise=False, processed="vc4")
    # The ISP's lens shading, gains and tone curve (16 bits) undone, then the same unmixing: measured 1.12 against
    # 1.19 (jig) and 0.17 against 0.16 (screen); the two differ in demosaicing and in where the flat field acts.
    assert isp["modes"]["centre"]["mean_delta_e"] == pytest.approx(raw["modes"]["centre"]["mean_delta_e"], abs=0.1)


# ---- the magnitudes of the issue -----------------------------------------------------------------------------

# (workflow, lowest, highest) accepted centre-mode mean CIEDE2000. The issue: jig on a monitor or print target
# about 1 to 2; full in-situ on the monitor at most 0.3; in situ (white through the lens + the jig's unmixing)
# about 2.5 to 5. Measured: 1.18, 0.99, 0.15 / 0.08 / 0.07, 2.99, 4.80.
MAGNITUDES = [
    ("jig-monitor", 0.8, 2.0),
    ("jig-print", 0.8, 2.0),
    ("screen", 0.0, 0.3),
    ("sheets-print", 0.0, 0.3),
    ("screen-long", 0.0, 0.3),
    ("screen-short", 0.0, 0.3),
    ("in-situ-long", 2.5, 5.0),
    ("in-situ-short", 2.5, 5.0),
]


@pytest.mark.parametrize(("workflow", "low", "high"), MAGNITUDES)
def test_each_workflow_shows_the_magnitude_the_issue_states(workflow, low, high):
    calibration, target, lens = WORKFLOWS[workflow]
    result = measure_workflow(calibration, target, lens, noise=False, modes=("centre",))
    mean = result["modes"]["centre"]["mean_delta_e"]
    assert low <= mean <= high, (workflow, mean)
    # Whatever the workflow, nothing per bin does better than the floor (to the demosaicing's 0.05).
    assert result["floor"]["mean_delta_e"] <= mean + 0.05


def test_modes_order_as_physics_says_on_a_monitor_target():
    result = measure_workflow("jig", "monitor", noise=False)
    scores = {mode: result["modes"][mode]["mean_delta_e"] for mode in ("uncorrected", "flat", "centre")}
    # Measured 10.5 > 4.7 > 1.2: the flat field removes vignetting and the edges' cast, the unmixing most of the
    # desaturation, even with the LEDs' spectra.
    assert scores["uncorrected"] > 1.5 * scores["flat"] > 1.5 * 1.5 * scores["centre"], scores


def test_in_situ_behind_a_short_lens_the_jig_unmixing_does_worse_than_the_flat_field_alone():
    result = measure_workflow("in-situ", "monitor", "short", noise=False, modes=("flat", "centre"))
    # Behind a lens whose chief rays nearly match the lenslet shift there is little crosstalk left, and the jig's
    # unmixing (measured at normal incidence) over-corrects: 4.8 against 0.87 for the flat field (measured).
    assert result["modes"]["centre"]["mean_delta_e"] > 2 * result["modes"]["flat"]["mean_delta_e"]


def test_noise_penalty_is_reported_and_grows_with_the_crosstalk():
    jig = measure_workflow("jig", "monitor", noise=False, modes=("centre",))
    screen = measure_workflow("screen", "monitor", "short", noise=False, modes=("centre",))
    # Normal incidence needs strong unmixing in the corners (measured 8.3 x); behind the short lens little (1.3 x).
    assert jig["noise_penalty"]["max"] > 4 and screen["noise_penalty"]["max"] < 2


# ---- a run on disk -------------------------------------------------------------------------------------------


def test_simulate_spectral_writes_a_run_that_calibrates(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exit_:
        main(
            [
                "simulate",
                "--spectral",
                "--source",
                "jig",
                "--target",
                "print",
                "--lens",
                "long",
                "--size",
                "320x240",
                "--format",
                "npz",
                "--colour",
                "amber=255,128,0",
                "-o",
                str(out),
            ]
        )
    assert exit_.value.code == 0
    names = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert names == [
        "black.npz",
        "blue.npz",
        "colour_amber.npz",
        "green.npz",
        "in_situ/white.npz",
        "layout.json",
        "red.npz",
        "target.npz",
        "truth.json",
        "truth.npz",
        "white.npz",
    ]
    record = json.loads((out / "truth.json").read_text())
    assert (record["source"], record["target"], record["lens"], record["chief_ray_corner_deg"]) == (
        "jig",
        "print",
        "long",
        8.0,
    )
    # The truth's floor is below what the run's own (noiseless) workflow reaches: in situ behind the long lens.
    assert record["floor"]["mean_delta_e"] < record["noiseless_centre"]["mean_delta_e"] / 3
    truth = np.load(out / "truth.npz")
    assert truth["floor_unmixing"].shape == (15, 20, 3, 3) and truth["target_truth"].shape == (7, 3)
    cal = calibrate(*(read_raw(out / f"{role}.npz") for role in ("white", "red", "green", "blue", "black")))
    assert cal.kind == "full" and read_raw(out / "target.npz").metadata["lens"] == "long"


def test_a_monitor_run_writes_no_in_situ_white_and_the_default_colours(tmp_path):
    paths = simulate_spectral_run(tmp_path / "run", size=SIZE, source="monitor", lens="short", fmt="npz")
    assert "in_situ_white" not in paths
    assert {"colour_cyan", "colour_magenta", "colour_yellow"} <= set(paths)
    assert read_raw(paths["colour_cyan"]).metadata["scene"] == "colour_cyan"


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--lens", "short"], "--lens needs --spectral"),
        (["--spectral", "--lens", "wide"], "--lens"),
        (["--spectral", "--target", "poster"], "--target"),
        (["--spectral", "--colour", "amber=256,0,0"], "from 0 to 255"),
        (["--spectral", "--colour", "amber"], "NAME=R,G,B"),
        (["--spectral", "--format", "brcm"], "dng, npy or npz"),
    ],
)
def test_simulate_spectral_refuses_bad_options_in_one_line(tmp_path, capsys, args, fragment):
    with pytest.raises(SystemExit) as exit_:
        main(["simulate", "--size", "320x240", "-o", str(tmp_path / "run"), *args])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("picamcal: error: ") and fragment in err[0], err
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_the_simulator_page_examples_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    text = (Path(__file__).resolve().parents[1] / "docs" / "simulator.md").read_text()
    for block in re.findall(r"```python\n(.*?)```", text, re.DOTALL):
        exec(compile(block, "docs/simulator.md", "exec"), {})
    printed = capsys.readouterr().out
    assert "| jig-monitor | jig | monitor | none |" in printed and "| in-situ-long |" in printed


@pytest.mark.slow
def test_the_simulator_page_commands_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text = (Path(__file__).resolve().parents[1] / "docs" / "simulator.md").read_text()
    commands = re.findall(r"```bash\n(.*?)```", text, re.DOTALL)[0].strip().splitlines()
    for line in commands:
        args = shlex.split(line.split("#")[0])[1:]  # without "picamcal"
        with pytest.raises(SystemExit) as exit_:
            main([*args])
        assert exit_.value.code == 0, line
    assert (tmp_path / "in-situ.npz").exists()


@pytest.mark.slow
def test_with_noise_at_1280x960_full_in_situ_stays_within_0_3_and_the_jig_near_1():
    screen = measure_workflow("screen", "monitor", size=(1280, 960), noise=True, seed=0, modes=("centre",))
    jig = measure_workflow("jig", "monitor", size=(1280, 960), noise=True, seed=0, modes=("centre",))
    # Shot and read noise of every frame (references and target) on top of the model's error: measured 0.19 and
    # 1.14 (0.15 and 1.18 without noise; at the full 3280 x 2464, 0.09 for the screen references).
    assert screen["modes"]["centre"]["mean_delta_e"] <= 0.3
    assert 0.8 <= jig["modes"]["centre"]["mean_delta_e"] <= 2.0
