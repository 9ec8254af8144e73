"""Live unmixing of a picamera2 stream (picamcal.live): per-frame time here, and an estimate for a Raspberry Pi 5.

Usage: python3 benchmarks/bench_live.py [--repeats 15] [--size 1332x990 ...] [--format RGB888 ...]

For each stream size (640x480, 1332x990 and 1920x1080 by default) and format (RGB888, 3 bytes a pixel, and
XBGR8888, 4), it prepares a :class:`picamcal.live.LiveUnmixer` from a full-size simulated IMX219 calibration and
the tuning file exported from it (timed once per size: it is done once per stream; a 16:9 stream gets the
centred 16:9 crop of the sensor), then times, each the median of several runs taken in turns with a copy of the
frame so that both see the same load, on a fresh copy of an emulated ISP frame each time:

- a copy of the frame into another array (``np.copyto``), the baseline;
- ``LiveUnmixer.apply`` with the numba kernel on one thread (the default), in place, and the numpy path at
  640x480 (what runs where numba is not installed);
- after every stream's one-thread runs, ``parallel=True`` (numba's threads), again beside a copy: a thread pool
  that has just run keeps its threads spinning for a while, and their CPU time would be counted in a one-thread
  run that followed.

"cpu ms" is the CPU time of all threads; from the one-thread run's and this CPU's clock come the cycles per
pixel, which the Pi 5 estimate scales. The estimate uses the Raspberry Pi 5's published figures: a quad-core Arm
Cortex-A76 at 2.4 GHz and LPDDR4X-4267 SDRAM on a 32-bit bus, 4267 MT/s x 4 bytes = 17.1 GB/s peak (Raspberry Pi
5 product brief).
Two assumptions, stated where the figures are printed: an A76 needs 1.5 times the cycles per pixel of this
machine's core (it issues fewer operations per cycle), and half the memory's peak bandwidth is what a core
streaming one frame gets. A frame moves ``2 x bytes per pixel`` (read and written in place) plus the 36-byte
field per pixel (nine float32). The conservative estimate adds the single-core compute time and the memory
time (no overlap, one core); the four-core one takes the larger of the two with the compute shared by four
cores. The goal (the issue's): at least 30 frames/s at 1332x990 on a Pi 5 by the conservative estimate.

These machines are shared: absolute times drift with the load, ratios less so.
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import time
from collections.abc import Callable, Sequence

import numpy as np
from bench_correct import timed  # wall and CPU ms of one call

import picamcal

#: Raspberry Pi 5 (product brief): quad-core Cortex-A76 at 2.4 GHz, LPDDR4X-4267 on a 32-bit bus.
PI5_CLOCK_HZ = 2.4e9
PI5_CORES = 4
PI5_PEAK_BYTES_PER_S = 4267e6 * 4
#: Assumptions of the estimate (module docstring).
A76_CYCLES_FACTOR = 1.5
BANDWIDTH_FRACTION = 0.5
GOAL_SIZE = (1332, 990)
GOAL_FPS = 30.0
SIZES = ((640, 480), (1332, 990), (1920, 1080))
FORMATS = ("RGB888", "XBGR8888")


def cpu_clock_hz() -> float | None:
    """This machine's core clock from /proc/cpuinfo (Linux), or None."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("cpu mhz"):
                    return float(line.split(":")[1]) * 1e6
    except (OSError, ValueError, IndexError):
        return None
    return None


def setup() -> tuple[picamcal.Calibration, dict, np.ndarray, tuple[float, float]]:
    """A full-size simulated IMX219 calibration, its exported tuning (adaptive contrast off), an ISP-like frame."""
    from picamcal.export.isp import apply_tuning, calibration_colour_gains
    from picamcal.export.tuning import export_tuning, load_tuning, stock_tuning_path
    from picamcal.live import tone_curve_tables
    from picamcal.simulate import make_camera, simulate_references, simulate_target

    camera = make_camera("imx219")
    cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    tuning = export_tuning(cal, load_tuning(stock_tuning_path("imx219", "pisp")), ccm=True)
    for algorithm in tuning["algorithms"]:
        if "rpi.contrast" in algorithm:
            algorithm["rpi.contrast"]["ce_enable"] = 0
    gains = calibration_colour_gains(cal)
    target, _ = simulate_target(camera, seed=2)
    linear = apply_tuning(target, tuning, colour_gains=gains, ccm=True)
    curve = tone_curve_tables(None, tuning)
    codes = np.searchsorted(curve.edges, linear, side="right") - 1  # the ISP's 8-bit output of the linear image
    return cal, tuning, np.clip(codes, 0, 255).astype(np.uint8), gains


