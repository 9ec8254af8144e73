"""The project's own rules: the README's Quick start, CONTRIBUTING.md and CI agree, the code is ruff- and mypy-clean,
every docstring example runs, no module grows past what one reader can hold, and the tests read nothing outside the
repository."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from picamcal.ckernel import cache_dir

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "picamcal"
#: The only modules whose examples may be skipped: they need a Raspberry Pi's camera or GPIO pins.
# Examples that need hardware: a Raspberry Pi camera (picamera2), a GPIO NeoPixel, an Arduino on a serial port.
HARDWARE_MODULES = {"acquire/cameras.py", "acquire/illuminators.py", "acquire/serial_illuminator.py"}
#: The most lines a module may have; past this it is split by responsibility (issue 12).
MAX_MODULE_LINES = 800


def quick_start_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Quick start", 1)[1]
    block = re.search(r"```(?:bash|sh|console)?\n(.*?)```", section, re.DOTALL)
    assert block, "the Quick start section has no code block"
    return [line.strip() for line in block.group(1).strip().splitlines() if line.strip()]


def test_readme_opens_with_a_quick_start_of_exactly_two_commands():
    text = (ROOT / "README.md").read_text()
    headings = re.findall(r"^## (.+)$", text, re.MULTILINE)
    assert headings[0] == "Quick start"
    commands = quick_start_commands()
    assert len(commands) == 2
    assert "picamcal demo" in commands[0]
    assert "pytest" in commands[1] and "[test]" in commands[1]


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text()
    test_command = quick_start_commands()[1]
    assert test_command in ci.splitlines()


def test_contributing_gives_the_ci_command_and_the_fast_loop():
    text = (ROOT / "CONTRIBUTING.md").read_text()
    commands = re.search(r"```bash\n(.*?)```", text, re.DOTALL)
    assert commands, "CONTRIBUTING.md has no commands"
    lines = [line.split("#")[0].strip() for line in commands.group(1).splitlines()]
    assert quick_start_commands()[1] in lines
    assert 'python3 -m pytest -n auto -m "not slow"' in lines
    assert "CONTRIBUTING.md" in (ROOT / "README.md").read_text().split("## Quick start", 1)[1].split("\n## ")[0]


def test_the_default_test_run_includes_the_doctests_and_the_slow_tests():
    # CI runs plain `python3 -m pytest`: the doctests run because the configuration collects src with
    # --doctest-modules, and the slow tests (mypy among them) because nothing deselects them by default.
    tomllib = pytest.importorskip("tomllib")  # Python 3.11 and later
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    assert "src/picamcal" in config["testpaths"] and "tests" in config["testpaths"]
    assert "--doctest-modules" in config["addopts"].split()
    assert "slow" not in config["addopts"]


def test_tests_read_nothing_outside_the_repository():
    # Fixtures live in tests/data: a test that reached for ../shared (or anything beside the checkout) would run
    # less, or differently, wherever that is absent.
    above = re.compile(r"parents\[[2-9]\]|\b(ROOT|HERE)\.parent\b|HERE\.parents\[1\]|['\"]/work/")
    offenders = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
        for path in sorted((ROOT / "tests").glob("*.py"))
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if above.search(line)
    ]
    assert not offenders, "paths outside the repository (copy the fixture into tests/data):\n" + "\n".join(offenders)


def test_ruff_is_clean():
    command = [sys.executable, "-m", "ruff", "check", "src", "tests", "benchmarks"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.slow
def test_mypy_is_clean():
    # Configured in pyproject.toml [tool.mypy] (files, Python version). Its incremental cache is kept in picamcal's
    # cache folder, not in the checkout, so that a fresh clone does not check numpy's, matplotlib's and every other
    # library's stubs again: a cold run took 71 to 95 s, a warm one about 18 s. mypy checks what changed
    # against the cache (sources, options, its own version), so what it reports does not depend on the cache.
    cache = cache_dir() / "mypy"
    command = [sys.executable, "-m", "mypy", "--cache-dir", str(cache)]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_no_docstring_example_is_skipped_outside_the_hardware_modules():
    offenders = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
        for path in sorted(SRC.rglob("*.py"))
        if path.relative_to(SRC).as_posix() not in HARDWARE_MODULES
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if re.search(r"doctest:.*[+]SKIP", line)
    ]
    assert not offenders, (
        "examples that do not run (build their inputs on the simulator; code that needs a Pi goes in a :: block):\n"
        + "\n".join(offenders)
    )


def test_no_module_is_over_800_lines():
    lengths = {path.relative_to(ROOT).as_posix(): len(path.read_text().splitlines()) for path in SRC.rglob("*.py")}
    offenders = [f"{name}: {lines} lines" for name, lines in sorted(lengths.items()) if lines > MAX_MODULE_LINES]
    assert not offenders, f"modules over {MAX_MODULE_LINES} lines (split them by responsibility):\n" + "\n".join(
        offenders
    )
