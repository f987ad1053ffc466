"""One chain, four forms: numpy ``propagate``/``fk``, the CasADi form, the compiled kernels and the paths built on
them (population positions, the service's FK and Newton) give the same poses; the compiled rotation conversions
are the numpy ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from robocal.identification.model import CalibrationModel, FitData
from robocal.kinematics import compiled
from robocal.kinematics.chain import fk
from robocal.kinematics.transforms import matrix_to_quat, matrix_to_rotvec, rotvec_to_matrix
from robocal.robot import load_robot

ROBOTS = sorted(p.stem for p in (Path(compiled.__file__).parents[1] / "robots").glob("*.yaml"))
T_REF = np.array([[0, -1, 0, 900.0], [1, 0, 0, -200], [0, 0, 1, 30], [0, 0, 0, 1]])

needs_numba = pytest.mark.skipif(not compiled.AVAILABLE, reason="numba is not installed")


def _robot(name, request):
    return request.getfixturevalue("abb_poe") if name == "abb_poe" else load_robot(name)


def _case(robot, seed):
    """A model with the tracker frame, random parameter errors (0.5 mm, 1 mrad), random poses and tools."""
    rng = np.random.default_rng(seed)
    model = CalibrationModel(robot, ("A", "B"), T_ref=T_REF)
    chain = model.full_chain
    kinds = np.array(chain.param_kind)
    eta = np.where(kinds == "length", rng.normal(0, 0.5, chain.n_params), rng.normal(0, 1e-3, chain.n_params))
    lo, hi = robot.q_limits[:, 0], robot.q_limits[:, 1]
    q = lo + (hi - lo) * rng.random((30, robot.n_joints))
    tool = np.eye(4)
    tool[:3, :3] = rotvec_to_matrix(rng.normal(0, 1.0, 3))
    tool[:3, 3] = rng.normal(0, 100, 3)
    T = fk(chain, q, eta, T_REF) @ tool  # the numpy reference
    return model, chain, eta, q, tool, T


def _close(p, R, T, rot_from_points=False):
    """Positions to 1e-12 relative (of the ~2 m reach), rotations to 1e-12 (``rot_from_points``: rotation columns
    taken as differences of two points, whose rounding grows with the points' size, 1e-15 of it: a robot on a
    6 m track has points ~8 m out)."""
    scale = np.abs(T[:, :3, 3]).max()
    assert np.abs(p - T[:, :3, 3]).max() <= 1e-12 * scale
    assert np.abs(R - T[:, :3, :3]).max() <= (max(1e-12, 1e-15 * scale) if rot_from_points else 1e-12)


@pytest.mark.parametrize("name", [*ROBOTS, "abb_poe"])
def test_every_form_of_the_chain_gives_the_same_pose(name, request):
    from robocal.serve.engine import compile_chain, forward, solve

    robot = _robot(name, request)
    model, chain, eta, q, tool, T = _case(robot, 7)
    if robot.has_prismatic:  # a track or a column: the folded forms refuse it by name (issue 34, not built yet)
        with pytest.raises(ValueError, match="joint 1 is prismatic"):
            compile_chain(chain, eta, T_REF)
    else:
        # numpy folding + the service's numpy FK (chain.step on the folded chain)
        cc = compile_chain(chain, eta, T_REF)
        p, R, _, _ = forward(cc, q, tool, record=True)
        _close(p, R, T)
    # the CasADi form (the same element code on CasADi expressions): tool offsets 0, e_x, e_y, e_z give p and R
    from robocal.calibration.problem import _casadi_point_function

    point = _casadi_point_function(model)
    x = np.zeros(model.n)
    x[: chain.n_params] = eta
    x[model.n_chain : model.n_chain + 3] = tool[:3, 3]
    T0 = T_REF[:3, :4]
    pc = np.array([np.asarray(point(x, qk, T0, [1.0, 0.0])).ravel() for qk in q])
    cols = []
    for k in range(3):
        x[model.n_chain + 3 : model.n_chain + 6] = tool[:3, 3] + tool[:3, k]
        cols.append(np.array([np.asarray(point(x, qk, T0, [0.0, 1.0])).ravel() for qk in q]) - pc)
    _close(pc, np.stack(cols, -1), T, rot_from_points=True)
    if not compiled.AVAILABLE or robot.has_prismatic:
        return
    # compiled folding = numpy folding
    B = np.empty((chain.n_joints + 1, 3, 4))
    compiled.fold(*compiled.chain_arrays(chain), T_REF, eta, B)
    assert np.abs(B - cc.blocks).max() <= 1e-12 * np.abs(B).max()
    # compiled FK of the folded chain (the service's forward)
    p, R = compiled.fk_poses(B, cc.axis, cc.joint, tool, q)
    _close(p, R, T)
    p, R, _, _ = forward(cc, q, tool)
    _close(p, R, T)
    # the service's Newton sees the same pose: at the reference pose it converges at once with zero error
    sol = solve(cc, tool, q, T[:, :3, 3], T[:, :3, :3], tol_mm=1e-8, tol_rad=1e-11, compiled=True)
    assert sol.converged.all() and sol.iterations == 0
    assert np.abs(sol.error_before_mm).max() <= 1e-12 * np.abs(T[:, :3, 3]).max()
    assert np.abs(sol.error_before_rad).max() <= 1e-12


@pytest.mark.parametrize("backend", ["numpy", *(["numba"] if compiled.AVAILABLE else [])])
@pytest.mark.parametrize("name", [*ROBOTS, "abb_poe"])
def test_population_positions_are_the_chain(name, backend, request):
    from robocal.optimizers.fastfk import PopulationPositions

    robot = _robot(name, request)
    rng = np.random.default_rng(3)
    model = CalibrationModel(robot, ("A", "B"), T_ref=T_REF)
    chain = model.full_chain
    _, _, _, q, _, _ = _case(robot, 3)
    tidx = rng.integers(0, 2, len(q))
    data = FitData(q=q, p_mm=np.zeros((len(q), 3)), target_index=tidx)
    X = np.zeros((5, model.n))
    for i in range(5):
        X[i, : chain.n_params] = _case(robot, 10 + i)[2]
        X[i, model.n_chain :] = rng.normal(0, 100, 6)
    if robot.has_prismatic:  # the kernel turns joints only: refused, the callers fall back to the model's own method
        with pytest.raises(ValueError, match="joint 1 must drive exactly one rotation element"):
            PopulationPositions(model, data, backend=backend)
        return
    got = PopulationPositions(model, data, backend=backend)(X).reshape(5, -1, 3)
    for i in range(5):
        T = fk(chain, q, X[i, : chain.n_params], T_REF)
        tools = X[i, model.n_chain :].reshape(2, 3)[tidx]
        want = T[:, :3, 3] + np.einsum("mij,mj->mi", T[:, :3, :3], tools)
        assert np.abs(got[i] - want).max() <= 1e-12 * np.abs(want).max()


def _rotations():
    """Random rotations and the hard cases: near 0, near pi (on both sides of the 1e-3 switch), exactly pi."""
    rng = np.random.default_rng(9)
    axes = rng.normal(0, 1, (400, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    th = np.concatenate(
        [
            rng.uniform(0, np.pi, 100),
            [0.0, 1e-12, 1e-9, 1e-7, 1e-6, 1.1e-6, 1e-5, 1e-3] * 5,
            np.pi - np.array([0.0, 1e-12, 1e-9, 1e-7, 1e-5, 1e-4, 9.99e-4, 1e-3, 1.001e-3, 2e-3]).repeat(26),
        ]
    )
    axes[-26:] = np.eye(3)[np.arange(26) % 3]  # exactly pi about the coordinate axes too
    return rotvec_to_matrix(axes[: len(th)] * th[:, None])


@needs_numba
def test_compiled_rotation_vectors_are_the_numpy_ones():
    R = _rotations()
    a, b = compiled.rotvec(R), matrix_to_rotvec(R)
    assert np.abs(a - b).max() <= 1e-13
    assert np.abs(rotvec_to_matrix(a) - R).max() <= 1e-12  # and they are right


@needs_numba
def test_compiled_quaternions_are_the_numpy_ones():
    R = _rotations()
    a, b = compiled.quat(R), matrix_to_quat(R)
    assert np.abs(a - b).max() <= 1e-13
    assert (a[:, 0] >= 0).all()
