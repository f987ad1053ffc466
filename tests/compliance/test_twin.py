"""The heavy-load twin: plan (same poses at each load, ISO cube), currents with friction, deflection truth."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from robocal.compensation import ActualRobot, desired_poses
from robocal.kinematics.chain import build_chain
from robocal.kinematics.gravity import gravity_torques
from robocal.sim.compliance import iso9283_cube_points


def test_plan_measures_the_same_poses_at_every_load(twin_dirs, sr210) -> None:
    df = pd.read_csv(twin_dirs[0] / "poses.csv")
    cal = df[df.split == "calibration"]
    val = df[df.split == "validation"]
    assert sorted(cal.payload_kg.unique()) == [0.0, 210.0]
    assert sorted(val.payload_kg.unique()) == [0.0, 43.0, 128.0, 210.0]
    assert len(cal) == 2 * 30 and len(val) == 5 * 4
    qcols = [f"q{j}_deg" for j in range(1, 7)]
    # every pose id has one joint configuration, whatever the load
    assert (df.groupby("pose_id")[qcols].nunique() == 1).all().all()
    # the validation poses reach the ISO 9283 points with the nominal robot (IK to 1e-6 mm, joints rounded 1e-6 deg)
    truth = json.loads((twin_dirs[0] / "truth.json").read_text())
    v0 = val[val.payload_kg == 0].sort_values("pose_id")
    chain = build_chain(sr210)
    nominal = ActualRobot(chain, np.zeros(chain.n_params), np.eye(4), np.array(truth["tools_mm"]["T1"]), np.eye(3))
    p, _ = desired_poses(nominal, np.deg2rad(v0[qcols].to_numpy()))
    np.testing.assert_allclose(p, iso9283_cube_points(np.array([1800.0, 0, 1200]), 800.0), atol=1e-3)


def test_currents_carry_gravity_plus_friction(tmp_path, sr210, twin_factory) -> None:
    truth = twin_factory(tmp_path, seed=2, n_poses=8, current_noise_A=0.0)
    tc = truth["effects"]["compliance"]
    df = pd.read_csv(tmp_path / "poses.csv")
    q = np.deg2rad(df[[f"q{j}_deg" for j in range(1, 7)]].to_numpy())
    cur = df[[f"i{j}_A" for j in range(1, 7)]].to_numpy()
    dirs = df[[f"dir{j}" for j in range(1, 7)]].to_numpy()
    tau_g = gravity_torques(sr210, q, df.payload_kg.to_numpy(), link_mass_kg=np.array(tc["link_mass_true_kg"]))
    friction = -dirs * (np.array(tc["coulomb_Nm"]) + np.array(tc["viscous_Nm_s_per_deg"]) * tc["approach_speed_deg_s"])
    # CSV keeps 6 decimals of amperes: 5e-7 A × K (<= 480 N·m/A) ~ 2.4e-4 N·m
    np.testing.assert_allclose(cur * np.array(tc["K_Nm_per_A"]), tau_g + friction, atol=1e-3)
    # the true masses differ from the robot file's estimates (the gravity model's handicap)
    assert not np.allclose(tc["link_mass_true_kg"], sr210.link_mass_kg)


def test_same_seed_same_bytes(tmp_path, twin_factory) -> None:
    twin_factory(tmp_path / "a", seed=5, n_poses=6)
    twin_factory(tmp_path / "b", seed=5, n_poses=6)
    assert (tmp_path / "a" / "poses.csv").read_bytes() == (tmp_path / "b" / "poses.csv").read_bytes()
