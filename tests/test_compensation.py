"""Differential error compensation reaches the nominal pose on a robot with known errors."""

from __future__ import annotations

import numpy as np

from robocal.compensation import ActualRobot, compensate, desired_poses, write_compensation_csv
from robocal.kinematics.chain import build_chain
from robocal.kinematics.transforms import homogeneous, rotvec_to_matrix


def _robots(robot, rng, deflection=None):
    chain = build_chain(robot)
    T = homogeneous(rotvec_to_matrix([0.01, -0.02, 2.0]), [2000.0, 500.0, -300.0])
    tool = np.array([20.0, -5.0, 150.0])
    nominal = ActualRobot(chain, np.zeros(chain.n_params), T, tool, np.eye(3))
    eta = np.where(
        np.array(chain.param_kind) == "length",
        rng.normal(0, 0.5, chain.n_params),
        rng.normal(0, np.deg2rad(0.05), chain.n_params),
    )
    return nominal, ActualRobot(chain, eta, T, tool, np.eye(3), deflection)


def test_full_pose_compensation_converges(kr16):
    rng = np.random.default_rng(0)
    nominal, actual = _robots(kr16, rng)
    q = rng.uniform(kr16.q_limits[:, 0], kr16.q_limits[:, 1], (30, 6)) * 0.7
    # keep the wrist away from its singularity (q5 = 0), where q4 and q6 trade off (see the next test)
    q[:, 4] = np.where(np.abs(q[:, 4]) < np.deg2rad(20), np.deg2rad(20) * np.sign(q[:, 4] + 1e-12), q[:, 4])
    p_d, R_d = desired_poses(nominal, q)
    comp = compensate(actual, q, p_d, R_d)
    assert np.linalg.norm(comp.error_before_mm, axis=1).mean() > 0.5  # errors of 0.5 mm / 0.05 deg
    assert comp.converged.all()
    # Newton on a smooth map converges quadratically: 1e-7 mm is reached in a few iterations
    assert np.abs(comp.residual_mm).max() < 1e-6 and np.abs(comp.residual_rad).max() < 1e-8
    # quadratic once close; the first steps are linear where the wrist is only 20 deg from its singularity
    assert comp.iterations <= 10
    # ~0.1 deg of orientation error needs wrist corrections of ~0.1 deg / sin(q5): at |q5| >= 20 deg that is
    # below ~0.3 deg typically and 1.3 deg at worst here; 3 deg would mean a wrong branch or a diverging step
    assert np.abs(comp.q - q).max() < np.deg2rad(3.0)


def test_near_the_wrist_singularity_the_correction_is_large(kr16):
    """Close to q5 = 0 a full-pose correction must turn q4 and q6 a lot. The one Newton of robocal (the
    service's: steps clipped, a target whose error stops halving stops) reports it unconverged instead of
    swinging the wrist, so the controller CSV and the service agree: such a pose is never corrected silently.
    (Before the solvers were unified, the offline pseudo-inverse Newton "converged" here with ~8.5 deg wrist
    swings while the service refused the same target.)"""
    from robocal.serve.engine import compile_chain, solve

    rng = np.random.default_rng(0)
    nominal, actual = _robots(kr16, rng)
    q = np.deg2rad([[-34.0, -94.5, 34.1, 50.0, -0.5, 40.0]])
    p_d, R_d = desired_poses(nominal, q)
    comp = compensate(actual, q, p_d, R_d, max_iter=30)
    assert not comp.converged.any()
    # what it attempted: q4/q6 motion growing like 1/sin(q5), tens of times the 0.05 deg error at q5 = -0.5 deg
    assert np.abs((comp.q - q)[0, [3, 5]]).max() > np.deg2rad(0.5)
    # the service's engine, called directly on the same robot, stops at the same joints
    T_tool = homogeneous(actual.tool_R, actual.tool_mm)
    sol = solve(compile_chain(actual.chain, actual.eta, actual.tracker_T_base), T_tool, q, p_d, R_d, max_iter=30,
                tol_mm=1e-7, tol_rad=1e-9)  # fmt: skip
    assert np.array_equal(sol.q, comp.q) and not sol.converged.any()


def test_position_only_and_joint_deflection(kr16, tmp_path):
    rng = np.random.default_rng(1)
    c = np.array([0, 2e-4, 1.5e-4, 0, 1e-4, 0])

    def sag(q):  # a pose-dependent deflection, like gravity on joints 2/3/5
        return -c * np.cos(q)

    nominal, actual = _robots(kr16, rng, sag)
    q = rng.uniform(-1, 1, (10, 6))
    p_d, _ = desired_poses(nominal, q)
    comp = compensate(actual, q, p_d)
    assert np.abs(comp.residual_mm).max() < 1e-5
    path = write_compensation_csv(
        tmp_path / "c.csv",
        [f"t{k}" for k in range(10)],
        comp.q,
        np.repeat(np.eye(4)[None], 10, 0),
        comp.residual_mm,
    )
    lines = path.read_text().splitlines()
    assert lines[0].startswith("target_id,status,applied,q1_deg") and len(lines) == 11  # the one layout


def test_a_plain_joint_offset_callable_answers_every_configuration_asked(kr16):
    """``ActualRobot.joint_offset`` may be a plain ``q -> dq`` callable over every target (per-target signals).
    The two-stage solve asks for each target at n + 1 configurations in one call (its forward-difference
    Jacobian): each must be evaluated, not the last one for all (the Jacobian was then the identity, and the
    joint-space inversion a slower fixed-point iteration that fails on strong effects)."""
    from robocal.compensation import _rows_of
    from robocal.kinematics.ik import offsets_and_jacobian

    rng = np.random.default_rng(3)
    q = rng.uniform(-2.0, 2.0, (5, 6))
    hook = _rows_of(lambda qq: 0.3 * np.sin(qq), q)
    d, J = offsets_and_jacobian(hook, q)
    assert np.array_equal(d, 0.3 * np.sin(q))
    # I + diag(0.3 cos q): forward differences with a 1e-6 rad step are within ~1e-7 of it
    assert np.abs(J - (np.eye(6) + np.einsum("mj,jk->mjk", 0.3 * np.cos(q), np.eye(6)))).max() < 1e-6
    nominal, actual = _robots(kr16, rng, deflection=lambda qq: 0.1 * np.sin(qq))
    qt = rng.uniform(kr16.q_limits[:, 0], kr16.q_limits[:, 1], (20, 6)) * 0.5
    qt[:, 4] = np.where(np.abs(qt[:, 4]) < np.deg2rad(20), np.deg2rad(20) * np.sign(qt[:, 4] + 1e-12), qt[:, 4])
    p_d, R_d = desired_poses(nominal, qt)
    comp = compensate(actual, qt, p_d, R_d)
    assert comp.converged.all()
    assert np.abs(desired_poses(actual, comp.q)[0] - p_d).max() < 1e-6  # mm; the solver's tolerance is 1e-7
