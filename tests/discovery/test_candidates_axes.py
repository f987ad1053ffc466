"""Issue 34, discovery: a linear axis's own errors offered as named candidates (``track:straightness_y``,
``column:bending``) and found on the twin's track and column scenarios; a robot without one gets none."""

from __future__ import annotations

import numpy as np
import pytest

import robocal
from robocal.discovery.candidates import build_library
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors

from .conftest import make_campaign

NOISE_MM = 0.015  # conf/scenario/track.yaml, column.yaml
FLOOR_MEAN_MM = NOISE_MM * np.sqrt(8 / np.pi)  # mean length of a 3-D Gaussian error: a complete model's held-out


def test_the_library_offers_a_tracks_errors_by_name_and_none_to_an_arm_alone(tmp_path):
    cfg = DiscoveryConfig()
    camp, robot, _ = make_campaign(tmp_path, "track", 0, n_poses=20, n_validation_poses=0)
    cands, _ = build_library(camp, robot, cfg)
    axis = {c.key: c for c in cands if c.effect == "axis"}
    assert sorted(axis) == sorted(
        f"track:{c}" for c in ("straightness_x", "straightness_y", "positioning", "pitch", "yaw", "roll")
    )
    assert axis["track:straightness_y"].coef_names == ("P2", "P3")  # P0, P1: the kinematic parameters hold them
    assert axis["track:pitch"].coef_names == ("P1", "P2", "P3")
    camp2, robot2, _ = make_campaign(tmp_path, "geometric", 0, n_poses=20, n_validation_poses=0)
    cands2, skipped2 = build_library(camp2, robot2, cfg)
    assert not [c for c in cands2 if c.effect == "axis"] and not [s for s in skipped2 if s.effect == "axis"]


def _discover(tmp_path, scenario: str, n_poses: int):
    camp, robot, truth = make_campaign(tmp_path, scenario, 0, n_poses=n_poses, n_validation_poses=15)
    res = robocal.discover(camp, robot, DiscoveryConfig.from_mapping({"report": False}))
    v = validation_errors(res)
    return res, summary(res, v), v, truth


def _within(named: list, truth: dict) -> None:
    """Every estimate of the named axis effects against the truth: |z| < 3.5 (~10 coefficients, fixed seed)."""
    for nm in named:
        for coef, est in nm["estimates"].items():
            f = 1.0 if est["unit"] == "mm" else 1e-6
            name = f"{nm['key']}_{coef}" if coef.startswith("P") else f"{nm['key'].split(':')[0]}:{coef}"
            z = (est["value"] * f - truth["axis_errors"].get(name, 0.0)) / (est["stderr"] * f)
            assert abs(z) < 3.5, (name, est, truth["axis_errors"].get(name))


def test_discovery_finds_the_tracks_straightness_and_pitch(tmp_path):
    res, s, v, truth = _discover(tmp_path, "track", 45)
    keys = sorted(a.cand.key for a in res.accepted)
    assert keys == ["track:pitch", "track:straightness_x", "track:straightness_y"]
    _within([n for n in s["named"] if n["effect"] == "axis"], truth)
    # held-out at the noise floor (within 15 %: 15 poses and the parameters' own error), far below the geometry's
    assert v["final"]["mean_position_mm"] < 1.15 * FLOOR_MEAN_MM < v["geometric"]["mean_position_mm"] / 3
    rec = next(n for n in s["named"] if n["key"] == "track:straightness_y")
    assert rec["estimates"]["P2"]["unit"] == "mm" and rec["rms_of_effect_mm"] > 0.05


