"""picamcal against the Raspberry Pi Camera Tuning Tool: how flat a white is after each tool's lens shading table.

Usage: python3 benchmarks/compare_ctt.py [--sensor imx219] [--sensor imx477] [--tuning-dir DIR]

For each sensor it simulates a full-size calibration run, writes the white as a DNG named as the
Camera Tuning Tool (PyPI ``rpi-ctt``) expects, runs ``ctt --alsc-only`` on it for each target (vc4:
16 x 12 cells, pisp: 32 x 32) and calibrates picamcal from the same run. Each tool's ``rpi.alsc``
goes into the sensor's stock libcamera tuning file as a static table (``n_iter`` 0, luminance
strength 1 for both), and picamcal's emulation of the ISP (:func:`picamcal.export.isp.apply_tuning`)
applies it to three whites:

- held-out: another white frame, with other noise, that neither tool was fitted to (the goal's frame);
- fitted: the white both tools were fitted to;
- noise-free: the expected white, so that what is left is the table's error alone.

The figure is the coefficient of variation over the whole frame, edges included, of the 16 x 16
pixel block means of G, and of the block ratios R/G and B/G. Pixel noise alone leaves a floor under
the figures of a noisy frame, printed as what a perfect table would score. The goal: picamcal at
least 4 times flatter than ctt on both grids. Temporary files are removed at the end.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

import picamcal
from picamcal.analysis.metrics import flatness
from picamcal.export.isp import alsc_section, apply_tuning
from picamcal.export.tuning import STOCK_TUNING_DIR, export_tuning, load_tuning
from picamcal.sensors import LSC_GRIDS
from picamcal.simulate import make_camera, render, simulate_references

GRIDS = {"vc4": "16x12", "pisp": "32x32"}
METRICS = ("G", "R/G", "B/G")
#: Colour temperature in the file name ctt reads it from, and of both tools' single table entry.
CT = 4500
LUMINANCE_STRENGTH = 1.0
BLOCK = 16
FIT_SEED, HELD_OUT_SEED = 0, 1
GOAL_RATIO = 4.0
SHARED_TUNING_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "libcamera-tuning"


def log(message: str) -> None:
    print(message, flush=True)


def block_means(rgb: np.ndarray) -> np.ndarray:
    """Means over square blocks from the top-left; the partial blocks at the right and bottom edges count."""
    rows, cols = np.arange(0, rgb.shape[0], BLOCK), np.arange(0, rgb.shape[1], BLOCK)
    sums = np.add.reduceat(np.add.reduceat(rgb, rows, axis=0, dtype=np.float64), cols, axis=1)
    counts = np.outer(np.diff(rows, append=rgb.shape[0]), np.diff(cols, append=rgb.shape[1]))
    return sums / counts[..., None]


def figures_of_means(means: np.ndarray) -> np.ndarray:
    """Coefficients of variation of the block means of G and of the block ratios R/G and B/G."""
    green = means[..., 1]
    return flatness(np.stack([green, means[..., 0] / green, means[..., 2] / green], axis=-1))


def with_alsc(base: dict[str, Any], alsc: dict[str, Any]) -> dict[str, Any]:
    """A copy of a tuning file whose ``rpi.alsc`` is replaced by ``alsc``."""
    tuning = copy.deepcopy(base)
    for entry in tuning["algorithms"]:
        if "rpi.alsc" in entry:
            entry["rpi.alsc"] = copy.deepcopy(alsc)
            return tuning
    raise SystemExit("the base tuning file has no rpi.alsc section")


def run_ctt(images: Path, out: Path, sensor: str, target: str, config: Path) -> tuple[dict[str, Any], float]:
    """Run the ``ctt --alsc-only`` command for one target; its ``rpi.alsc`` and the command's wall time."""
    command = [sys.executable, "-m", "ctt", "--alsc-only", "-t", target, "-i", str(images), "-o", str(out)]
    command += ["--name", sensor, "-c", str(config)]
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - start
    output = out / f"{sensor}_{target}.json"
    if result.returncode or not output.is_file():
        tail = "\n".join((result.stdout + result.stderr).strip().splitlines()[-15:])
        raise SystemExit(f"ctt failed for {sensor} {target} (exit status {result.returncode}):\n{tail}")
    return alsc_section(json.loads(output.read_text())), seconds


