"""The size of the virtual environment ``make setup`` creates, as the README and the Makefile state it (issue 30,
item 11: they said ~1.2 GB of a 1.9 GB ``.venv``)."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: the stated size is a disk-space expectation, not a measurement to the last wheel: pip and wheel versions and
#: the platform move it by a few per cent; 20 % still catches a figure that is out of date (1.2 for 1.9)
REL_TOL = 0.2


def _stated_gb(text: str, where: str) -> float:
    m = re.search(r"~(\d+(?:\.\d+)?) GB", text)
    assert m, f"{where} states no size of .venv (~N GB)"
    return float(m.group(1))


def _disk_bytes(root: Path) -> int:
    """Disk space of ``root`` as ``du -s`` counts it (allocated blocks, each inode once)."""
    seen: set[tuple[int, int]] = set()
    total = 0
    for d, dirs, files in os.walk(root):
        for name in dirs + files:
            st = os.lstat(os.path.join(d, name))
            if (st.st_dev, st.st_ino) not in seen:
                seen.add((st.st_dev, st.st_ino))
                total += st.st_blocks * 512
    return total


def test_readme_and_makefile_state_the_size_of_the_venv():
    make = next(line for line in (REPO / "Makefile").read_text().splitlines() if "setting up $(VENV)" in line)
    readme = next(line for line in (REPO / "README.md").read_text().splitlines() if line.startswith("make run "))
    stated = _stated_gb(make, "Makefile")
    assert _stated_gb(readme, "README.md") == stated
    venv = Path(sys.prefix)
    if venv.name != ".venv" or not (venv / ".installed").is_file():
        pytest.skip(f"not running in a virtual environment made by make setup ({venv})")
    measured = _disk_bytes(venv) / 1e9
    assert abs(measured - stated) <= REL_TOL * measured, f"{venv} takes {measured:.2f} GB; stated ~{stated} GB"
