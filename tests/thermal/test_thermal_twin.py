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
    from robocal.thermal import fit as wf

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
    from robocal.thermal import fit as wf
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
    # sensors and order chosen by cross-validation, coefficients with uncertainties, eq. 28 printed
    for name, e in out["model"].items():
        cv = e["cross_validation"]
        assert set(e["sensors"]) <= set(cv["candidate_sensors"]) and cv["n_candidates"] > 1, name
        assert cv["cv_best_rmse"] <= cv["cv_rmse"] <= cv["cv_best_rmse"] * (1 + cv["cv_tolerance"]) + 1e-300, name
        assert e["order"] >= 1 and len(e["stderr"]) == len(e["coefficients"]) and all(v > 0 for v in e["stderr"])
        assert e["equation_with_stderr"].count("±") == len(e["coefficients"]) and e["equation"].startswith(f"Δ{name}")
    assert len(out["equations_absolute"]) == len(out["model"]) == len(out["equations_with_stderr"])
    scr = out["screening"]
    assert all(np.isfinite(r["drift_z"]) for r in scr["table"] if r["drift"] is not None)  # std. errors passed on
    assert all(w["text"].startswith("would ") for w in scr["what_if"] if "selection." not in w["text"])
    from robocal.thermal.model import ThermalModel

    m = ThermalModel.from_json(tmp_path / "thermal_model.json")
    assert m.deta(np.tile(m.T_ref_C + 5.0, (2, 1))).shape == (2, len(m.param_names))
    csv = (tmp_path / "compensation.csv").read_text().splitlines()
    assert csv[0].startswith("target_id,status,applied,q1_deg") and len(csv) == 16  # header + 15 validation poses
    assert out["compensation"]["n_targets"] == 15 and set(out["compensation"]["columns"]) >= {"status", "reason"}


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
        assert json.loads((root / "reports/metrics/validate.json").read_text())["validate"] == "ok"
        met = json.loads((root / "reports/validate/all_metrics.json").read_text())  # the full set
        assert met["status"] == "ok"
        assert met["validation"]["proposed"]["mean_position_mm"] < met["validation"]["none"]["mean_position_mm"]
        assert (root / "reports/validate/thermal_model.json").is_file()
        assert sum(met["compensation_status"].values()) == 15 and met["n_rows_out_of_range"] == 0  # default margin
        assert "cross-validated choice" in (root / "reports/thermal/report.html").read_text()
        # a campaign without temperatures: both stages report an explicit skip and succeed
        (interim / "prepare.json").write_text(json.dumps({"has_temperatures": False}))
        _run_stage("thermal_fit", root)
        _run_stage("validate", root)
        for name in ("thermal_fit", "validate"):
            assert json.loads((root / f"reports/metrics/{name}.json").read_text()) == {name: "skipped"}
            m = json.loads((root / f"reports/{name.split('_')[0]}/result.json").read_text())
            assert m["status"] == "skipped" and "no temperature log" in m["reason"]
    finally:
        monkeypatch.chdir(cwd)


def _stretched(fit) -> np.ndarray:
    """Joints with the arm fully stretched (q3 maximising the shoulder-flange distance, q1 = q4 = q5 = q6 = 0)."""
    from robocal.kinematics.chain import fk

    chain = fit.reference.model.chain
    q = np.zeros((2001, 6))
    q[:, 1] = np.deg2rad(-45.0)
    q[:, 2] = np.deg2rad(np.linspace(-30.0, 30.0, 2001))
    shoulder = np.array([fit.robot.a_mm[1], 0.0, fit.robot.d_mm[0]])  # joint-2 origin at q1 = 0 (MD-H a2, d1)
    k = int(np.argmax(np.linalg.norm(fk(chain, q)[:, :3, 3] - shoulder, axis=1)))
    return q[k : k + 1]


