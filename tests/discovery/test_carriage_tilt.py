"""A carriage inclinometer on a linear axis (issue 33 item 1, newcomer pass 17): the carriage of the axis carrying
the arm turns about its own origin, which travels with the axis; a logged signal is offered as that rotation
(``signal:<col>:carriage_rot``), found on the twin's track laid in segments, and compensated about the carriage's
origin by compensation.csv and the service. A fixed base's tilt could not follow it: the gain came out at 0.17
(0.75 on the newcomer's 5 m track) and the held-out error 6x the floor."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from robocal.compensation.discovered import frame_transforms
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.logged import frame_columns
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors
from robocal.identification.model import CalibrationModel, FitData
from robocal.kinematics.axes import carriage_origin, carrying_axis
from robocal.kinematics.transforms import rotvec_to_matrix
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario

from .conftest import make_campaign

#: conf/scenario/track.yaml: 0.015 mm per coordinate; the mean 3-D error of pure noise is 1.596 sigma
FLOOR_MEAN_MM = 1.596 * 0.015
#: the rail's pitch and yaw (RMS 150 / 60 urad over 4 segments: up to ~0.7 mm at the tool 1.5 m from the carriage)
RAIL = {"segments": 4, "pitch_urad": 150.0, "yaw_urad": 60.0}


def _effects(inclinometer: bool) -> dict:
    eff = copy.deepcopy(load_scenario("track")["effects"])
    eff["linear_axis"]["rail"] = RAIL
    if inclinometer:
        eff["linear_axis"]["inclinometer"] = {"noise_urad": 2.0}
    return eff


def test_a_carriage_rotation_is_the_rotation_about_its_travelling_origin():
    """The regressor is the first-order change of the model's prediction when the arm turns about the carriage's
    origin (exact prediction), and the compensation's transform is that rotation."""
    robot = load_robot("kr16_2_track")
    j = carrying_axis(robot)
    assert j == 0
    rng = np.random.default_rng(2)
    q = rng.uniform(-1, 1, (6, robot.n_joints))
    q[:, 0] = rng.uniform(500.0, 5500.0, 6)  # mm along the track
    model = CalibrationModel(robot, ("T1",))
    x = model.zeros()
    x[model.index("tool_T1_x") : model.index("tool_T1_x") + 3] = [35.0, -20.0, 120.0]
    ti = np.zeros(6, dtype=int)
    _, J = model.residuals_and_jacobian(x, FitData(q, np.zeros((6, 3)), ti))
    c = carriage_origin(robot, q, j)
    assert np.ptp(c[:, 0] ** 2 + c[:, 1] ** 2 + c[:, 2] ** 2) > 1e6  # the pivot travels metres
    G = frame_columns("carriage_rot", J.reshape(6, 3, model.n), model.names, model.tools(x), ti, c)
    w = np.array([2e-6, -3e-6, 1e-6])
    T = model.base_transform(x)
    p = model.predict(x, q, ti)[0]
    pb = (p - T[:3, 3]) @ T[:3, :3]  # base frame
    turned = (pb - c) @ rotvec_to_matrix(w).T + c
    dp = turned @ T[:3, :3].T + T[:3, 3] - p
    assert np.allclose(G @ w, dp, atol=1e-8)  # first order: the second-order term is |w|² |p - c| ~ 1e-8 mm
    rec = {"key": "k", "signal": "logged_frame", "frame": "carriage_rot", "column": "s", "centre": 0.0,
           "coefficients": w.tolist(), "axis_joint": j + 1}  # fmt: skip
    A, D = frame_transforms([rec], {"s": np.ones(6)}, 6, q, robot)
    assert np.allclose(np.einsum("mij,mj->mi", A[:, :3, :3], pb) + A[:, :3, 3], turned, atol=1e-9)
    assert np.allclose(D, np.eye(4))
    with pytest.raises(ValueError, match="turns a carriage"):
        frame_transforms([rec], {"s": np.ones(6)}, 6)


def test_a_carriage_inclinometer_is_found_as_the_carriage_rotation_and_held_out_at_the_floor(tmp_path):
    camp, robot, _ = make_campaign(tmp_path, "track", 0, _effects(True), n_poses=60, n_validation_poses=20)
    res = discover(camp, robot, DiscoveryConfig(layer=False, dictionary=False))
    v = validation_errors(res)
    s = summary(res, v)
    keys = {n["key"] for n in s["named"]}
    assert {"signal:carriage_incl_x:carriage_rot", "signal:carriage_incl_y:carriage_rot"} <= keys, keys
    assert not any(k.endswith(":base_rot") for k in keys)
    # the carriage's x is the base's x (conf/robot/kr16_2_track.yaml): the pitch reading is the rotation about it,
    # gain 1 within 3 standard errors (one seed, ~6 coefficients tested together)
    est = next(n for n in s["named"] if n["key"] == "signal:carriage_incl_x:carriage_rot")["estimates"]["rx_gain"]
    assert abs(est["value"] - 1.0) < 3.0 * est["stderr"], est
    # held-out within 15 % of the noise floor (20 poses, the parameters' own error); the geometry alone 10x it
    assert v["final"]["mean_position_mm"] < 1.15 * FLOOR_MEAN_MM < v["geometric"]["mean_position_mm"] / 5


