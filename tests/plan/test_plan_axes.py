"""Issue 34, planning: a robot on a track has its axis errors along the travel in the design's model, so the plan
spreads the poses along the track (a design for the kinematics alone puts them at the track's ends), and plan.csv
gives the track in mm."""

from __future__ import annotations

import numpy as np

import robocal.plan.planner as planner
from robocal.kinematics.axes import travel_coordinate
from robocal.plan.design import information
from robocal.plan.output import plan_csv
from robocal.robot import load_robot

CFG = {
    "n_poses": 30,
    "n_candidates": 1200,
    "criterion": "D",
    "singularity": {"wrist_joint": 6},  # the arm's A5 is joint 6 on the track
    "region": {"n": 40},
    "tracker": {"position_mm": [2000.0, 3000.0, 300.0]},  # beside the track's middle
}


_BUILD = planner.build_problem


def _plan(monkeypatch, axis_terms: bool):
    build = _BUILD
    monkeypatch.setattr(planner, "build_problem", lambda r, c: build(r, c, axis_terms=axis_terms))
    return planner.plan_poses(load_robot("kr16_2_track"), CFG, curve=False)


def test_the_plan_spreads_the_poses_along_the_track(monkeypatch):
    res = _plan(monkeypatch, True)
    robot = res.problem.robot
    assert {"track:straightness_y_P2", "track:pitch_P3"} <= set(res.problem.names)  # designed for, identifiable
    hist = np.histogram(travel_coordinate(res.q[:, 0], robot.q_limits[0]), bins=6, range=(-1, 1))[0]
    assert hist.min() >= 2, hist  # every sixth of the 6 m travel holds poses
    # the kinematics alone see the track only through its direction: their design crowds the ends, and leaves
    # the axis errors less determined (the same candidates: same seed; standard errors of the axis terms from
    # the axis-aware model's information at either design)
    alone = _plan(monkeypatch, False)
    assert not any(":" in n for n in alone.problem.names)
    hist0 = np.histogram(travel_coordinate(alone.q[:, 0], robot.q_limits[0]), bins=6, range=(-1, 1))[0]
    assert hist0[0] + hist0[5] > hist[0] + hist[5], (hist, hist0)
    assert np.array_equal(alone.problem.cand.q, res.problem.cand.q)
    axis = [k for k, n in enumerate(res.problem.names) if ":" in n]

    def se(idx):
        C = np.linalg.inv(information(res.problem.F, idx))
        return np.sqrt(np.diag(C)[axis])

    assert np.median(se(alone.idx) / se(res.idx)) > 1.2  # at least 20 % better determined
    # plan.csv: the track in mm, the arm in degrees, and the twin reads it back as the same poses
    head, first = plan_csv(res).splitlines()[:2]
    assert head.split(",")[:3] == ["pose_id", "q1_mm", "q2_deg"]
    assert float(first.split(",")[1]) == np.round(res.q[0, 0], 6)


def test_a_coupled_robots_plan_is_written_as_reported_and_read_back_by_the_twin(tmp_path):
    """FANUC-style J2/J3: the plan draws inside the controller's limits (reported), plans with the kinematic
    angles, writes plan.csv as reported, and the twin measuring it has the planned kinematic angles."""
    import yaml

    from robocal.data import read_campaign
    from robocal.robot import SHIPPED_ROBOT_DIR, robot_from_dict
    from robocal.sim.twin import load_scenario, simulate

    data = yaml.safe_load((SHIPPED_ROBOT_DIR / "kr16_2.yaml").read_text())
    data["coupling"] = "fanuc_j2j3"
    robot = robot_from_dict(data, "kr16_2_fanuc.yaml")
    res = planner.plan_poses(robot, {"n_poses": 20, "n_candidates": 800, "region": {"n": 30}}, curve=False)
    (tmp_path / "plan.csv").write_text(plan_csv(res))
    rep = np.loadtxt(tmp_path / "plan.csv", delimiter=",", skiprows=1, usecols=range(1, 7))
    lim = np.rad2deg(robot.q_limits)
    assert np.all((rep >= lim[:, 0]) & (rep <= lim[:, 1]))  # the controller's values, inside its limits
    assert np.allclose(rep[:, 2], np.rad2deg(res.q[:, 2] + res.q[:, 1]), atol=1e-5)  # J3 reported from the horizon
    sc = dict(load_scenario("geometric"), poses_deg=str(tmp_path / "plan.csv"), n_validation_poses=0)
    simulate(sc, tmp_path / "twin", robot=robot)
    camp = read_campaign(tmp_path / "twin", robot)
    assert np.abs(camp.q - res.q).max() < 1e-7  # the planned kinematic angles, to the files' 1e-6 deg
