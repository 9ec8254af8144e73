"""The sensor-mode matrix of docs/sensor-modes.md: a calibration from each mode, its tuning loaded, every mode checked.

For each sensor (the IMX219 and the IMX477) and each of its sensor modes, through the real picamera2 on picamcal's
virtual camera (a Raspberry Pi 5 for the acquisition; the raw frames are the same on a Pi 4): ``picamcal acquire
--sensor-mode`` takes the five references in that mode, ``picamcal calibrate`` and ``picamcal export-tuning`` make
the tuning files for both platforms, and ``picamcal verify --tuning`` captures the white's main stream in every mode
on a Pi 5 and on a Pi 4, the tone curve and the colour matrix made identity so that lens shading alone is measured,
with the colour gains the file records for each mode. Each cell of the matrix is the worst corner's departure from
the centre, in any channel, of one verified mode with the tuning from one calibration mode; the modes inside the
calibration's crop are the ones its table covers.

The sensors are reduced to ``--size`` pixels (as ``picamcal virtual-camera --size`` reduces them, every mode and
crop with them), which keeps the run to a few minutes. From the repository's root:

    python3 docs/images/sensor_modes.py                       # docs/images/sensor-modes.json and .png
    python3 docs/images/sensor_modes.py --size 1280x960 --sensors imx219 --out /tmp/matrix

``tests/test_sensor_modes_matrix.py`` runs :func:`run_matrix` and checks that every covered mode is flat within 2 %.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from picamcal.sensors import sensor_modes

HERE = Path(__file__).resolve().parent
SENSORS = ("imx219", "imx477")
PLATFORMS = ("pisp", "vc4")
TARGETS = {"pisp": "pisp", "vc4": "vc4"}
SIZE = (1280, 960)
#: Every covered mode's corners within this of the centre (the issue's goal).
FLATNESS = 0.02
CLI = [sys.executable, "-c", "from picamcal.cli import main; main()"]


def calibration_modes(sensor: str, size: tuple[int, int]) -> list[str]:
    """The sensor's modes on the reduced sensor, one per size (the deepest bit depth), as ``WIDTHxHEIGHT:BITS``."""
    deepest: dict[tuple[int, int], int] = {}
    for mode in sensor_modes(sensor, size):
        deepest[(mode.width, mode.height)] = max(mode.bit_depth, deepest.get((mode.width, mode.height), 0))
    return [f"{w}x{h}:{bits}" for (w, h), bits in sorted(deepest.items())]