@pytest.mark.slow
def test_discovery_finds_the_columns_bending_and_lean(tmp_path):
    res, s, v, truth = _discover(tmp_path, "column", 40)
    keys = sorted(a.cand.key for a in res.accepted)
    assert keys == ["column:bending", "column:pitch", "column:yaw"]
    _within([n for n in s["named"] if n["effect"] == "axis"], truth)
    assert v["final"]["mean_position_mm"] < 1.15 * FLOOR_MEAN_MM < v["geometric"]["mean_position_mm"] / 3
    # the axis errors are no joint-level effect: said so, and written under the calibration's 'axes' instead
    from robocal.discovery.effects import effect_records

    joint_level, other = effect_records(res.final)
    assert not joint_level
    assert {o["key"] for o in other} == set(keys) and "external axis" in other[0]["reason"]


def test_a_column_without_link_masses_is_offered_its_bending_per_unknown_mass_parameter(tmp_path):
    from dataclasses import replace

    from robocal.calibration.axes import mass_parameter_names

    camp, robot, _ = make_campaign(tmp_path, "column", 0)  # the scenario's 120 + 40 poses (with 60 the bending is not
    # told from a gear harmonic of joint 3)
    bare = replace(robot, link_mass_kg=None, link_com_mm=None)  # the description as a user may give it
    cands, skipped = build_library(camp, bare, DiscoveryConfig())
    bend = next(c for c in cands if c.key == "column:bending")
    params = mass_parameter_names(bare, 0)
    assert bend.coef_names == tuple(f"bending_{a}_{p}" for a in "xy" for p in params)
    assert not [s for s in skipped if s.key == "column:bending"]
    # on the twin (its column bends under the arm's weight) it is found without the masses, and beats the model
    # without it: seeds 0-2 held out 0.042 / 0.043 / 0.037 mm with it, 0.050 / 0.048 / 0.042 without (a gear
    # harmonic of joint 3 took its place); the geometric model 0.073-0.080
    res = robocal.discover(camp, bare, DiscoveryConfig.from_mapping({"dictionary": False}))
    assert "column:bending" in [a.cand.key for a in res.accepted]
    v = validation_errors(res)
    assert v["final"]["mean_position_mm"] < 0.6 * v["geometric"]["mean_position_mm"]
    # what the geometry cannot determine stays out of the extended model: the first arm joint's offset turns the arm
    # about a vertical axis as the base's yaw does; the carriage's tilt with the travel had let the rank test keep
    # it, and it was fitted 4.9 deg off (0.086 rad), its compensation 4.9 deg off on that joint
    geo = res.extra["geometric_calibration"]
    held = {e.name for e in geo.eliminated}
    assert "theta2" in held and held <= set(res.final.eliminated)
    assert res.final.theta[res.final.model.index("theta2")] == 0.0


def test_robocal_discover_on_a_track_names_the_axis_errors_and_compensates_with_the_track_kept(tmp_path):
    import pandas as pd

    from robocal.workflows.discovery import run

    camp, robot, _ = make_campaign(tmp_path, "track", 0, n_poses=40, n_validation_poses=10)
    out = tmp_path / "disc"
    summ = run(None, robot, out, {"report": False}, campaign=camp, report=False)
    assert {n["key"] for n in summ["named"]} == {"track:pitch", "track:straightness_x", "track:straightness_y"}
    assert "compensation.csv" in summ["written"] and not summ["not_written"]
    comp = pd.read_csv(out / "compensation.csv")
    assert list(comp.columns[3:5]) == ["q1_mm", "q2_deg"]  # the track in mm
    ok = comp["status"] != "refused"
    # judged by the service's safety policy (newcomer pass 17: the file said "ok" where the service refused): a
    # random validation pose may lie near a singular arm configuration (the stretched elbow), not converging, or
    # ask for more than the 0.5 deg bound (beyond the calibration's own zero offsets) the twin's random geometry
    # needs there: refused, as the service refuses it (4 of these 10; none refused but by those reasons)
    assert len(comp) == 10 and ok.sum() >= 5
    assert (comp.loc[~ok, "applied"] == 0).all() and (comp.loc[ok, "applied"] == 1).all()
    why = comp["reason"].fillna("")
    assert why[comp["status"] != "ok"].str.contains("did not converge|exceeds the bound").all()
    val = camp.validation()
    e1 = {f"{p}/{t}": q for p, t, q in zip(val.pose_id, val.target, val.q[:, 0], strict=True)}
    assert np.allclose(comp["q1_mm"], [e1[i] for i in comp["target_id"]], atol=1e-6)  # the track not moved
    assert (comp.loc[ok, "correction_max_deg"] > 0).all() and (comp.loc[ok, "pred_err_mm"] < 1e-3).all()
    # the discovered axis errors go with the calibration into the service's bundle (robocal serve)
    from robocal.serve.bundle import load_bundle, write_bundle

    bundle = load_bundle(write_bundle(tmp_path / "bundle", robot.name, out / "calibration.json"))
    served = {t.name.rsplit("_P", 1)[0] for t in bundle.axis_fit.terms}
    assert served == {"track:pitch", "track:straightness_x", "track:straightness_y"}


