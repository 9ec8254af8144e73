"""A folder of raw frames to corrected files: where a batch's time goes, and how close it comes to the disk.

Usage: python3 benchmarks/bench_batch.py [--frames 24] [--workers N] [--rounds 5] [--format uint16-tiff+zstd ...]

Simulated 8 MP IMX219 frames are written once as DNG files into a temporary folder (not timed). Then, all in
this one run:

- the split of one frame's time, each stage alone in one thread (median over the frames): reading the DNG
  (``picamcal.read_raw``: plain DNGs, as rpicam-still's, from their strips), correcting it (``picamcal.correct``,
  mode centre, into a reused output; the uint16 formats straight to codes, ``dtype=np.uint16``) and writing it in
  each output format (float32 TIFF, uint16 TIFF, uint16 zstd TIFF, sRGB PNG 8 and 16 bit, sRGB JPEG, one frame
  of an OME-Zarr stack);
- the whole batch, ``run_batch`` with the given workers, for each format: its wall time (the pool's start
  included), and its time per file once running (from the first output finished to the last, over the
  ``n - workers`` files finished after each worker's first), in files/s and MB/s of input and of output;
- baselines, with the same number of worker processes, already started: reading the n files alone, writing
  the same corrected arrays alone in each format, and a plain copy of the n input files (``shutil.copyfile``,
  one stream: what this file system gives);
- the CPU per file of this benchmark's own processes (its workers and the batch's, all cores: ``psutil``) while
  writing alone and while the batch ran, beside their wall time per file: what the batch costs besides what it
  waits for; and the whole machine's (``/proc/stat``, every process), whose idle time says whether writing
  alone left cores free (on a shared machine it counts the other users' work too);
- the goal: with fewer workers than cores (the default: one fewer, at least one), the batch to uint16 zstd TIFF
  at most 1.3 times the slower of reading alone and writing alone with the same workers, "met" or "MISSED by
  N %". Fewer workers than cores, because the batch reads and corrects each file besides writing it: when
  writing alone already keeps every core busy, no overlap can bring the batch within 1.3 times of it (the CPU
  per file says by how much it cannot), and the goal is not judged. The host's speed drifts by tens of percent
  within seconds, so for this format writing alone and the batch are timed in turn for ``--rounds`` rounds
  (5), each round's ratio is printed and the median round's figures are the table's.

The first line names the machine (CPU model and cores from ``/proc/cpuinfo`` and the process's CPU affinity,
the platform, Python): figures from another machine are not comparable.

The files are not synced to the disk (the batch does not either), but each timed phase starts after an
``os.sync()``, with nothing left to write back: "the disk" is this machine's file system, its page cache and,
for outputs of many MB per second, its disk's own write-back speed. Formats slower than a second per frame are
batched with fewer files. These machines are shared: times drift with the load, ratios less so.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import platform
import shutil
import statistics
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

import picamcal
from picamcal.batch import BatchOptions, run_batch
from picamcal.batch.executors import available_cores
from picamcal.correct import correct
from picamcal.output import OUTPUT_SUFFIXES, camera_to_srgb, write_corrected
from picamcal.output.ome_zarr import ZarrStack, write_frame
from picamcal.raw import read_raw, write_dng
from picamcal.simulate import make_camera, simulate_references, simulate_target

GOAL = 1.3  # the batch at most this many times the slower of reading alone and writing alone, fewer workers than cores
GOAL_FORMAT = "uint16-tiff+zstd"
#: The outputs measured: name -> (output format, compression); "ome-zarr" is a zarr stack.
FORMATS: dict[str, tuple[str, str | None]] = {
    "float32-tiff": ("float32-tiff", None),
    "uint16-tiff": ("uint16-tiff", None),
    "uint16-tiff+zstd": ("uint16-tiff", "zstd"),
    "srgb-png": ("srgb-png", None),
    "srgb-png16": ("srgb-png16", None),
    "srgb-jpeg": ("srgb-jpeg", None),
    "ome-zarr": ("float32-tiff", None),
}
WRITE_SAMPLES = 3  # frames timed per format for the split (the slow formats take seconds per frame)
SLOW_WRITE_MS = 1000.0  # formats slower than this to write get only SLOW_FRAMES files in a batch
SLOW_FRAMES = 6

# What the baselines' worker processes use (inherited through fork): the corrected arrays and the zarr stack.
_ARRAYS: dict[str, Any] = {}


def machine() -> str:
    """The machine the figures come from: CPU model, cores this process may use, platform and Python."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), model)
    except OSError:
        pass
    return (
        f"{model}, {available_cores()} cores ({os.cpu_count()} on the machine), {platform.system()} "
        f"{platform.release()} {platform.machine()}, Python {platform.python_version()}"
    )


