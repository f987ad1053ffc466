"""Discovery on real robots with their own descriptions (no link masses): issue 25's figures.

The ABB IRB 120 (../shared/data/abb-irb120, 36 configurations x 3 targets, validated on target T4) runs in a few
seconds; the UR10 (../shared/data/ur10-ipa, 1 046 calibration rows) takes minutes and is measured by
``benchmarks/real_robots.py`` (figures in the README), not here. Skipped without ../shared.
"""

from __future__ import annotations

import functools

import pytest

from robocal.calibration.fit import calibrate
from robocal.calibration.validation import validate
from robocal.data import read_campaign
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors
from robocal.robot import load_robot


@functools.lru_cache(maxsize=1)
def _abb(folder: str):
    robot = load_robot(f"{folder}/robot.yaml")
    camp = read_campaign(folder, robot)
    res = discover(camp, robot)
    return camp, robot, summary(res, validation_errors(res))


@pytest.fixture()
def abb(shared_dir):
    d = shared_dir / "data" / "abb-irb120"
    if not (d / "poses.csv").is_file():
        pytest.skip(f"{d} has no poses.csv")
    return _abb(str(d))


def test_abb_own_description_reaches_020_mm_on_t4_without_masses(abb):
    _camp, robot, s = abb
    assert not robot.has_dynamics  # the dataset's own description: no link masses
    v = s["validation"]
    # the bar: T4 mean <= 0.20 mm (0.255 before this work; calibrate's geometric model: 0.277)
    assert v["final"]["mean_position_mm"] <= 0.20, v["final"]
    assert v["final"]["max_position_mm"] < v["geometric"]["max_position_mm"]
    # compliance under the arm's own weight is found without masses, and is physical (within 3x its prior)
    weight = [n for n in s["named"] if n["effect"] == "weight"]
    assert weight, [n["key"] for n in s["named"]]
    assert all(n["estimates"]["physical"]["value"] for n in weight)


def test_abb_geometric_step_is_calibrates_result(abb):
    """Issue 23 item 9: discovery's geometric figures are calibrate's (same rows, noise and gross errors)."""
    camp, robot, s = abb
    ref = validate(calibrate(camp, robot, None), camp)
    g = s["validation"]["geometric"]
    for k in ("n_rows", "mean_position_mm", "rms_position_mm", "max_position_mm"):
        assert g[k] == pytest.approx(ref[k], rel=1e-12), k


def test_abb_cross_validated_estimate_and_contributions_are_reported(abb):
    _camp, _robot, s = abb
    cv = s["cross_validation"]
    assert cv["cv_mean_position_mm"] > 0
    for n in s["named"]:
        if n["effect"] in ("weight", "transmission"):
            # each effect's own held-out contribution: the error without it is larger
            assert n["held_out"]["cv_mean_without_mm"] > cv["cv_mean_position_mm"], n["key"]


@functools.lru_cache(maxsize=1)
def _abb_held_out_range(folder: str):
    from dataclasses import replace

    import numpy as np

    robot = load_robot(f"{folder}/robot.yaml")
    camp = read_campaign(folder, robot)
    q2 = camp.q[:, 1]
    split = np.where(q2 <= np.quantile(q2, 0.75), "calibration", "validation").astype(object)
    camp = replace(camp, split=split)
    return camp, robot, discover(camp, robot)


