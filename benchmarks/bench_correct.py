"""Full-resolution correction of one raw frame: the fused kernel against a memory copy and the paper's way.

Usage: python3 benchmarks/bench_correct.py [--sensor imx219 --sensor imx477] [--engine c --engine numba]
[--repeats 9] [--slow-repeats 1] [--no-slow]

For an 8 MP (IMX219) and a 12 MP (IMX477) simulated frame, each corrected in mode ``centre`` (black, flat field,
demosaic, unmixing), it prints milliseconds per frame, each the median of several runs, all measured in this one
process:

- ``picamcal.correct`` with the fused kernel, C (``engine="c"``, what ``auto`` picks) and numba, writing each
  output into a reused array (``out=``) and into a new one: float32 (H, W, 3); the ``uint16-tiff`` codes
  (``dtype=np.uint16``); the sRGB formats' codes, uint8 (``srgb-png``, ``srgb-jpeg``) and uint16 (``srgb-png16``),
  through a camera colour matrix (``encoding=srgb_encoding(...)``); each written by the kernel row by row, with no
  float32 image;
- where the C kernel's time goes: the same frame in mode ``uncorrected`` (demosaic and writing, the white a
  constant), ``flat`` (and the flat field) and ``centre`` (and the matrix field), float32 into a reused array, and
  each kind of codes beside float32;
- the sRGB conversion of the single-file path, a float32 image to its uint8 codes (``encode_srgb``, the same
  compiled code), beside Pillow's JPEG encoding of those codes at picamcal's settings (quality 95, 4:4:4), the
  encoder it feeds;
- the numpy path, the plain reference implementation and the paper-style application of the unmixing field alone
  (the 2019 code: the 3x3 field upsampled to full resolution with ``scipy.ndimage.zoom(order=1)``, applied with
  ``numpy.sum`` broadcasting, on the same flat-fielded, demosaiced image), unless ``--no-slow``;
- a plain ``np.copyto`` of an (H, W, 3) float32 array, and of uint16 and uint8 ones, the memory-bandwidth floor of
  writing each output;

with each method's time against the float32 copy and against the copy of its own output's type (the goal is
judged against the float32 copy: the kernel computes the float32 image in every case, and only its last step
differs), against the paper-style application, each method's peak memory per frame relative to the (H, W, 3)
float32 output, and the C kernel's time relative to numba's. Peak memory is tracemalloc's peak over one run
(numpy registers every array allocation with tracemalloc, and the numba kernel allocates only numpy arrays, in
its Python wrapper), so it counts arrays, not the interpreter or numba itself; the C kernel's few rows per
thread are its own allocations, which tracemalloc does not see. The first call of a kernel compiles it (or loads
it from its cache), and the first ``correct`` of a calibration solves for its spline coefficients (kept for the
next frames): both are a warm-up, not timed.

These machines are shared: absolute times drift with the load, ratios less so. The copies and the fused kernels
are timed in turns (round-robin) so that they see the same load; "cpu ms" is the CPU time of all threads (the
kernels run on every core, ``picamcal.kernels.kernel_threads()``; the copy on one), which says what a frame costs
when the machine is busy with other work (when cpu ms is no more than the wall time, the kernel had one core to
itself at most).
"""

from __future__ import annotations

import argparse
import io
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
from picamcal.output.colour import ColourMatrix, encode_srgb, srgb_encoding
from picamcal.simulate import make_camera, simulate_references, simulate_target

GOAL_PAPER = 25.0  # the fused kernel at least this many times faster than the paper-style application
GOAL_COPY = 2.0  # and with a reused output at most this many times the time of copying the float32 image
GOAL_COPY_8MP = 1.8  # the float32 output at 8 MP at most this
GOAL_MEMORY = 4.0  # peak memory per frame at most this many times the output

#: Linear sRGB from the corrected image's RGB: a camera's colour correction matrix (rows summing to 1, as
#: libcamera's), so that the sRGB rows time a real matrix.
CAMERA_MATRIX = ColourMatrix([[1.9, -0.6, -0.3], [-0.4, 1.7, -0.3], [0.1, -0.8, 1.7]], "a camera's CCM")
COPIES = {np.float32: "memory copy, float32 (H, W, 3)", np.uint16: "memory copy, uint16 (H, W, 3)"}
COPIES[np.uint8] = "memory copy, uint8 (H, W, 3)"
COPY_FLOAT = COPIES[np.float32]
#: The kinds of output: name -> (the codes' type, sRGB bits or None).
KINDS = {"float32": (np.float32, None), "uint16": (np.uint16, None), "srgb8": (np.uint8, 8), "srgb16": (np.uint16, 16)}
PAPER = "paper-style: zoom(order=1) + numpy.sum"
ENCODE = "encode_srgb, float32 image -> uint8 codes"
JPEG = "Pillow JPEG of those codes (q95, 4:4:4)"


def fused_row(engine: str, kind: str, reuse: bool, mode: str = "centre") -> str:
    where = "reused output" if reuse else "new output"
    return f"fused kernel ({engine}), {kind}, {where}" + ("" if mode == "centre" else f", mode {mode}")


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