def _run(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    result = subprocess.run([*CLI, *argv], cwd=cwd, capture_output=True, text=True, timeout=900)
    if result.returncode not in (0, 1):
        raise RuntimeError(f"picamcal {' '.join(argv)} failed ({result.returncode}): {result.stderr[-2000:]}")
    return result


def _virtual(sensor: str, platform: str, size: tuple[int, int]) -> list[str]:
    return ["virtual-camera", "--sensor", sensor, "--platform", platform, "--size", f"{size[0]}x{size[1]}", "--"]


def one_calibration(sensor: str, mode: str, size: tuple[int, int], work: Path) -> dict[str, Any]:
    """Acquire, calibrate and export in ``mode``; verify each platform's tuning in every mode: the row of the matrix."""
    folder = work / f"{sensor}-{mode.replace(':', '-')}"
    folder.mkdir(parents=True, exist_ok=True)
    _run(*_virtual(sensor, "pisp", size), *CLI, "acquire", "--camera", "picamera2", "--illuminator", "virtual",
         "--sensor-mode", mode, "--out", "run", cwd=folder)  # fmt: skip
    _run("calibrate", "run", "--out", "cal.npz", cwd=folder)
    _run("export-tuning", "cal.npz", "--out", "tuning", cwd=folder)
    row: dict[str, Any] = {}
    for platform in PLATFORMS:
        tuning = folder / "tuning" / f"{sensor}_{TARGETS[platform]}.json"
        record = json.loads(tuning.read_text())["picamcal"]
        verified = _run(*_virtual(sensor, platform, size), *CLI, "verify", "--camera", "picamera2", "--illuminator",
                        "virtual", "--tuning", str(tuning), "--json", cwd=folder)  # fmt: skip
        checks = json.loads(verified.stdout)
        row[platform] = {
            "crop": record["geometry"]["crop"],
            "covered": record["modes_covered"],
            "modes": {
                check["mode"]: {
                    "flatness": check["flatness"],
                    "neutrality": check["neutrality"],
                    "worst": check["worst"],
                    "centre": check["centre"],
                    "covered": check["mode"] in record["modes_covered"],
                }
                for check in checks["modes"]
            },
        }
    return row


def run_matrix(
    sensors: tuple[str, ...] = SENSORS, size: tuple[int, int] = SIZE, work: Path | None = None, jobs: int = 2
) -> dict[str, Any]:
    """The whole matrix: ``{"size", "sensors": {sensor: {platform: {calibration mode: row}}}}``, two calibrations at a
    time (the machine has two cores)."""
    with tempfile.TemporaryDirectory() as scratch:
        base = work or Path(scratch)
        tasks = [(sensor, mode) for sensor in sensors for mode in calibration_modes(sensor, size)]
        with ThreadPoolExecutor(max_workers=jobs) as pool:
            rows = list(pool.map(lambda task: one_calibration(*task, size, base), tasks))
    result: dict[str, Any] = {"size": list(size), "sensors": {}}
    for (sensor, mode), row in zip(tasks, rows, strict=True):
        for platform, checks in row.items():
            result["sensors"].setdefault(sensor, {}).setdefault(platform, {})[mode] = checks
    return result


def covered_failures(result: dict[str, Any], tolerance: float = FLATNESS) -> list[str]:
    """Every covered mode whose corners are further than ``tolerance`` from the centre, named."""
    failures = []
    for sensor, platforms in result["sensors"].items():
        for platform, rows in platforms.items():
            for calibrated, row in rows.items():
                for mode, check in row["modes"].items():
                    if check["covered"] and check["flatness"] > tolerance:
                        failures.append(f"{sensor} {platform}: tuning from {calibrated}, mode {mode}: "
                                        f"{100 * check['flatness']:.2f} %")  # fmt: skip
    return failures


def plot_matrix(result: dict[str, Any], path: Path) -> Path:
    """One panel per sensor and platform: rows the calibration's mode, columns the mode verified, each cell the worst
    corner's departure from the centre in per cent; the modes a calibration covers are framed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    sensors = list(result["sensors"])
    fig, axes = plt.subplots(len(sensors), len(PLATFORMS), figsize=(11, 4.2 * len(sensors)), squeeze=False)
    for i, sensor in enumerate(sensors):
        for j, platform in enumerate(PLATFORMS):
            ax = axes[i][j]
            rows = result["sensors"][sensor][platform]
            calibrated = list(rows)
            verified = sorted({m for row in rows.values() for m in row["modes"]}, key=lambda m: _size_key(m))
            values = [[100 * rows[c]["modes"][v]["flatness"] for v in verified] for c in calibrated]
            image = ax.imshow(values, cmap="viridis_r", vmin=0, vmax=20)
            for r, c in enumerate(calibrated):
                for k, v in enumerate(verified):
                    check = rows[c]["modes"][v]
                    shade = "white" if values[r][k] > 10 else "black"
                    ax.text(k, r, f"{values[r][k]:.1f}", ha="center", va="center", color=shade, fontsize=8)
                    if check["covered"]:
                        ax.add_patch(Rectangle((k - 0.5, r - 0.5), 1, 1, fill=False, edgecolor="red", linewidth=2))
            ax.set_xticks(range(len(verified)), verified, rotation=35, ha="right", fontsize=8)
            ax.set_yticks(range(len(calibrated)), calibrated, fontsize=8)
            ax.set_xlabel("mode verified")
            ax.set_ylabel("calibrated in")
            name = {"pisp": "Raspberry Pi 5", "vc4": "Raspberry Pi 4"}[platform]
            ax.set_title(f"{sensor} ({result['size'][0]}x{result['size'][1]} virtual sensor), {name}", fontsize=9)
            fig.colorbar(image, ax=ax, label="worst corner vs centre, %", shrink=0.8)
    fig.suptitle("Worst corner's departure from the centre (%); framed: modes inside the calibration's crop")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _size_key(mode: str) -> tuple[int, int, int]:
    size, _, bits = mode.partition(":")
    width, _, height = size.partition("x")
    return int(width) * int(height), int(width), int(bits)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default=f"{SIZE[0]}x{SIZE[1]}", help="the virtual sensors' size WIDTHxHEIGHT")
    parser.add_argument("--sensors", default=",".join(SENSORS), help="comma-separated: imx219,imx477")
    parser.add_argument("--out", default=str(HERE), help="folder for sensor-modes.json and sensor-modes.png")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result = run_matrix(tuple(args.sensors.split(",")), (width, height), jobs=min(2, os.cpu_count() or 1))
    (out / "sensor-modes.json").write_text(json.dumps(result, indent=1) + "\n")
    plot_matrix(result, out / "sensor-modes.png")
    failures = covered_failures(result)
    print(f"wrote {out / 'sensor-modes.json'} and {out / 'sensor-modes.png'}; covered modes over 2 %: "
          + ("; ".join(failures) if failures else "none"))  # fmt: skip


if __name__ == "__main__":
    main()
