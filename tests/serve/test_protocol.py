"""The correct op: corrected joints reach the nominal pose on the bundle's model; safety refusals and flags."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import LOADERS
from robocal.compensation import ActualRobot, desired_poses
from robocal.serve.bundle import load_bundle
from robocal.serve.protocol import SafetyConfig, Service, ServiceConfig

Q1 = [10.0, -80.0, 60.0, 20.0, 40.0, 30.0]
Q2 = [-35.0, -100.0, 80.0, -60.0, -50.0, 120.0]


def _ask(svc, req):
    return json.loads(svc.handle_line(json.dumps(req).encode()))


@pytest.fixture(scope="module")
def full(full_bundle):
    return load_bundle(full_bundle, loaders=LOADERS)


def _temps(b, value=30.0):
    return {s: value for s in b.sensors}


def test_corrected_joints_reach_nominal_pose(full):
    svc = Service(full)
    temps = _temps(full)
    r = _ask(svc, {"temperatures": temps, "payload_kg": 4.0, "targets": [{"q_deg": Q1}, {"q_deg": Q2}]})
    assert r["ok"] and r["n_refused"] == 0, r
    # independent check with the reference model: thermal drift + deflection, tracker frame
    eta = full.eta0 + full.thermal.deta(np.array([[temps[s] for s in full.sensors]]))[0]
    tool = full.tools["T1"]
    pay = np.full(1, 4.0)

    def defl(q):
        return full.compliance.joint_offsets(q, np.resize(pay, len(q)), None, None)

    actual = ActualRobot(full.chain, eta, full.tracker_T_base, tool[:3, 3], tool[:3, :3], defl)
    nominal = ActualRobot(full.chain, np.zeros_like(eta), full.tracker_T_base, tool[:3, 3], tool[:3, :3])
    q_t = np.deg2rad([Q1, Q2])
    p_d, _ = desired_poses(nominal, q_t)
    q_c = np.deg2rad([res["q_deg"] for res in r["results"]])
    p, _, _ = actual.pose(q_c)
    # solver tolerance 1e-4 mm, joints rounded to 1e-9 deg in the reply (~3e-8 mm at 2 m)
    assert np.abs(p - p_d).max() < 2e-4
    p0, _, _ = actual.pose(q_t)
    before = np.linalg.norm(p0 - p_d, axis=1)
    assert np.allclose([res["predicted_error_mm"] for res in r["results"]], before, atol=1e-6)
    assert before.min() > 0.05  # the stand-in drift and calibrated errors are a real correction


def test_pose_target_equals_joint_target(full):
    svc = Service(full)
    r_j = _ask(svc, {"temperatures": _temps(full), "targets": [{"q_deg": Q1}]})
    cmd = r_j["results"][0]
    # the nominal pose of Q1 (base frame) asked as a Cartesian target, IK seeded 5 deg away
    from robocal.kinematics.transforms import matrix_to_quat
    from robocal.serve.engine import compile_chain, forward

    p, R, _, _ = forward(compile_chain(full.chain), np.deg2rad([Q1]), full.tools["T1"])
    seed = (np.array(Q1) + 5.0).tolist()
    t = {"xyz_mm": p[0].tolist(), "quat_wxyz": matrix_to_quat(R)[0].tolist(), "q_seed_deg": seed}
    r_p = _ask(svc, {"temperatures": _temps(full), "targets": [t]})["results"][0]
    assert r_p["status"] == "ok"
    # nominal IK recovers Q1 and the corrected joints agree (solver tolerance 1e-4 mm -> ~1e-7 deg)
    assert np.abs(np.array(r_p["q_nominal_deg"]) - Q1).max() < 1e-5
    assert np.abs(np.array(r_p["q_deg"]) - cmd["q_deg"]).max() < 1e-5


def _nominal_pose(full, q_deg):
    from robocal.serve.engine import compile_chain, forward

    p, R, _, _ = forward(compile_chain(full.chain), np.deg2rad([q_deg]), full.tools["T1"])
    return p[0], R[0]


def _lands(full, temps, res) -> float:
    """How far (mm) the calibrated robot at the reply's corrected joints is from where the nominal controller
    puts the tool at the reply's nominal joints (tracker frame; payload 0)."""
    eta = full.eta0 + full.thermal.deta(np.array([[temps[s] for s in full.sensors]]))[0]
    tool = full.tools["T1"]

    def defl(q):
        return full.compliance.joint_offsets(q, np.zeros(len(q)), None, None)

    actual = ActualRobot(full.chain, eta, full.tracker_T_base, tool[:3, 3], tool[:3, :3], defl)
    nominal = ActualRobot(full.chain, np.zeros_like(eta), full.tracker_T_base, tool[:3, 3], tool[:3, :3])
    p_d, _ = desired_poses(nominal, np.deg2rad([res["q_nominal_deg"]]))
    p, _, _ = actual.pose(np.deg2rad([res["q_deg"]]))
    return float(np.linalg.norm(p - p_d))


