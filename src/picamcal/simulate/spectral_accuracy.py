"""The ground truth of the spectral simulator, the floor of a target, and the accuracy of each workflow.

**Truth.** A corrected image should show everywhere what the centre of the sensor sees: for a colour of
spectrum ``E``, the noiseless bin responses to ``E`` divided per Bayer site by the calibration's white (as
``correct`` does) and averaged per channel, ``r_E(b)``, then averaged over the central ninth of the bins
(:func:`picamcal.bayer.centre_region`, where the ``centre`` mode's ``M_centre`` is measured): ``t_E``.

**Floor.** The best any per-bin 3 x 3 can do on a target: per bin, the least-squares ``X(b)`` mapping the
flat-fielded responses ``r_k(b)`` of the target's colours (its white background and six segments) onto their
truths ``t_k`` (:func:`floor_unmixing`). Put in place of a calibration's unmixing field (:func:`floor_calibration`),
the same ``correct`` and the same wheel analysis score it (:func:`score_target`). When the target's spectra
span only three dimensions (a monitor's three primaries, without its black leak) ``X`` is exact and the floor
is 0; inks, or a monitor's black leak, leave something no 3 x 3 can remove.

**Workflows.** :func:`measure_workflow` calibrates as a user would (jig LEDs at normal incidence; the monitor's
full-screen references through the lens; an in-situ white through the lens with the jig's unmixing; a white
alone), photographs the target behind the lens and scores every correction mode and the floor with
:func:`picamcal.analysis.wheels.analyse` (CIEDE2000 of the outer wheels against the centre wheel).
:data:`WORKFLOWS` names the ones ``docs/accuracy.md`` reports.

Examples
--------
>>> result = measure_workflow("jig", "monitor", size=(320, 240), noise=False)
>>> sorted(result["modes"]), result["floor"]["mean_delta_e"] < result["modes"]["centre"]["mean_delta_e"]
(['centre', 'flat', 'uncorrected'], True)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..calibrate import calibrate, calibrate_in_situ
from ..calibration import Calibration
from ..correct import correct
from ..errors import PicamcalError
from ..raw.model import RawImage
from ..references import colour_name
from .spectral import (
    SpectralCamera,
    bin_responses,
    centre_truth,
    flat_fielded,
    least_squares_unmixing,
    make_spectral_camera,
)
from .spectral_scenes import (
    SECONDARY_COLOURS,
    TargetScene,
    jig_source,
    monitor_source,
    print_references,
    spectral_references,
    spectral_target,
    target_white,
)

__all__ = [
    "CALIBRATIONS",
    "WORKFLOWS",
    "WORKFLOW_OPTIONS",
    "accuracy_table",
    "calibrate_references",
    "floor_calibration",
    "floor_residual",
    "floor_unmixing",
    "format_accuracy_table",
    "measure_workflow",
    "processed_target",
    "score_target",
    "target_truth",
    "unmixing_residual",
]

#: How a workflow calibrates: ``jig`` (the LED references at normal incidence, whatever the target's lens),
#: ``screen`` (the monitor's full-screen white, red, green, blue and black through the lens), ``sheets`` (printed
#: reference sheets under the print's light through the lens: paper, the red, green and blue overprints and the
#: three inks, a least-squares unmixing: :func:`~picamcal.simulate.spectral_scenes.print_references`), ``in-situ``
#: (the target's white through the lens, with the jig's unmixing: :func:`picamcal.calibrate_in_situ`) and ``flat``
#: (the target's white through the lens alone: flat field only).
CALIBRATIONS = ("jig", "screen", "sheets", "in-situ", "flat")

#: The workflows docs/accuracy.md reports: name -> (calibration, target, lens).
WORKFLOWS: dict[str, tuple[str, str, str]] = {
    "jig-monitor": ("jig", "monitor", "none"),
    "jig-print": ("jig", "print", "none"),
    "in-situ-long": ("in-situ", "monitor", "long"),
    "in-situ-short": ("in-situ", "monitor", "short"),
    "screen": ("screen", "monitor", "none"),
    "sheets-print": ("sheets", "print", "none"),
    "screen-long": ("screen", "monitor", "long"),
    "screen-short": ("screen", "monitor", "short"),
    "flat-long": ("flat", "monitor", "long"),
    "screen-extras": ("screen", "monitor", "none"),
    "jig-extras": ("jig", "monitor", "none"),
    "jig-bounded-4": ("jig", "monitor", "none"),
    "screen-bounded-4": ("screen", "monitor", "none"),
    "jig-monitor-processed": ("jig", "monitor", "none"),
    "screen-processed": ("screen", "monitor", "none"),
}

#: Workflows that add to their calibration, by name: extra references (a least-squares unmixing per bin) or a bound
#: on the noise penalty (:func:`picamcal.calibrate`'s ``colours`` and ``max_noise_penalty``); or that correct the
#: camera's processed image instead of the raw one (``processed``: :func:`measure_workflow`).
WORKFLOW_OPTIONS: dict[str, dict[str, Any]] = {
    "screen-extras": {"colours": SECONDARY_COLOURS},
    "jig-extras": {"colours": SECONDARY_COLOURS},
    "jig-bounded-4": {"max_noise_penalty": 4.0},
    "screen-bounded-4": {"max_noise_penalty": 4.0},
    "jig-monitor-processed": {"processed": "vc4"},
    "screen-processed": {"processed": "vc4"},
}


def target_truth(camera: SpectralCamera, calibration: Calibration, scene: TargetScene) -> tuple[np.ndarray, np.ndarray]:
    """Flat-fielded bin responses of the target's colours and what they should become (the centre's).

    Returns
    -------
    flat : ndarray, shape (C, nby, nbx, 3)
        ``r_k(b)`` for each of ``scene.colour_names`` on the calibration's bin grid, divided by its white.
    truth : ndarray, shape (C, 3)
        ``t_k``, their mean over the central ninth.

    Examples
    --------
    >>> from picamcal.simulate.spectral_scenes import target_scene
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> cal = calibrate(**spectral_references(camera, jig_source(), noise=False))
    >>> flat, truth = target_truth(camera, cal, target_scene(camera, "monitor"))
    >>> flat.shape, truth.shape
    ((7, 15, 20, 3), (7, 3))
    """
    responses = bin_responses(camera, scene.colour_spectra, calibration.bin_size)
    flat = flat_fielded(responses, calibration.site_white.astype(np.float64), calibration.pattern)
    return flat, centre_truth(flat)


def floor_unmixing(camera: SpectralCamera, calibration: Calibration, scene: TargetScene) -> np.ndarray:
    """The best per-bin 3 x 3 for a target: least squares from its colours' responses to their truths.

    Parameters
    ----------
    camera : SpectralCamera
        The camera (and lens) that photographs the target.
    calibration : Calibration
        Its flat field (``site_white``) and bin grid are the ones the field is made for.
    scene : TargetScene
        The target (:func:`picamcal.simulate.spectral_scenes.target_scene`).

    Returns
    -------
    ndarray of float32, shape (nby, nbx, 3, 3)
        On the calibration's bin grid, acting on the flat-fielded image as its ``unmixing`` does.

    Examples
    --------
    >>> from picamcal.simulate.spectral_scenes import target_scene
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> cal = calibrate(**spectral_references(camera, jig_source(), noise=False))
    >>> floor_unmixing(camera, cal, target_scene(camera, "print")).shape
    (15, 20, 3, 3)
    """
    flat, truth = target_truth(camera, calibration, scene)
    return least_squares_unmixing(flat, truth).astype(np.float32)


def floor_residual(camera: SpectralCamera, calibration: Calibration, scene: TargetScene) -> dict[str, float]:
    """How far the floor's field misses the target's colours at the bin level: CIEDE2000 of ``X r_k`` against ``t_k``.

    Mean and max over the bins and the target's colours: 0 when the target's spectra span three dimensions
    (a target made of the calibration's own primaries), what no 3 x 3 can remove otherwise. Scoring the
    corrected image (:func:`score_target`) adds what demosaicing and interpolating the bin fields cost.

    Examples
    --------
    >>> from picamcal.simulate.spectral_scenes import target_scene
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> cal = calibrate(**spectral_references(camera, jig_source(), noise=False))
    >>> floor_residual(camera, cal, target_scene(camera, "led"))["max_delta_e"] < 1e-3
    True
    """
    flat, truth = target_truth(camera, calibration, scene)
    return unmixing_residual(flat, truth, least_squares_unmixing(flat, truth))


def unmixing_residual(flat: np.ndarray, truth: np.ndarray, unmixing: np.ndarray) -> dict[str, float]:
    """CIEDE2000 of the bin responses ``flat`` (:func:`target_truth`) mapped by a per-bin ``unmixing`` against their
    ``truth``: mean and max (:func:`floor_residual` for the floor's field, computed once).

    Examples
    --------
    >>> flat = np.ones((2, 3, 4, 3)); truth = np.ones((2, 3))
    >>> unmixing_residual(flat, truth, np.broadcast_to(np.eye(3), (3, 4, 3, 3)))["max_delta_e"]
    0.0
    """
    from ..analysis.metrics import delta_e2000

    mapped = np.einsum("yxpq,kyxq->kyxp", unmixing, flat)
    delta_e = delta_e2000(mapped, truth[:, None, None, :])
    return {"mean_delta_e": float(delta_e.mean()), "max_delta_e": float(delta_e.max())}


def floor_calibration(calibration: Calibration, unmixing: np.ndarray) -> Calibration:
    """The calibration with its unmixing field replaced (by :func:`floor_unmixing`'s), for ``correct``'s centre mode.

    Examples
    --------
    >>> from picamcal.simulate.spectral_scenes import target_scene
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> cal = calibrate(**spectral_references(camera, jig_source(), noise=False))
    >>> best = floor_calibration(cal, floor_unmixing(camera, cal, target_scene(camera, "monitor")))
    >>> best.unmixing.shape == cal.unmixing.shape
    True
    """
    field = np.asarray(unmixing, dtype=np.float32)
    if calibration.has_unmixing:
        return dataclasses.replace(calibration, unmixing=field)
    # A flat calibration: made full, with placeholders that the centre mode does not read.
    white = calibration.site_responses[:1]
    return dataclasses.replace(
        calibration,
        kind="full",
        unmixing=field,
        site_responses=np.concatenate([white, np.repeat(white / 3, 3, axis=0)]),
        crosstalk=np.broadcast_to(np.eye(3, dtype=np.float32), field.shape).copy(),
        pure_unmixing=field,
        condition_number=np.ones(field.shape[:2], dtype=np.float32),
        ill_conditioned=np.zeros(field.shape[:2], dtype=bool),
        centre_response=np.eye(3),
        colour_response_inverse=np.eye(3),
    )


def score_target(image: np.ndarray, scene: TargetScene) -> dict[str, float]:
    """Corner-vs-centre CIEDE2000 of a corrected target image: mean and max over the outer wheels' segments.

    :func:`picamcal.analysis.wheels.analyse`'s summary, with the wheels where the layout puts them.

    Examples
    --------
    >>> from picamcal.colour_wheel import wheel_scene
    >>> from picamcal.simulate.spectral_scenes import target_scene
    >>> scene = target_scene(make_spectral_camera("imx219", size=(320, 240)))
    >>> score_target(wheel_scene(scene.layout), scene)
    {'mean_delta_e': 0.0, 'max_delta_e': 0.0}
    """
    from ..analysis.wheels import analyse

    summary = analyse({"image": image}, scene.layout)["image"]["summary"]
    return {"mean_delta_e": float(summary["mean_delta_e"]), "max_delta_e": float(summary["max_delta_e"])}


def calibrate_references(
    refs: Mapping[str, RawImage], *, bin_size: int = 16, max_noise_penalty: float | None = None
) -> Calibration:
    """:func:`picamcal.calibrate` of rendered references keyed by role, extra ``colour_<name>`` ones included.

    Examples
    --------
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> refs = spectral_references(camera, monitor_source(), colours={"cyan": (0, 1, 1)}, noise=False)
    >>> [i["role"] for i in calibrate_references(refs).inputs]
    ['white', 'red', 'green', 'blue', 'colour_cyan', 'black']
    """
    colours = {name: raw for role, raw in refs.items() if (name := colour_name(role))}
    return calibrate(
        refs["white"],
        refs.get("red"),
        refs.get("green"),
        refs.get("blue"),
        refs.get("black"),
        colours=colours or None,
        max_noise_penalty=max_noise_penalty,
        bin_size=bin_size,
    )


def _calibrate(how: str, camera: SpectralCamera, jig: SpectralCamera, target: str, **options: Any) -> Calibration:
    """The calibration of a workflow; ``options``: noise, seed, bin_size, colours, max_noise_penalty."""
    noise, seed, colours = options["noise"], options["seed"], options["colours"]
    fit = {"bin_size": options["bin_size"], "max_noise_penalty": options["max_noise_penalty"]}
    if how == "screen":
        return calibrate_references(
            spectral_references(camera, monitor_source(), colours=colours, noise=noise, seed=seed), **fit
        )
    if how == "sheets":
        return calibrate_references(print_references(camera, noise=noise, seed=seed), **fit)
    jig_cal = calibrate_references(
        spectral_references(jig, jig_source(), colours=colours, noise=noise, seed=seed), **fit
    )
    if how == "jig":
        return jig_cal
    white = _render_white(camera, target_white(target), noise, seed)
    if how == "flat":
        return calibrate(white, bin_size=options["bin_size"])
    return calibrate_in_situ(white, jig_cal)


def _render_white(camera: SpectralCamera, white: np.ndarray, noise: bool, seed: int) -> RawImage:
    from .scenes import stream
    from .spectral import render_spectral

    return render_spectral(camera, white, noise=noise, rng=stream(seed, 0), scene="white")


def measure_workflow(
    calibration: str = "jig",
    target: str = "monitor",
    lens: str = "none",
    *,
    sensor: str = "imx219",
    size: tuple[int, int] | None = (320, 240),
    noise: bool = True,
    seed: int = 0,
    bin_size: int = 16,
    modes: Sequence[str] = ("uncorrected", "flat", "centre"),
    colours: Mapping[str, tuple[float, float, float]] | None = None,
    max_noise_penalty: float | None = None,
    processed: str | None = None,
    camera_options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Calibrate as a workflow does, photograph the target through the lens, and score every mode and the floor.

    Parameters
    ----------
    calibration : {"jig", "screen", "sheets", "in-situ", "flat"}
        How the calibration is made (:data:`CALIBRATIONS`).
    target : {"monitor", "print"}
        The colour-wheel target's form.
    lens : {"none", "long", "short"}
        The optics in front of the sensor for the target (and the in-situ references).
    sensor, size : as :func:`make_spectral_camera`
    noise : bool
        Shot and read noise in every frame.
    seed : int
        Seed of the references' and the target's noise.
    bin_size : int
        The calibration's bin size.
    modes : sequence of str
        The correction modes to score (``centre`` and ``pure`` are skipped for a flat calibration).
    colours : mapping of str to 3 amounts, optional
        Extra references of the calibration's source (``{"cyan": (0, 1, 1)}``: LED mixtures for the jig,
        full-screen colours for the monitor), for a least-squares unmixing per bin (:func:`picamcal.calibrate`'s
        ``colours``).
    max_noise_penalty : float, optional
        :func:`picamcal.calibrate`'s noise-limited unmixing.
    processed : {"vc4", "pisp"}, optional
        Correct what the camera's ISP makes of the target instead of the raw frame (:func:`processed_target`): the
        sensor's stock tuning file for that platform with the calibration's lens shading table, no colour matrix,
        its tone curve into 16 bits and back, then :func:`picamcal.correct.correct_processed` in the centre mode
        (the only mode scored).
    camera_options : dict, optional
        More keyword arguments of :func:`make_spectral_camera` (spot widths, optics), for both cameras.

    Returns
    -------
    dict
        ``"workflow"`` (calibration, target, lens), ``"modes"`` (mode -> ``mean_delta_e``, ``max_delta_e``),
        ``"floor"`` (the same for :func:`floor_unmixing`'s field), ``"floor_residual"`` (:func:`floor_residual`: the
        floor at the bin level, without the demosaicing and interpolation), ``"noise_penalty"`` (the centre mode's,
        :meth:`Calibration.noise_penalty`: ``max`` and ``mean`` over bins and channels; the flat mode's for a
        flat calibration).

    Examples
    --------
    >>> result = measure_workflow("screen", "monitor", "short", noise=False)
    >>> result["workflow"], result["modes"]["centre"]["mean_delta_e"] < 0.3
    ({'calibration': 'screen', 'target': 'monitor', 'lens': 'short'}, True)
    """
    if calibration not in CALIBRATIONS:
        raise PicamcalError(f"unknown calibration {calibration!r} (expected one of {', '.join(CALIBRATIONS)})")
    options = dict(camera_options or {})
    jig = make_spectral_camera(sensor, size=size, lens="none", **options)
    camera = make_spectral_camera(sensor, size=size, lens=lens, white=target_white(target), **options)
    cal = _calibrate(
        calibration,
        camera,
        jig,
        target,
        noise=noise,
        seed=seed,
        bin_size=bin_size,
        colours=colours,
        max_noise_penalty=max_noise_penalty,
    )
    raw, scene = spectral_target(camera, target, noise=noise, seed=seed)
    if processed is not None:
        scores = {"centre": score_target(processed_target(raw, cal, sensor, processed), scene)}
    else:
        scores = {
            mode: score_target(correct(raw, cal, mode), scene) for mode in modes if mode in {m.value for m in cal.modes}
        }
    flat, truth = target_truth(camera, cal, scene)  # once, for the floor's field and its residual
    floor = least_squares_unmixing(flat, truth)
    best = floor_calibration(cal, floor.astype(np.float32))
    penalty = cal.noise_penalty("centre" if cal.has_unmixing else "flat")
    return {
        "workflow": {"calibration": calibration, "target": target, "lens": lens},
        "modes": scores,
        "floor": score_target(correct(raw, best, "centre"), scene),
        "floor_residual": unmixing_residual(flat, truth, floor),
        "noise_penalty": {"max": float(penalty.max()), "mean": float(penalty.mean())},
    }


def processed_target(raw: RawImage, calibration: Calibration, sensor: str, platform: str) -> np.ndarray:
    """The target through the camera's ISP and back, corrected: what ``picamcal correct --processed --tuning`` gives.

    The ISP is emulated (:func:`picamcal.export.isp.apply_tuning`) with the sensor's stock tuning file for
    ``platform`` (``vc4`` or ``pisp``) carrying the calibration's lens shading table
    (:func:`picamcal.export.tuning.export_tuning`) and no colour matrix, at the colour gains the camera froze on the
    calibration's white (:func:`picamcal.export.isp.calibration_colour_gains`); the result is encoded with the
    tuning's tone curve to 16 bits, as a PNG holds it, decoded (:func:`picamcal.raw.processed.linearise`) and
    corrected in the centre mode with :func:`picamcal.export.isp.processed_inputs`.

    Examples
    --------
    >>> camera = make_spectral_camera("imx219", size=(320, 240))
    >>> cal = calibrate_references(spectral_references(camera, monitor_source(), noise=False))
    >>> raw, scene = spectral_target(camera, "monitor", noise=False)
    >>> processed_target(raw, cal, "imx219", "vc4").shape
    (240, 320, 3)
    """
    import warnings

    from ..correct import correct_processed
    from ..export.isp import apply_tuning, calibration_colour_gains, processed_inputs
    from ..export.tuning import TARGET_NAMES, export_tuning, load_tuning, stock_tuning_path
    from ..raw.processed import linearise, tuning_gamma_curve

    path = stock_tuning_path(sensor, TARGET_NAMES[platform])
    with warnings.catch_warnings():  # the stock file's other sections are not what is measured
        warnings.simplefilter("ignore")
        tuning = export_tuning(calibration, load_tuning(path))
    gains = calibration_colour_gains(calibration)
    isp = apply_tuning(raw, tuning, colour_gains=gains)
    linear, encoded = tuning_gamma_curve(path)
    scale = float(np.percentile(isp, 99.9))
    codes = np.round(65535 * np.interp(np.clip(isp / scale, 0, 1), linear, encoded))
    image = linearise(codes / 65535, f"tuning:{path}")
    inputs: dict[str, Any] = {**processed_inputs(tuning, calibration, image, colour_gains=gains), "ccm": None}
    return correct_processed(image, calibration, "centre", **inputs) * scale


def accuracy_table(workflows: Sequence[str] | None = None, **options: Any) -> list[dict[str, Any]]:
    """:func:`measure_workflow` of each named workflow (:data:`WORKFLOWS`), as rows for a table.

    Parameters
    ----------
    workflows : sequence of str, optional
        Names of :data:`WORKFLOWS`; default all of them, in its order.
    **options
        Passed to :func:`measure_workflow` (``size``, ``noise``, ``seed``, ``sensor``, ...).

    Returns
    -------
    list of dict
        Each :func:`measure_workflow`'s result with ``"name"`` and, for the workflows of :data:`WORKFLOW_OPTIONS`,
        ``"options"`` (the extra references' names, the noise bound).

    Examples
    --------
    >>> rows = accuracy_table(["screen-short"], noise=False)
    >>> rows[0]["name"], rows[0]["modes"]["centre"]["mean_delta_e"] < 0.3
    ('screen-short', True)
    """
    names = list(WORKFLOWS) if workflows is None else list(workflows)
    unknown = [name for name in names if name not in WORKFLOWS]
    if unknown:
        raise PicamcalError(f"unknown workflow {unknown[0]!r} (expected one of {', '.join(WORKFLOWS)})")
    rows = []
    for name in names:
        extra = WORKFLOW_OPTIONS.get(name, {})
        row = {"name": name, **measure_workflow(*WORKFLOWS[name], **{**options, **extra})}
        if extra:
            row["options"] = {
                "colours": sorted(extra.get("colours", {})),
                "max_noise_penalty": extra.get("max_noise_penalty"),
                "processed": extra.get("processed"),
            }
        rows.append(row)
    return rows


def format_accuracy_table(rows: Sequence[dict[str, Any]]) -> str:
    """A Markdown table of :func:`accuracy_table`'s rows: CIEDE2000 mean / max per mode, the floor, the noise penalty.

    Examples
    --------
    >>> print(format_accuracy_table(accuracy_table(["screen-short"], noise=False)).splitlines()[0])
    | workflow | calibration | target | lens | uncorrected | flat | centre | floor | noise penalty (max) |
    """
    header = ["workflow", "calibration", "target", "lens", "uncorrected", "flat", "centre", "floor"]
    lines = ["| " + " | ".join([*header, "noise penalty (max)"]) + " |", "|" + "---|" * (len(header) + 1)]
    for row in rows:
        flow = row["workflow"]
        cells = [row["name"], flow["calibration"], flow["target"], flow["lens"]]
        for mode in ("uncorrected", "flat", "centre"):
            score = row["modes"].get(mode)
            cells.append(f"{score['mean_delta_e']:.2f} / {score['max_delta_e']:.2f}" if score else "-")
        cells.append(f"{row['floor']['mean_delta_e']:.2f} / {row['floor']['max_delta_e']:.2f}")
        cells.append(f"{row['noise_penalty']['max']:.1f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