def time_ctt_in_process(images: Path, out: Path, sensor: str, target: str, config: Path) -> float:
    """ctt's own time for the same calibration, without the command's interpreter start-up and imports."""
    from ctt.core.runner import run_ctt_targets  # the function the ctt command calls

    out.mkdir(exist_ok=True)
    start = time.perf_counter()
    run_ctt_targets(out, sensor, str(images), str(config), [target], alsc_only=True)
    return time.perf_counter() - start


def compare_sensor(sensor: str, tuning_dir: Path, folder: Path) -> list[dict[str, Any]]:
    """Both tools' tables for one sensor on both grids and their flatness: one row per grid and white."""
    start = time.perf_counter()
    camera = make_camera(sensor)
    refs = simulate_references(camera, noise=True, seed=FIT_SEED)
    frames = {
        "held-out": render(camera, "white", noise=True, rng=HELD_OUT_SEED),
        "fitted": refs["white"],
        "noise-free": render(camera, "white", noise=False),
    }
    seconds = time.perf_counter() - start
    log(f"[{sensor}] simulated the {camera.width}x{camera.height} references and whites in {seconds:.1f} s")

    # ctt reads every DNG in its input folder; only the white goes there, named alsc_<ct>k_<n>.dng.
    ctt_images, ctt_out = folder / "ctt_images", folder / "ctt_out"
    ctt_images.mkdir()
    paths = {"white": picamcal.write_dng(ctt_images / f"alsc_{CT}k_0.dng", refs["white"])}
    paths |= {role: picamcal.write_dng(folder / f"{role}.dng", raw) for role, raw in refs.items() if role != "white"}
    config = folder / "ctt_config.json"
    config.write_text(json.dumps({"alsc": {"luminance_strength": LUMINANCE_STRENGTH}}))

    start = time.perf_counter()
    calibration = picamcal.calibrate(**paths)
    calibrate_seconds = time.perf_counter() - start
    log(f"[{sensor}] picamcal calibrated from the five DNG files in {calibrate_seconds:.2f} s")

    bases = {grid: load_tuning(tuning_dir / grid / f"{sensor}.json") for grid in GRIDS}
    cols, rows = LSC_GRIDS["bcm2835"]
    unity = with_alsc(bases["vc4"], {"n_iter": 0, "luminance_strength": 1.0, "luminance_lut": [1.0] * (cols * rows)})
    held_out, expected = (block_means(apply_tuning(frames[f], unity)) for f in ("held-out", "noise-free"))
    uncorrected = figures_of_means(held_out)
    # Any table multiplies both frames alike, so this ratio is what a perfect table leaves on the held-out white.
    noise_floor = figures_of_means(held_out / expected)

    results = []
    for grid, size in GRIDS.items():
        start = time.perf_counter()
        ours = export_tuning(calibration, bases[grid], ct=CT, luminance_strength=LUMINANCE_STRENGTH)
        export_seconds = time.perf_counter() - start
        ctt_alsc, ctt_command_seconds = run_ctt(ctt_images, ctt_out, sensor, grid, config)
        ctt_seconds = time_ctt_in_process(ctt_images, ctt_out / "in_process", sensor, grid, config)
        theirs = with_alsc(bases[grid], {**ctt_alsc, "n_iter": 0})
        log(f"[{sensor} {grid}] ctt --alsc-only {ctt_command_seconds:.1f} s; picamcal export {export_seconds:.2f} s")
        for frame, raw in frames.items():
            start = time.perf_counter()
            figures = {
                tool: figures_of_means(block_means(apply_tuning(raw, tuning)))
                for tool, tuning in (("picamcal", ours), ("ctt", theirs))
            }
            log(f"[{sensor} {grid}] applied both tables to the {frame} white in {time.perf_counter() - start:.1f} s")
            results.append(
                {
                    "sensor": sensor,
                    "grid": f"{grid} {size}",
                    "frame": frame,
                    **figures,
                    "uncorrected": uncorrected,
                    "noise_floor": noise_floor,
                    "seconds": {
                        "picamcal": calibrate_seconds + export_seconds,
                        "ctt": ctt_seconds,
                        "ctt command": ctt_command_seconds,
                    },
                }
            )
    return results


