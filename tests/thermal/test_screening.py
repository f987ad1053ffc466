"""Sensitivity screening (Guo et al. 2026, section 3.4): analytic cases, selection rules, determinism, config
errors, persistence, figures and the pipeline stage (fast: small configuration counts)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from robocal.errors import ConfigError
from robocal.kinematics.chain import build_chain, fk
from robocal.thermal.screening import (
    FIGURE_FILES,
    ScreeningResult,
    add_to_report,
    load_drift,
    load_drift_stderr,
    sample_configurations,
    screen,
    screening_figures,
    write_screening,
)

REPO = Path(__file__).resolve().parents[2]
STEP_DEG = 0.01
STEP_MM = 0.1
# Exact-geometry tolerances: positions are ~1e3 mm in double precision (ulp ~1e-13 mm), so 1e-9 mm leaves a
# factor 1e4 for rounding through the ~30 elementary transforms and still fails on any real error (>= 1e-6 mm).
EXACT_MM = 1e-9


def _row(res: ScreeningResult, name: str):
    return res.table.set_index("parameter").loc[name]


# ------------------------------------------------------------------------------------------ analytic cases


def test_length_perturbation_is_a_pure_translation_of_exactly_the_step(kr16, abb_poe):
    # every length parameter of an MD-H or POE chain is a Trans element: it moves every point after it by the
    # step along its axis, whatever the configuration -> position error exactly 0.1 mm, orientation error 0
    for robot in (kr16, abb_poe):
        res = screen(robot, {"n_configs": 40, "tool_mm": [35.0, -20.0, 120.0]}, seed=1)
        t = res.table[res.table["kind"] == "length"]
        assert len(t) > 0
        np.testing.assert_allclose(t["mean_position_mm"], STEP_MM, atol=EXACT_MM)
        np.testing.assert_allclose(t["max_position_mm"], STEP_MM, atol=EXACT_MM)
        np.testing.assert_allclose(t["max_orientation"], 0.0, atol=1e-15)  # R unchanged bit for bit
        # the geometric bound: a length step never moves the tool by more than the step
        assert (t["max_position_mm"] <= STEP_MM + EXACT_MM).all()


def test_angle_perturbation_orientation_error_is_the_rotation_of_the_step(kr16):
    # a single elementary rotation by delta changes the flange rotation by a rotation of angle delta (conjugated),
    # and ||R_delta - I||_F = 2 sqrt(2) sin(delta / 2) for any axis
    res = screen(kr16, {"n_configs": 30}, seed=2)
    t = res.table[res.table["kind"] == "angle"]
    expected = 2.0 * np.sqrt(2.0) * np.sin(np.deg2rad(STEP_DEG) / 2.0)
    # the Frobenius norm is formed from entries of size ~1e-4 computed to ~1e-16: relative error << 1e-9
    np.testing.assert_allclose(t["mean_orientation"], expected, rtol=1e-9)
    np.testing.assert_allclose(t["max_orientation"], expected, rtol=1e-9)
    np.testing.assert_allclose(t["mean_orientation_deg"], STEP_DEG, rtol=1e-9)


def test_rotation_about_the_axis_the_tool_lies_on_cannot_move_it(kr16):
    # theta6 rotates about the flange z axis: a tool point on that axis does not move (only the orientation
    # changes), whereas a point 100 mm off the axis moves on a circle of radius 100 mm
    on_axis = screen(kr16, {"n_configs": 25, "tool_mm": [0.0, 0.0, 150.0]}, params=["theta6"], seed=3)
    assert _row(on_axis, "theta6")["max_position_mm"] < EXACT_MM
    off_axis = screen(kr16, {"n_configs": 25, "tool_mm": [100.0, 0.0, 150.0]}, params=["theta6"], seed=3)
    chord = 2.0 * 100.0 * np.sin(np.deg2rad(STEP_DEG) / 2.0)
    assert _row(off_axis, "theta6")["mean_position_mm"] == pytest.approx(chord, abs=EXACT_MM)
    assert _row(off_axis, "theta6")["max_position_mm"] == pytest.approx(chord, abs=EXACT_MM)


def test_theta1_sensitivity_matches_the_chord_about_the_base_axis(kr16):
    # independent computation: a rotation delta about base z moves the tool point by 2 r sin(delta/2), r its
    # distance from the z axis, in each of the screening's configurations (nominal forward kinematics)
    tool = np.array([35.0, -20.0, 120.0])
    n, seed = 60, 4
    res = screen(kr16, {"n_configs": n, "tool_mm": tool.tolist()}, params=["theta1"], seed=seed)
    T = fk(build_chain(kr16), sample_configurations(kr16, n, seed))
    p = T[:, :3, 3] + T[:, :3, :3] @ tool
    chord = 2.0 * np.hypot(p[:, 0], p[:, 1]) * np.sin(np.deg2rad(STEP_DEG) / 2.0)
    assert _row(res, "theta1")["mean_position_mm"] == pytest.approx(chord.mean(), abs=EXACT_MM)
    assert _row(res, "theta1")["max_position_mm"] == pytest.approx(chord.max(), abs=EXACT_MM)


def test_simulation_agrees_with_the_error_jacobian(kr16):
    # eq. 22: |J_eta| delta is the first-order position error; the exact chord differs by delta^2/24 ~ 1e-9
    # relative for 0.01 deg, plus second-order coupling of the same size: 1e-6 relative is ample and still
    # fails for any wrong column or step unit (factor 57 for deg/rad)
    res = screen(kr16, {"n_configs": 50, "tool_mm": [35.0, -20.0, 120.0]}, seed=5)
    np.testing.assert_allclose(res.table["jacobian_mean_position_mm"], res.table["mean_position_mm"], rtol=1e-6)


def test_total_error_is_position_plus_orientation(kr16):
    res = screen(kr16, {"n_configs": 20}, seed=6)
    t = res.table
    # E_mean = mean(pos + ori) = mean(pos) + mean(ori) (one tool point): identical up to summation rounding
    np.testing.assert_allclose(t["E_mean"], t["mean_position_mm"] + t["mean_orientation"], rtol=1e-12)


def test_steps_are_configurable(kr16):
    res = screen(kr16, {"n_configs": 10, "length_step_mm": 0.5, "angle_step_deg": 0.02}, params=["d4", "theta2"])
    assert _row(res, "d4")["mean_position_mm"] == pytest.approx(0.5, abs=EXACT_MM)
    assert _row(res, "theta2")["step"] == pytest.approx(0.02)
    assert list(res.table["parameter"]) == ["theta2", "d4"]  # chain order, whatever order params has


# ------------------------------------------------------------------------------------------ P_o, H, selection

# lengths only: E_mean = 0.1 mm exactly for a 0.1 mm step, so H = E_mean * drift / step = drift (mm)
LENGTH_DRIFT = {"d1": 0.05, "d4": 0.03, "a2": 0.01, "a3": -0.02}


def _screen_lengths(kr16, selection, **kw):
    cfg = {"n_configs": 10, "drift": LENGTH_DRIFT, "selection": selection}
    return screen(kr16, cfg, seed=0, **kw)


def test_influence_follows_eq_26_27(kr16):
    res = _screen_lengths(kr16, {"rule": "top_k", "top_k": 1})
    for name, d in LENGTH_DRIFT.items():
        r = _row(res, name)
        assert r["P_o"] == pytest.approx(d / STEP_MM, rel=1e-12)
        assert r["H"] == pytest.approx(d, abs=EXACT_MM)  # sign kept, as in table 4
    assert np.isnan(_row(res, "theta4")["H"])  # no drift known
    assert res.score == "|H|"
    # an angle drift: config in deg and keyword in rad give the same H = E_mean * drift / step
    a = screen(kr16, {"n_configs": 10, "drift": {"theta4": -0.0315}}, params=["theta4"])
    b = screen(kr16, {"n_configs": 10}, params=["theta4"], drift={"theta4": np.deg2rad(-0.0315)})
    ra, rb = _row(a, "theta4"), _row(b, "theta4")
    assert ra["P_o"] == pytest.approx(-3.15, rel=1e-12)
    assert rb["H"] == pytest.approx(ra["H"], rel=1e-12)
    assert ra["H"] == pytest.approx(ra["E_mean"] * -3.15, rel=1e-12)


@pytest.mark.parametrize(
    ("selection", "expected"),
    [
        ({"rule": "threshold", "h_min": 0.015}, {"d1", "d4", "a3"}),  # |H| = .05 .03 .02 >= .015 > .01
        ({"rule": "top_k", "top_k": 2}, {"d1", "d4"}),
        ({"rule": "share", "share": 0.8}, {"d1", "d4", "a3"}),  # cumulative .455 .727 .909 of .11
        ({"rule": "share", "share": 0.7}, {"d1", "d4"}),  # .727 >= .7 already
        ({"rule": "relative", "relative": 0.5}, {"d1", "d4"}),  # >= .025
        ({"rule": "threshold", "h_min": 0.015, "exclude": ["d4"], "include": ["a2"]}, {"d1", "a3", "a2"}),
        ({"rule": "top_k", "top_k": 1, "include": ["theta[46]"]}, {"d1", "theta4", "theta6"}),
    ],
)
def test_selection_rules(kr16, selection, expected):
    res = _screen_lengths(kr16, selection)
    assert set(res.selected) == expected
    assert res.selected == [n for n in res.table["parameter"] if n in expected]  # chain order
    assert list(res.table.loc[res.table["selected"], "parameter"]) == res.selected


def test_insignificant_drift_is_dropped_with_min_z(kr16):
    # d4 drifts 0.03 mm but with a 0.02 mm standard error (z = 1.5): kept without the test, dropped at min_z 2
    se = {"d1": 0.005, "d4": 0.02, "a3": 0.005}
    off = _screen_lengths(kr16, {"rule": "threshold", "h_min": 0.015}, drift_stderr=None)
    on = screen(
        kr16,
        {"n_configs": 10, "drift": LENGTH_DRIFT, "selection": {"rule": "threshold", "h_min": 0.015, "min_z": 2}},
        drift_stderr=se,
    )
    assert set(off.selected) == {"d1", "d4", "a3"}
    assert set(on.selected) == {"d1", "a3"}
    assert _row(on, "d4")["drift_z"] == pytest.approx(1.5)
    assert np.isnan(_row(on, "a2")["drift_z"])  # no standard error: not tested (and below h_min anyway)
    assert any("not significant" in n and "d4" in n for n in on.notes)


def _apply(selection: dict, change: dict) -> dict:
    """The selection with one ``what_if`` change applied, just past the flip point (1e-9 relative: H is exact to
    ~1e-12 mm here, so the nudge decides the side without being a real change)."""
    v = change["value"]
    if change["setting"] == "top_k":
        v = v if change["op"] == ">=" else v - 1
    else:
        v = v * (1 - 1e-9) if change["op"] in ("<=", "<") else v * (1 + 1e-9)
    return {**selection, change["setting"]: v}


@pytest.mark.parametrize(
    "selection",
    [
        {"rule": "threshold", "h_min": 0.018, "explain_band": 1.5},  # near: a3 (.02)
        {"rule": "top_k", "top_k": 2, "explain_band": 1.6},  # cut .03: near d4 (.03) and a3 (.02)
        {"rule": "share", "share": 0.8, "explain_band": 2.2},  # cut .02: near a2, a3, d4
        {"rule": "relative", "relative": 0.5, "explain_band": 1.6},  # cut .025: near a3, d4
        {"rule": "threshold", "h_min": 0.015, "min_z": 2},  # d4 (z = 1.5) kept out by min_z
    ],
)
def test_what_if_says_which_change_would_add_or_drop(kr16, selection):
    """Every what_if entry names a change of the rule's setting; applying it really flips that parameter."""
    se = {"d1": 0.005, "d4": 0.02, "a2": 0.001, "a3": 0.005}  # z: 10, 1.5, 10, 4
    cfg = {"n_configs": 10, "drift": LENGTH_DRIFT}
    res = screen(kr16, {**cfg, "selection": selection}, drift_stderr=se)
    assert res.what_if, "LENGTH_DRIFT puts a parameter near every cut above"
    for w in res.what_if:
        assert w["selected"] == (w["parameter"] in res.selected)
        assert w["text"].startswith(f"would {w['action']} {w['parameter']} if ")
        for change in w["changes"]:
            flipped = screen(kr16, {**cfg, "selection": _apply(selection, change)}, drift_stderr=se)
            assert (w["parameter"] in flipped.selected) != w["selected"], (w, change)
    # d4 is selected on its influence (|H| = .03) although its drift is only 1.5 std. errors: always explained
    d4 = next((w for w in res.what_if if w["parameter"] == "d4"), None)
    assert d4 is not None and d4["significant"] is False and "not significant" in d4["text"]
    # far from every cut and significant: not listed
    assert "d1" not in {w["parameter"] for w in res.what_if}


