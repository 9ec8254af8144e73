"""Every output format as picamcal writes it, beside its encoder alone on the same codes made beforehand.

Usage: python3 benchmarks/bench_outputs.py [--sensor imx219 --sensor imx477] [--rounds 3]

A simulated colour-wheel frame of an 8 MP IMX219 (3280x2464; ``--sensor imx477`` adds or picks the 12 MP
4056x3040) is corrected once, mode centre (not timed), and from it are made beforehand, as a batch has them:
the float32 image, its ``uint16-tiff`` codes (``encode_uint16``) and its sRGB codes at 8 and 16 bit
(``encode_srgb`` through the camera's colour matrix). Then, in one run, for every format of
``picamcal.output.OUTPUT_FORMATS`` and the TIFFs with zstd:

- picamcal: ``picamcal.output.write_corrected`` to a file, metadata, ICC profile and atomic rename included,
  from what the batch gives it: the float image for ``float32-tiff``; for ``uint16-tiff`` and the sRGB formats,
  both the float image (the single-file path, which converts it) and the codes (what the correction kernel gives
  a batch). Where ``write_corrected`` does not take sRGB codes yet, the codes row writes them through
  ``picamcal.output.encoders`` (``write_png``, ``write_jpeg``: what ``write_srgb`` calls with its codes) with the
  same metadata and atomic rename, and is marked ``*``;
- the encoder alone on the codes, to a file of the same folder: tifffile (uncompressed, or zstd with its
  predictor), Pillow's PNG at zlib level 1 (one thread, adaptive filters), imagecodecs' PNG at level 1 (libpng,
  8 and 16 bit), Pillow's JPEG (libjpeg-turbo) at ``picamcal.output.JPEG_QUALITY``, 4:4:4;

each the median of ``--rounds`` (3) rounds, every method run once a round in turn (interleaved: each sees the
same load), after an untimed round. "cpu ms" is the CPU time of all threads: picamcal's PNG deflates its
strips on every kernel thread (``picamcal.kernels.kernel_threads()``), the other encoders use one; MB is the
file's size. The ratio is picamcal's time over the encoder's; the goal (issue 33) is at most 1.3 for every
format. Then one 8 MP ``srgb-png`` from its codes: picamcal's PNG encoder on every kernel thread and on one,
beside Pillow's (one thread; goal: faster) and imagecodecs'.

The files go to a temporary folder in ``/dev/shm`` (memory) where there is one, else in the system's temporary
folder, or in ``--folder``: the encoders' time, not the disk's write-back (which lands on whichever method is
running when it starts: bench_batch.py measures the disk). These machines are shared: absolute times drift with
the load, ratios less so.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import imagecodecs
import numpy as np
import tifffile
from PIL import Image

import picamcal
from picamcal._atomic import atomic_path
from picamcal.kernels import kernel_threads
from picamcal.output import (
    JPEG_QUALITY,
    OUTPUT_FORMATS,
    SRGB_WHITE_LEVEL,
    camera_to_srgb,
    encode_srgb,
    encode_uint16,
    srgb_transfer,
    write_corrected,
)
from picamcal.output.encoders import PNG_ZLIB_LEVEL, write_jpeg, write_png
from picamcal.simulate import make_camera, simulate_references, simulate_target

GOAL = 1.3  # picamcal at most this many times its encoder alone
INFO = {"source": "frame.dng", "calibration": "cal.npz", "mode": "centre", "binned": False}
SUFFIX = {"tiff": ".tiff", "png": ".png", "jpeg": ".jpg"}
#: Memory (tmpfs), where Linux has it: the encoders' time, not the disk's write-back, which would land on whichever
#: method happens to run when it starts.
SHM = Path("/dev/shm")


class Row(NamedTuple):
    """One line of the table: picamcal writing ``given`` in ``output_format`` beside ``baseline``."""

    output_format: str
    given: str
    picamcal: Callable[[Path], object]
    baseline: str
    marked: bool = False


def frame(sensor: str) -> dict[str, Any]:
    """The corrected frame and the codes made from it beforehand (not timed)."""
    camera = make_camera(sensor)
    cal = picamcal.calibrate(**simulate_references(camera, seed=1))
    raw, _ = simulate_target(camera, seed=2)
    rgb = picamcal.correct(raw, cal, "centre")
    matrix = camera_to_srgb(raw.metadata)
    return {
        "rgb": rgb,
        "matrix": matrix,
        "uint16": encode_uint16(rgb),
        "srgb8": encode_srgb(rgb, matrix, bits=8),
        "srgb16": encode_srgb(rgb, matrix, bits=16),
    }


def baselines(arrays: dict[str, Any]) -> dict[str, Callable[[Path], object]]:
    """The encoders alone, each writing the codes (or the float image) to a file."""
    rgb, codes16, srgb8, srgb16 = arrays["rgb"], arrays["uint16"], arrays["srgb8"], arrays["srgb16"]

    def tiff(image: np.ndarray, compression: str | None) -> Callable[[Path], object]:
        def write(path: Path) -> None:
            tifffile.imwrite(path, image, photometric="rgb", compression=compression, predictor=bool(compression))

        return write

    def pillow(codes: np.ndarray, **options: Any) -> Callable[[Path], object]:
        return lambda path: Image.fromarray(codes).save(path, **options)

    def libpng(codes: np.ndarray) -> Callable[[Path], object]:
        return lambda path: path.write_bytes(imagecodecs.png_encode(codes, level=PNG_ZLIB_LEVEL))

    return {
        "tifffile": tiff(rgb, None),
        "tifffile zstd + predictor": tiff(rgb, "zstd"),
        "tifffile (uint16)": tiff(codes16, None),
        "tifffile zstd + predictor (uint16)": tiff(codes16, "zstd"),
        "Pillow PNG, level 1": pillow(srgb8, format="PNG", compress_level=PNG_ZLIB_LEVEL),
        "imagecodecs PNG, level 1": libpng(srgb8),
        "imagecodecs PNG, level 1 (16 bit)": libpng(srgb16),
        f"Pillow JPEG q{JPEG_QUALITY}, 4:4:4": pillow(srgb8, format="JPEG", quality=JPEG_QUALITY, subsampling=0),
    }


def takes_srgb_codes(output_format: str, codes: np.ndarray, folder: Path) -> bool:
    """Whether ``write_corrected`` writes sRGB codes as they are (else it takes them for a float image)."""
    probe = np.ascontiguousarray(codes[:64, :64])
    path = folder / f"probe-{output_format}{SUFFIX['jpeg' if output_format == 'srgb-jpeg' else 'png']}"
    try:
        write_corrected(path, probe, output_format, INFO, overwrite=True)
    except (TypeError, ValueError):
        return False
    back = imagecodecs.imread(path).astype(float)
    return back.shape == probe.shape and float(np.abs(back - probe).mean()) < 0.01 * np.iinfo(probe.dtype).max


def codes_writer(output_format: str, codes: np.ndarray, matrix: Any) -> Callable[[Path], object]:
    """sRGB codes through picamcal's encoders as ``write_srgb`` gives them its codes: its metadata, atomically."""
    from picamcal.output.srgb import _srgb_profile

    bits = 8 * codes.dtype.itemsize

    def write(path: Path) -> None:
        info = {
            **INFO,
            "output_format": output_format,
            "picamcal_version": picamcal.__version__,
            "encoding": "sRGB (IEC 61966-2-1), sRGB ICC profile embedded",
            "white_level": SRGB_WHITE_LEVEL,
            "white_code": int(np.rint((2**bits - 1) * srgb_transfer(np.array(SRGB_WHITE_LEVEL)))),
            "colour_matrix": np.round(matrix.matrix, 6).tolist(),
            "colour_matrix_source": matrix.source,
        }
        description = json.dumps({"picamcal": info})
        with atomic_path(path, overwrite=True) as tmp:
            if output_format == "srgb-jpeg":
                write_jpeg(tmp, codes, quality=JPEG_QUALITY, description=description, icc_profile=_srgb_profile())
            else:
                write_png(tmp, codes, description=description, icc_profile=_srgb_profile())

    return write