def _distinct_frames(folder: Path, count: int) -> tuple[Path, list[Path]]:
    """A calibration and ``count`` DNG files of three distinct simulated targets (not timed)."""
    camera = make_camera("imx219")
    cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    cal_path = cal.save(folder / "cal.npz")
    targets = [simulate_target(camera, seed=2 + i)[0] for i in range(min(3, count))]
    frames = folder / "frames"
    frames.mkdir()
    paths = [write_dng(frames / f"f{i:02d}.dng", targets[i % len(targets)]) for i in range(count)]
    return cal_path, paths


class Round(NamedTuple):
    """One round of writing alone then the batch: times in seconds; the machine's CPU (busy, idle seconds) and
    the CPU seconds of this benchmark's own processes while writing alone and while the batch ran (from its first
    output finished to its last)."""

    ratio: float
    write_alone_s: float
    batch_s: float
    per_file_s: float
    out_bytes: int
    alone_cpu: tuple[float, float] | None
    batch_cpu: tuple[float, float] | None
    alone_own: float | None
    batch_own: float | None


class CpuMeter:
    """The machine's CPU time (all cores, every process: ``/proc/stat``), sampled every 20 ms in a thread, and
    the CPU time of this process and its descendants (the pools' workers, the batch's forkserver and workers),
    sampled every :data:`OWN_EVERY` samples, so that the CPU a phase spent between two moments can be read
    afterwards. Linux only (elsewhere ``busy`` and ``own`` are None). On a shared machine the first counts the
    other users' work too; the second does not.
    """

    OWN_EVERY = 5  # the descendants' CPU every 100 ms: reading each process's /proc entry costs CPU itself

    def __init__(self) -> None:
        self.samples: list[tuple[float, int, int]] = []  # (time.time(), busy ticks, idle ticks)
        self.own_samples: list[tuple[float, float]] = []  # (time.time(), CPU seconds of this process and descendants)
        self._seen: dict[tuple[int, float], float] = {}  # (pid, start) -> its CPU seconds when last seen
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        if os.path.exists("/proc/stat"):
            self._thread.start()

    def _run(self) -> None:
        count = 0
        while not self._stop.is_set():
            with open("/proc/stat") as f:
                user, nice, system, idle, iowait, irq, softirq = map(int, f.readline().split()[1:8])
            self.samples.append((time.time(), user + nice + system + irq + softirq, idle + iowait))
            if count % self.OWN_EVERY == 0:
                self.own_samples.append((time.time(), self._own_seconds()))
            count += 1
            self._stop.wait(0.02)

    def _own_seconds(self) -> float:
        """CPU seconds of this process and every descendant seen so far (an ended one keeps its last figure)."""
        import psutil  # with dask.distributed, which the test install brings

        me = psutil.Process()
        for process in [me, *me.children(recursive=True)]:
            try:
                with process.oneshot():
                    times = process.cpu_times()
                    self._seen[(process.pid, process.create_time())] = times.user + times.system
            except psutil.Error:  # ended meanwhile
                continue
        return sum(self._seen.values())

    def own(self, start: float, end: float) -> float | None:
        """CPU seconds of this process and its descendants from ``start`` to ``end`` (``time.time()``)."""
        if len(self.own_samples) < 2:
            return None
        times, seconds = (np.array(column, dtype=float) for column in zip(*self.own_samples, strict=True))
        return float(np.diff(np.interp([start, end], times, seconds))[0])

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def busy(self, start: float, end: float) -> tuple[float, float] | None:
        """Seconds of CPU busy and idle, all cores together, from ``start`` to ``end`` (``time.time()``)."""
        if len(self.samples) < 2:
            return None
        times, busy, idle = (np.array(column, dtype=float) for column in zip(*self.samples, strict=True))
        busy_s, idle_s = (
            np.diff(np.interp([start, end], times, ticks))[0] / os.sysconf("SC_CLK_TCK") for ticks in (busy, idle)
        )
        return float(busy_s), float(idle_s)