def test_what_if_in_json_and_report(kr16):
    from robocal.report.html import Report

    sel = {"rule": "threshold", "h_min": 0.018, "explain_band": 1.5, "include": ["a2"]}
    res = screen(kr16, {"n_configs": 10, "drift": LENGTH_DRIFT, "selection": sel}, drift_stderr={"d4": 0.02})
    by = {w["parameter"]: w for w in res.what_if}
    assert "selection.include" in by["a2"]["text"] and by["a3"]["action"] == "drop"
    back = ScreeningResult.from_dict(json.loads(json.dumps(res.to_dict())))
    assert [w["text"] for w in back.what_if] == [w["text"] for w in res.what_if]
    html = add_to_report(res, Report("screen")).to_html()
    assert "what would add or drop them" in html and "would drop a3 if h_min were" in html
    with pytest.raises(ConfigError, match=r"screen\.selection\.explain_band"):
        screen(kr16, {"n_configs": 5, "selection": {"explain_band": 0.5}})


def test_unknown_drift_is_never_selected_by_the_rule(kr16):
    res = _screen_lengths(kr16, {"rule": "relative", "relative": 1e-6})
    assert set(res.selected) == set(LENGTH_DRIFT)
    assert any("no drift known" in n for n in res.notes)


def test_without_drift_the_rule_ranks_sensitivity(kr16):
    res = screen(kr16, {"n_configs": 30, "selection": {"rule": "top_k", "top_k": 3}}, seed=0)
    assert res.score == "E_mean"
    top = res.table.sort_values("E_mean", ascending=False)["parameter"].head(3)
    assert set(res.selected) == set(top)
    assert res.table["H"].isna().all()