def rows(arrays: dict[str, Any], folder: Path) -> list[Row]:
    """The table's rows: every output format, from the float image and, where it differs, from the codes."""
    rgb, matrix = arrays["rgb"], arrays["matrix"]

    def corrected(image: np.ndarray, output_format: str, compression: str | None = None) -> Callable[[Path], object]:
        def write(path: Path) -> None:
            write_corrected(
                path, image, output_format, INFO, colour_matrix=matrix, overwrite=True, compression=compression
            )

        return write

    table: list[Row] = []
    for output_format in OUTPUT_FORMATS:
        if output_format == "float32-tiff":
            table.append(Row(output_format, "float image", corrected(rgb, output_format), "tifffile"))
            table.append(
                Row(
                    f"{output_format}, zstd",
                    "float image",
                    corrected(rgb, output_format, "zstd"),
                    "tifffile zstd + predictor",
                )
            )
        elif output_format == "uint16-tiff":
            for given, image in (("float image", rgb), ("codes", arrays["uint16"])):
                table.append(Row(output_format, given, corrected(image, output_format), "tifffile (uint16)"))
            for given, image in (("float image", rgb), ("codes", arrays["uint16"])):
                table.append(
                    Row(
                        f"{output_format}, zstd",
                        given,
                        corrected(image, output_format, "zstd"),
                        "tifffile zstd + predictor (uint16)",
                    )
                )
        else:
            codes = arrays["srgb16" if output_format == "srgb-png16" else "srgb8"]
            baseline = {
                "srgb-png": "Pillow PNG, level 1",
                "srgb-png16": "imagecodecs PNG, level 1 (16 bit)",
                "srgb-jpeg": f"Pillow JPEG q{JPEG_QUALITY}, 4:4:4",
            }[output_format]
            table.append(Row(output_format, "float image", corrected(rgb, output_format), baseline))
            if takes_srgb_codes(output_format, codes, folder):
                table.append(Row(output_format, "codes", corrected(codes, output_format), baseline))
            else:
                table.append(Row(output_format, "codes", codes_writer(output_format, codes, matrix), baseline, True))
            if output_format == "srgb-png":
                table.append(table[-1]._replace(baseline="imagecodecs PNG, level 1"))
    return table


