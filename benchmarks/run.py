"""picamcal benchmarks: one command, every figure against a baseline measured in the same run.

Usage: python3 benchmarks/run.py [--sensor imx219] [--repeats 5] [--only NAME ...] [--write-docs]

It times calibration, raw reading, the matrix inversion and the wheel search itself, then runs the other
benchmarks of this folder one after the other: start-up (bench_startup), single commands beside their work
(bench_commands), correction (bench_correct), batches
file to file (bench_batch), every output format beside its encoder alone (bench_outputs), live unmixing
(bench_live) and the virtual camera's frame rate (bench_virtualcam); `--only calibration startup ...` picks some. With
`--write-docs` it also writes everything it printed into docs/benchmarks.md, the documentation site's Benchmarks
page, between the markers of its "The figures" section, so that the page's figures are those of one run. The whole
run takes about 13 minutes on a 2-core machine.

These machines are shared and noisy, so each figure is the median of several runs and is printed
beside a baseline timed in the same process (absolute times drift from run to run; ratios less so).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

import picamcal
from picamcal.calibrate import invert_3x3
from picamcal.errors import PicamcalWarning
from picamcal.references import ROLES
from picamcal.simulate import simulate_run


def median_time(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def bench_calibration(sensor: str, repeats: int, folder: Path) -> list[tuple[str, float, str]]:
    paths = simulate_run(folder, sensor, overwrite=True)
    refs = {role: paths[role] for role in ROLES}
    decoded = {role: picamcal.read_raw(path) for role, path in refs.items()}
    mosaics = [raw.bayer for raw in decoded.values()]
    size = f"{decoded['white'].width}x{decoded['white'].height}"
    copy = median_time(lambda: [m.copy() for m in mosaics], repeats)
    read = median_time(lambda: [picamcal.read_raw(p) for p in refs.values()], repeats)
    from_files = median_time(lambda: picamcal.calibrate(**refs), repeats)
    from_decoded = median_time(lambda: picamcal.calibrate(**decoded), repeats)
    return [
        (f"copy of the five {size} mosaics (baseline)", copy, "1.0"),
        ("read the five DNG files (read_raw)", read, f"{read / copy:.1f}"),
        ("calibrate from the five DNG files, reading included", from_files, f"{from_files / copy:.1f}"),
        ("calibrate from decoded references", from_decoded, f"{from_decoded / copy:.1f}"),
    ]


def bench_calibration_12mp(repeats: int, folder: Path) -> list[tuple[str, float, str]]:
    """Decoded 12 MP (IMX477) references to a saved calibration file (goal: under 0.5 s)."""
    from picamcal.simulate import make_camera, simulate_references

    refs = simulate_references(make_camera("imx477"), seed=0)
    picamcal.calibrate(**refs)  # warm up (first allocations, imports)
    copy = median_time(lambda: [r.bayer.copy() for r in refs.values()], repeats)
    seconds = median_time(lambda: picamcal.calibrate(**refs).save(folder / "cal12.npz"), repeats)
    return [
        ("copy of the five 4056x3040 mosaics (baseline)", copy, "1.0"),
        ("calibrate from decoded references and save", seconds, f"{seconds / copy:.1f}"),
    ]


def bench_reading(sensor: str, repeats: int, folder: Path) -> list[tuple[str, float, str]]:
    from picamcal.raw import from_picamera2, to_picamera2
    from picamcal.raw.dng.libraw import decode
    from picamcal.raw.picamera2.pisp import pisp_compress
    from picamcal.simulate import make_camera, simulate_references

    raw = simulate_references(make_camera(sensor), seed=0)["white"]
    dng = picamcal.write_dng(folder / "white.dng", raw)
    brcm = picamcal.write_brcm(folder / "white.jpg", raw)
    buffer, config, metadata = to_picamera2(raw)
    # The Pi 5's compressed raw stream of the same frame (the front end's mode 1, rows padded to 64 bytes).
    pisp_stride = -(-raw.width // 64) * 64
    pisp_buffer = pisp_compress(raw.bayer, pisp_stride, shift=16 - raw.bit_depth)
    pisp_config = {
        "raw": {**config["raw"], "format": f"{raw.pattern}_PISP_COMP1", "stride": pisp_stride},
        "sensor": {"bit_depth": raw.bit_depth},
    }

    def decode_compressed() -> object:
        with warnings.catch_warnings():  # that the compression is lossy, which the benchmark knows
            warnings.simplefilter("ignore", PicamcalWarning)
            return from_picamera2(pisp_buffer, pisp_config, metadata)

    copy = median_time(lambda: raw.bayer.copy(), repeats)
    rows = [(f"copy of one {raw.width}x{raw.height} mosaic (baseline)", copy, "1.0")]
    for name, fn in (
        ("read the DNG file (read_raw: a plain DNG, from its strips)", lambda: picamcal.read_raw(dng)),
        ("decode the same DNG with LibRaw, as any other DNG", lambda: decode(dng, None, [])),
        ("read the legacy JPEG+BRCM file", lambda: picamcal.read_raw(brcm)),
        (f"decode the picamera2 {config['raw']['format']} buffer", lambda: from_picamera2(buffer, config, metadata)),
        ("decode the Pi 5's compressed buffer of it (PISP_COMP1)", lambda: decode_compressed()),
    ):
        seconds = median_time(fn, repeats)
        rows.append((name, seconds, f"{seconds / copy:.1f}"))
    return rows


def bench_inversion(repeats: int) -> list[tuple[str, float, str]]:
    rng = np.random.default_rng(0)
    # IMX219 at 16-pixel bins, in float32 as calibrate() inverts them.
    m = (rng.normal(size=(154, 205, 3, 3)) * 0.1 + np.eye(3)).astype(np.float32)
    loop = median_time(lambda: [np.linalg.inv(b) for b in m.reshape(-1, 3, 3)], max(1, repeats // 2))
    batched = median_time(lambda: np.linalg.inv(m), repeats)
    ours = median_time(lambda: invert_3x3(m), repeats)
    return [
        ("per-bin numpy.linalg.inv loop (baseline, as the paper's code)", loop, "1.0"),
        ("numpy.linalg.inv on the stack", batched, f"{loop / batched:.0f}x faster"),
        ("picamcal invert_3x3 (vectorised adjugate)", ours, f"{loop / ours:.0f}x faster"),
    ]


def bench_wheels(repeats: int) -> list[tuple[str, float, str]]:
    """Finding the nine wheels of ``picamcal target``'s target in a 12 MP (4056x3040) linear RGB image."""
    from picamcal.analysis.wheels import find_wheels
    from picamcal.colour_wheel import wheel_layout, wheel_scene

    layout = wheel_layout(4056, 3040)
    image = wheel_scene(layout).astype(np.float32)
    copy = median_time(lambda: image.copy(), repeats)
    rows = [("copy of the 4056x3040 RGB image (baseline)", copy, "1.0")]
    for name, given in (("find the wheels by themselves", None), ("find them through the fiducial marks", layout)):
        seconds = median_time(lambda given=given: find_wheels(image, layout=given), repeats)
        rows.append((name, seconds, f"{seconds / copy:.1f}"))
    return rows