def jpeg(codes: np.ndarray) -> bytes:
    """Pillow's JPEG of the codes at ``srgb-jpeg``'s settings, into memory."""
    from PIL import Image

    from picamcal.output.srgb import JPEG_QUALITY

    buffer = io.BytesIO()
    Image.fromarray(codes).save(buffer, "JPEG", quality=JPEG_QUALITY, subsampling=0)
    return buffer.getvalue()


def bench_sensor(sensor: str, repeats: int, slow_repeats: int, slow: bool, wanted: Sequence[str]) -> list[str]:
    camera = make_camera(sensor)
    cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    raw, _ = simulate_target(camera, seed=2)
    height, width = raw.height, raw.width
    output_bytes = height * width * 3 * 4
    rng = np.random.default_rng(0)
    copies = {}
    for kind in COPIES:
        source = rng.random((height, width, 3), dtype=np.float32) if kind == np.float32 else None
        if source is None:
            source = rng.integers(0, np.iinfo(kind).max + 1, size=(height, width, 3), dtype=kind)
        copies[kind] = (source, np.empty_like(source))
    encodings = {bits: srgb_encoding(CAMERA_MATRIX, bits=bits) for bits in (8, 16)}

    fast: list[tuple[str, Callable[[], object]]] = [
        (COPIES[kind], lambda kind=kind: np.copyto(copies[kind][1], copies[kind][0])) for kind in COPIES
    ]
    there = {"c": c_available(), "numba": numba_available()}
    engines = [name for name in ("c", "numba") if there[name] and name in wanted]
    numba_rows: list[tuple[str, Callable[[], object]]] = []
    for engine in engines:
        for kind, (dtype, bits) in KINDS.items():
            for reuse in (True, False):
                out = np.empty((height, width, 3), dtype) if reuse else None
                options = {"encoding": encodings[bits]} if bits else {"dtype": dtype}

                def run(engine: str = engine, out: np.ndarray | None = out, options: dict = options) -> np.ndarray:
                    return correct(raw, cal, "centre", engine=engine, out=out, **options)

                (numba_rows if engine == "numba" else fast).append((fused_row(engine, kind, reuse), run))
    if "c" in engines:  # where the time goes: the modes that leave steps out
        reused = np.empty((height, width, 3), np.float32)
        for mode in ("uncorrected", "flat"):

            def partial(mode: str = mode) -> np.ndarray:
                return correct(raw, cal, mode, engine="c", out=reused)

            fast.append((fused_row("c", "float32", True, mode), partial))
    rgb = correct(raw, cal, "centre")
    codes = encode_srgb(rgb, CAMERA_MATRIX)
    fast += [(ENCODE, lambda: encode_srgb(rgb, CAMERA_MATRIX)), (JPEG, lambda: jpeg(codes)), *numba_rows]
    slow_rows: list[tuple[str, Callable[[], object]]] = []
    if slow:
        flat_rgb = correct(raw, cal, "flat")  # the paper-style application's input (not timed)
        slow_rows = [
            ("numpy path, float32", lambda: correct(raw, cal, "centre", engine="numpy")),
            ("numpy path, uint16", lambda: correct(raw, cal, "centre", engine="numpy", dtype=np.uint16)),
            ("reference (colour-demosaicing, dense splines)", lambda: correct(raw, cal, "centre", engine="reference")),
            (PAPER, lambda: paper_style(flat_rgb, cal.unmixing)),
        ]
    peaks, runs = {}, {}
    for name, fn in fast:
        fn()  # warm-up: the kernel's compile (or cache load), the cached spline coefficients, the sRGB tables
        peaks[name], runs[name] = peak_bytes(fn), []
    for _ in range(repeats):  # round-robin, so that the copies and the kernels see the same load
        for name, fn in fast:
            runs[name].append(timed(fn))
        if numba_rows:  # numba's OpenMP threads spin a while after a kernel: not into the next round's first rows
            time.sleep(0.5)
    for name, fn in slow_rows:
        peaks[name] = peak_bytes(fn)  # nothing to warm up: this run is the warm-up
        runs[name] = [timed(fn) for _ in range(slow_repeats)]
    results = {
        name: (statistics.median(w for w, _ in times), statistics.median(c for _, c in times), peaks[name], len(times))
        for name, times in runs.items()
    }

    copy_ms = results[COPY_FLOAT][0]
    paper_ms = results[PAPER][0] if slow else None
    lines = [
        f"{sensor}: {width}x{height} ({width * height / 1e6:.1f} MP), mode centre, "
        f"float32 output {output_bytes / 2**20:.0f} MiB, uint16 {output_bytes / 2**21:.0f} MiB, "
        f"uint8 {output_bytes / 2**22:.0f} MiB",
        f"  {'method':<56} {'ms/frame':>9} {'cpu ms':>8} {'runs':>5} {'x f32 copy':>11} {'x its copy':>11} "
        f"{'x faster than paper':>20} {'peak MiB':>9} {'x output':>9}",
    ]
    for name, (ms, cpu_ms, peak, n) in results.items():
        own = _own_copy(name)
        own_ratio = f"{ms / results[own][0]:>11.2f}" if own else f"{'':>11}"
        faster = f"{paper_ms / ms:>20.1f}" if paper_ms else f"{'':>20}"
        lines.append(
            f"  {name:<56} {ms:>9.1f} {cpu_ms:>8.1f} {n:>5} {ms / copy_ms:>11.2f} {own_ratio} {faster} "
            f"{peak / 2**20:>9.1f} {peak / output_bytes:>9.2f}"
        )
    if engines == ["c", "numba"]:
        lines.append("  C kernel / numba kernel, wall (cpu) ms:")
        for kind in KINDS:
            for reuse in (True, False):
                c, numba = results[fused_row("c", kind, reuse)], results[fused_row("numba", kind, reuse)]
                label = f"{kind}, {'reused' if reuse else 'new'}"
                lines.append(f"    {label:<24} {c[0] / numba[0]:.2f}x ({c[1] / numba[1]:.2f}x)")
    if "c" in engines:
        lines += _breakdown(results)
    convert, encoder = results[ENCODE][0], results[JPEG][0]
    lines.append(
        f"  sRGB conversion of a float32 image: {convert:.1f} ms, {convert / encoder:.2f}x the JPEG encoding it feeds "
        f"({encoder:.1f} ms); from the kernel's codes (batches) a JPEG needs none"
    )
    engine = engines[0] if engines else None
    if engine is None:
        return [*lines, "  no fused kernel timed (neither C nor numba here, or none asked for): no goal is judged"]
    goal_copy = GOAL_COPY_8MP if width * height < 10e6 else GOAL_COPY
    lines.append(f"  goals (fused kernel, {engine}, what engine='auto' picks here):")
    for kind in KINDS:
        ms = results[fused_row(engine, kind, True)][0]
        goal = goal_copy if kind == "float32" else GOAL_COPY
        lines.append("    " + _goal(f"{kind}, reused output, at most {goal:g}x the float32 copy", ms / copy_ms, goal))
    new_peak = results[fused_row(engine, "float32", False)][2]
    lines.append(
        "    "
        + _goal(f"peak memory at most {GOAL_MEMORY:g}x the output, new output", new_peak / output_bytes, GOAL_MEMORY)
    )
    if paper_ms:
        fused = results[fused_row(engine, "float32", True)][0]
        text = f"at least {GOAL_PAPER:g}x faster than the paper-style application"
        lines.append("    " + _goal(text, paper_ms / fused, GOAL_PAPER, True))
    return lines


