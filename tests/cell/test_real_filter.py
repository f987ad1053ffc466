"""``robocal filter`` with the real ABB IRB 120 calibration (../shared/data/abb-irb120, skipped without it): the
calibration's 1.3/2.0/1.2 deg zero offsets make every correction about 2 deg; the one safety policy bounds the
correction beyond them, so the targets are corrected, not refused, and the bound is settable from the command."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

PROGRAM = """MODULE Pick
  CONST robtarget pPick := [[350,20,300],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
  CONST robtarget pPlace := [[300,-100,350],[0,0,1,0],[-1,0,-1,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
  CONST jointtarget jHome := [[0,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
  PROC main()
    MoveAbsJ jHome, v1000, fine, tool0;
    MoveJ pPick, v1000, fine, tool0;
    MoveL pPlace, v200, fine, tool0;
  ENDPROC
ENDMODULE
"""


@pytest.fixture(scope="module")
def irb120_bundle(tmp_path_factory):
    from robocal.cli import main

    d = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "abb-irb120"  # tests/conftest.py's SHARED
    if not (d / "poses.csv").is_file():
        pytest.skip(f"{d} has no poses.csv (real-data tests need ../shared)")
    w = tmp_path_factory.mktemp("irb120")
    assert main(["calibrate", str(d), "--robot", str(d / "robot.yaml"), "--out", str(w / "cal")]) == 0
    args = ["serve", "--make-bundle", str(w / "bundle"), "--calibration", str(w / "cal" / "calibration.json")]
    assert main([*args, "--robot", str(d / "robot.yaml")]) == 0
    (w / "prog").mkdir()
    (w / "prog" / "Pick.mod").write_text(PROGRAM)
    return w


def _table(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_real_irb120_program_is_corrected_not_refused(irb120_bundle, capsys):
    from robocal.cli import main

    w = irb120_bundle
    out = w / "out"
    assert main(["filter", str(w / "prog" / "Pick.mod"), "--bundle", str(w / "bundle"), "--out", str(out)]) == 0
    rows = _table(out / "Pick_filter.csv")
    assert [r["status"] for r in rows] == ["ok", "ok", "ok"], [r["reasons"] for r in rows]
    # the whole correction is the calibration's ~2 deg zero offsets (the old 0.5 deg bound refused it) ...
    assert all(float(r["max_correction_deg"]) > 1.5 for r in rows)
    # ... and the program really changed: every target value rewritten, everything else kept
    text = (out / "Pick.mod").read_text()
    assert "[[350,20,300]" not in text and "[[0,0,0,0,30,0]" not in text and "PROC main()" in text
    assert "3 corrected, 0 flagged, 0 refused" in capsys.readouterr().out
    # what the bound sees: the correction minus the calibration's own (minus its zero offsets)
    import json

    err = json.loads((w / "cal" / "calibration.json").read_text())["kinematic_errors"]
    theta = np.rad2deg([err.get(f"theta{j}", 0.0) for j in range(1, 7)])
    for r in rows:
        dq = np.array([float(r[f"dq{j}_deg"]) for j in range(1, 7)])
        assert 0.01 < np.abs(dq + theta).max() < 0.2  # the length/twist errors' share: ~0.1 deg


def test_the_bound_is_settable_on_the_command(irb120_bundle, tmp_path, capsys):
    from robocal.cli import main

    w = irb120_bundle
    base = ["filter", str(w / "prog" / "Pick.mod"), "--bundle", str(w / "bundle")]
    assert main([*base, "--out", str(tmp_path / "a"), "safety.max_correction_deg=0.001"]) == 0
    rows = _table(tmp_path / "a" / "Pick_filter.csv")
    # every target needs ~0.1 deg beyond the offsets (the pose-dependent share of the geometric errors)
    assert [r["status"] for r in rows] == ["refused"] * 3
    assert "exceeds the bound (0.001 deg" in rows[1]["reasons"]
    cfg = tmp_path / "safety.yaml"
    cfg.write_text("safety:\n  max_correction_deg: 0.001\n  on_correction_bound: flag\n")
    assert main([*base, "--out", str(tmp_path / "b"), "--config", str(cfg)]) == 0
    assert [r["status"] for r in _table(tmp_path / "b" / "Pick_filter.csv")] == ["flagged"] * 3
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "c"), "safety.max_corection_deg=1"]) != 0
    assert "Did you mean 'max_correction_deg'" in capsys.readouterr().err