def test_position_mode_takes_a_target_without_orientation(full):
    """A 3-DoF reflector or a drilling point: xyz only, in mode 'position' (issue 30, item 6: it was "quat_wxyz
    must be a list of 4 numbers"). Mode 'pose' still needs the orientation and says which mode to use."""
    svc = Service(full)
    temps = _temps(full)
    p0, _ = _nominal_pose(full, Q1)
    seed = (np.array(Q1) + 3.0).tolist()
    target = {"xyz_mm": p0.tolist(), "q_seed_deg": seed}
    r = _ask(svc, {"temperatures": temps, "targets": [target]})
    assert r["ok"] is False and r["error"]["code"] == "bad_request", r
    assert "quat_wxyz" in r["error"]["message"] and '"mode": "position"' in r["error"]["message"]
    r = _ask(svc, {"temperatures": temps, "mode": "position", "targets": [target, {"q_deg": Q2}]})
    assert r["ok"] and r["n_refused"] == 0, r
    res = r["results"][0]
    assert res["status"] == "ok" and "notes" not in res, res
    # the nominal joints put the tool at the asked position (solver tolerance 1e-4 mm)
    p_nom, _ = _nominal_pose(full, res["q_nominal_deg"])
    assert np.linalg.norm(p_nom - p0) < 2e-4
    # the orientation is free: the position-only solution stays nearer the seed than the full pose Q1 does
    assert np.abs(np.array(res["q_nominal_deg"]) - seed).sum() < np.abs(np.array(Q1) - seed).sum()
    # and the corrected joints land the calibrated robot there (solver tolerance 1e-4 mm + reply rounding)
    assert _lands(full, temps, res) < 2e-4
    assert res["predicted_error_mm"] > 0.05  # a real correction, not a no-op
    # the orientation is not matched in this mode: its errors are null, not 0.0 (read as "no orientation error")
    assert res["predicted_error_deg"] is None and res["residual_deg"] is None


def test_position_mode_gives_up_an_orientation_the_robot_cannot_take(full):
    """In mode 'position' an orientation the robot cannot take at the position does not make the target
    unreachable: it is solved for the position only, with a note; a reachable one is kept as before."""
    from robocal.kinematics.transforms import matrix_to_quat

    svc = Service(full)
    temps = _temps(full)
    p0, R0 = _nominal_pose(full, Q1)
    # the tool turned a quarter turn about its x axis (not half a turn: the solver's orientation error
    # vee(E - E^T) / 2 vanishes at 180 deg, so it takes a half-turned tool for the pose itself)
    turn = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    bad = {"xyz_mm": p0.tolist(), "quat_wxyz": matrix_to_quat(R0 @ turn).tolist(), "q_seed_deg": Q1}
    r = _ask(svc, {"temperatures": temps, "targets": [bad]})
    res = r["results"][0]
    assert res["status"] == "refused" and "unreachable" in res["reasons"][0], r  # the premise: as a full pose
    r = _ask(svc, {"temperatures": temps, "mode": "position", "targets": [bad]})
    res = r["results"][0]
    assert res["status"] == "ok", res
    assert any("solved for the position only" in n for n in res["notes"]), res
    p_nom, _ = _nominal_pose(full, res["q_nominal_deg"])
    assert np.linalg.norm(p_nom - p0) < 2e-4
    assert _lands(full, temps, res) < 2e-4
    # a reachable orientation in mode 'position' is still the nominal IK's full pose (Q1), without a note
    good = {"xyz_mm": p0.tolist(), "quat_wxyz": matrix_to_quat(R0).tolist(), "q_seed_deg": (np.array(Q1) + 3).tolist()}
    res = _ask(svc, {"temperatures": temps, "mode": "position", "targets": [good]})["results"][0]
    assert res["status"] == "ok" and "notes" not in res
    assert np.abs(np.array(res["q_nominal_deg"]) - Q1).max() < 1e-5  # IK tolerance 1e-4 mm -> ~1e-7 deg


