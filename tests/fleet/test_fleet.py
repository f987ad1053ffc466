"""robocal fleet in-process: planted events flagged, a new campaign computes only itself, same bytes every time."""

from __future__ import annotations

import json
import os
import shutil

import pytest

from conftest import TWIN, settings
from robocal.cli import main
from robocal.fleet.run import run_fleet


def _tree(d):
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.mark.e2e  # three fleet runs for the cache and the bytes (8 s): make e2e (CI), outside make test's 5 minutes
def test_fleet_flags_cache_and_determinism(fleet_copy, tmp_path):
    old = os.umask(0o027)
    try:
        res = run_fleet(fleet_copy, tmp_path / "out", settings(), progress=False)
    finally:
        os.umask(old)
    out = tmp_path / "out"
    assert res["counts"] == {"robots": 3, "campaigns": 9, "accepted": 9, "rejected": 0, "errors": 0}
    assert len(res["computed"]) == 9 and res["n_cached"] == 0
    # the planted jump and drift are flagged, with their kind, and nothing else: the events (>= 0.02 deg,
    # >= 0.04 mm per campaign) are > 10 standard errors on 40 poses, while the Bonferroni threshold (~4.2) keeps
    # the family-wise false-flag rate at 1 %
    truth = json.loads((fleet_copy / "truth.json").read_text())
    planted = {(s, e["parameter"], e["kind"]) for s, r in truth["robots"].items() for e in r["events"]}
    assert {e[2] for e in planted} == {"jump", "drift"}
    assert {(f["serial"], f["parameter"], f["kind"]) for f in res["trends"]["flags"]} == planted
    assert res["truth"]["n_false_flags"] == 0
    # outputs: no timings, the user's umask, a self-contained report naming the flagged robots
    files = _tree(out)
    assert not any(b"wall_time_s" in v or b"solver_time_s" in v for v in files.values())
    assert all(((out / f).stat().st_mode & 0o777) == 0o640 for f in files)
    html = files["report.html"].decode()
    assert all(s in html for s, _, _ in planted) and "http://" not in html and "https://" not in html
    # run again: everything cached, every byte the same
    again = run_fleet(fleet_copy, out, settings(), progress=False)
    assert again["computed"] == [] and again["n_cached"] == 9
    assert _tree(out) == files
    # a new campaign of one robot: only that campaign is computed, the other files keep their bytes
    from robocal.fleet.twin import simulate_fleet

    more = tmp_path / "more"
    simulate_fleet(more, 3, 4, seed=7, config=TWIN)  # the same robots, one campaign more
    new = sorted(p.name for p in (more / "R0002").iterdir() if p.is_dir())[-1]
    shutil.copytree(more / "R0002" / new, fleet_copy / "R0002" / new)
    third = run_fleet(fleet_copy, out, settings(), progress=False)
    assert third["computed"] == [("R0002", new)] and third["n_cached"] == 9
    now = _tree(out)
    assert {k for k in files if now.get(k) != files[k]} == {"fleet.json", "report.html"}
    # the same fleet into a fresh folder: the same bytes as the incremental runs
    fresh = run_fleet(fleet_copy, tmp_path / "fresh", settings(), progress=False)
    assert len(fresh["computed"]) == 10 and _tree(tmp_path / "fresh") == now


def test_cli_runs_one_robot_and_names_a_bad_campaign(fleet_copy, tmp_path, capsys):
    out = tmp_path / "out"
    assert (
        main(["fleet", str(fleet_copy), "--out", str(out), "--robot", "R0003", "--no-tracking", "--no-progress"]) == 0
    )
    assert sorted(p.name for p in (out / "robots").iterdir()) == ["R0003"]
    assert not (out / "fleet.json").exists()  # a part of the fleet writes no fleet files
    # a campaign that breaks the data contract: the others are calibrated, the error names the file, exit code 1
    bad = fleet_copy / "R0001" / "2026-10-05"
    bad.mkdir()
    (bad / "poses.csv").write_text("pose_id,timestamp\np1,2026-10-05T07:00:00Z\n")
    code = main(["fleet", str(fleet_copy), "--out", str(out), "--no-tracking", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 1
    assert "R0001 2026-10-05" in err and "poses.csv" in err
    summary = json.loads((out / "fleet.json").read_text())
    assert summary["counts"]["errors"] == 1 and summary["counts"]["accepted"] == 9


def test_cli_errors(tmp_path, capsys):
    assert main(["fleet", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "fleet folder" in err and str(tmp_path / "nope") in err
    assert main(["fleet", "--simulate", "2"]) == 2
    assert "--out" in capsys.readouterr().err


@pytest.mark.parametrize("engine", ["spark"])
def test_unknown_engine(engine, twin_fleet, tmp_path):
    from robocal.errors import ConfigError
    from robocal.fleet.engine import calibrate_fleet
    from robocal.fleet.layout import read_fleet

    with pytest.raises(ConfigError, match="engine"):
        calibrate_fleet(read_fleet(twin_fleet), tmp_path, settings(), engine=engine)


def test_a_crash_in_one_campaign_is_reported_not_cached(twin_fleet, tmp_path, monkeypatch):
    import robocal
    from robocal.calibration import fit

    real = fit.calibrate

    def flaky(campaign, robot, config=None, x0=None):
        if "R0002" in str(campaign.source) and "2026-04-06" in str(campaign.source):
            raise FloatingPointError("a stand-in for a bug")
        return real(campaign, robot, config, x0)

    monkeypatch.setattr(robocal, "calibrate", flaky)
    res = run_fleet(twin_fleet, tmp_path / "out", settings(), progress=False)
    bad = [s for r in res["robots"] for s in r["campaigns"] if s["status"] == "error"]
    assert [(s["serial"], s["campaign"]) for s in bad] == [("R0002", "2026-04-06")]
    assert "FloatingPointError" in bad[0]["reason"] and res["counts"]["accepted"] == 8
    monkeypatch.setattr(robocal, "calibrate", real)
    again = run_fleet(twin_fleet, tmp_path / "out", settings(), progress=False)
    assert again["computed"] == [("R0002", "2026-04-06")] and again["counts"]["accepted"] == 9
