"""The public API: the README's Python example runs as written, and every advertised name resolves."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import robocal

README = Path(__file__).resolve().parents[1] / "README.md"


def test_every_public_name_resolves():
    for name in robocal.__all__:
        assert getattr(robocal, name) is not None
    assert set(robocal.__all__) <= set(dir(robocal))


def test_readme_example_runs(tmp_path):
    text = README.read_text(encoding="utf-8")
    section = text.split("## Python API", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S)
    assert code, "the README's Python API section has no python block"
    out = subprocess.run(
        [sys.executable, "-c", code.group(1)], cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr
    # the example's campaign has two blunders: the calibration names two rows
    m = re.search(r"flagged rows \[(\d+), (\d+)\]", out.stdout)
    assert m, out.stdout
    assert "validation mean" in out.stdout and "correction" in out.stdout
