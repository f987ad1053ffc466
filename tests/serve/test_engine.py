"""The service's compiled-chain Newton solver agrees with the reference robocal.compensation.compensate."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.compensation import ActualRobot, compensate, desired_poses
from robocal.kinematics.chain import build_chain
from robocal.kinematics.transforms import homogeneous, rotvec_to_matrix
from robocal.serve.engine import compile_chain, forward, rotation_error, solve


def _setup(robot, seed):
    rng = np.random.default_rng(seed)
    chain = build_chain(robot)
    T = homogeneous(rotvec_to_matrix([0.01, -0.02, 2.0]), [2000.0, 500.0, -300.0])
    tool, tool_R = np.array([20.0, -5.0, 150.0]), rotvec_to_matrix([0.1, -0.2, 0.3])
    kind = np.array(chain.param_kind)
    eta = np.where(
        kind == "length", rng.normal(0, 0.5, chain.n_params), rng.normal(0, np.deg2rad(0.05), chain.n_params)
    )
    nominal = ActualRobot(chain, np.zeros(chain.n_params), T, tool, tool_R)
    actual = ActualRobot(chain, eta, T, tool, tool_R)
    lim = robot.q_limits
    q = rng.uniform(lim[:, 0], lim[:, 1], (200, robot.n_joints)) * 0.7
    return chain, eta, T, homogeneous(tool_R, tool), nominal, actual, q


@pytest.mark.parametrize("robot_name", ["kr16", "abb_poe"])
def test_forward_matches_propagate(robot_name, request):
    robot = request.getfixturevalue(robot_name)
    chain, eta, T, tool_T, _, actual, q = _setup(robot, 0)
    cc = compile_chain(chain, eta, T)
    p, R, U, O = forward(cc, q, tool_T, record=True)
    p_ref, R_ref, _ = actual.pose(q)
    # two float64 evaluations of the same product of ~30 transforms: round-off only (1e-9 mm at 2 m)
    assert np.abs(p - p_ref).max() < 1e-8 and np.abs(R - R_ref).max() < 1e-12
    # joint axes: finite differences of the tool point along each joint
    h = 1e-6
    for j in range(robot.n_joints):
        dq = np.zeros_like(q)
        dq[:, j] = h
        p2, _, _, _ = forward(cc, q + dq, tool_T)
        num = (p2 - p) / h
        ana = np.cross(U[:, :, j], p - O[:, :, j])
        assert np.abs(num - ana).max() < 1e-3  # forward difference, O(h * |p|) = 1e-3 mm/rad


def _regular(robot, q):
    """Away from the KR16 elbow (q3 near -3 deg) and wrist (q5 = 0) singularities, where Newton is well posed."""
    deg = np.rad2deg(q)
    return (np.abs(deg[:, 2] + 3.0) > 15.0) & (np.abs(deg[:, 4]) > 15.0)


def test_full_pose_matches_reference(kr16):
    chain, eta, T, tool_T, nominal, actual, q = _setup(kr16, 1)
    q = q[_regular(kr16, q)]
    p_d, R_d = desired_poses(nominal, q)
    ref = compensate(actual, q, p_d, R_d)
    sol = solve(compile_chain(chain, eta, T), tool_T, q, p_d, R_d, tol_mm=1e-7, tol_rad=1e-10)
    assert sol.converged.all() and ref.converged.all()
    # both solve the same square system to 1e-7 mm; joint solutions then agree to that tolerance over the smallest
    # singular value of the joint Jacobian (>= ~1 mm/rad 15 deg away from the singularities): 1e-7 rad
    assert np.abs(sol.q - ref.q).max() < 1e-7
    assert np.abs(sol.error_before_mm - ref.error_before_mm).max() < 1e-8
    assert np.abs(sol.error_before_rad - ref.error_before_rad).max() < 1e-12
    assert sol.iterations <= 4  # quadratic convergence from ~1 mm errors


def test_position_only_is_minimum_norm_like_reference(kr16):
    chain, eta, T, tool_T, nominal, actual, q = _setup(kr16, 2)
    q = q[_regular(kr16, q)]
    p_d, _ = desired_poses(nominal, q)
    ref = compensate(actual, q, p_d)
    sol = solve(compile_chain(chain, eta, T), tool_T, q, p_d, None, tol_mm=1e-7)
    assert sol.converged.all()
    assert np.abs(sol.residual_mm).max() < 1e-7
    # Gauss-Newton minimum-norm steps from the same start: same solution up to second-order terms (1e-6 rad)
    assert np.abs(sol.q - ref.q).max() < 1e-6


def test_joint_deflection_matches_reference(kr16):
    chain, eta, T, tool_T, nominal, _, q = _setup(kr16, 3)
    q = q[_regular(kr16, q)][:50]
    c = np.array([0, 2e-4, 1.5e-4, 0, 1e-4, 0])

    def sag(qc):
        return -c * np.cos(qc)

    actual = ActualRobot(chain, eta, T, tool_T[:3, 3], tool_T[:3, :3], sag)
    p_d, R_d = desired_poses(nominal, q)
    ref = compensate(actual, q, p_d, R_d, max_iter=30)
    sol = solve(compile_chain(chain, eta, T), tool_T, q, p_d, R_d, lambda qc, rows: sag(qc), tol_mm=1e-7, tol_rad=1e-10)
    assert sol.converged.all()
    assert np.abs(sol.q - ref.q).max() < 1e-8  # same fixed point of a contraction, 1e-7 mm tolerance


def test_singular_target_stops_unconverged(kr16):
    chain, eta, T, tool_T, nominal, _, _ = _setup(kr16, 4)
    # the elbow stretched out (q3 at the elbow singularity) and the wrist straight (q5 = 0)
    q = np.deg2rad(np.array([[10.0, -60.0, -2.95, 30.0, 0.0, 10.0], [10.0, -60.0, 40.0, 30.0, 50.0, 10.0]]))
    p_d, R_d = desired_poses(nominal, q)
    sol = solve(compile_chain(chain, eta, T), tool_T, q, p_d, R_d, max_step_rad=0.05)
    assert not sol.converged[0] and sol.converged[1]
    # clipped steps and the stall rule keep the failed target near its start (< 20 steps of 0.05 rad)
    assert np.abs(sol.q[0] - q[0]).max() <= 20 * 0.05 + 1e-12


def test_rotation_error_matches_reference():
    rng = np.random.default_rng(5)
    rv = rng.normal(0, 1.0, (500, 3))
    rv = rv / np.linalg.norm(rv, axis=1, keepdims=True) * rng.uniform(0, np.pi * 0.999, (500, 1))
    R = rotvec_to_matrix(rv)
    # exact atan2 form: round-off level up to 179.8 deg
    assert np.abs(rotation_error(R, np.tile(np.eye(3), (500, 1, 1))) - rv).max() < 1e-9


def test_compiled_kernels_match_the_numpy_reference(kr16):
    """The numba path (robocal.kinematics.compiled) runs the same iteration as the numpy path: same fixed point,
    same convergence flags, same errors; FK, rotation vectors and quaternions match the library's."""
    from robocal.kinematics import compiled
    from robocal.kinematics.chain import build_chain
    from robocal.kinematics.transforms import matrix_to_quat, matrix_to_rotvec, rotvec_to_matrix
    from robocal.serve.engine import compile_chain, forward, quaternions, rotvec, solve

    if not compiled.AVAILABLE:
        pytest.skip("numba is not installed: only the numpy path exists")
    rng = np.random.default_rng(5)
    ch = build_chain(kr16)
    kinds = np.array(ch.param_kind)
    eta = np.where(kinds == "length", rng.normal(0, 0.5, ch.n_params), rng.normal(0, np.deg2rad(0.05), ch.n_params))
    cc_nom, cc = compile_chain(ch), compile_chain(ch, eta)
    tool = np.eye(4)
    tool[:3, 3] = [35.0, -20.0, 120.0]
    q = rng.uniform(kr16.q_limits[:, 0], kr16.q_limits[:, 1], (100, 6)) * 0.7
    p, R, _, _ = forward(cc_nom, q, tool)  # compiled FK (record=False)
    p_ref, R_ref, _, _ = forward(cc_nom, q, tool, record=True)  # numpy FK
    assert np.abs(p - p_ref).max() < 1e-9 and np.abs(R - R_ref).max() < 1e-12  # float64 round-off of ~1 m
    for R_d in (R, None):
        kw = {"tol_mm": 1e-4, "tol_rad": 1e-8, "max_step_rad": np.deg2rad(3.0)}
        a = solve(cc, tool, q, p, R_d, compiled=False, **kw)
        b = solve(cc, tool, q, p, R_d, compiled=True, **kw)
        assert (a.converged == b.converged).all() and a.converged.sum() >= 95
        # the same arithmetic in another order: agreement to round-off, far below the 1e-4 mm tolerance
        assert np.abs(a.q - b.q).max() < 1e-10
        assert np.abs(a.residual_mm - b.residual_mm).max() < 1e-9
        assert np.abs(a.error_before_rad - b.error_before_rad).max() < 1e-12
    E = rotvec_to_matrix(rng.normal(0, 1.0, (200, 3)))
    assert np.abs(rotvec(E) - matrix_to_rotvec(E)).max() < 1e-9
    qa, qb = quaternions(E), matrix_to_quat(E)
    assert np.abs(qa - qb).max() < 1e-9