def _own_copy(name: str) -> str | None:
    """The copy of the same output type as the row's, for its "x its copy" column."""
    if name.startswith("fused kernel"):
        kind = name.split(", ")[1]
        return COPIES[KINDS[kind][0]]
    if name == ENCODE:
        return COPIES[np.uint8]
    return COPY_FLOAT if name.startswith(("numpy path, float32", "reference", "paper")) else None


def _breakdown(results: dict[str, tuple[float, float, int, int]]) -> list[str]:
    """Where the C kernel's time goes, from the modes and outputs timed: each step's extra wall ms."""
    wall = {name: result[0] for name, result in results.items()}
    uncorrected = wall[fused_row("c", "float32", True, "uncorrected")]
    flat = wall[fused_row("c", "float32", True, "flat")]
    centre = wall[fused_row("c", "float32", True)]
    steps = [
        ("black, demosaic and writing float32 (mode uncorrected)", uncorrected),
        ("the flat field (flat less uncorrected)", flat - uncorrected),
        ("the matrix field (centre less flat)", centre - flat),
    ]
    for kind in ("uint16", "srgb8", "srgb16"):
        steps.append((f"{kind} codes instead of float32", wall[fused_row("c", kind, True)] - centre))
    return ["  where the C kernel's time goes (reused output, wall ms):"] + [
        f"    {text:<58} {ms:>7.1f} ({100 * ms / centre:+.0f} % of centre's float32)" for text, ms in steps
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
    parser.add_argument(
        "--engine", action="append", choices=["c", "numba"], help="fused kernels to time (default both)"
    )
    parser.add_argument("--no-slow", action="store_true", help="leave out the numpy paths, reference and paper-style")
    args = parser.parse_args(argv)
    print(
        f"picamcal {picamcal.__version__}: {os.cpu_count()} CPUs, kernel threads {kernel_threads()}, "
        f"C kernel {'built' if c_available() else 'not available'}, load average {os.getloadavg()[0]:.1f} at the start"
    )
    for sensor in args.sensor or ["imx219", "imx477"]:
        print()
        lines = bench_sensor(sensor, args.repeats, args.slow_repeats, not args.no_slow, args.engine or ["c", "numba"])
        print("\n".join(lines))
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end (these machines are shared)")


if __name__ == "__main__":
    main()