def test_abb_outside_the_calibrated_range_of_joint_2_the_extended_model_beats_geometry(shared_dir):
    """benchmarks/real_robots.py --hold-out-range on the ABB: calibrated on the lower 75 % of joint 2's range.
    The library's gear harmonics of joints 2 and 3 (65-87 deg visited, less than their period: a smooth trend
    fitted with the geometry) used to stand in for the arm's weight and made the held-out mean 0.405 mm against
    the geometry's 0.307; with the weight tested by the library's F-test it is named too, and a gear harmonic over
    less than its period is held at the visited range's ends outside it (0.248 with the weight's combinations
    loaded at least half as much as the strongest, WEIGHT_MIN_EXCITATION)."""
    import numpy as np

    from robocal.compensation.discovered import DiscoveredEffects, joint_offsets
    from robocal.compensation.effects import Signals
    from robocal.discovery.effects import extended_calibration

    d = shared_dir / "data" / "abb-irb120"
    if not (d / "poses.csv").is_file():
        pytest.skip(f"{d} has no poses.csv")
    camp, robot, res = _abb_held_out_range(str(d))
    v = validation_errors(res)
    assert v is not None
    keys = [a.cand.key for a in res.final.model.accepted]
    assert "weight:j2" in keys, keys
    held = [a.cand for a in res.final.model.accepted if a.cand.effect == "gear" and a.cand.joint == 2]
    assert all(c.extra["held_outside_deg"] is not None for c in held), held  # less than a period: held outside
    assert v["final"]["mean_position_mm"] < v["geometric"]["mean_position_mm"], v
    assert v["final"]["max_position_mm"] < v["geometric"]["max_position_mm"], v
    # calibration.json's effects and the service give the fit's joint offsets on every row (to 1e-9 rad, 1e-6 mm
    # at a metre: the weight effect is evaluated from its basis and scale, the rounding of another product)
    cal = extended_calibration(res.final, robot, {})
    dq_fit = res.final.model.joint_offsets(res.final.theta, np.arange(camp.n_rows), 0)
    assert joint_offsets(cal["effects"], robot, camp.q) == pytest.approx(dq_fit, abs=1e-9)
    svc = DiscoveredEffects(tuple(cal["effects"]), robot)
    assert svc.offsets(camp.q, Signals(np.zeros(camp.n_rows))) == pytest.approx(dq_fit, abs=1e-9)


@pytest.mark.e2e  # series D read and its regressors compiled (~18 s): make e2e (CI), outside make test's 5 minutes
def test_the_weight_never_deflects_a_configuration_much_beyond_what_the_calibration_poses_show(shared_dir):
    """UR10 series D (ISO cubes: joint 5 barely loaded by gravity): a joint-5 weight combination reached 189x its
    largest calibration value at the arm stretched upright (q = 0, -90, 0, 0, 0, 0, one of D's validation rows),
    6.1 deg there and the discovered model 20 mm off where the geometry is 0.3 mm. Every weight candidate's column
    now stays within WEIGHT_MAX_AMPLIFICATION of its calibration maximum over the joint limits."""
    import numpy as np

    from robocal.compensation.signals import weight_signal
    from robocal.data.contract import read_campaign
    from robocal.discovery.config import DiscoveryConfig
    from robocal.discovery.grow import physics_candidates
    from robocal.discovery.physics import WEIGHT_MAX_AMPLIFICATION, workspace_sample
    from robocal.kinematics.gravity import gravity_regressor
    from robocal.robot import load_robot

    d = shared_dir / "data" / "ur10-ipa-D"
    if not d.exists():
        pytest.skip("no ../shared/data/ur10-ipa-D")
    robot = load_robot(d / "robot.yaml")
    camp = read_campaign(d, robot)
    rows = np.flatnonzero(camp.split == "calibration")
    weights = [c for c, _ in physics_candidates(camp, robot, DiscoveryConfig(), rows, ("weight",))]
    assert weights, "the UR10's description has no masses: weight candidates are offered"
    Qw = np.vstack([workspace_sample(robot), np.deg2rad([[0.0, -90, 0, 0, 0, 0]])])
    Yw = gravity_regressor(robot, Qw)
    for c in weights:
        # every column: the torque combinations and a counterbalance's harmonics on the shoulder (when offered)
        S_ws = weight_signal(robot, Qw, {**c.extra, "joint": c.joint}, Yw)
        top = np.abs(c.S[rows]).max(axis=0)
        # the sample's bound (the upright pose was not in the sample: 1.5x slack for configurations between)
        assert np.all(np.abs(S_ws).max(axis=0) <= 1.5 * WEIGHT_MAX_AMPLIFICATION * top), c.key
