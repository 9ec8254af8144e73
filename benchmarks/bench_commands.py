"""Single commands at the speed of their work: what a ``picamcal`` command costs beyond the work it does.

Usage: python3 benchmarks/bench_commands.py [--repeats 5] [--sensor imx477]

Two commands a user runs one at a time, on full-size frames of the simulated sensor (IMX477, 12 MP):
``picamcal calibrate`` of the five DNG references and ``picamcal correct`` of one DNG to a TIFF. Each is timed
two ways, in turns (round-robin), so that both see the same load:

- **the command**: a fresh ``python3 -m picamcal ...`` process, from start to exit (wall, and its CPU time from
  the operating system's accounting of the child), as a user runs it;
- **its work (baseline)**: the same command line run again inside one warm process (``picamcal.cli.main``), whose
  modules are imported and whose compiled kernels are loaded by an earlier run: reading, calibrating or
  correcting, checks and writing, and nothing of starting up. What the earlier run loaded and kept (the
  calibration and its correction fields) is forgotten first: loading them is the command's work.

The difference is the start-up a user feels on every command: the interpreter, imports, loading the compiled
kernels. The goal: at most 0.5 s for each command, printed as met, or MISSED by how much. The processes
run with a byte-code cache of their own (``PYTHONPYCACHEPREFIX``), filled by one untimed run, as an installed
package has one; the caches of compiled kernels (picamcal's C kernel, numba's) are the installation's own, also
filled by that run.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
GOAL_S = 0.5  # start-up beyond the command's work, wall


def run_process(args: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU seconds (user + system) of one ``python3 -m picamcal ARGS`` process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "picamcal", *args],
        env=env,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run_in_process(args: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds of the same command line run by ``picamcal.cli.main`` in this (warm) process."""
    from picamcal.batch.worker import forget
    from picamcal.cli import main

    forget()  # the calibration and its fields are the command's work, as in a new process
    start, cpu = time.perf_counter(), time.process_time()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        try:
            main(args)
        except SystemExit as exit_:
            if exit_.code not in (0, None):
                raise RuntimeError(f"picamcal {' '.join(args)} exited {exit_.code}") from None
    return time.perf_counter() - start, time.process_time() - cpu


def verdict(seconds: float) -> str:
    return "met" if seconds <= GOAL_S else f"MISSED by {1e3 * (seconds - GOAL_S):.0f} ms"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="timed runs of each line (the median is printed)")
    parser.add_argument("--sensor", default="imx477", help="the simulated sensor (full size)")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(SRC))
    from picamcal.simulate import simulate_run

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths = simulate_run(folder / "run", args.sensor, overwrite=True)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env["PYTHONPATH"] = os.pathsep.join([str(SRC), *filter(None, [os.environ.get("PYTHONPATH")])])
        env["PYTHONPYCACHEPREFIX"] = str(folder / "pycache")
        counter = iter(range(10**6))

        def calibrate() -> list[str]:
            return ["calibrate", str(folder / "run"), "-o", str(folder / f"cal{next(counter)}.npz")]

        def correct() -> list[str]:
            return [
                "correct",
                str(folder / "cal.npz"),
                str(paths["target"]),
                "--out",
                str(folder / f"out{next(counter)}"),
            ]

        run_process(["calibrate", str(folder / "run"), "-o", str(folder / "cal.npz")], env)  # caches; not timed
        commands: dict[str, Callable[[], list[str]]] = {
            "calibrate (five DNGs)": calibrate,
            "correct (one DNG)": correct,
        }
        for make in commands.values():
            run_process(make(), env)
            run_in_process(make())
        times: dict[str, dict[str, list[tuple[float, float]]]] = {
            name: {"process": [], "work": []} for name in commands
        }
        for _ in range(args.repeats):
            for name, make in commands.items():
                times[name]["process"].append(run_process(make(), env))
                times[name]["work"].append(run_in_process(make()))

    def median(name: str, kind: str, which: int) -> float:
        return statistics.median(run[which] for run in times[name][kind])

    print(
        f"One command at a time, {args.sensor} full size (python {sys.version.split()[0]}, {os.cpu_count()} CPUs, "
        f"median of {args.repeats} runs each)"
    )
    width = max(len(name) for name in commands) + 24
    print(f"{'':{width}}  {'wall ms':>8}  {'cpu ms':>7}  goal: start-up <= {1e3 * GOAL_S:.0f} ms")
    missed = []
    for name in commands:
        work, process = median(name, "work", 0), median(name, "process", 0)
        print(f"{name + ': its work (baseline)':{width}}  {1e3 * work:8.0f}  {1e3 * median(name, 'work', 1):7.0f}")
        print(f"{name + ': the command':{width}}  {1e3 * process:8.0f}  {1e3 * median(name, 'process', 1):7.0f}")
        startup = process - work
        print(f"{name + ': start-up':{width}}  {1e3 * startup:8.0f}  {'':7}  {verdict(startup)}")
        if startup > GOAL_S:
            missed.append(name)
    print(f"goal: each command's start-up at most {1e3 * GOAL_S:.0f} ms: " + ("met" if not missed else "MISSED"))


if __name__ == "__main__":
    main()