def sensor_crop(sensor: tuple[int, int], size: tuple[int, int]) -> tuple[int, int, int, int]:
    """The centred sensor area of the stream's aspect ratio, as libcamera crops for a 16:9 stream of a 4:3 sensor."""
    (sw, sh), (w, h) = sensor, size
    if w * sh >= h * sw:
        ch = 2 * round(sw * h / w / 2)
        return (0, (sh - ch) // 2, sw, ch)
    cw = 2 * round(sh * w / h / 2)
    return ((sw - cw) // 2, 0, cw, sh)


def stream_frame(rgb: np.ndarray, size: tuple[int, int], layout: str) -> np.ndarray:
    """The sensor-size RGB frame scaled (nearest) to a stream size, in a picamera2 format's byte order."""
    from picamcal.live import stream_format

    width, height = size
    ys = (np.arange(height) * rgb.shape[0]) // height
    xs = (np.arange(width) * rgb.shape[1]) // width
    scaled = rgb[ys][:, xs]
    fmt = stream_format(layout)
    frame = np.full((height, width, fmt.bytes_per_pixel), 255, np.uint8)
    for channel, offset in enumerate((fmt.red, fmt.green, fmt.blue)):
        frame[..., offset] = scaled[..., channel]
    return frame


def time_in_turns(methods: list[tuple[str, Callable[[], object]]], reset: Callable[[], object], repeats: int) -> dict:
    """Median (wall, cpu) ms of each method, run in turns; ``reset`` (untimed) before each run."""
    runs: dict[str, list[tuple[float, float]]] = {name: [] for name, _ in methods}
    for _ in range(repeats):
        for name, fn in methods:
            reset()
            runs[name].append(timed(fn))
    return {
        name: (statistics.median(w for w, _ in times), statistics.median(c for _, c in times))
        for name, times in runs.items()
    }


def _time_stream(stream: dict, phase: str, repeats: int) -> dict:
    """The copy and the phase's methods on one stream, in turns, each on a fresh copy of the frame."""
    source, frame, copy, unmixers = stream["source"], stream["frame"], stream["copy"], stream["unmixers"]
    names = ["one thread", "numpy"] if phase == "one thread" and stream["size"] == SIZES[0] else [phase]
    methods: list[tuple[str, Callable[[], object]]] = [("copy", lambda: np.copyto(copy, source))]
    methods += [(name, functools.partial(unmixers[name].apply, frame)) for name in names]
    return time_in_turns(methods, lambda: np.copyto(frame, source), repeats)


def bench_streams(
    cal: picamcal.Calibration,
    tuning: dict,
    rgb: np.ndarray,
    gains: tuple[float, float],
    sizes: list[tuple[int, int]],
    layouts: Sequence[str],
    repeats: int,
    clock: float | None,
) -> list[tuple[tuple[int, int], str, list[str], float]]:
    """Each stream's table lines and its one-thread CPU seconds per frame.

    One thread first, for every stream, then numba's threads: a thread pool that has just run keeps its threads
    spinning for a while, and their CPU time would be counted in a one-thread run that follows.
    """
    from picamcal.live import LiveUnmixer, stream_format

    streams = []
    for size in sizes:
        start = time.perf_counter()
        crop = sensor_crop((cal.width, cal.height), size)
        prepared = LiveUnmixer.prepare(cal, size, layouts[0], tuning=tuning, crop=crop, colour_gains=gains)
        prepare_s = time.perf_counter() - start
        x, y, cw, ch = crop
        for layout in layouts:
            # The field does not depend on the byte order: one preparation per size.
            fmt = stream_format(layout)
            source = stream_frame(rgb[y : y + ch, x : x + cw], size, layout)
            streams.append(
                {
                    "size": size,
                    "layout": layout,
                    "prepare_s": prepare_s,
                    "field_mib": prepared.field.nbytes / 2**20,
                    "unmixers": {
                        "one thread": LiveUnmixer(size, fmt, prepared.field, prepared.curve, "numba", parallel=False),
                        "numpy": LiveUnmixer(size, fmt, prepared.field, prepared.curve, "numpy"),
                        "threads": LiveUnmixer(size, fmt, prepared.field, prepared.curve, "numba", parallel=True),
                    },
                    "source": source,
                    "frame": source.copy(),
                    "copy": np.empty_like(source),
                }
            )
    for phase in ("one thread", "threads"):
        for stream in streams:
            stream.setdefault("results", {})[phase] = _time_stream(stream, phase, repeats)
    labels = {
        "one thread": "LiveUnmixer.apply, numba, one thread",
        "numpy": "LiveUnmixer.apply, numpy path",
        "threads": "LiveUnmixer.apply, numba, parallel=True",
    }
    out = []
    for stream in streams:
        (width, height), pixels = stream["size"], stream["size"][0] * stream["size"][1]
        lines = [
            f"{width}x{height} {stream['layout']}: prepared in {stream['prepare_s']:.2f} s "
            f"(field {stream['field_mib']:.0f} MiB)",
            f"  {'method':<40} {'ms/frame':>9} {'cpu ms':>8} {'x copy':>8} {'cycles/px':>10}",
        ]
        for phase, results in stream["results"].items():
            copy_ms = results["copy"][0]
            for name, (wall, cpu) in results.items():
                label = "copy of the frame (baseline)" if name == "copy" else labels[name]
                if name == "copy" and phase == "threads":
                    label = "copy of the frame, again (baseline)"
                cycles = f"{cpu * 1e-3 * clock / pixels:10.1f}" if clock else f"{'-':>10}"
                lines.append(f"  {label:<40} {wall:>9.2f} {cpu:>8.2f} {wall / copy_ms:>8.1f} {cycles}")
        out.append((stream["size"], stream["layout"], lines, stream["results"]["one thread"]["one thread"][1] * 1e-3))
    return out


def pi5_estimate(cpu_s: float, clock: float, size: tuple[int, int], bytes_per_pixel: int) -> tuple[float, float]:
    """(conservative, four-core) seconds per frame on a Pi 5 from this machine's CPU seconds per frame."""
    pixels = size[0] * size[1]
    cycles_per_pixel = cpu_s * clock / pixels * A76_CYCLES_FACTOR
    compute = cycles_per_pixel * pixels / PI5_CLOCK_HZ
    memory = pixels * (2 * bytes_per_pixel + 36) / (PI5_PEAK_BYTES_PER_S * BANDWIDTH_FRACTION)
    return compute + memory, max(compute / PI5_CORES, memory)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="runs of each method (median)")
    parser.add_argument("--size", action="append", help="stream size WIDTHxHEIGHT (default 640x480 1332x990 1920x1080)")
    parser.add_argument("--format", action="append", choices=FORMATS, help="stream format (default both)")
    args = parser.parse_args(argv)
    sizes = [tuple(int(v) for v in s.lower().split("x")) for s in args.size] if args.size else list(SIZES)
    from picamcal.kernels import numba_available
    from picamcal.live import stream_format

    if not numba_available():
        print("numba is not installed: the live kernel is numba's (pip install numba)")
        return
    import numba

    clock = cpu_clock_hz()
    print(
        f"picamcal {picamcal.__version__}: {os.cpu_count()} CPUs at {clock / 1e9 if clock else float('nan'):.2f} GHz, "
        f"numba threads {numba.get_num_threads()}, load average {os.getloadavg()[0]:.1f} at the start"
    )
    start = time.perf_counter()
    cal, tuning, rgb, gains = setup()
    print(
        f"simulated a 3280x2464 IMX219 calibration, its tuning and an ISP frame in {time.perf_counter() - start:.0f} s"
    )
    estimates = []
    for size, layout, lines, cpu_s in bench_streams(
        cal, tuning, rgb, gains, sizes, args.format or FORMATS, args.repeats, clock
    ):
        print("\n" + "\n".join(lines))
        if clock:
            estimates.append((size, layout, pi5_estimate(cpu_s, clock, size, stream_format(layout).bytes_per_pixel)))
    print(
        f"\nRaspberry Pi 5 estimate: Cortex-A76 at {PI5_CLOCK_HZ / 1e9:g} GHz x {PI5_CORES}, LPDDR4X-4267 x 32 bit = "
        f"{PI5_PEAK_BYTES_PER_S / 1e9:.1f} GB/s peak; assumed {A76_CYCLES_FACTOR:g}x this core's cycles per pixel and "
        f"{BANDWIDTH_FRACTION:.0%} of the peak bandwidth"
    )
    if not clock:
        print("  this CPU's clock is unknown (no /proc/cpuinfo): no estimate")
        return
    print(f"  {'stream':<22} {'one core ms':>12} {'fps':>6} {'four cores ms':>14} {'fps':>6}")
    for (width, height), layout, (one, four) in estimates:
        stream = f"{width}x{height} {layout}"
        print(f"  {stream:<22} {1e3 * one:>12.1f} {1 / one:>6.0f} {1e3 * four:>14.1f} {1 / four:>6.0f}")
    goal = [one for size, _, (one, _) in estimates if size == GOAL_SIZE]
    if goal:
        fps = 1 / max(goal)
        verdict = "met" if fps >= GOAL_FPS else f"MISSED by {100 * (1 - fps / GOAL_FPS):.0f} %"
        print(
            f"  goal: at least {GOAL_FPS:g} frames/s at {GOAL_SIZE[0]}x{GOAL_SIZE[1]} on a Pi 5 (conservative "
            f"estimate, slower format): {fps:.0f} frames/s -- {verdict}"
        )
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end (these machines are shared)")


if __name__ == "__main__":
    main()