def test_refusals_and_flags(full):
    temps = _temps(full)
    svc = Service(full)
    lim = np.rad2deg(full.robot.q_limits)
    out = list(Q1)
    out[1] = lim[1, 1] + 1.0  # joint 2 beyond its upper limit
    r = _ask(svc, {"temperatures": temps, "targets": [{"q_deg": out}, {"q_deg": Q1}]})
    a, b = r["results"]
    assert a["status"] == "refused" and "joint limits" in a["reasons"][0] and "q_deg" not in a
    assert b["status"] == "ok" and r["n_refused"] == 1
    # temperatures outside the fitted range: every target refused, the sensor named
    hot = dict(temps, T_j2_C=60.0)
    r = _ask(svc, {"temperatures": hot, "targets": [{"q_deg": Q1}]})
    assert r["results"][0]["status"] == "refused" and "T_j2_C=60.00" in r["results"][0]["reasons"][0]
    # flag instead of refuse: values are returned with the reason
    flag = Service(full, ServiceConfig(safety=SafetyConfig(on_temperature_range="flag", max_correction_deg=1e-6)))
    r = _ask(flag, {"temperatures": hot, "targets": [{"q_deg": Q1}]})
    res = r["results"][0]
    assert res["status"] == "refused" and any("exceeds the bound" in x for x in res["reasons"])
    flag = Service(
        full,
        ServiceConfig(
            safety=SafetyConfig(on_temperature_range="flag", on_correction_bound="flag", max_correction_deg=1e-6)
        ),
    )
    res = _ask(flag, {"temperatures": hot, "targets": [{"q_deg": Q1}]})["results"][0]
    assert res["status"] == "flagged" and len(res["reasons"]) == 2 and "q_deg" in res


@pytest.mark.parametrize(
    ("req", "code", "words"),
    [
        ({"targets": [{"q_deg": Q1}]}, "bad_request", "temperatures"),
        ({"temperatures": {"T_j1_C": 20}, "targets": [{"q_deg": Q1}]}, "bad_request", "lacks sensor"),
        ({"temperatures": [20.0] * 9, "targets": [{"q_deg": Q1[:5]}]}, "bad_request", "targets[0].q_deg"),
        ({"temperatures": [20.0] * 9, "targets": [{"q_deg": Q1}], "tool": "T9"}, "bad_request", "tool"),
        ({"temperatures": [20.0] * 9, "targets": []}, "bad_request", "non-empty"),
        ({"op": "fly"}, "unknown_op", "fly"),
        ({"temperatures": [20.0] * 9, "targets": [{"q_deg": [True] * 6}]}, "bad_request", "number"),
        # a JSON integer beyond the float range is a bad value, not a server error
        ({"temperatures": [20.0] * 9, "targets": [{"q_deg": [*Q1[:5], 10**400]}]}, "bad_request", "q_deg[5]"),
    ],
)
def test_bad_requests_name_the_field(full, req, code, words):
    r = _ask(Service(full), {"id": "x", **req})
    assert r["ok"] is False and r["error"]["code"] == code and words in r["error"]["message"] and r["id"] == "x"


def test_token_required_once_per_session(full):
    svc = Service(full, ServiceConfig(token="s3cret"))
    session: dict = {}
    r = json.loads(svc.handle_line(b'{"op": "ping"}', session))
    assert r["error"]["code"] == "unauthorized"
    r = json.loads(svc.handle_line(b'{"op": "auth", "token": "wrong"}', session))
    assert r["error"]["code"] == "unauthorized"
    assert json.loads(svc.handle_line(b'{"op": "auth", "token": "s3cret"}', session))["ok"]
    assert json.loads(svc.handle_line(b'{"op": "ping"}', session))["ok"]
    assert json.loads(svc.handle_line(b'{"op": "ping"}', {}))["error"]["code"] == "unauthorized"