def print_table(title: str, rows: list[tuple[str, float, str]]) -> None:
    print(f"\n{title}")
    width = max(len(r[0]) for r in rows)
    print(f"  {'':{width}}  {'ms':>9}  ratio")
    for name, seconds, ratio in rows:
        print(f"  {name:{width}}  {1000 * seconds:9.1f}  {ratio}")


def calibration_benchmarks(args: argparse.Namespace) -> None:
    with tempfile.TemporaryDirectory() as folder:
        calibration = bench_calibration(args.sensor, args.repeats, Path(folder))
        reading = bench_reading(args.sensor, args.repeats, Path(folder))
        calibration_12 = bench_calibration_12mp(args.repeats, Path(folder))
    inversion = bench_inversion(args.repeats)
    wheels = bench_wheels(args.repeats)
    print_table(f"Calibration ({args.sensor}, median of {args.repeats})", calibration)
    print_table("Inverting the 154 x 205 crosstalk matrices", inversion)
    print_table(f"Reading one raw frame ({args.sensor}, median of {args.repeats})", reading)
    print_table(f"Calibration at 12 MP (IMX477, median of {args.repeats})", calibration_12)
    print_table(f"The colour wheels at 12 MP (median of {args.repeats})", wheels)
    total = calibration[2][1]
    speedup = inversion[0][1] / inversion[2][1]
    slowest_read = max(reading[3][1], reading[4][1])
    compressed = reading[5][1]
    print("\nGoals:")
    print(f"  calibrate from five DNG files in under 2 s: {total:.2f} s, {'met' if total < 2 else 'MISSED'}")
    print(f"  vectorised inversion at least 100x the loop: {speedup:.0f}x, {'met' if speedup >= 100 else 'MISSED'}")
    twelve = calibration_12[1][1]
    print(
        f"  12 MP decoded references to a saved calibration in under 0.5 s: {twelve:.2f} s, "
        f"{'met' if twelve < 0.5 else 'MISSED'}"
    )
    print(
        f"  read a BRCM file or packed buffer in under 150 ms: {1000 * slowest_read:.0f} ms, "
        f"{'met' if slowest_read < 0.15 else 'MISSED'}"
    )
    print(
        f"  decode a Pi 5 compressed buffer in under 1 s: {1000 * compressed:.0f} ms, "
        f"{'met' if compressed < 1 else 'MISSED'}"
    )


