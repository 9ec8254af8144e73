"""The napari plugin: opening a 12 MP DNG as layers against reading it and demosaicing it to linear RGB.

Usage: python3 benchmarks/bench_napari.py [--repeats 7]

A simulated IMX477 frame at full size (4056 x 3040, 12.3 MP) is written as a DNG, then timed, in interleaved rounds
(each round runs every method once, so that all see the same load; each figure is the median over the rounds):

- the plugin's reader, as napari runs it: ``get_reader(path)(path)`` (recognising the file, ``read_raw``, the
  linear RGB, the record and the contrast limits of both layers);
- the baseline: ``read_raw(path)`` and the library's demosaic of it to linear RGB, the fused kernel of
  :func:`picamcal.correct` with no flat field or unmixing (:func:`picamcal.napari._layers.linear_rgb`);
- for scale, ``read_raw`` plus colour-demosaicing's Malvar (:func:`picamcal.correct.demosaic`, the reference
  implementation) of the black-subtracted, white-balanced mosaic, and ``read_raw`` alone.

Goal (issue 32): opening costs at most 1.5 times the baseline. Then the correction preview of a 12 MP frame (the
Correct widget's :func:`picamcal.napari.correct_layer`), goal under 0.5 s on the 2-core development machine.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

import picamcal
from picamcal.correct import demosaic
from picamcal.napari._layers import linear_fields, linear_rgb
from picamcal.napari._reader import get_reader
from picamcal.raw import write_dng
from picamcal.simulate import make_camera, simulate_target

GOAL_OPEN = 1.5  # opening as layers at most this many times read_raw plus the demosaic to linear RGB
GOAL_PREVIEW_S = 0.5  # a correction preview of a 12 MP layer under this many seconds

READER = "plugin reader: get_reader(path)(path)"
BASELINE = "read_raw + linear RGB (fused kernel) (baseline)"
REFERENCE = "read_raw + colour-demosaicing Malvar"
READ_ONLY = "read_raw alone"


def reference_rgb(path: Path) -> np.ndarray:
    """read_raw, then the plain way: black subtracted, white balanced per site, colour-demosaicing's Malvar."""
    raw = picamcal.read_raw(path)
    mosaic = raw.black_subtracted()
    gains = linear_fields(raw).site_gains
    for site in range(4):
        mosaic[site // 2 :: 2, site % 2 :: 2] *= gains[site]
    return demosaic(mosaic, raw.pattern)


def interleaved(methods: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median seconds of each method over ``repeats`` rounds, each round running every method once, in turn."""
    for fn in methods.values():
        fn()  # warm-up: the C kernel's load, first allocations, imports
    times: dict[str, list[float]] = {name: [] for name in methods}
    for _ in range(repeats):
        for name, fn in methods.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(values) for name, values in times.items()}


def bench_open(path: Path, repeats: int) -> list[str]:
    def open_as_layers() -> object:
        reader = get_reader(str(path))
        assert reader is not None
        return reader(str(path))

    methods = {
        READER: open_as_layers,
        BASELINE: lambda: linear_rgb(picamcal.read_raw(path)),
        READ_ONLY: lambda: picamcal.read_raw(path),
    }
    results = interleaved(methods, repeats)
    results[REFERENCE] = statistics.median(_seconds(lambda: reference_rgb(path)) for _ in range(max(1, repeats // 3)))
    baseline = results[BASELINE]
    lines = [f"  {'method':<52} {'ms':>8} {'x baseline':>11}"]
    for name in (READER, BASELINE, REFERENCE, READ_ONLY):
        lines.append(f"  {name:<52} {1e3 * results[name]:>8.1f} {results[name] / baseline:>11.2f}")
    ratio = results[READER] / baseline
    verdict = "met" if ratio <= GOAL_OPEN else f"MISSED by {100 * (ratio / GOAL_OPEN - 1):.0f} %"
    lines.append(f"  goal: opening at most {GOAL_OPEN:g}x read_raw + linear RGB: {ratio:.2f}x -- {verdict}")
    return lines


def _seconds(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def bench_preview(path: Path, repeats: int) -> list[str]:
    """The Correct widget's preview of a 12 MP frame, ``correct_layer(raw, calibration, "centre")`` (the widget's
    layer of a corrected frame: :func:`picamcal.correct` and the layer around it)."""
    from picamcal.napari import correct_layer
    from picamcal.simulate import simulate_references

    cal = picamcal.calibrate(**simulate_references(make_camera("imx477"), seed=1))
    raw = picamcal.read_raw(path)
    seconds = interleaved({"preview": lambda: correct_layer(raw, cal, "centre")}, repeats)["preview"]
    verdict = "met" if seconds < GOAL_PREVIEW_S else "MISSED"
    return [f"  correction preview (centre) of a 12 MP frame: {1e3 * seconds:.0f} ms (goal under 500 ms) -- {verdict}"]


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="interleaved rounds (median)")
    args = parser.parse_args(argv)
    print(f"picamcal {picamcal.__version__}: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at the start")
    with tempfile.TemporaryDirectory() as folder:
        raw, _ = simulate_target(make_camera("imx477"), seed=2)
        path = write_dng(Path(folder) / "target.dng", raw)
        del raw
        print(f"\nopening a {4056}x{3040} (12.3 MP) IMX477 DNG as napari layers, {args.repeats} rounds:")
        print("\n".join(bench_open(path, args.repeats)))
        print("\ncorrection preview:")
        print("\n".join(bench_preview(path, args.repeats)))
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end (these machines are shared)")


if __name__ == "__main__":
    main()
