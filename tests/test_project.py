"""The project's own rules: the README's Quick start and CI agree, and the code is ruff-clean."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


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


def test_ruff_is_clean():
    command = [sys.executable, "-m", "ruff", "check", "src", "tests", "benchmarks"]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