def test_drift_states(kr16):
    drift = {"d1": [0.0, 0.04, 0.02], "d4": [0.0, 0.01, 0.03]}
    last = screen(kr16, {"n_configs": 5, "drift": drift}, params=["d1", "d4"])
    assert list(last.table["drift"]) == pytest.approx([0.02, 0.03])
    assert last.drift_states == 3
    peak = screen(kr16, {"n_configs": 5, "drift": drift, "drift_state": "max_abs"}, params=["d1", "d4"])
    assert list(peak.table["drift"]) == pytest.approx([0.04, 0.03])
    one = screen(kr16, {"n_configs": 5, "drift": drift, "drift_state": 1}, params=["d1", "d4"])
    assert list(one.table["drift"]) == pytest.approx([0.04, 0.01])
    with pytest.raises(ConfigError, match=r"screen\.drift_state"):
        screen(kr16, {"n_configs": 5, "drift": drift, "drift_state": 3})


# ------------------------------------------------------------------------------------------ determinism


def test_deterministic_by_seed(kr16):
    cfg = {"n_configs": 40, "tool_mm": [35.0, -20.0, 120.0]}
    a, b, c = screen(kr16, cfg, seed=7), screen(kr16, cfg, seed=7), screen(kr16, cfg, seed=8)
    assert a.table.equals(b.table)
    assert screen(kr16, {**cfg, "seed": 99}, seed=7).table.equals(a.table)  # the argument is the seed used
    angles = a.table["kind"] == "angle"
    assert not np.allclose(a.table.loc[angles, "mean_position_mm"], c.table.loc[angles, "mean_position_mm"])


