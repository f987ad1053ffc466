"""`robocal compliance` and the compliance_fit stage (run in-process, tracking off)."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from robocal.cli import main

REPO = Path(__file__).resolve().parents[2]


def test_cli_writes_compliance_json_and_compensation(twin_dirs, tmp_path, capsys) -> None:
    out = tmp_path / "out"
    code = main(["compliance", str(twin_dirs[7]), "geometric.noise_mm=0.02", "--robot", "sr210", "--out", str(out)])
    assert code == 0
    data = json.loads((out / "compliance.json").read_text())
    assert data["kind"] == "current" and data["unit"] == "rad/A"
    j2 = data["compliance"]["J2"]
    assert j2["identified"] and j2["stderr"] > 0
    loads = {(c["split"], c["payload_kg"]) for c in data["conditions"]}
    assert ("validation", 43.0) in loads and ("calibration", 210.0) in loads
    for c in data["conditions"]:
        assert {"mean_mm", "max_mm"} <= set(c["after_compliance"]) and {"mean_mm", "max_mm"} <= set(
            c["after_geometric"]
        )
    assert data["controller_parameters"]["L_nominal_mm"][0] == 312.0
    comp = pd.read_csv(out / "compensation.csv")
    # the one controller CSV layout (robocal.compensation.controller_csv), every row judged by the safety policy
    assert list(comp.columns[:9]) == ["target_id", "status", "applied", *[f"q{j}_deg" for j in range(1, 7)]]
    assert set(comp["status"]) == {"ok"} and set(comp["applied"]) == {1}
    assert len(comp) == 20 and comp["pred_err_mm"].max() < 1e-4  # Newton converged on every validation row
    assert (out / "report.html").stat().st_size > 10_000
    assert "helps" in capsys.readouterr().out


def test_cli_bad_setting_is_a_clear_error(twin_dirs, tmp_path, capsys) -> None:
    code = main(["compliance", str(twin_dirs[0]), "method=magic", "--robot", "sr210", "--out", str(tmp_path)])
    assert code == 2 and "compliance.method: " in capsys.readouterr().err


@pytest.fixture()
def common():
    sys.path.insert(0, str(REPO / "stages"))
    import common as mod  # type: ignore[import-not-found]
    import compliance_fit  # type: ignore[import-not-found]

    yield mod, compliance_fit
    sys.path.remove(str(REPO / "stages"))


def _run(common, root: Path, robot: str):
    mod, stage = common
    cfg = {
        "robot": yaml.safe_load((REPO / "conf" / "robot" / f"{robot}.yaml").read_text()),
        "compliance": {**yaml.safe_load((REPO / "conf" / "compliance" / "default.yaml").read_text()), "report": False},
        "tracking": {"enabled": False},
    }
    return mod.execute(
        stage.STAGE,
        stage.compute,
        cfg,
        root=root,
        out=root / "out",
        metrics_path=root / "metrics.json",
        plots=root / "plots",
    )


def test_stage_skips_without_payload(common, tmp_path) -> None:
    (tmp_path / "data" / "interim").mkdir(parents=True)
    (tmp_path / "data" / "interim" / "prepare.json").write_text(json.dumps({"has_payload": False}))
    metrics = _run(common, tmp_path, "kr16_2")
    assert (
        metrics["status"] == "skipped"
        and "payload" in json.loads((tmp_path / "out" / "result.json").read_text())["reason"]
    )
    assert json.loads((tmp_path / "metrics.json").read_text()) == {"compliance_fit": "skipped"}


def test_stage_fits_a_payload_campaign(common, tmp_path, twin_dirs) -> None:
    interim = tmp_path / "data" / "interim"
    interim.mkdir(parents=True)
    shutil.copy(twin_dirs[0] / "poses.csv", interim / "poses.csv")
    (interim / "prepare.json").write_text(json.dumps({"has_payload": True}))
    metrics = _run(common, tmp_path, "sr210")
    assert metrics["status"] == "ok" and metrics["kind"] == "current"
    assert metrics["validation_210kg"]["after_mean_mm"] < metrics["validation_210kg"]["before_mean_mm"]
    assert (tmp_path / "plots" / "load_table.png").is_file() and (tmp_path / "out" / "compliance.json").is_file()


def test_stage_skips_a_campaign_with_one_payload_on_every_row(common, tmp_path, twin_dirs) -> None:
    """A heavy robot measured with its working payload always mounted (newcomer pass 11: the pipeline stopped
    with "no unloaded calibration rows"): no load step, the stage is skipped with its reason."""
    interim = tmp_path / "data" / "interim"
    interim.mkdir(parents=True)
    poses = pd.read_csv(twin_dirs[0] / "poses.csv")
    poses["payload_kg"] = 150.0
    poses.to_csv(interim / "poses.csv", index=False)
    (interim / "prepare.json").write_text(json.dumps({"has_payload": True, "source": "../cells/kr210-line3"}))
    metrics = _run(common, tmp_path, "sr210")
    reason = json.loads((tmp_path / "out" / "result.json").read_text())["reason"]
    assert metrics["status"] == "skipped" and "only loaded" in reason and "150" in reason, reason
    assert reason.startswith("campaign ../cells/kr210-line3:")  # the user's folder, not the interim copy
    assert "weight effect" in reason