def print_figures(rows: list[dict[str, Any]]) -> None:
    log("\nFlatness of a white after each tool's table: CV % of the 16x16 block means (lower is flatter)")
    head = "".join(f" | {metric + ': picamcal':>13} {'ctt':>6} {'ratio':>6}" for metric in METRICS)
    log(f"{'sensor':7} {'grid':10} {'frame':10}{head}")
    for row in rows:
        cells = "".join(
            f" | {100 * ours:13.3f} {100 * theirs:6.3f} {theirs / ours:5.1f}x"
            for ours, theirs in zip(row["picamcal"], row["ctt"], strict=True)
        )
        log(f"{row['sensor']:7} {row['grid']:10} {row['frame']:10}{cells}")
    log("\nFor scale, on the held-out white (CV %):")
    for row in rows:
        if row["grid"].startswith("vc4") and row["frame"] == "held-out":
            for name, key in (("no lens shading", "uncorrected"), ("a perfect table (pixel noise)", "noise_floor")):
                values = ", ".join(f"{m} {100 * v:.3f}" for m, v in zip(METRICS, row[key], strict=True))
                log(f"  {row['sensor']:7} {name:29} {values}")


def print_times(rows: list[dict[str, Any]]) -> None:
    log("\nTime for one table (s); picamcal: calibrate from the five DNG files (once per sensor) + export_tuning;")
    log("ctt: its calibration run in-process, and the whole ctt command (with interpreter start-up and imports)")
    for row in rows:
        if row["frame"] == "held-out":
            s = row["seconds"]
            log(
                f"  {row['sensor']:7} {row['grid']:10} picamcal {s['picamcal']:5.2f}   ctt {s['ctt']:5.2f}"
                f"   ctt command {s['ctt command']:5.2f}"
            )


def print_goal(rows: list[dict[str, Any]], frame: str, title: str) -> None:
    ratios = sorted(
        (theirs / ours, theirs / floor, row["sensor"], row["grid"], metric)
        for row in rows
        if row["frame"] == frame
        for ours, theirs, floor, metric in zip(row["picamcal"], row["ctt"], row["noise_floor"], METRICS, strict=True)
    )
    worst = ratios[0]
    missed = [r for r in ratios if r[0] < GOAL_RATIO]
    where = f"{worst[2]} {worst[3]} {worst[4]}"
    if not missed:
        log(f"  {title}: met; smallest ratio {worst[0]:.1f}x ({where})")
        return
    log(
        f"  {title}: MISSED in {len(missed)} of {len(ratios)} figures; smallest ratio {worst[0]:.1f}x ({where}), "
        f"{GOAL_RATIO / worst[0]:.1f}x short"
    )
    for ratio, bound, sensor, grid, metric in missed:
        reachable = f"; a perfect table would reach {bound:.1f}x" if frame == "held-out" else ""
        log(f"    {sensor} {grid} {metric}: {ratio:.1f}x{reachable}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensor", action="append", choices=("imx219", "imx477"), help="default: both")
    parser.add_argument(
        "--tuning-dir",
        type=Path,
        help=f"folder of {{vc4,pisp}}/<sensor>.json tuning files (default {SHARED_TUNING_DIR} or {STOCK_TUNING_DIR})",
    )
    args = parser.parse_args()
    if importlib.util.find_spec("ctt") is None:
        sys.exit('the Camera Tuning Tool (rpi-ctt) is not installed: python3 -m pip install -e ".[compare]"')
    tuning_dir = args.tuning_dir or next((d for d in (SHARED_TUNING_DIR, STOCK_TUNING_DIR) if d.is_dir()), None)
    if tuning_dir is None:
        sys.exit(f"no libcamera tuning files in {SHARED_TUNING_DIR} or {STOCK_TUNING_DIR}: give --tuning-dir")
    rows = []
    with tempfile.TemporaryDirectory(prefix="compare_ctt_") as tmp:
        for sensor in args.sensor or ["imx219", "imx477"]:
            folder = Path(tmp) / sensor
            folder.mkdir()
            rows += compare_sensor(sensor, tuning_dir, folder)
    print_figures(rows)
    print_times(rows)
    log(f"\nGoal: picamcal at least {GOAL_RATIO:g}x flatter than ctt on both grids, in G, R/G and B/G")
    print_goal(rows, "held-out", "on the held-out white (the goal)")
    print_goal(rows, "fitted", "on the fitted white")
    print_goal(rows, "noise-free", "on the noise-free white (the tables' error alone)")


if __name__ == "__main__":
    main()
