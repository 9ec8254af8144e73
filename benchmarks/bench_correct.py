"""Full-resolution correction of one raw frame: the fused kernel against the paper's way and a memory copy.

Usage: python3 benchmarks/bench_correct.py [--sensor imx219 --sensor imx477] [--repeats 9] [--slow-repeats 1]

For an 8 MP (IMX219) and a 12 MP (IMX477) simulated frame, each corrected in mode ``centre`` (black,
flat field, demosaic, unmixing), it prints milliseconds per frame, each the median of several runs,
all measured in this one process:

- ``picamcal.correct`` with the fused kernel, C (``engine="c"``) and numba, each writing float32 (H, W, 3)
  into a reused output array (``out=``) and into a new one, and the same for the ``uint16-tiff`` codes
  (``dtype=np.uint16``, (H, W, 3), written by the kernel with no float32 image); with the numpy path (both
  outputs); with the plain reference implementation;
- the paper-style application of the unmixing field alone (the 2019 code: the 3x3 field upsampled to
  full resolution with ``scipy.ndimage.zoom(order=1)``, applied with ``numpy.sum`` broadcasting), on
  the same flat-fielded, demosaiced image;
- a plain ``np.copyto`` of an (H, W, 3) float32 array and of an (H, W, 3) uint16 one, the memory-bandwidth
  floor of writing each output;

with ratios against the paper-style application and against the copy of the same output type, each
method's peak memory per frame relative to the (H, W, 3) float32 output, and the C kernel's time relative to
numba's for each output. Peak memory is tracemalloc's peak over one run (numpy registers every array
allocation with tracemalloc, and the numba kernel allocates only numpy arrays, in its Python wrapper), so it
counts arrays, not the interpreter or numba itself; the C kernel's few rows per thread are its own
allocations, which tracemalloc does not see. The first call of a kernel compiles it (or loads it from its
cache), and the first ``correct`` of a calibration solves for its spline coefficients (kept for the next
frames): both are a warm-up, not timed.

These machines are shared: absolute times drift with the load, ratios less so. The copies and the fused
kernels are timed in turns (round-robin) so that they see the same load; "cpu ms" is the CPU time of
all threads (the kernels run on every core, ``picamcal.kernels.kernel_threads()``; the copy on one), which
says what a frame costs when the machine is busy with other work (when cpu ms is no more than the wall time,
the kernel had one core to itself at most).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import tracemalloc
from collections.abc import Callable, Sequence

import numpy as np

import picamcal
from picamcal.ckernel import c_available
from picamcal.correct import correct
from picamcal.kernels import kernel_threads, numba_available
from picamcal.simulate import make_camera, simulate_references, simulate_target

GOAL_PAPER = 25.0  # the fused kernel at least this many times faster than the paper-style application
GOAL_COPY = 2.5  # and with a reused output at most this many times the time of copying that output
GOAL_MEMORY = 4.0  # peak memory per frame at most this many times the output

COPY_FLOAT = "memory copy, float32 (H, W, 3)"
COPY_CODES = "memory copy, uint16 (H, W, 3)"
#: The fused kernel's rows, per engine: (output, whether uint16 codes, whether into a reused array).
OUTPUTS = [
    ("float32, reused output", False, True),
    ("float32, new output", False, False),
    ("uint16, reused output", True, True),
    ("uint16, new output", True, False),
]


def fused_row(engine: str, output: str) -> str:
    return f"fused kernel ({engine}), {output}"


FUSED_FLOAT = fused_row("numba", "float32, reused output")
FUSED_FLOAT_NEW = fused_row("numba", "float32, new output")
FUSED_CODES = fused_row("numba", "uint16, reused output")
PAPER = "paper-style: zoom(order=1) + numpy.sum"


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
    from scipy.ndimage import zoom

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
    rng = np.random.default_rng(0)
    source = rng.random((height, width, 3), dtype=np.float32)
    source_codes = rng.integers(0, 65536, size=(height, width, 3), dtype=np.uint16)
    target, target_codes = np.empty_like(source), np.empty_like(source_codes)
    reused, reused_codes = np.empty_like(source), np.empty_like(source_codes)
    u16 = np.uint16

    fast: list[tuple[str, Callable[[], object]]] = [
        (COPY_FLOAT, lambda: np.copyto(target, source)),
        (COPY_CODES, lambda: np.copyto(target_codes, source_codes)),
    ]
    engines = [name for name, there in (("c", c_available()), ("numba", numba_available())) if there]
    for engine in engines:
        for output, codes, reuse in OUTPUTS:
            out = (reused_codes if codes else reused) if reuse else None

            def run(engine: str = engine, out: np.ndarray | None = out, dtype: type = u16 if codes else np.float32):
                return correct(raw, cal, "centre", engine=engine, out=out, dtype=dtype)

            fast.append((fused_row(engine, output), run))
    slow: list[tuple[str, Callable[[], object]]] = [
        ("numpy path, float32", lambda: correct(raw, cal, "centre", engine="numpy")),
        ("numpy path, uint16", lambda: correct(raw, cal, "centre", engine="numpy", dtype=u16)),
        ("reference (colour-demosaicing, dense splines)", lambda: correct(raw, cal, "centre", engine="reference")),
        (PAPER, lambda: paper_style(flat_rgb, cal.unmixing)),
    ]
    peaks, runs = {}, {}
    for name, fn in fast:
        fn()  # warm-up: numba's compile (or cache load) and the cached spline coefficients
        peaks[name], runs[name] = peak_bytes(fn), []
    for _ in range(repeats):  # round-robin, so that the copies and the kernel see the same load
        for name, fn in fast:
            runs[name].append(timed(fn))
    for name, fn in slow:
        peaks[name] = peak_bytes(fn)  # nothing to warm up: this run is the warm-up
        runs[name] = [timed(fn) for _ in range(slow_repeats)]
    results = {
        name: (statistics.median(w for w, _ in times), statistics.median(c for _, c in times), peaks[name], len(times))
        for name, times in runs.items()
    }

    paper_ms = results[PAPER][0]
    lines = [
        f"{sensor}: {width}x{height} ({width * height / 1e6:.1f} MP), mode centre, "
        f"float32 output {output_bytes / 2**20:.0f} MiB, uint16 {output_bytes / 2**21:.0f} MiB",
        f"  {'method':<48} {'ms/frame':>9} {'cpu ms':>8} {'runs':>5} {'x faster than paper':>20} "
        f"{'x its copy':>11} {'peak MiB':>9} {'x output':>9}",
    ]
    for name, (ms, cpu_ms, peak, n) in results.items():
        copy_ms = results[COPY_CODES if "uint16" in name else COPY_FLOAT][0]
        lines.append(
            f"  {name:<48} {ms:>9.1f} {cpu_ms:>8.1f} {n:>5} {paper_ms / ms:>20.1f} {ms / copy_ms:>11.2f} "
            f"{peak / 2**20:>9.1f} {peak / output_bytes:>9.2f}"
        )
    if engines == ["c", "numba"]:
        lines.append("  C kernel / numba kernel, wall (cpu) ms:")
        for output, _, _ in OUTPUTS:
            c, numba = results[fused_row("c", output)], results[fused_row("numba", output)]
            lines.append(f"    {output:<24} {c[0] / numba[0]:.2f}x ({c[1] / numba[1]:.2f}x)")
    if not numba_available():
        return [*lines, "  numba is not installed: the goals are the numba kernel's (pip install numba)"]
    copy_float, copy_codes = results[COPY_FLOAT][0], results[COPY_CODES][0]
    fused, codes = results[FUSED_FLOAT][0], results[FUSED_CODES][0]
    new_peak = results[FUSED_FLOAT_NEW][2]
    return [
        *lines,
        "  goals (fused kernel, numba):",
        "    "
        + _goal(
            f"at least {GOAL_PAPER:g}x faster than the paper-style application", paper_ms / fused, GOAL_PAPER, True
        ),
        "    " + _goal(f"reused output at most {GOAL_COPY:g}x the copy of the output", fused / copy_float, GOAL_COPY),
        f"    (uint16 codes, reused output: {codes / copy_float:.2f}x the float32 copy, {codes / copy_codes:.2f}x "
        "the uint16 copy; no goal)",
        "    "
        + _goal(f"peak memory at most {GOAL_MEMORY:g}x the output, new output", new_peak / output_bytes, GOAL_MEMORY),
    ]


def _goal(text: str, value: float, goal: float, higher: bool = False) -> str:
    met = value >= goal if higher else value <= goal
    short = goal / value if higher else value / goal
    verdict = "met" if met else f"MISSED by {100 * (short - 1):.0f} %"
    return f"{text}: {value:.2f}x -- {verdict}"


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensor", action="append", help="sensor(s) to simulate (default imx219 and imx477)")
    parser.add_argument("--repeats", type=int, default=9, help="runs of the fast methods (median)")
    parser.add_argument(
        "--slow-repeats", type=int, default=1, help="runs of the numpy paths, reference and paper-style (median)"
    )
    args = parser.parse_args(argv)
    print(
        f"picamcal {picamcal.__version__}: {os.cpu_count()} CPUs, kernel threads {kernel_threads()}, "
        f"C kernel {'built' if c_available() else 'not available'}, load average {os.getloadavg()[0]:.1f} at the start"
    )
    for sensor in args.sensor or ["imx219", "imx477"]:
        print()
        print("\n".join(bench_sensor(sensor, args.repeats, args.slow_repeats)))
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end (these machines are shared)")


if __name__ == "__main__":
    main()
