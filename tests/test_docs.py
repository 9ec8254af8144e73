"""Every example in docs/api.md runs, in order, in one empty folder: the Python blocks, then the commands; the
Python examples of docs/errors.md; and the docstring-style example of CONTRIBUTING.md."""

from __future__ import annotations

import doctest
import re
import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest

import picamcal

ROOT = Path(__file__).resolve().parents[1]


def blocks(language: str, page: str = "api.md") -> list[str]:
    text = (ROOT / "docs" / page).read_text()
    return [textwrap.dedent(block) for block in re.findall(rf"```{language}\n(.*?)```", text, re.DOTALL)]


@pytest.mark.slow
def test_api_examples_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks("python"):
        exec(compile(block, "docs/api.md", "exec"), namespace)
    assert (tmp_path / "cal.npz").exists() and (tmp_path / "demo" / "figures.json").exists()
    for line in blocks("bash")[0].strip().splitlines():
        result = subprocess.run(line, shell=True, cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, (line, result.stderr)
    assert (tmp_path / "corrected" / "target.tiff").exists() and (tmp_path / "tuning-flat.json").exists()


def test_errors_examples_run_and_print_one_line_errors(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("PICAMCAL_MAX_PIXELS", raising=False)
    for block in blocks("python", "errors.md"):
        exec(compile(block, "docs/errors.md", "exec"), {})
    printed = capsys.readouterr().out
    for message in (
        "smoothing 1e+06 bins is over the limit",
        "forged.dng: declares an image of 34000x34000 pixels",
        "/dev/null: is a character device, not a regular file",
        "white.dng: --black-level nan",
        "t.json: rpi.alsc calibrations_Cr at 5000 K gives a gain of 9, outside the pisp hardware's range",
    ):
        assert message in printed, printed


def test_the_contributing_example_of_a_doctest_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text = (ROOT / "CONTRIBUTING.md").read_text()
    examples = [block for block in re.findall(r"```python\n(.*?)```", text, re.DOTALL) if block.startswith(">>>")]
    assert examples
    for block in examples:
        # The namespace the repository-root conftest.py gives every docstring example.
        test = doctest.DocTestParser().get_doctest(block, {"np": np, "picamcal": picamcal}, "CONTRIBUTING", None, 0)
        runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
        assert runner.run(test).failed == 0