# ------------------------------------------------------------------------------------------ errors


@pytest.mark.parametrize(
    ("cfg", "key"),
    [
        ({"n_config": 10}, "screen.n_config"),
        ({"n_configs": 0}, "screen.n_configs"),
        ({"n_configs": 2.5}, "screen.n_configs"),
        ({"angle_step_deg": -0.01}, "screen.angle_step_deg"),
        ({"length_step_mm": "0.1"}, "screen.length_step_mm"),
        ({"joint_range_fraction": 1.5}, "screen.joint_range_fraction"),
        ({"tool_mm": [1.0, 2.0]}, "screen.tool_mm"),
        ({"drift": {"d1": "hot"}}, "screen.drift.d1"),
        ({"drift_state": "first"}, "screen.drift_state"),
        ({"selection": {"rule": "best"}}, "screen.selection.rule"),
        ({"selection": {"h_mn": 0.1}}, "screen.selection.h_mn"),
        ({"selection": {"share": 1.5, "rule": "share"}}, "screen.selection.share"),
        ({"selection": {"top_k": 0}}, "screen.selection.top_k"),
        ({"selection": {"min_z": -1}}, "screen.selection.min_z"),
        ({"selection": {"include": "d1"}}, "screen.selection.include"),
        ({"selection": {"exclude": ["nope*"]}}, "screen.selection.exclude"),
        ({"seed": "3"}, "screen.seed"),
    ],
)
def test_bad_config_names_the_key(kr16, cfg, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        screen(kr16, {"n_configs": 5, **cfg} if "n_config" not in cfg else cfg, seed=0)


def test_bad_parameters_are_named(kr16):
    with pytest.raises(ConfigError, match="theta9"):
        screen(kr16, {"n_configs": 5}, params=["theta9"])
    with pytest.raises(ConfigError, match="beta3"):
        screen(kr16, {"n_configs": 5, "drift": {"beta3": 0.01}})


# ------------------------------------------------------------------------------------------ persistence, figures


def test_round_trip_and_drift_file(kr16, tmp_path):
    res = _screen_lengths(kr16, {"rule": "threshold", "h_min": 0.015})
    write_screening(res, tmp_path)
    back = ScreeningResult.from_json(tmp_path / "screening.json")
    assert back.selected == res.selected
    assert back.table.columns.tolist() == res.table.columns.tolist()
    num = res.table.select_dtypes("number").columns
    np.testing.assert_allclose(back.table[num].to_numpy(float), res.table[num].to_numpy(float), rtol=1e-12)
    assert (tmp_path / "screening.csv").read_text().startswith("parameter,kind,unit,step")
    # drift file in the thermal fit's per-state form (mm / rad), with an unidentified parameter as null
    (tmp_path / "states.json").write_text(
        json.dumps({"states": {"names": ["d1", "theta4", "a1"], "deta": [[0, 0, None], [0.02, -5e-4, None]]}})
    )
    drift = load_drift(tmp_path / "states.json")
    assert drift == {"d1": (0.0, 0.02), "theta4": (0.0, -5e-4)}
    assert load_drift_stderr(tmp_path / "states.json") is None
    (tmp_path / "se.json").write_text(json.dumps({"names": ["d1", "a1"], "deta": [[0.02, 0]], "stderr": [0.004, None]}))
    assert load_drift_stderr(tmp_path / "se.json") == {"d1": 0.004}
    with pytest.raises(ConfigError, match="does not exist"):
        load_drift(tmp_path / "missing.json")


def test_figures_and_report(kr16, tmp_path):
    from robocal.report.html import Report

    res = _screen_lengths(kr16, {"rule": "threshold", "h_min": 0.015})
    figs = screening_figures(res)
    assert len(figs) == len(FIGURE_FILES) == 3
    assert all(hasattr(f, "savefig") and isinstance(c, str) and c for f, c in figs)
    html = add_to_report(res, Report("screen")).to_html()
    assert "Sensitivity screening" in html and "d1, a3, d4" in html


# ------------------------------------------------------------------------------------------ stage


def _load_stage() -> ModuleType:
    stages = REPO / "stages"
    if str(stages) not in sys.path:
        sys.path.insert(0, str(stages))
    spec = importlib.util.spec_from_file_location("_stage_screen", stages / "screen.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run_stage(root: Path, screen_cfg: dict) -> dict:
    import yaml

    mod = _load_stage()
    from common import execute

    robot = yaml.safe_load((REPO / "conf" / "robot" / "kr16_2.yaml").read_text())
    cfg = {"robot": robot, "screen": screen_cfg, "tracking": {"enabled": False}}
    return execute(
        mod.STAGE,
        mod.compute,
        cfg,
        root=root,
        out=root / "out",
        metrics_path=root / "metrics.json",
        plots=root / "plots",
    )


def test_stage_skips_without_temperatures(tmp_path):
    (tmp_path / "data/interim").mkdir(parents=True)
    (tmp_path / "data/interim/prepare.json").write_text(json.dumps({"has_temperatures": False}))
    metrics = _run_stage(tmp_path, {"n_configs": 5})
    assert metrics["status"] == "skipped"
    assert "no temperature log" in json.loads((tmp_path / "out/result.json").read_text())["reason"]


def test_stage_writes_screening(tmp_path):
    (tmp_path / "data/interim").mkdir(parents=True)
    (tmp_path / "data/interim/prepare.json").write_text(json.dumps({"has_temperatures": True}))
    (tmp_path / "reports/geometric").mkdir(parents=True)
    (tmp_path / "reports/geometric/calibration.json").write_text(json.dumps({"tools_mm": {"T1": [35, -20, 120]}}))
    (tmp_path / "drift.json").write_text(json.dumps({"names": ["d1", "d4"], "deta": [[0, 0], [0.04, 0.01]]}))
    cfg = {"n_configs": 10, "drift_file": "drift.json", "selection": {"rule": "threshold", "h_min": 0.015}}
    metrics = _run_stage(tmp_path, cfg)
    assert metrics["status"] == "ok" and metrics["n_selected"] == 1 and metrics["selected"] == "d1"
    saved = json.loads((tmp_path / "out/screening.json").read_text())
    assert saved["selected"] == ["d1"]
    assert saved["config"]["tool_mm"] == [[35.0, -20.0, 120.0]]  # taken from the geometric calibration
    assert (tmp_path / "out/report.html").is_file() and (tmp_path / "out/screening.csv").is_file()
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == sorted(FIGURE_FILES)
    # a missing drift file is an error naming it, not a silent sensitivity-only screening
    with pytest.raises(ConfigError, match=r"missing\.json"):
        _run_stage(tmp_path, {**cfg, "drift_file": "missing.json"})
