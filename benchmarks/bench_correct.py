"""Full-resolution correction of one raw frame: the fused kernel against the paper's way and a memory copy.

Usage: python3 benchmarks/bench_correct.py [--sensor imx219 --sensor imx477] [--repeats 7] [--slow-repeats 3]

For an 8 MP (IMX219) and a 12 MP (IMX477) simulated frame, each corrected in mode ``centre`` (black,
flat field, demosaic, unmixing), it prints milliseconds per frame, each the median of several runs,
all measured in this one process:

- ``picamcal.correct`` with the fused numba kernel, writing into a reused output array (``out=``) and
  into a new one; with the numpy path; with the plain reference implementation;
- the paper-style application of the unmixing field alone (the 2019 code: the 3x3 field upsampled to
  full resolution with ``scipy.ndimage.zoom(order=1)``, applied with ``numpy.sum`` broadcasting), on
  the same flat-fielded, demosaiced image;
- a plain ``np.copyto`` of an (H, W, 3) float32 array, the memory-bandwidth floor of writing the output;

with ratios against the paper-style application and against the copy, and each method's peak
memory per frame relative to the (H, W, 3) float32 output. Peak memory is tracemalloc's peak over
one run (numpy registers every array allocation with tracemalloc, and the numba kernel allocates
only numpy arrays, in its Python wrapper), so it counts arrays, not the interpreter or numba itself.
The first numba call compiles the kernel (or loads it from numba's cache), and the first ``correct`` of a
calibration solves for its spline coefficients (kept for the next frames): both are a warm-up, not timed.

These machines are shared: absolute times drift with the load, ratios less so. The copy and the fused
kernel are timed in turns (round-robin) so that they see the same load; "cpu ms" is the CPU time of
all threads (the kernel runs on every core numba has; the copy on one), which says what a frame
costs when the machine is busy with other work.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import tracemalloc
from collections.abc import Callable

import numpy as np
from scipy.ndimage import zoom

import picamcal
from picamcal.correct import correct
from picamcal.kernels import numba_available
from picamcal.simulate import make_camera, simulate_references, simulate_target

GOAL_PAPER = 25.0  # the fused kernel at least this many times faster than the paper-style application
GOAL_COPY = 3.0  # and at most this many times the time of the memory copy
GOAL_MEMORY = 4.0  # peak memory per frame at most this many times the output


def timed(fn: Callable[[], object]) -> tuple[float, float]:
    """Wall and CPU (all threads) milliseconds of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return 1e3 * (time.perf_counter() - wall), 1e3 * (time.process_time() - cpu)


def peak_bytes(fn: Callable[[], object]) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def paper_style(rgb: np.ndarray, matrices: np.ndarray) -> np.ndarray:
    """The 2019 code's unmixing: zoom the (nby, nbx, 3, 3) field to every pixel, then a broadcast sum."""
    height, width = rgb.shape[:2]
    factors = (height / matrices.shape[0], width / matrices.shape[1], 1, 1)
    field = zoom(matrices, factors, order=1)
    return np.sum(field * rgb[..., np.newaxis, :], axis=-1)


