"""Issue 25 item 6: a parameter the data cannot determine is never reported as identified."""

from __future__ import annotations

import copy

import numpy as np

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.data.contract import read_campaign
from robocal.robot import load_robot
from robocal.sim.twin import load_scenario, simulate


def _campaign(tmp_path, wrist_deg: float):
    """KR16-2 twin whose wrist (joints 4-6) barely moves: the tool offset and the wrist's geometry are then
    determined only through a +-wrist_deg wiggle (a constant tool orientation in the limit)."""
    sc = copy.deepcopy(load_scenario("geometric"))
    sc["n_poses"] = 60
    w = float(wrist_deg)
    sc["joint_ranges_deg"] = [[-150.0, 150.0], [-60.0, 10.0], [-100.0, 40.0], [10 - w, 10 + w], [30 - w, 30 + w],
                              [-w, w]]  # fmt: skip
    simulate(sc, tmp_path / "c", seed=3)
    robot = load_robot("kr16_2")
    return read_campaign(tmp_path / "c", robot), robot


def test_poorly_determined_parameters_are_held_and_listed(tmp_path):
    camp, robot = _campaign(tmp_path, 1.0)
    reported = calibrate(camp, robot, CalibrationConfig(poorly_determined="report"))
    poor = {p["name"]: p for p in reported.fit["poorly_determined"]}
    # the tool's z (along the barely turning flange axis) is the classic case: tens of mm of standard error
    assert "tool_T1_z" in poor and poor["tool_T1_z"]["stderr"] > 10 * poor["tool_T1_z"]["bound"]
    fixed = calibrate(camp, robot)  # default: poorly_determined = fix
    held = {p["name"] for p in fixed.fit["poorly_determined"] if p["action"].startswith("held")}
    assert held and held <= set(poor) | set(fixed.model.names)
    names = list(fixed.model.names)
    for n in held:
        assert not fixed.identified[names.index(n)], n  # never reported as identified
    # what is left is determined: every identified standard error at the configured noise within its bound
    s_fit = np.sqrt(max(fixed.fit["reduced_chi2"], 1.0))
    se = fixed.stderr[fixed.identified] / s_fit
    units = np.array(fixed.model.units)[fixed.identified]
    assert np.all(np.where(units == "mm", se <= 1.0, se <= np.deg2rad(0.1)))
    # held one at a time, worst first: fewer held than the report lists (a correlated pair needs one held)
    assert len(held) <= len(poor)
    assert fixed.fixed_by_user == ()  # held by the rule, not by the user


def test_a_well_determined_campaign_lists_nothing(tmp_path):
    camp, robot = _campaign(tmp_path, 60.0)
    res = calibrate(camp, robot)
    assert "poorly_determined" not in res.fit


def test_the_pipeline_fit_holds_them_too(tmp_path):
    """``robocal calibrate`` and the stage fit through :func:`fit_with_optimizer`: its default (Levenberg-Marquardt)
    is the same fit as ``calibrate``, poorly determined parameters held (it used to fit once and only report them)."""
    from robocal.calibration.fit import fit_with_optimizer

    camp, robot = _campaign(tmp_path, 1.0)
    out = fit_with_optimizer(camp, robot, CalibrationConfig(), None)
    held = [p["name"] for p in out.result.fit["poorly_determined"] if p["action"].startswith("held")]
    assert held
    np.testing.assert_array_equal(out.result.x, calibrate(camp, robot).x)  # one path: the same bits
