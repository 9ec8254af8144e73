"""Every example in docs/api.md runs, in order, in one empty folder: the Python blocks, then the commands."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def blocks(language: str) -> list[str]:
    text = (ROOT / "docs" / "api.md").read_text()
    return re.findall(rf"```{language}\n(.*?)```", text, re.DOTALL)


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
