"""The fleet's DVC pipeline (foreach over the robots): `dvc repro` after a new campaign re-runs that robot's stage
and the fleet stage only. ~15 s: each stage is a `robocal fleet` process."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from conftest import TWIN
from robocal.fleet.dvc import pipeline, write_dvc_pipeline

pytestmark = pytest.mark.slow


def test_pipeline_is_a_foreach_over_robots():
    p = pipeline(["R1", "R2"], extra=["--no-tracking"])
    st = p["stages"]["calibrate"]
    assert st["foreach"] == ["R1", "R2"] and st["do"]["deps"] == ["${item}"]
    assert "--robot ${item}" in st["do"]["cmd"] and st["do"]["cmd"].endswith("--no-tracking")
    assert p["stages"]["fleet"]["deps"] == ["out/robots/R1", "out/robots/R2"]


def _git(root: Path, *args: str) -> None:
    subprocess.run(
        ["git", "-c", "user.name=robocal-test", "-c", "user.email=test@robocal.invalid", *args],
        cwd=root,
        check=True,
        capture_output=True,
    )


def _reproduce(root: Path) -> list[str]:
    from contextlib import chdir

    from dvc.repo import Repo

    with chdir(root), Repo(str(root)) as repo:
        return sorted(s.addressing for s in repo.reproduce())


@pytest.mark.e2e  # dvc repro in a copy (16 s): make e2e (CI), outside make test's 5 minutes
def test_dvc_repro_reruns_only_the_robot_with_a_new_campaign(tmp_path, monkeypatch):
    from robocal.fleet.twin import simulate_fleet

    root = tmp_path / "fleet"
    simulate_fleet(root, 2, 2, seed=3, config={**TWIN, "jump_share": 0, "drift_share": 0})
    more = tmp_path / "more"
    simulate_fleet(more, 2, 3, seed=3, config={**TWIN, "jump_share": 0, "drift_share": 0})
    monkeypatch.setenv("PATH", f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("DVC_NO_ANALYTICS", "1")
    monkeypatch.delenv("DVC_ROOT", raising=False)
    _git(root, "init", "-q")
    from dvc.repo import Repo

    Repo.init(str(root)).close()
    path = write_dvc_pipeline(root, extra=["--no-tracking"])
    text = path.read_text()
    assert "foreach" in yaml.safe_load(text)["stages"]["calibrate"]
    # write_dvc_pipeline is what `robocal fleet --write-dvc` runs; the test adds --no-tracking to every stage
    assert _reproduce(root) == ["calibrate@R0001", "calibrate@R0002", "fleet"]
    assert (root / "out" / "report.html").is_file()
    assert _reproduce(root) == []  # nothing changed, nothing runs
    new = sorted(p.name for p in (more / "R0002").iterdir() if p.is_dir())[-1]
    shutil.copytree(more / "R0002" / new, root / "R0002" / new)
    assert _reproduce(root) == ["calibrate@R0002", "fleet"]
    assert (root / "out" / "robots" / "R0002" / new / "summary.json").is_file()