def test_a_linear_axis_gets_no_angle_harmonics(tmp_path):
    """A column's or a track's value is mm: the gear harmonics, the transmission error and the dictionary's
    harmonics of it were offered as sin(h q) of its mm (a random column, a burden on the multiple testing and a
    chance to be named). Its errors along the travel are the axis candidates; the arm's joints keep theirs."""
    from robocal.discovery.dictionary import build_dictionary
    from robocal.discovery.grow import physics_candidates

    cfg = DiscoveryConfig()
    camp, robot, _ = make_campaign(tmp_path, "column", 0, n_poses=60, n_validation_poses=0)
    assert robot.prismatic[0]
    cands, skipped = build_library(camp, robot, cfg)
    assert not [c for c in cands if c.effect == "gear" and c.joint == 1]
    assert {s.key for s in skipped if s.reason == "joint 1 is a linear axis"} == {"gear:j1:h1", "gear:j1:h2"}
    assert [c for c in cands if c.effect == "gear" and c.joint == 2]  # the arm's first joint keeps them
    physics = [c.key for c, _ in physics_candidates(camp, robot, cfg, np.arange(camp.n_rows))]
    assert "transmission:j2" in physics and "transmission:j1" not in physics
    dic = build_dictionary(camp, robot)
    assert all(f[1] != 1 for t in dic.terms for f in t.factors if f[0] in ("sin", "cos")), dic.terms[:3]


def test_the_axis_candidates_reach_the_order_calibrate_chooses(tmp_path):
    """Newcomer passes 17/18: a rail the search followed to Legendre order 3 held out 0.2638 mm where calibrate,
    its cross-validation picking order 4, gave 0.1879 (now 0.1928). A pitch of order 4 on the twin's track: the
    search's pitch candidate carries P4, and the held-out error is near calibrate's (the twin's 15 poses)."""
    import copy

    from robocal.discovery.axes import with_calibrate_order
    from robocal.sim.scenario import load_scenario

    eff = copy.deepcopy(load_scenario("track")["effects"])
    eff["linear_axis"]["legendre"]["pitch"] = {1: 40.0, 2: -25.0, 4: 60.0}  # urad
    camp, robot, _ = make_campaign(tmp_path, "track", 0, eff, n_poses=60, n_validation_poses=15)
    res = robocal.discover(camp, robot, DiscoveryConfig.from_mapping({"report": False}))
    v = validation_errors(res)
    pitch = next(a.cand for a in res.accepted if a.cand.key == "track:pitch")
    assert pitch.coef_names == ("P1", "P2", "P3", "P4"), pitch.coef_names
    assert v["final"]["mean_position_mm"] < 1.05 * v["geometric"]["with_axes"]["mean_position_mm"], v
    # a campaign whose axes calibrate fits to order 3 or less keeps the library's candidates as they are
    plain, robot2, _ = make_campaign(tmp_path, "track", 0, n_poses=40, n_validation_poses=10)
    lib = [object()]
    out, af = with_calibrate_order(lib, plain, robot2, None)
    assert out is lib and af is None  # no axis candidate: nothing fitted
