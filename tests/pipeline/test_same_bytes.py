"""Same config, same bytes on any machine (issue 30 item 4): the default pipeline, run in fresh copies of the
repository under two OpenBLAS kernels, writes outputs whose hashes are those committed in dvc.lock.

This is the check behind "a fresh clone's ``make run`` leaves ``git status`` clean": dvc.lock records every
output's md5, so any output that changes with the CPU (a float written at a precision its noise does not allow,
a choice between candidates tied up to rounding) changes dvc.lock. Each run is the whole default pipeline
(~3 min on one core), so the test is marked ``repro`` and left out of ``make test``; ``make repro-check`` runs
it, and CI runs that after the tests. x86_64 only: ``OPENBLAS_CORETYPE=Prescott`` (an SSE3 kernel every x86_64
CPU runs) is the second kernel, the machine's own (Haswell, SkylakeX, Zen ...) the first.
"""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.repro


def _copy(dest: Path) -> Path:
    """The tracked files of the working tree (with uncommitted edits) in a fresh git repository."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, check=True, capture_output=True).stdout
    for rel in filter(None, listed.decode().split("\0")):
        src = REPO / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    git = ["git", "-c", "user.name=robocal-test", "-c", "user.email=test@robocal.invalid"]
    subprocess.run([*git, "init", "-q"], cwd=dest, check=True)
    subprocess.run([*git, "add", "-A"], cwd=dest, check=True)
    subprocess.run([*git, "commit", "-q", "-m", "copy"], cwd=dest, check=True)
    return dest


def _outs(lock: Path) -> dict[str, str]:
    """Every stage output's md5 in a dvc.lock (the deps are code and config, the same in every copy)."""
    stages = yaml.safe_load(lock.read_text())["stages"]
    return {f"{name}:{o['path']}": o["md5"] for name, s in stages.items() for o in s.get("outs", [])}


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="OPENBLAS_CORETYPE=Prescott is x86_64")
@pytest.mark.parametrize("coretype", ["", "Prescott"], ids=["own-kernel", "Prescott"])
def test_default_pipeline_writes_the_committed_bytes(tmp_path: Path, coretype: str) -> None:
    root = _copy(tmp_path / "repo")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("DVC_", "MLFLOW_TRACKING"))}
    env.update(
        PATH=f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}",
        OPENBLAS_NUM_THREADS="1",
        OMP_NUM_THREADS="1",
        DVC_NO_ANALYTICS="1",
        MLFLOW_DISABLE_TELEMETRY="1",
        MLFLOW_TRACKING_URI=f"sqlite:///{root / 'mlflow.db'}",
    )
    if coretype:
        env["OPENBLAS_CORETYPE"] = coretype
    else:
        env.pop("OPENBLAS_CORETYPE", None)
    run = subprocess.run(["dvc", "repro", "--force"], cwd=root, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    want, got = _outs(REPO / "dvc.lock"), _outs(root / "dvc.lock")
    differ = sorted(k for k in want if got.get(k) != want[k])
    assert not differ, f"outputs whose bytes differ from dvc.lock under OPENBLAS_CORETYPE={coretype!r}: {differ}"
