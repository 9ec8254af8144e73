"""How long the ``picamcal`` command takes to start: ``--help``, ``--version`` and every command's ``--help``.

Usage: python3 benchmarks/bench_startup.py [--repeats 7]

Each line is a fresh ``python3`` process, timed from start to exit (wall) and by the CPU time it used (user +
system, from the operating system's accounting of the child), each the median of several runs; the processes
of all lines are started in turns (round-robin), so that they see the same load. The baseline is
``python3 -c pass``, the interpreter's own start, measured in the same run; the ratio is a line's wall time over
it. The floors: typer, which every command needs before it does anything (its help included); rich's console,
which a command imports when it first prints (not for ``--help``); and numpy, which ``import picamcal`` does not
need.

The processes run with a byte-code cache of their own (``PYTHONPYCACHEPREFIX`` in a temporary folder, filled by
one run of each line before the timed ones), as an installed package has one: without it every run would compile
the modules it imports, which an installation does once.

The goal: ``picamcal --help``, ``--version`` and every command's ``--help`` under 0.3 s wall on this machine,
printed as met, or MISSED by how much. These machines are shared: absolute times drift with the load, and the
CPU column says what a start costs when the machine is busy with other work.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
GOAL_S = 0.3  # --help, --version and every command's --help under this, wall


def commands() -> list[str]:
    """The names of the commands, as ``picamcal --help`` lists them."""
    sys.path.insert(0, str(SRC))
    from picamcal.cli import app

    return [command.name for command in app.registered_commands if command.name]


def lines_to_time(names: list[str]) -> list[tuple[str, list[str], bool]]:
    """(label, arguments of python3, held to the goal) for every line of the table."""
    picamcal = ["-m", "picamcal"]
    return [
        ("python3 -c pass (baseline)", ["-c", "pass"], False),
        ("import numpy (floor of the library)", ["-c", "import numpy"], False),
        ("import typer (floor of the command line)", ["-c", "import typer"], False),
        ("import typer, rich.console (what printing adds)", ["-c", "import typer, rich.console"], False),
        ("import picamcal", ["-c", "import picamcal"], False),
        ("import picamcal.cli", ["-c", "import picamcal.cli"], False),
        ("picamcal --version", [*picamcal, "--version"], True),
        ("picamcal --help", [*picamcal, "--help"], True),
        *((f"picamcal {name} --help", [*picamcal, name, "--help"], True) for name in names),
    ]


def run_once(args: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU seconds (user + system) of one ``python3 ARGS`` process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, *args], env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def verdict(seconds: float) -> str:
    return "met" if seconds < GOAL_S else f"MISSED by {100 * (seconds / GOAL_S - 1):.0f} %"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="timed runs of each line (the median is printed)")
    args = parser.parse_args(argv)
    lines = lines_to_time(commands())
    with tempfile.TemporaryDirectory() as cache:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env["PYTHONPATH"] = os.pathsep.join([str(SRC), *filter(None, [os.environ.get("PYTHONPATH")])])
        env["PYTHONPYCACHEPREFIX"] = cache
        for _, line_args, _ in lines:  # fills the byte-code cache; not timed
            run_once(line_args, env)
        times: dict[str, list[tuple[float, float]]] = {label: [] for label, _, _ in lines}
        for _ in range(args.repeats):
            for label, line_args, _ in lines:
                times[label].append(run_once(line_args, env))
    wall = {label: statistics.median(w for w, _ in runs) for label, runs in times.items()}
    cpu = {label: statistics.median(c for _, c in runs) for label, runs in times.items()}
    baseline = wall[lines[0][0]]
    width = max(len(label) for label, _, _ in lines)
    print(f"Start-up of the picamcal command (python {sys.version.split()[0]}, median of {args.repeats} runs each)")
    print(f"{'':{width}}  {'wall ms':>8}  {'cpu ms':>7}  {'x baseline':>10}  goal < {1e3 * GOAL_S:.0f} ms wall")
    for label, _, goal in lines:
        print(
            f"{label:{width}}  {1e3 * wall[label]:8.0f}  {1e3 * cpu[label]:7.0f}  {wall[label] / baseline:10.1f}  "
            + (verdict(wall[label]) if goal else "")
        )
    held = [label for label, _, goal in lines if goal]
    slowest = max(held, key=wall.__getitem__)
    missed = [label for label in held if wall[label] >= GOAL_S]
    print(
        f"goal: every --help and --version under {1e3 * GOAL_S:.0f} ms wall: "
        + ("met" if not missed else f"MISSED on {len(missed)} of {len(held)} lines")
        + f" (slowest: {slowest}, {1e3 * wall[slowest]:.0f} ms, {verdict(wall[slowest])})"
    )


if __name__ == "__main__":
    main()