def test_compensation_csv_and_the_service_turn_the_carriage_back(tmp_path):
    """compensation.csv corrects each validation target with the carriage turned by its inclinometer reading
    about its origin (the Newton solve on the calibrated model, frames included, converged), the corrections move
    with the reading, and the service gives the same joints from the signals sent with each target (and refuses
    a target without them)."""
    import pandas as pd

    from robocal.serve.bundle import load_bundle, write_bundle
    from robocal.serve.protocol import Service
    from robocal.workflows.discovery import run

    camp, robot, _ = make_campaign(tmp_path, "track", 0, _effects(True), n_poses=60, n_validation_poses=20)
    out = tmp_path / "out"
    s = run(None, robot, out, {"layer": False, "dictionary": False}, campaign=camp, report=False)
    assert "compensation.csv" in s["written"]
    data = json.loads((out / "calibration.json").read_text())
    frames = [e for e in data["effects"] if e["signal"] == "logged_frame"]
    assert {e["frame"] for e in frames} == {"carriage_rot"} and all(e["axis_joint"] == 1 for e in frames)
    comp = pd.read_csv(out / "compensation.csv")
    ok = (comp["status"] != "refused").to_numpy()  # flagged: a correction over the 0.5 deg bound (random geometry)
    assert ok.sum() >= 10 and (comp.loc[ok, "pred_err_mm"] < 1e-3).all()
    val = camp.validation()
    cols = ("carriage_incl_x", "carriage_incl_y")
    svc = Service(load_bundle(write_bundle(tmp_path / "bundle", "kr16_2_track", out / "calibration.json")))
    k_ok = np.flatnonzero(ok)[:4]
    targets = [
        {"q_deg": np.rad2deg(val.q[k, 1:]).tolist(), "ext_mm": [float(val.q[k, 0])],
         "signals": {c: float(np.asarray(val.extra[c], dtype=float)[k]) for c in cols}}
        for k in k_ok
    ]  # fmt: skip
    r = json.loads(svc.handle_line(json.dumps({"op": "correct", "mode": "position", "targets": targets}).encode()))
    assert r["ok"], r
    # the one compensation path and the one policy (csv: 6 decimals)
    assert [res["status"] for res in r["results"]] == comp.loc[k_ok, "status"].tolist(), r
    q_csv = comp.loc[k_ok, [f"q{j}_deg" for j in range(2, 8)]].to_numpy()
    assert np.allclose([res["q_deg"] for res in r["results"]], q_csv, atol=1e-5), (r, q_csv)
    for t in targets:  # the carriage level: other corrections, by the tilt's lever (~0.1-0.7 mm at the tool)
        t["signals"] = {c: float(np.mean(np.asarray(val.extra[c], dtype=float))) for c in cols}
    flat = json.loads(svc.handle_line(json.dumps({"op": "correct", "mode": "position", "targets": targets}).encode()))
    moved = [np.abs(np.subtract(a["q_deg"], b["q_deg"])).max()
             for a, b in zip(r["results"], flat["results"], strict=True) if "q_deg" in a and "q_deg" in b]  # fmt: skip
    assert max(moved) > 1e-3, moved  # deg
    for t in targets:
        del t["signals"]
    r = json.loads(svc.handle_line(json.dumps({"op": "correct", "mode": "position", "targets": targets}).encode()))
    assert r["error"]["code"] == "bad_request" and "signals.carriage_incl_" in r["error"]["message"], r


def test_a_rail_inclinometers_gaps_are_filled_along_the_track():
    """Newcomer pass 17 (D2): the poses jump along the rail in time, and the rail's pitch follows where the carriage
    is: its empty cells were filled from the pose and time (0.0055 deg, the signal's spread 0.0098), along the
    track 0.0020. Each pose is read once for its two reflectors: its leave-one-out error is taken from the
    neighbouring positions only (from its own other row it was ~0)."""
    from robocal.discovery.logged import fill_gaps

    rng = np.random.default_rng(5)
    n_pose = 90
    s = np.repeat(rng.uniform(0.0, 5000.0, n_pose), 2)  # mm: two reflector rows per pose
    t = np.arange(2 * n_pose) * 30.0  # s: the poses in random order along the rail
    knots = np.linspace(0.0, 5000.0, 5)
    truth = np.interp(s, knots, rng.normal(0.0, 0.01, 5))  # deg: a rail in 4 straight segments
    x = truth + np.repeat(rng.normal(0.0, 0.0003, n_pose), 2)  # one reading per pose
    miss = np.zeros(2 * n_pose, dtype=bool)
    miss[np.repeat(rng.choice(n_pose, 9, replace=False) * 2, 2) + np.tile([0, 1], 9)] = True
    xm = np.where(miss, np.nan, x)
    B = np.column_stack([np.ones(2 * n_pose), rng.normal(size=(2 * n_pose, 3))])  # a pose basis that cannot hold it
    filled, how = fill_gaps(xm, t, B, {"E1": s})
    assert how["way"] == "linear interpolation along E1 between the readings" and how["rows"] == 18
    err = float(np.sqrt(np.mean((filled[miss] - truth[miss]) ** 2)))
    # the fill's error on the truth is near its stated leave-one-out figure (the readings' noise, 0.0003, in it),
    # and far below the time's (the neighbours in time are anywhere on the rail)
    assert err < 2.0 * how["loo_rms"] and how["loo_rms"] > 0.0003  # from its own pose's other row: 0
    _, by_time = fill_gaps(xm, t, B)
    assert by_time["loo_rms"] > 5 * how["loo_rms"], (by_time, how)