def _median_ms(fn: Callable[[Any], object], items: Sequence[Any]) -> tuple[float, float]:
    """Median wall and CPU milliseconds of ``fn(item)`` (CPU: of every thread of this process)."""
    walls, cpus = [], []
    for item in items:
        wall, cpu = time.perf_counter(), time.process_time()
        fn(item)
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return 1e3 * statistics.median(walls), 1e3 * statistics.median(cpus)


def _write(name: str, path: Path, index: int = 0) -> None:
    """Write the corrected frame ``_ARRAYS`` holds for ``name`` to ``path`` (a zarr stack's frame ``index``)."""
    output_format, compression = FORMATS[name]
    if name == "ome-zarr":
        write_frame(_ARRAYS["zarr"], index, _ARRAYS["float32"], source=str(path))
        return
    image = _ARRAYS["uint16"] if output_format == "uint16-tiff" else _ARRAYS["float32"]
    matrix = _ARRAYS["matrix"] if output_format.startswith("srgb") else None
    info = {"source": "f.dng", "calibration": "cal.npz", "mode": "centre", "binned": False}
    write_corrected(path, image, output_format, info, colour_matrix=matrix, overwrite=True, compression=compression)


def _read_only(path: Path) -> None:
    read_raw(path)


def _write_only(task: tuple[str, Path, int]) -> None:
    _write(*task)


def _pool_seconds(
    fn: Callable[[Any], None], tasks: list[Any], workers: int, meter: CpuMeter | None = None
) -> tuple[float, tuple[float, float] | None, float | None]:
    """Seconds for ``workers`` forked processes, started beforehand, to run ``fn`` on every task; the CPU the
    machine spent meanwhile, busy and idle, and that of this process and its workers (``meter``)."""
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
        list(pool.map(time.sleep, [0.2] * workers))  # start every worker before the clock
        start, wall = time.perf_counter(), time.time()
        list(pool.map(fn, tasks))
        seconds = time.perf_counter() - start
        time.sleep(0.15)  # the workers live on until the meter has seen their CPU since
    if meter is None:
        return seconds, None, None
    return seconds, meter.busy(wall, wall + seconds), meter.own(wall, wall + seconds)


def _batch(
    cal: Path, frames: list[Path], out: Path, name: str, workers: int
) -> tuple[float, float, int, tuple[float, float]]:
    """``run_batch`` over ``frames`` in format ``name``: its wall seconds, its seconds per file once running, the
    bytes it wrote, and when it was running (``time.time()`` of the first and the last output finished).

    Once running: from the first output finished to the last (their modification times: the end of each file's
    write, which the rename keeps), over the files finished after each worker's first, ``n - workers``. So the
    pool's start and the first file of each worker (reading it, correcting it: nothing to overlap yet) are left
    out, as the baselines' pools are started beforehand.
    """
    output_format, compression = FORMATS[name]
    shutil.rmtree(out, ignore_errors=True)
    if name == "ome-zarr":
        options = BatchOptions(zarr_path=out, mode="centre", workers=workers)
    else:
        options = BatchOptions(
            out_dir=out, mode="centre", output_format=output_format, compression=compression, workers=workers
        )
    start = time.perf_counter()
    result = run_batch(cal, frames, options)
    seconds = time.perf_counter() - start
    if result.failed or len(result.done) != len(frames):
        raise RuntimeError(f"the {name} batch failed: {result.failed}")
    files = [p for p in out.rglob("*") if p.is_file()]
    if name == "ome-zarr":  # a frame is finished when the last of its chunks (0/c/<frame>/...) is
        ends: dict[str, int] = {}
        for chunk in (p for p in files if "c" in p.relative_to(out).parts[:2]):
            frame = chunk.relative_to(out / "0" / "c").parts[0]
            ends[frame] = max(ends.get(frame, 0), chunk.stat().st_mtime_ns)
        finished = sorted(ends.values())
    else:
        finished = sorted(p.stat().st_mtime_ns for p in files)
    per_file = (finished[-1] - finished[0]) / 1e9 / max(1, len(frames) - workers)
    return seconds, per_file, sum(p.stat().st_size for p in files), (finished[0] / 1e9, finished[-1] / 1e9)