def bench_sensor(sensor: str, repeats: int, slow_repeats: int) -> list[str]:
    camera = make_camera(sensor)
    cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    raw, _ = simulate_target(camera, seed=2)
    height, width = raw.height, raw.width
    output_bytes = height * width * 3 * 4
    flat_rgb = correct(raw, cal, "flat")  # the paper-style application's input (not timed)
    source = np.random.default_rng(0).random((height, width, 3), dtype=np.float32)
    target = np.empty_like(source)
    reused = np.empty_like(source)

    fast: list[tuple[str, Callable[[], object]]] = [
        ("memory copy, np.copyto of the output", lambda: np.copyto(target, source))
    ]
    if numba_available():
        fast += [
            ("fused kernel (numba), reused output", lambda: correct(raw, cal, "centre", engine="numba", out=reused)),
            ("fused kernel (numba), new output", lambda: correct(raw, cal, "centre", engine="numba")),
        ]
    slow: list[tuple[str, Callable[[], object]]] = [
        ("numpy path", lambda: correct(raw, cal, "centre", engine="numpy")),
        ("reference (colour-demosaicing, dense splines)", lambda: correct(raw, cal, "centre", engine="reference")),
        ("paper-style: zoom(order=1) + numpy.sum", lambda: paper_style(flat_rgb, cal.unmixing)),
    ]
    peaks, runs = {}, {}
    for name, fn in fast:
        fn()  # warm-up: numba's compile (or cache load) and the cached spline coefficients
        peaks[name], runs[name] = peak_bytes(fn), []
    for _ in range(repeats):  # round-robin, so that the copy and the kernel see the same load
        for name, fn in fast:
            runs[name].append(timed(fn))
    for name, fn in slow:
        peaks[name] = peak_bytes(fn)  # nothing to warm up: this run is the warm-up
        runs[name] = [timed(fn) for _ in range(slow_repeats)]
    results = {
        name: (statistics.median(w for w, _ in times), statistics.median(c for _, c in times), peaks[name], len(times))
        for name, times in runs.items()
    }
    methods = fast + slow

    copy_ms = results[methods[0][0]][0]
    paper_ms = results[methods[-1][0]][0]
    lines = [
        f"{sensor}: {width}x{height} ({width * height / 1e6:.1f} MP), mode centre, "
        f"output {output_bytes / 2**20:.0f} MiB",
        f"  {'method':<48} {'ms/frame':>9} {'cpu ms':>8} {'runs':>5} {'x faster than paper':>20} "
        f"{'x copy time':>12} {'peak MiB':>9} {'x output':>9}",
    ]
    for name, (ms, cpu_ms, peak, n) in results.items():
        lines.append(
            f"  {name:<48} {ms:>9.1f} {cpu_ms:>8.1f} {n:>5} {paper_ms / ms:>20.1f} {ms / copy_ms:>12.2f} "
            f"{peak / 2**20:>9.1f} {peak / output_bytes:>9.2f}"
        )
    if numba_available():
        fused_ms = results[methods[1][0]][0]
        new_ms, _, new_peak, _ = results[methods[2][0]]
        lines += [
            "  goals (fused kernel):",
            "    "
            + _goal(
                f"at least {GOAL_PAPER:g}x faster than the paper-style application",
                paper_ms / fused_ms,
                GOAL_PAPER,
                higher=True,
            ),
            "    " + _goal(f"at most {GOAL_COPY:g}x the memory copy, reused output", fused_ms / copy_ms, GOAL_COPY),
            "    " + _goal(f"at most {GOAL_COPY:g}x the memory copy, new output", new_ms / copy_ms, GOAL_COPY),
            "    "
            + _goal(
                f"peak memory at most {GOAL_MEMORY:g}x the output, new output", new_peak / output_bytes, GOAL_MEMORY
            ),
        ]
    else:
        lines.append("  numba is not installed: no fused kernel to measure (pip install numba)")
    return lines


def _goal(text: str, value: float, goal: float, higher: bool = False) -> str:
    met = value >= goal if higher else value <= goal
    verdict = "met" if met else f"MISSED by {goal / value if higher else value / goal:.2f}x"
    return f"{text}: {value:.2f}x -- {verdict}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensor", action="append", help="sensor(s) to simulate (default imx219 and imx477)")
    parser.add_argument("--repeats", type=int, default=7, help="runs of the fast methods (median)")
    parser.add_argument("--slow-repeats", type=int, default=3, help="runs of the numpy path, reference and paper-style")
    args = parser.parse_args()
    threads = "-"
    if numba_available():
        import numba

        threads = str(numba.get_num_threads())
    print(
        f"picamcal {picamcal.__version__}: {os.cpu_count()} CPUs, numba threads {threads}, "
        f"load average {os.getloadavg()[0]:.1f} at the start"
    )
    for sensor in args.sensor or ["imx219", "imx477"]:
        print()
        print("\n".join(bench_sensor(sensor, args.repeats, args.slow_repeats)))
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end (these machines are shared)")


if __name__ == "__main__":
    main()
