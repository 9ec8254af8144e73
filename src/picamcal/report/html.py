"""Writing ``DIR/index.html`` and its figures (PNG files beside it), all or nothing.

The report is built in a temporary folder beside ``DIR`` (:func:`picamcal._atomic.make_temporary`, with
the permissions of an ordinary folder) and renamed into place when complete, so a partially written report
never remains; the folders a killed run left are removed by the next report written beside ``DIR``. The page
loads nothing from the network: figures are PNG files next to it, styles are inline.
"""

from __future__ import annotations

import html
import json
import os
import shutil
from collections.abc import Callable, Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from .._atomic import make_temporary, refuse_inputs_as_output, remove_stale_temporaries, temporary_name
from .._version import __version__
from ..calibration import Calibration
from ..errors import OutputError
from ..modes import Mode
from ..raw import RawImage, read_raw
from ..records import json_default

_CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; line-height: 1.45; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; margin-top: 2em; }
table { border-collapse: collapse; margin: 1em 0; } td, th { border: 1px solid #ccc; padding: .3em .6em; }
th { background: #f3f3f3; text-align: left; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
.pass { color: #1a7f37; font-weight: bold; } .warn { color: #b35900; font-weight: bold; }
.fail { color: #c62828; font-weight: bold; }
figure { margin: 1.5em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { color: #555; font-size: .92em; } code { background: #f5f5f5; padding: 0 .2em; }
.note { background: #f6f8fa; border-left: 4px solid #888; padding: .5em .8em; }
"""

#: After the page has loaded, record how many images rendered (the browser test reads it from the DOM).
_LOAD_CHECK = """
window.addEventListener("load", function () {
  var images = Array.prototype.slice.call(document.images);
  var loaded = images.filter(function (im) { return im.complete && im.naturalWidth > 0; }).length;
  document.body.setAttribute("data-images", loaded + "/" + images.length);
});
"""

_FIGURES = (
    (
        "lens_shading_maps",
        "Flat field (lens shading) per channel",
        "Gain that makes the white reference uniform, per colour channel, normalised to 1 at the brightest point.",
    ),
    (
        "unmixing_grid",
        "Colour-unmixing field",
        "The 3 x 3 matrix U(x, y) that restores the colours of the sensor centre (rows: output channel, columns: input "
        "channel). It is the identity at the centre and grows towards the edges, where the crosstalk is strongest.",
    ),
    (
        "noise_penalty_maps",
        "Noise penalty",
        "Factor by which the correction multiplies read noise: for the vignetting correction alone and with unmixing.",
    ),
    (
        "normalised_references",
        "Normalised references",
        "The white, red, green and blue references normalised as in the paper, with R, G, B sections through "
        "the centre.",
    ),
    (
        "vignetting_centre_plot",
        "Centre of the vignetting",
        "Where the white reference peaks, against the sensor centre: an offset means a tilted sensor or optics.",
    ),
    ("dust_map", "Dust and dirt", "Small-scale structure in the white reference; circles mark what was found."),
)
#: The figures about the colour unmixing, which a flat-field calibration (white only) does not have.
_UNMIXING_FIGURES = ("unmixing_grid",)
#: Why a flat-field calibration's report leaves the unmixing checks and figures out, and how to get them.
_FLAT_NOTE = (
    "This is a flat-field calibration, from a white reference alone: it corrects vignetting and colour balance "
    "(modes uncorrected and flat) and has no colour unmixing. The checks and figures about the unmixing (conditioning, "
    "noise penalty of unmixing, smoothness of the unmixing field, the unmixing field itself) are left out because "
    "there is nothing to check. For colour unmixing, calibrate with red, green and blue references too, or combine "
    "this white with a jig calibration (picamcal calibrate --white WHITE --unmixing-from JIG.npz)."
)


#: The file that marks a folder as a report picamcal wrote: the only kind of folder ``overwrite`` replaces.
REPORT_MARKER = ".picamcal-report"


def _esc(value: Any) -> str:
    return html.escape(str(value))


def _prepare_target(out: Path, overwrite: bool) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        if not overwrite:
            raise OutputError("exists and is not empty (use --overwrite to replace the report)", out)
        if out.is_symlink() or not (out / REPORT_MARKER).is_file():
            raise OutputError(
                f"is not a picamcal report (no {REPORT_MARKER} in it): --overwrite replaces only reports picamcal "
                "wrote; choose another --out",
                out,
            )
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the folder: {exc.strerror or exc}", out.parent) from exc


def _swap_into_place(build: Path, out: Path) -> None:
    """Rename the finished report into place, replacing an old one only once the new one is complete."""
    old = None
    if out.exists():
        old = temporary_name(out, ".old")  # a temporary like any other: a run killed here leaves it to the next
        os.replace(out, old)
    os.replace(build, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True) if old.is_dir() else old.unlink(missing_ok=True)


def _figures(cal: Calibration, folder: Path, step: Callable[[str], None]) -> list[tuple[str, str, str]]:
    from ..analysis import figures

    made = []
    for name, title, caption in _FIGURES:
        if name in _UNMIXING_FIGURES and not cal.has_unmixing:
            continue
        if name == "noise_penalty_maps" and not cal.has_unmixing:
            caption = "Factor by which the vignetting correction multiplies read noise."
        if name == "normalised_references" and not cal.has_unmixing:
            caption = "The white reference normalised to its centre, with R, G, B sections through the centre."
        step(f"figure: {title.lower()}")
        getattr(figures, name)(cal, folder / f"{name}.png")
        made.append((f"{name}.png", title, caption))
    return made


def _test_image_section(
    cal: Calibration, raw: RawImage, folder: Path, index: int, layout: dict | None
) -> tuple[str, dict[str, Any]]:
    from ..analysis.metrics import save_preview
    from ..analysis.verdicts import image_verdict
    from ..analysis.wheels import analyse, find_wheels, polar_plot, wheel_crops
    from ..correct import correct

    stem = f"test{index}"
    images = {mode.value: correct(raw, cal, mode) for mode in cal.modes}
    found = find_wheels(images[Mode.UNCORRECTED.value], layout=layout)
    result = analyse(images, found)
    verdict = image_verdict(cal, result)
    parts = [
        f"<h3>{_esc(Path(raw.source).name)}</h3>",
        _verdict_html(verdict),
        "<table><tr><th>mode</th><th>corner CIEDE2000 max</th>"
        "<th>CIEDE2000 mean</th><th>saturation vs centre</th></tr>",
    ]
    for mode in images:
        summary = result[mode]["summary"] if "summary" in result[mode] else result[mode]
        parts.append(
            f"<tr><td>{mode}</td><td class='num'>{summary['max_delta_e']:.2f}</td>"
            f"<td class='num'>{summary['mean_delta_e']:.2f}</td>"
            f"<td class='num'>{summary['mean_saturation_ratio']:.2f}</td></tr>"
        )
    parts.append("</table>")
    for mode in (m.value for m in (Mode.UNCORRECTED, Mode.FLAT, Mode.CENTRE) if m in cal.modes):
        save_preview(folder / f"{stem}_{mode}.png", images[mode], max_size=900)
        polar_plot(result[mode], folder / f"{stem}_{mode}_polar.png", title=f"{mode}: hue and saturation")
        wheel_crops(images[mode], found, folder / f"{stem}_{mode}_wheels.png")
        parts.append(
            f"<figure><img src='{stem}_{mode}.png' alt='{mode} image'><img src='{stem}_{mode}_wheels.png' "
            f"alt='{mode} wheels'><img src='{stem}_{mode}_polar.png' alt='{mode} polar plot'>"
            f"<figcaption>{_esc(mode)}: the image (sRGB preview), its colour wheels, and the hue (angle) and "
            "saturation (radius) of each segment: centre wheel solid, the others dashed.</figcaption></figure>"
        )
    return "\n".join(parts), {"image": raw.source, "verdict": verdict, "analysis": result}


def _verdict_html(verdict: Mapping[str, Any]) -> str:
    """The verdict on a test image, its thresholds, and what to try when it does worse than its workflow."""
    advice = f"<p class='note'>{_esc(verdict['advice'])}.</p>" if verdict["advice"] else ""
    return (
        f"<p>Verdict: <span class='{_esc(verdict['verdict'])}'>{_esc(verdict['verdict'])}</span>: corner CIEDE2000 "
        f"mean {verdict['mean_delta_e']:.2f}, max {verdict['max_delta_e']:.2f} in the {_esc(verdict['mode'])} mode "
        f"(the expected accuracy is above). Thresholds: {_esc(verdict['thresholds'])}.</p>{advice}"
    )


def _expected_html(cal: Calibration) -> str:
    """What the workflows that could have made the calibration reach on the spectral simulator: those of the light
    it records, or of every light when it records none."""
    from ..analysis.verdicts import expected_accuracy
    from ..calibration import LIGHTS

    expected = expected_accuracy(cal)
    conditions = expected["conditions"]
    light = expected["light"]
    if expected["kind"] not in ("full", "least-squares"):
        which = f"What this kind of calibration ({_esc(expected['kind'])}) reaches"
    elif light is not None:
        which = f"Light: {_esc(light)} ({_esc(LIGHTS[light])}), as the calibration records it. What it reaches"
    else:
        which = (
            "Unknown light: expected accuracy of each workflow (the calibration does not record its light: "
            "<code>picamcal calibrate --light jig|screen|sheets</code> does, and calibrating the folder of "
            "<code>picamcal acquire</code> reads it from the manifest). What each reaches"
        )
    rows = "".join(
        f"<tr><td>{_esc(w['name'])}</td><td>{_esc(w['calibration'])}</td><td>{_esc(w['target'])}</td>"
        f"<td>{_esc(w['lens'])}</td><td class='num'>{w['mean_delta_e']:.2f}</td>"
        f"<td class='num'>{w['max_delta_e']:.2f}</td><td class='num'>{w['floor_mean_delta_e']:.2f}</td></tr>"
        for w in expected["workflows"]
    )
    return (
        f"<h2>Expected accuracy</h2><p>{which} on the spectral simulator ({_esc(conditions['sensor'])} at "
        f"{conditions['size'][0]} x {conditions['size'][1]}, with noise; docs/accuracy.md): corner-vs-centre "
        f"CIEDE2000 of the colour-wheel target in the {_esc(expected['mode'])} mode, with the floor, the best any "
        "per-bin 3 x 3 reaches on that target. Test images (<code>picamcal report --test</code>) are scored the same "
        "way.</p><table><tr><th>workflow</th><th>calibration</th><th>target</th><th>lens</th><th>mean</th>"
        f"<th>max</th><th>floor (mean)</th></tr>{rows}</table>"
    )


def write_report(
    calibration: Calibration,
    out_dir: str | os.PathLike[str],
    *,
    test_images: Sequence[RawImage | str | os.PathLike[str]] = (),
    layout: dict | None = None,
    cra_corner_deg: float | None = None,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write the calibration report: ``out_dir/index.html`` with its figures beside it.

    Parameters
    ----------
    calibration : Calibration
    out_dir : path
        The report folder; refused if it exists and is not empty, unless ``overwrite``.
    test_images : raw images or paths
        Images of a colour-wheel target to show before and after correction, with polar plots, in every mode
        the calibration has (``uncorrected`` and ``flat`` for a flat-field calibration).
    layout : dict, optional
        The target's layout (``picamcal target``); without it the wheels are found in the image.
    cra_corner_deg : float, optional
        Chief ray angle of the sensor's lenslets at the corner, to turn the vignetting offset into a tilt.
    overwrite : bool
        Replace an existing report (only once the new one is complete); only a folder that holds picamcal's
        :data:`REPORT_MARKER`, never another folder.
    progress : callable, optional
        Called with a description of each step.

    Returns
    -------
    Path
        The written ``index.html``.

    Examples
    --------
    >>> from picamcal.simulate import make_camera, simulate_references
    >>> cal = picamcal.calibrate(**simulate_references(make_camera("imx219", size=(320, 240)), seed=1))
    >>> write_report(cal, "report")
    PosixPath('report/index.html')
    """
    from ..analysis.diagnostics import diagnose

    step = progress or (lambda _: None)
    out = Path(out_dir)
    sources = [image for image in test_images if not isinstance(image, RawImage)]
    refuse_inputs_as_output(out, [calibration.path, *sources])
    _prepare_target(out, overwrite)
    shape = (calibration.height, calibration.width)  # a test image of another size fails before it is decoded
    raws = [image if isinstance(image, RawImage) else read_raw(image, expected_shape=shape) for image in test_images]
    for raw in raws:
        calibration.check_compatible(raw)
    remove_stale_temporaries(out.parent)
    build = make_temporary(out, folder=True, suffix="")
    try:
        step("diagnostics")
        checks = [c.to_dict() for c in diagnose(calibration, cra_corner_deg=cra_corner_deg)]
        figures = _figures(calibration, build, step)
        sections, analyses = [], []
        for index, raw in enumerate(raws):
            step(f"test image {index + 1} of {len(raws)}")
            section, result = _test_image_section(calibration, raw, build, index, layout)
            sections.append(section)
            analyses.append(result)
        page = _page(calibration, checks, figures, sections)
        (build / "index.html").write_text(page, encoding="utf-8")
        record = {"software_version": __version__, "checks": checks, "test_images": analyses}
        (build / "report.json").write_text(json.dumps(record, indent=2, default=json_default))
        (build / REPORT_MARKER).write_text(f"a report written by picamcal {__version__}\n")
        step("finishing")
        _swap_into_place(build, out)
    except BaseException:
        shutil.rmtree(build, ignore_errors=True)
        raise
    return out / "index.html"


def _percent(fraction: float | None, decimals: int) -> str:
    return "&ndash;" if fraction is None else f"{100 * fraction:.{decimals}f} %"


def _frames_cell(info: Mapping[str, Any]) -> str:
    """The checksum of a single-frame reference, or the count and temporal noise of averaged frames."""
    if info.get("frame_count", 1) > 1:
        return (
            f"{info['frame_count']} frames: temporal noise {info['temporal_noise_dn']:.2f} DN per pixel in one, "
            f"{info['averaged_noise_dn']:.2f} DN in their average"
        )
    return f"<code>{_esc(info['sha256'][:16])}</code>" if info.get("sha256") else "&ndash;"


def _page(cal: Calibration, checks: list[dict], figures: list[tuple[str, str, str]], tests: list[str]) -> str:
    made = cal.provenance
    inputs = "".join(
        f"<tr><td>{_esc(i['role'])}</td><td><code>{_esc(i.get('name', ''))}</code></td><td>{_esc(i['format'])}</td>"
        f"<td class='num'>{_percent(i.get('median_fraction'), 1)}</td>"
        f"<td class='num'>{_percent(i.get('clipped_fraction'), 3)}</td>"
        f"<td>{_frames_cell(i)}</td></tr>"
        for i in cal.inputs
    )
    verdicts = "".join(
        f"<tr><td>{_esc(c['name'])}</td><td class='{_esc(c['verdict'])}'>{_esc(c['verdict'])}</td>"
        f"<td>{_esc(c['summary'])}</td></tr>"
        for c in checks
    )
    warned = sum(c["verdict"] != "pass" for c in checks)
    figure_html = "".join(
        f"<figure><img src='{_esc(src)}' alt='{_esc(title)}'><figcaption><b>{_esc(title)}.</b> "
        f"{_esc(caption)}</figcaption></figure>"
        for src, title, caption in figures
    )
    test_html = "<h2>Test images</h2>" + "".join(tests) if tests else ""
    if cal.has_unmixing:
        kind = "Flat-field and colour-crosstalk calibration"
        worst = float(cal.noise_penalty("centre").max())
        penalty = f"Worst noise penalty of the recommended (centre) correction: {worst:.2f}."
        note = ""
    else:
        kind = "Flat-field calibration (white reference only)"
        penalty = f"Worst noise penalty of the flat-field correction: {cal.noise_penalty('flat').max():.2f}."
        note = f"<p class='note'>{_esc(_FLAT_NOTE)}</p>"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>picamcal report: {_esc(cal.sensor or "camera")} {cal.width}x{cal.height}</title>
<style>{_CSS}</style></head>
<body>
<h1>Calibration report: {_esc((cal.sensor or "unknown sensor").upper())}, {cal.width} x {cal.height}</h1>
<p>{kind} after Bowman, Vodenicharski, Collins and Stirling, <i>Flat-field and
colour correction for the Raspberry Pi camera module</i>. Bayer order {_esc(cal.pattern)}, {cal.white.shape[1]} x
{cal.white.shape[0]} bins of {cal.bin_size} pixels, smoothing {_esc(cal.smoothing)} bins, created
{_esc(made.get("created", "?"))} with picamcal {_esc(made.get("software_version", "?"))}; report written
{datetime.now(timezone.utc).isoformat(timespec="seconds")} with picamcal {__version__}.
{penalty}</p>
{note}
<h2>Verdicts</h2>
<p>{len(checks) - warned} of {len(checks)} checks pass{"" if not warned else f"; {warned} need a look"}.</p>
<table><tr><th>check</th><th>verdict</th><th>what was measured</th></tr>{verdicts}</table>
<h2>Reference images</h2>
<table><tr><th>role</th><th>file</th><th>format</th><th>median exposure</th><th>clipped</th>
<th>sha256, or frames averaged</th></tr>
{inputs}</table>
{_expected_html(cal)}
<h2>Diagnostics</h2>
{figure_html}
{test_html}
<script>{_LOAD_CHECK}</script>
</body></html>
"""