def _cpu_ms(timed: Round, n: int, workers: int, own: bool = False) -> tuple[float, float] | None:
    """CPU ms per file (:class:`CpuMeter`) while writing alone and while the batch ran: the whole machine's, or
    with ``own`` this benchmark's processes'."""
    if own:
        if timed.alone_own is None or timed.batch_own is None:
            return None
        return 1e3 * timed.alone_own / n, 1e3 * timed.batch_own / (n - workers)
    if timed.alone_cpu is None or timed.batch_cpu is None:
        return None
    return 1e3 * timed.alone_cpu[0] / n, 1e3 * timed.batch_cpu[0] / (n - workers)


def _cpu_lines(timed: Round, n: int, workers: int) -> list[str]:
    """What the machine's cores did per file (:class:`CpuMeter`) while writing alone and while the batch ran."""
    alone, batch, cpu = timed.alone_cpu, timed.batch_cpu, _cpu_ms(timed, n, workers)
    if alone is None or batch is None or cpu is None:
        return ["  (the machine's CPU time per file needs /proc/stat: Linux)"]
    alone_ms, batch_ms = cpu
    alone_idle = alone[1] / sum(alone)
    own = _cpu_ms(timed, n, workers, own=True)
    own_line = (
        []
        if own is None
        else [
            f"  its own processes' CPU per file (the same round): writing alone {own[0]:.0f} ms, the batch "
            f"{own[1]:.0f} ms: {own[1] / own[0]:.2f}x; the rest of the machine's is other work on it."
        ]
    )
    return [
        *own_line,
        f"  the machine's CPU per file, all cores (/proc/stat, the same round): writing alone {alone_ms:.0f} ms "
        f"({100 * alone_idle:.0f} % of the cores' time idle), the batch {batch_ms:.0f} ms "
        f"({100 * batch[1] / sum(batch):.0f} % idle): {batch_ms / alone_ms:.2f}x.",
        "  Writing alone keeps the cores busy, so the batch, which reads and corrects each file besides, can come no "
        "closer to it than that."
        if alone_idle < 0.1
        else "  Writing alone leaves cores idle, which the batch's reading and correcting can use.",
    ]


def _goal(value: float, goal: float) -> str:
    return "met" if value <= goal else f"MISSED by {100 * (value / goal - 1):.0f} %"


def _verdict(
    timed: list[Round], median: Round, n: int, workers: int, slower_alone: float, one_stream_ms: float
) -> list[str]:
    """The goal's lines: judged with fewer workers than cores, else only the figures and why not."""
    cores = available_cores()
    rounds = (
        f" (the median of {len(timed)} rounds: {', '.join(f'{r.ratio:.2f}' for r in timed)})" if len(timed) > 1 else ""
    )
    figures = (
        f"{1e3 * median.per_file_s:.0f} ms/file against {1e3 * slower_alone:.0f} ms/file, {median.ratio:.2f}x{rounds}"
    )
    if workers < cores:
        head = (
            f"  goal: the batch to {GOAL_FORMAT} with fewer workers than cores ({workers} on {cores}) at most "
            f"{GOAL:g}x the slower of reading alone and writing alone with the same workers: {figures} -- "
            f"{_goal(median.ratio, GOAL)}"
        )
    else:
        head = (
            f"  goal not judged: it is stated for fewer workers than cores, and {workers} workers on {cores} cores "
            f"leave none for reading and correcting while writing alone keeps them busy (give --workers "
            f"{max(1, cores - 1)}); {figures}"
        )
    return [
        head,
        f"  (against the slower stage alone in one stream, {one_stream_ms:.0f} ms: "
        f"{1e3 * median.per_file_s / one_stream_ms:.2f}x)",
        *_cpu_lines(median, n, workers),
    ]