#: The other benchmarks of this folder, in the order they run: name -> module (each has ``main(argv)``).
SUITES = {
    "startup": "bench_startup",
    "commands": "bench_commands",
    "correct": "bench_correct",
    "batch": "bench_batch",
    "outputs": "bench_outputs",
    "live": "bench_live",
    "virtualcam": "bench_virtualcam",
    "napari": "bench_napari",
}
#: The documentation site's Benchmarks page, where ``--write-docs`` puts the figures.
PAGE = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"
START, END = "<!-- benchmarks/run.py --write-docs: start -->", "<!-- benchmarks/run.py --write-docs: end -->"


def write_page(text: str, page: Path = PAGE) -> None:
    """Put ``text`` (what this run printed) between the markers of the Benchmarks page."""
    source = page.read_text()
    head, _, rest = source.partition(START)
    _, _, tail = rest.partition(END)
    if not rest or not tail:
        raise SystemExit(f"{page}: the markers {START} and {END} are missing")
    page.write_text(f"{head}{START}\n```text\n{text.strip()}\n```\n{END}{tail}")


def main(argv: list[str] | None = None) -> None:
    import contextlib
    import importlib
    import io
    import sys

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensor", default="imx219")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--only", nargs="+", choices=["calibration", *SUITES], help="run only these")
    parser.add_argument(
        "--write-docs", action="store_true", help="write the printed figures into docs/benchmarks.md (the site's page)"
    )
    args = parser.parse_args(argv)
    chosen = args.only or ["calibration", *SUITES]
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    printed = io.StringIO()

    class Tee(io.TextIOBase):
        def write(self, text: str) -> int:
            printed.write(text)
            return sys.__stdout__.write(text)

        def flush(self) -> None:
            sys.__stdout__.flush()

    with contextlib.redirect_stdout(Tee()):
        for name in chosen:
            print(f"\n===== {name} =====")
            if name == "calibration":
                calibration_benchmarks(args)
            else:
                importlib.import_module(SUITES[name]).main([])
    if args.write_docs:
        write_page(printed.getvalue())


if __name__ == "__main__":
    main()
