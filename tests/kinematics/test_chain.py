"""The chain engine against independent implementations and finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.identification.model import CalibrationModel, FitData
from robocal.kinematics.chain import build_chain, fk, point_jacobians, propagate
from robocal.kinematics.transforms import homogeneous, rotvec_to_matrix, rotx, roty, rotz, skew


def _T(R=None, t=(0.0, 0.0, 0.0)):
    return homogeneous(np.eye(3) if R is None else R, np.asarray(t, float))


def mdh_fk_reference(robot, q, eta=None):
    """Explicit product of 4x4 link matrices, written independently of the chain engine."""
    n = robot.n_joints
    e = {} if eta is None else eta
    T = np.eye(4)
    for i in range(n):
        k = i + 1
        al = robot.alpha[i] + e.get(f"alpha{k}", 0.0)
        a = robot.a_mm[i] + e.get(f"a{k}", 0.0)
        th = q[i] + robot.theta_offset[i] + e.get(f"theta{k}", 0.0)
        d = robot.d_mm[i] + e.get(f"d{k}", 0.0)
        be = robot.beta[i] + e.get(f"beta{k}", 0.0)
        T = T @ _T(rotx(al)) @ _T(t=(a, 0, 0)) @ _T(rotz(th)) @ _T(t=(0, 0, d)) @ _T(roty(be))
    return T


def poe_fk_reference(robot, q):
    """Global product of exponentials exp(xi_1 q_1) ... exp(xi_n q_n) M (Rodrigues, independent)."""
    T = np.eye(4)
    for i in range(robot.n_joints):
        w = robot.poe_w[i]
        p = robot.poe_p_mm[i]
        R = rotvec_to_matrix(w * q[i])
        # rotation about an axis through p: x -> R (x - p) + p
        T = T @ homogeneous(R, p - R @ p)
    return T @ robot.poe_flange0


def test_mdh_matches_reference(kr16):
    rng = np.random.default_rng(1)
    chain = build_chain(kr16)
    q = rng.uniform(kr16.q_limits[:, 0], kr16.q_limits[:, 1], (20, 6))
    eta_vals = rng.normal(0, 1e-3, chain.n_params)
    eta = dict(zip(chain.param_names, eta_vals, strict=True))
    T = fk(chain, q, eta_vals)
    for k in range(20):
        # 1e-9 mm: float64 round-off on a ~2 m chain
        np.testing.assert_allclose(T[k], mdh_fk_reference(kr16, q[k], eta), atol=1e-9)


def test_kr16_nominal_zero_pose(kr16):
    # At q = 0 the MD-H table puts the flange at x = a2 + a3... : check against the reference product
    T = fk(build_chain(kr16), np.zeros((1, 6)))[0]
    np.testing.assert_allclose(T, mdh_fk_reference(kr16, np.zeros(6)), atol=1e-9)


def test_poe_matches_product_of_exponentials(abb_poe):
    rng = np.random.default_rng(2)
    chain = build_chain(abb_poe)
    q = rng.uniform(-2, 2, (15, 6))
    T = fk(chain, q)
    for k in range(15):
        np.testing.assert_allclose(T[k], poe_fk_reference(abb_poe, q[k]), atol=1e-9)


def test_poe_equals_mdh_for_the_abb(abb, abb_poe):
    # The shared README states both descriptions of the IRB 120 agree to 1e-12 mm.
    rng = np.random.default_rng(3)
    q = rng.uniform(-2, 2, (15, 6))
    np.testing.assert_allclose(fk(build_chain(abb), q), fk(build_chain(abb_poe), q), atol=1e-9)


def test_population_propagation_equals_loop(kr16):
    rng = np.random.default_rng(4)
    chain = build_chain(kr16)
    q = rng.uniform(-1, 1, (9, 6))
    E = rng.normal(0, 1e-2, (5, chain.n_params))
    Tpop = fk(chain, q, E)
    assert Tpop.shape == (5, 9, 4, 4)
    for i in range(5):
        np.testing.assert_allclose(Tpop[i], fk(chain, q, E[i]), atol=1e-12)


@pytest.mark.parametrize("robot_name", ["kr16", "abb_poe", "sr210"])
@pytest.mark.parametrize("orientation", [False, True])
def test_identification_jacobian_matches_finite_differences(robot_name, orientation, request):
    robot = request.getfixturevalue(robot_name)
    rng = np.random.default_rng(5)
    m = 12
    q = rng.uniform(robot.q_limits[:, 0], robot.q_limits[:, 1], (m, robot.n_joints)) * 0.8
    T_ref = homogeneous(rotvec_to_matrix(rng.normal(0, 1, 3)), rng.normal(0, 1000, 3))
    model = CalibrationModel(robot, ["T1", "T2", "T3"], orientation=orientation, T_ref=T_ref)
    x = rng.normal(0, 1e-3, model.n)
    x[model.n_chain : model.n_chain + 9] = rng.normal(0, 80, 9)
    ti = rng.integers(0, 3, m)
    p, R = model.predict(x, q, ti)
    Rm = rotvec_to_matrix(rng.normal(0, 0.2, (m, 3))) @ R  # residual rotations well away from zero
    data = FitData(q, p + rng.normal(0, 1, p.shape), ti, Rm if orientation else None)
    _, J = model.residuals_and_jacobian(x, data)
    Jn = np.zeros_like(J)
    for k in range(model.n):
        h = 1e-6 if model.units[k] == "mm" else 1e-7
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        Jn[:, k] = (model.residuals(xp, data) - model.residuals(xm, data)) / (2 * h)
    # central differences: truncation ~h² * third derivative, round-off ~1e-16 * |r| / h ~ 1e-7 mm
    scale = np.maximum(np.abs(Jn).max(axis=0), 1.0)
    assert np.max(np.abs(J - Jn) / scale) < 1e-6


def test_joint_jacobian_matches_finite_differences(kr16):
    rng = np.random.default_rng(6)
    model = CalibrationModel(kr16, ["T1"])
    x = rng.normal(0, 1e-3, model.n)
    x[model.n_chain : model.n_chain + 3] = [20.0, -10.0, 150.0]
    q = rng.uniform(-1, 1, (7, 6))
    ti = np.zeros(7, dtype=int)
    Jq = model.joint_jacobian(x, q, ti)
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = 1e-7
        fd = (model.predict(x, q + dq, ti)[0] - model.predict(x, q - dq, ti)[0]) / 2e-7
        np.testing.assert_allclose(Jq[:, :, j], fd, atol=1e-5)  # mm/rad; FD round-off ~1e-6


def test_point_jacobian_rotation_rows_are_the_axes(kr16):
    chain = build_chain(kr16)
    q = np.zeros((1, 6))
    st = propagate(chain, q, None, None, record=True)
    _, W, _, Wq = point_jacobians(chain, st, st.o)
    # joint 1 rotates about the base z axis
    np.testing.assert_allclose(Wq[0, :, 0], [0, 0, 1], atol=1e-12)
    assert np.allclose(W[0][:, chain.param_names.index("d1")], 0)


def test_skew_is_cross_product():
    rng = np.random.default_rng(7)
    a, b = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(skew(a) @ b, np.cross(a, b), atol=1e-14)