def bench(folder: Path, count: int, workers: int, names: Sequence[str], rounds: int = 5) -> list[str]:
    cal_path, frames = _distinct_frames(folder, count)
    meter = CpuMeter()
    try:
        return _bench(folder, cal_path, frames, workers, names, rounds, meter)
    finally:
        meter.stop()


def _bench(
    folder: Path, cal_path: Path, frames: list[Path], workers: int, names: Sequence[str], rounds: int, meter: CpuMeter
) -> list[str]:
    count = len(frames)
    cal = picamcal.load_calibration(cal_path)
    raw = read_raw(frames[0])
    input_mb = sum(p.stat().st_size for p in frames) / 1e6
    float_out = correct(raw, cal, "centre")  # warm-up: the kernel (C, or numba's) and the calibration's fields
    codes_out = correct(raw, cal, "centre", dtype=np.uint16)
    _ARRAYS.update(float32=float_out, uint16=codes_out, matrix=camera_to_srgb(raw.metadata))
    stack = ZarrStack(folder / "alone.zarr", [str(p) for p in frames], {}, "cal.npz")
    stack.plan(overwrite=True)
    stack.prepare(float_out.shape, 1, None)
    stack.release()
    _ARRAYS["zarr"] = str(folder / "alone.zarr" / "0")

    raws = [read_raw(p) for p in frames[:3]]
    read_ms, read_cpu = _median_ms(read_raw, frames)
    correct_ms, correct_cpu = _median_ms(lambda r: correct(r, cal, "centre", out=float_out), raws)
    codes_ms, codes_cpu = _median_ms(lambda r: correct(r, cal, "centre", out=codes_out, dtype=np.uint16), raws)
    del raws

    copy_dir = folder / "copy"
    copy_dir.mkdir()
    os.sync()
    start = time.perf_counter()
    for path in frames:
        shutil.copyfile(path, copy_dir / path.name)
    copy_s = time.perf_counter() - start
    os.sync()
    read_alone_s = _pool_seconds(_read_only, frames, workers)[0]

    size = f"{raw.width}x{raw.height}"
    lines = [
        f"{count} simulated {size} IMX219 DNG files ({input_mb / count:.1f} MB each), mode centre, "
        f"{workers} worker{'s' if workers > 1 else ''} on {available_cores()} cores; median ms per frame, one "
        "thread, for the split",
        "",
        f"  baselines: read one DNG {read_ms:.0f} ms; correct it {correct_ms:.0f} ms (float32), {codes_ms:.0f} ms "
        "(uint16 codes)",
        f"  plain copy of the {count} inputs, one stream: {copy_s:.2f} s, {input_mb / copy_s:.0f} MB/s",
        f"  reading the {count} inputs alone, {workers} worker(s): {read_alone_s:.2f} s, "
        f"{count / read_alone_s:.1f} files/s, {input_mb / read_alone_s:.0f} MB/s",
        "",
        f"  {'':<17} {'one frame, one thread':^29} {'write alone':^13} {'batch, once running':^34}",
        f"  {'format':<17} {'read':>5} {'corr':>5} {'write':>5} {'sum':>5} {'cpu':>5} {'ms/f':>6} {'cpu/f':>6} "
        f"{'n':>3} {'batch s':>7} {'ms/f':>6} {'cpu/f':>6} {'files/s':>7} {'MB/s in':>7} {'MB/s out':>8} "
        f"{'x slower':>8}",
    ]
    verdict: list[str] | None = None
    for name in names:
        output_format = FORMATS[name][0]
        codes = output_format == "uint16-tiff" and name != "ome-zarr"
        stage_ms, stage_cpu = (codes_ms, codes_cpu) if codes else (correct_ms, correct_cpu)
        out = folder / f"write-{name}"
        out.mkdir()
        targets = [out / f"f{i:02d}{OUTPUT_SUFFIXES[output_format]}" for i in range(count)]
        tasks = [(name, target, i) for i, target in enumerate(targets)]
        write_ms, write_cpu = _median_ms(_write_only, tasks[:WRITE_SAMPLES])
        cpu_ms = read_cpu + stage_cpu + write_cpu
        n = count if write_ms < SLOW_WRITE_MS else min(count, SLOW_FRAMES)  # a slow format: fewer files
        timed: list[Round] = []  # writing alone and the batch in turn
        for _ in range(rounds if name == GOAL_FORMAT else 1):
            shutil.rmtree(out)  # new files each round, as the batch writes (replacing a file costs more)
            out.mkdir()
            os.sync()  # each timed phase starts with nothing left to write back to the disk
            write_alone_s, alone_cpu, alone_own = _pool_seconds(_write_only, tasks[:n], workers, meter)
            os.sync()
            batch_s, per_file_s, out_bytes, running = _batch(cal_path, frames[:n], folder / "batch", name, workers)
            ratio = per_file_s / max(read_alone_s / count, write_alone_s / n)
            timed.append(
                Round(
                    ratio,
                    write_alone_s,
                    batch_s,
                    per_file_s,
                    out_bytes,
                    alone_cpu,
                    meter.busy(*running),
                    alone_own,
                    meter.own(*running),
                )
            )
        shutil.rmtree(out)
        median = sorted(timed)[len(timed) // 2]
        ratio, write_alone_s, batch_s, per_file_s, out_bytes = median[:5]
        slower_alone = max(read_alone_s / count, write_alone_s / n)
        alone_cpu_ms, batch_cpu_ms = _cpu_ms(median, n, workers, own=True) or (float("nan"), float("nan"))
        lines.append(
            f"  {name:<17} {read_ms:>5.0f} {stage_ms:>5.0f} {write_ms:>5.0f} {read_ms + stage_ms + write_ms:>5.0f} "
            f"{cpu_ms:>5.0f} {1e3 * write_alone_s / n:>6.0f} {alone_cpu_ms:>6.0f} {n:>3} {batch_s:>7.2f} "
            f"{1e3 * per_file_s:>6.0f} {batch_cpu_ms:>6.0f} {1 / per_file_s:>7.1f} "
            f"{input_mb / count / per_file_s:>7.0f} {out_bytes / 1e6 / n / per_file_s:>8.0f} {ratio:>8.2f}"
        )
        if name == GOAL_FORMAT:
            verdict = _verdict(timed, median, n, workers, slower_alone, max(read_ms, write_ms))
    lines += [
        "",
        "  one frame: ms per frame, each stage alone, called from one thread; cpu: their CPU ms (all threads: the",
        f"  kernel and zstd use more than one); write alone: the same arrays written by {workers} worker(s), wall ms",
        "  per file (ms/f) and CPU ms per file of this benchmark's processes, all cores (cpu/f); n: files in the batch",
        f"  and in writing alone ({SLOW_FRAMES} for formats slower than {SLOW_WRITE_MS:g} ms to write); batch s:",
        "  run_batch of the n files (the pool's start included); ms/f, cpu/f, files/s and MB/s: once running, from",
        "  the first output finished to the last, over n - workers files; x slower: ms/f over the slower of reading",
        "  alone and writing alone (per file, workers started beforehand).",
    ]
    if verdict is not None:
        lines += ["", *verdict]
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24, help="frames in a batch (more than the workers)")
    parser.add_argument(
        "--workers",
        type=int,
        default=max(1, available_cores() - 1),
        help="worker processes of the batch and the baselines (default: one fewer than the cores, at least one)",
    )
    parser.add_argument(
        "--format", action="append", choices=list(FORMATS), help="output format(s) to measure (default: all)"
    )
    parser.add_argument(
        "--rounds", type=int, default=5, help=f"rounds of writing alone then the batch for {GOAL_FORMAT} (the median)"
    )
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error("--rounds: at least 1")
    if args.frames <= args.workers:
        parser.error("--frames: more than --workers (the time per file leaves out each worker's first)")
    print(f"picamcal {picamcal.__version__}, load average {os.getloadavg()[0]:.1f} at the start")
    print(f"machine: {machine()}")
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as folder:
        print("\n".join(bench(Path(folder), args.frames, args.workers, args.format or list(FORMATS), args.rounds)))
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end (these machines are shared)")


if __name__ == "__main__":
    main()