def timed(fn: Callable[[Path], object], path: Path) -> tuple[float, float, float]:
    """Wall and CPU (all threads) milliseconds of one call, and the size of the file it wrote in MB."""
    wall, cpu = time.perf_counter(), time.process_time()
    fn(path)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    size = path.stat().st_size / 1e6
    path.unlink()
    return 1e3 * wall, 1e3 * cpu, size


def interleaved(methods: dict[str, tuple[Callable[[Path], object], Path]], rounds: int) -> dict[str, tuple]:
    """Each method once a round, in turn, after an untimed round: the medians of wall ms, CPU ms and MB."""
    for fn, path in methods.values():
        timed(fn, path)
    runs: dict[str, list[tuple[float, float, float]]] = {name: [] for name in methods}
    for _ in range(rounds):
        for name, (fn, path) in methods.items():
            runs[name].append(timed(fn, path))
    return {
        name: tuple(statistics.median(column) for column in zip(*times, strict=True)) for name, times in runs.items()
    }


def bench_sensor(sensor: str, rounds: int, folder: Path) -> list[str]:
    arrays = frame(sensor)
    height, width = arrays["rgb"].shape[:2]
    table = rows(arrays, folder)
    encoders = baselines(arrays)
    methods: dict[str, tuple[Callable[[Path], object], Path]] = {}
    for k, row in enumerate(table):  # each encoder alone right after the first row it is the baseline of
        kind = "jpeg" if "jpeg" in row.output_format else "png" if "png" in row.output_format else "tiff"
        methods[f"picamcal {k}"] = (row.picamcal, folder / f"picamcal-{k}{SUFFIX[kind]}")
        if row.baseline not in methods:
            methods[row.baseline] = (encoders[row.baseline], folder / f"encoder-{k}{SUFFIX[kind]}")
    single = arrays["srgb8"]
    methods["picamcal PNG, 1 thread"] = (lambda path: write_png(path, single, threads=1), folder / "one.png")
    methods["picamcal PNG, every thread"] = (lambda path: write_png(path, single), folder / "every.png")
    results = interleaved(methods, rounds)

    lines = [
        f"{sensor}: {width}x{height} ({width * height / 1e6:.1f} MP), median of {rounds} interleaved rounds; "
        f"kernel threads {kernel_threads()}",
        f"  {'format':<20} {'from':<13} {'picamcal ms':>11} {'cpu ms':>7} {'MB':>6}   {'the encoder alone':<34} "
        f"{'ms':>7} {'cpu ms':>7} {'MB':>6} {'ratio':>6}  goal {GOAL:g}",
    ]
    missed = []
    for k, row in enumerate(table):
        ms, cpu, size = results[f"picamcal {k}"]
        base_ms, base_cpu, base_size = results[row.baseline]
        ratio = ms / base_ms
        verdict = "met" if ratio <= GOAL else f"MISSED by {100 * (ratio / GOAL - 1):.1f} %"
        if ratio > GOAL:
            missed.append(row)
        given = row.given + ("*" if row.marked else "")
        lines.append(
            f"  {row.output_format:<20} {given:<13} {ms:>11.1f} {cpu:>7.1f} {size:>6.1f}   {row.baseline:<34} "
            f"{base_ms:>7.1f} {base_cpu:>7.1f} {base_size:>6.1f} {ratio:>6.2f}  {verdict}"
        )
    if any(row.marked for row in table):
        lines.append(
            "  * write_corrected takes no sRGB codes yet: the codes through picamcal.output.encoders (write_png, "
            "write_jpeg), the same metadata and ICC profile, written atomically"
        )
    pillow = results["Pillow PNG, level 1"]
    every, one = results["picamcal PNG, every thread"], results["picamcal PNG, 1 thread"]
    lines += [
        f"  one {width}x{height} srgb-png from its codes (PNG encoders alone, no metadata):",
        f"    {'':<44} {'ms':>7} {'cpu ms':>7} {'MB':>6} {'x Pillow':>9}",
    ]
    for name, (ms, cpu, size) in (
        (f"picamcal's PNG, {kernel_threads()} threads", every),
        ("picamcal's PNG, 1 thread", one),
        ("Pillow PNG, level 1 (1 thread)", pillow),
        ("imagecodecs PNG, level 1 (1 thread)", results["imagecodecs PNG, level 1"]),
    ):
        lines.append(f"    {name:<44} {ms:>7.1f} {cpu:>7.1f} {size:>6.1f} {ms / pillow[0]:>9.2f}")
    faster = every[0] < pillow[0]
    lines.append("  goals:")
    for given, what in (
        ("codes", "from what a batch gives (codes; float32: the image)"),
        ("float image", "from the float image"),
    ):
        judged = [
            row for row in table if row.given == given or (given == "codes" and row.output_format.startswith("float32"))
        ]
        late = [f"{row.output_format} ({row.baseline})" for row in judged if row in missed]
        lines.append(
            f"    every format within {GOAL:g}x its encoder alone, {what}: "
            + ("met" if not late else f"MISSED for {len(late)} of {len(judged)}: {', '.join(late)}")
        )
    lines += [
        f"    one srgb-png written faster than Pillow's single-threaded encoder: {every[0] / pillow[0]:.2f}x its time"
        f" -- {'met' if faster else 'MISSED'}",
    ]
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensor", action="append", help="sensor(s) to simulate (default imx219; imx477: 12 MP)")
    parser.add_argument("--rounds", type=int, default=3, help="timed rounds, every method once a round (median)")
    parser.add_argument(
        "--folder", type=Path, default=SHM if SHM.is_dir() else None, help="where the files go (default /dev/shm)"
    )
    args = parser.parse_args(argv)
    print(
        f"picamcal {picamcal.__version__}: {os.cpu_count()} CPUs, kernel threads {kernel_threads()}, "
        f"imagecodecs {imagecodecs.__version__}, load average {os.getloadavg()[0]:.1f} at the start"
    )
    with tempfile.TemporaryDirectory(prefix="bench-outputs-", dir=args.folder) as folder:
        print(f"files written to {folder}")
        for sensor in args.sensor or ["imx219"]:
            print()
            print("\n".join(bench_sensor(sensor, args.rounds, Path(folder))))
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end (these machines are shared)")


if __name__ == "__main__":
    main()