def _shrinking_model(fit, c_mm_per_C: float):
    """A model where d4 shrinks by ``c`` mm per degC of the first sensor, fitted range +/- 50 degC: no extrapolation"""
    from robocal.thermal.model import ParameterModel, ThermalModel

    m = fit.model_all
    p = ParameterModel(
        "d4", "length", "expansion", (m.sensors[0],), ((1,),), np.array([-c_mm_per_C]), np.array([0.01]), np.eye(1)
    )
    rng = np.column_stack([m.T_ref_C - 50.0, m.T_ref_C + 50.0])
    return ThermalModel(m.robot, m.param_names, m.sensors, m.T_ref_C, rng, (p,))


def test_controller_csv_refuses_unreachable_and_singular_targets(done, tmp_path) -> None:
    import csv

    from robocal.thermal.compensate import compensate_targets, write_controller_csv

    fit = done[0]
    T = fit.drift.temperatures[-1]  # the warmest state: the largest drift
    q_ok = np.deg2rad([[10.0, -70.0, 100.0, 30.0, 45.0, 20.0]])  # far from every singularity
    q_wrist = np.deg2rad([[10.0, -70.0, 100.0, 30.0, 0.02, 20.0]])  # axes 4 and 6 (almost) aligned
    q = np.vstack([q_ok, q_wrist])
    comp = compensate_targets(fit.reference, fit.model_all, T, q, ["T1", "T1"], q_limits=fit.robot.q_limits)
    # near the wrist singularity the sub-mm error needs degrees on q4 / q6: the one Newton (the service's) stops
    # there unconverged instead of swinging the wrist; refused, the nominal joints are kept
    assert list(comp.status) == ["ok", "refused"] and "did not converge" in comp.reason[1]
    assert np.array_equal(comp.q[1], q[1]) and not comp.applied[1]
    assert comp.applied[0] and not np.array_equal(comp.q[0], q[0])
    # the unreachable target: the real arm is 5 mm shorter than nominal and fully stretched (position only)
    shrink = _shrinking_model(fit, 1.0)
    q_far = _stretched(fit)
    far = compensate_targets(fit.reference, shrink, shrink.T_ref_C + 5.0, q_far, ["T1"], orientation=False)
    assert list(far.status) == ["refused"] and np.array_equal(far.q, q_far) and "converge" in far.reason[0]
    # the predicted error of the nominal command is what the controller gets: the 5 mm shortening, not zero
    assert np.linalg.norm(far.residual_mm[0]) > 1.0
    write_controller_csv(tmp_path / "c.csv", comp)
    rows = list(csv.DictReader((tmp_path / "c.csv").open()))
    assert [r["status"] for r in rows] == ["ok", "refused"] and [r["applied"] for r in rows] == ["1", "0"]
    assert rows[0]["reason"] == "" and rows[1]["reason"] != ""
    sent = np.array([[float(r[f"q{j}_deg"]) for j in range(1, 7)] for r in rows])
    assert np.allclose(sent[1], np.rad2deg(q_wrist[0]), atol=1e-6)  # CSV rounding 1e-6 deg


def test_out_of_range_temperatures_are_flagged(done) -> None:
    from robocal.compensation.safety import SafetyPolicy
    from robocal.thermal.compensate import compensate_targets, extrapolation_summary

    fit = done[0]
    m = fit.model_all
    used = next(s for s in m.sensors if any(s in p.sensors for p in m.parameters))
    j = m.sensors.index(used)
    q = np.deg2rad([[10.0, -70.0, 100.0, 30.0, 45.0, 20.0]])
    hot = m.fitted_range_C[:, 1].copy()
    hot[j] += 3.0  # 3 degC above what the fit saw, margin 1 degC
    margin = SafetyPolicy(temperature_margin_C=1.0)  # the thermal stage's setting
    comp = compensate_targets(fit.reference, m, hot, q, ["T1"], limits=margin)
    assert list(comp.status) == ["refused"] and not comp.applied[0] and used in comp.reason[0]
    assert comp.extrapolation_C == pytest.approx(3.0)
    flag = SafetyPolicy(temperature_margin_C=1.0, on_temperature_range="flag")
    applied = compensate_targets(fit.reference, m, hot, q, ["T1"], limits=flag)
    assert applied.applied[0] and applied.status[0] == "flagged" and not np.array_equal(applied.q, q)
    inside = m.fitted_range_C[:, 1] + 0.5  # within the margin
    assert list(compensate_targets(fit.reference, m, inside, q, ["T1"], limits=margin).status) == ["ok"]
    # the warm-up summary counts rows and states outside the range and names the sensor
    T = np.vstack([m.T_ref_C, hot, hot])
    ext = extrapolation_summary(m, T, np.array([0, 1, 1]), [0.0, 30.0], 1.0)
    assert ext["n_rows_out_of_range"] == 2 and ext["states_out_of_range_t_min"] == [30.0]
    assert set(ext["sensors_out_of_range"]) == {used} and "extrapolates" in ext["warning"]
    assert extrapolation_summary(m, T[:1], np.array([0]), [0.0], 1.0)["warning"] == ""


