"""End to end on the twin's thermal campaign (conf/scenario/thermal.yaml, seed 0): the twin, the thermal fit,
the compensation comparison of table 5, the CLI, and the stages (including the explicit skip)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
#: Sensors of the twin's true length models (conf/scenario/thermal.yaml, effects.thermal.drift).
TRUE_LENGTH_SENSORS = {"d1": ["T_l1_C"], "d4": ["T_l4_C"], "d6": ["T_j6_C"], "a2": ["T_j2_C"], "a3": ["T_j3_C"]}


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    from robocal.data import read_campaign
    from robocal.robot import load_robot
    from robocal.sim.twin import load_scenario, simulate

    d = tmp_path_factory.mktemp("thermal_twin")
    truth = simulate(load_scenario("thermal"), d, seed=0)
    robot = load_robot("kr16_2")
    return d, truth, robot, read_campaign(d, robot)


@pytest.fixture(scope="module")
def done(twin):
    from robocal.thermal import workflow as wf

    _d, truth, robot, camp = twin
    fit = wf.fit_thermal(camp, robot, wf.ThermalConfig())
    selected, _ = wf.choose_selected(fit, wf.run_screening(fit, None))
    proposed, _, _ = wf.fit_selected(fit, selected)
    ev = wf.validate_thermal(fit, proposed, truth)
    return fit, selected, proposed, ev


def test_twin_writes_a_warm_up(twin) -> None:
    d, truth, robot, camp = twin
    log = (d / "temperatures.csv").read_text().splitlines()
    assert log[0].split(",") == ["timestamp", *robot.sensor_names]
    th = truth["effects"]["thermal"]
    assert camp.has_temperatures and camp.has_orientation
    # steady-state tool drift of the paper's size (0.154 / 0.078 / 0.212 mm): within a factor 2 on every axis
    last = th["tool_drift"][-1]
    for axis, paper in (("x", 0.154), ("y", 0.078), ("z", 0.212)):
        assert paper / 2 < last[f"mean_abs_{axis}_mm"] < paper * 2, (axis, last)
    # heating is monotone and saturates: the last two states differ by < 10 % of the total rise
    drift = [r["mean_3d_mm"] for r in th["tool_drift"]]
    assert np.all(np.diff(drift) > 0) and drift[-1] - drift[-2] < 0.1 * drift[-1]


def test_compensation_table5(done) -> None:
    _fit, _selected, _proposed, ev = done
    tab = ev["table"]
    # the drift is ~0.2 mm, the noise floor ~0.025 mm: proposed must remove most of it
    assert tab["proposed"]["mean_position_mm"] < 0.3 * tab["none"]["mean_position_mm"]
    assert tab["proposed"]["mean_position_mm"] <= tab["traditional"]["mean_position_mm"]
    assert tab["proposed"]["mean_orientation_deg"] < tab["traditional"]["mean_orientation_deg"]
    # the bar: within 1.3x of an oracle that compensates with the true parameters
    assert tab["proposed"]["mean_position_mm"] < 1.3 * tab["oracle"]["mean_position_mm"]
    # closed loop on the twin (no tracker noise): the corrected joints really bring the robot closer
    cl = ev["closed_loop"]
    assert cl["proposed"]["mean_position_mm"] < 0.25 * cl["none"]["mean_position_mm"]


def test_length_coefficients_recover_truth(twin) -> None:
    """With the true sensors given, every expansion coefficient is within 3.5 of its standard errors."""
    from robocal.thermal import workflow as wf
    from robocal.thermal.model import ThermalModel

    _d, truth, robot, camp = twin
    cfg = wf.ThermalConfig.from_mapping({"regression": {"candidates": TRUE_LENGTH_SENSORS}})
    fit = wf.fit_thermal(camp, robot, cfg)
    model, _, _ = wf.fit_selected(fit, list(TRUE_LENGTH_SENSORS))
    tm = ThermalModel.from_dict(truth["effects"]["thermal"]["model"])
    for name in TRUE_LENGTH_SENSORS:
        p, t = model.parameter(name), tm.parameter(name)
        assert p.sensors == t.sensors
        z = (p.coefficients[0] - t.coefficients[0]) / p.stderr[0]
        # 3.5 sigma over five coefficients: a false alarm rate ~0.2 %, yet a bias of a few sigma would show
        assert abs(z) < 3.5, (name, p.coefficients[0], t.coefficients[0], p.stderr[0])


def test_drifting_parameters_found(done) -> None:
    fit, selected, proposed, _ev = done
    # the strong drifts of the twin (tool effect >> noise) must have a model; beta2 (~0.01 mm) may not
    for name in ("d1", "d4", "a3", "theta4", "theta6"):
        assert name in fit.model_all.names
    assert set(proposed.names) <= set(selected)


def test_cli_writes_thermal_json(twin, tmp_path) -> None:
    from robocal.cli import main

    d, _truth, _robot, _camp = twin
    assert main(["thermal", str(d), "--robot", "kr16_2", "--out", str(tmp_path), "--no-report"]) == 0
    out = json.loads((tmp_path / "thermal.json").read_text())
    assert set(out["validation"]) == {"none", "traditional", "proposed", "all", "oracle"}
    assert set(out["validation"]["none"]) == {
        "mean_position_mm",
        "max_position_mm",
        "mean_orientation_deg",
        "max_orientation_deg",
    }
    assert out["selected"] and set(out["model"]) <= set(out["selected"])
    from robocal.thermal.model import ThermalModel

    m = ThermalModel.from_json(tmp_path / "thermal_model.json")
    assert m.deta(np.tile(m.T_ref_C + 5.0, (2, 1))).shape == (2, len(m.param_names))
    csv = (tmp_path / "compensation.csv").read_text().splitlines()
    assert csv[0].startswith("target_id,q1_deg") and len(csv) == 16  # header + the 15 validation poses


def _stage_root(tmp_path: Path, data: Path) -> Path:
    robot = yaml.safe_load((REPO / "conf" / "robot" / "kr16_2.yaml").read_text())
    thermal = yaml.safe_load((REPO / "conf" / "thermal" / "default.yaml").read_text())
    params = {"robot": robot, "thermal": thermal, "data": {"campaign": str(data)}, "tracking": {"enabled": False}}
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    return tmp_path


def _run_stage(name: str, root: Path) -> None:
    import importlib.util

    if str(REPO / "stages") not in sys.path:
        sys.path.insert(0, str(REPO / "stages"))
    spec = importlib.util.spec_from_file_location(f"_thermal_stage_{name}", REPO / "stages" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    try:
        sys.modules["common"].run(mod.STAGE, mod.compute, argv=[], root=root)
    except SystemExit as exc:
        assert not exc.code


def test_stages_run_and_skip(twin, tmp_path, monkeypatch) -> None:
    import shutil

    d, _truth, _robot, _camp = twin
    root = _stage_root(tmp_path, d)
    interim = root / "data" / "interim"
    interim.mkdir(parents=True)
    for f in ("poses.csv", "temperatures.csv"):
        shutil.copy(d / f, interim / f)
    (interim / "prepare.json").write_text(json.dumps({"has_temperatures": True, "source": str(d)}))
    cwd = Path.cwd()
    try:
        _run_stage("thermal_fit", root)
        _run_stage("validate", root)
        met = json.loads((root / "reports/metrics/validate.json").read_text())
        assert met["status"] == "ok"
        assert met["validation"]["proposed"]["mean_position_mm"] < met["validation"]["none"]["mean_position_mm"]
        assert (root / "reports/validate/thermal_model.json").is_file()
        # a campaign without temperatures: both stages report an explicit skip and succeed
        (interim / "prepare.json").write_text(json.dumps({"has_temperatures": False}))
        _run_stage("thermal_fit", root)
        _run_stage("validate", root)
        for name in ("thermal_fit", "validate"):
            m = json.loads((root / f"reports/metrics/{name}.json").read_text())
            assert m["status"] == "skipped" and "no temperature log" in m["reason"]
    finally:
        monkeypatch.chdir(cwd)