def test_cli_flags_extrapolation_and_large_corrections(twin, tmp_path) -> None:
    """margin 0: the validation day starts ~0.5 degC colder than the calibration day, so its cold state is an
    extrapolation; a 0.1 deg bound refuses the twin's largest corrections (~2 deg near the stretched elbow)."""
    import csv

    from robocal.cli import main

    d, _truth, _robot, camp = twin
    args = ["thermal", str(d), "--robot", "kr16_2", "--out", str(tmp_path)]
    assert main([*args, "compensation.temperature_margin_C=0.0", "compensation.max_correction_deg=0.1"]) == 0
    out = json.loads((tmp_path / "thermal.json").read_text())
    ext, comp = out["extrapolation"], out["compensation"]
    assert ext["n_rows_out_of_range"] > 0 and 0.0 in ext["states_out_of_range_t_min"] and ext["warning"]
    rows = list(csv.DictReader((tmp_path / "compensation.csv").open()))
    refused = [r for r in rows if r["status"] == "refused" and "exceeds the bound" in r["reason"]]
    assert comp["status_counts"]["refused"] >= len(refused) > 0 and len(out["warnings"]) == 2
    val = camp.validation()
    for r in refused:  # the nominal joints of that validation pose are sent unchanged
        k = list(val.pose_id).index(r["target_id"].split("/")[0])
        sent = [float(r[f"q{j}_deg"]) for j in range(1, 7)]
        assert np.allclose(sent, np.rad2deg(val.q[k]), atol=1e-6)
    html = (tmp_path / "report.html").read_text()
    assert "the thermal model extrapolates" in html and "columns of compensation.csv" in html


def test_large_joint_corrections_are_listed_largest_first() -> None:
    """compensation_summary flags corrections above LARGE_CORRECTION_DEG (0.5 deg) without refusing them."""
    from robocal.thermal.compensate import ThermalCompensation
    from robocal.workflows.thermal import LARGE_CORRECTION_DEG, compensation_summary

    m = 3
    comp = ThermalCompensation(
        ids=np.array(["p1/T1", "p2/T1", "p3/T1"], dtype=object),
        q_target=np.zeros((m, 6)),
        q=np.zeros((m, 6)),
        command_T=np.tile(np.eye(4), (m, 1, 1)),
        residual_mm=np.zeros(m),
        residual_rad=np.zeros(m),
        deta=np.zeros(1),
        results={},
        status=np.array(["ok", "ok", "ok"], dtype=object),
        reason=np.array(["", "", ""], dtype=object),
        applied=np.ones(m, dtype=bool),
        correction_max_deg=np.array([0.1, 1.34, 0.6]),
    )
    summary = compensation_summary(comp, 90.0)
    assert LARGE_CORRECTION_DEG == summary["large_correction_deg"] == 0.5
    assert [r["target_id"] for r in summary["large_corrections"]] == ["p2/T1", "p3/T1"]  # largest first
    assert summary["status_counts"]["ok"] == 3 and summary["n_applied"] == 3  # flagged, not refused
