"""Gravity torques: checked against the derivative of the potential energy (an independent computation)."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.kinematics.gravity import gravity_torques, potential_energy


@pytest.mark.parametrize("name", ["sr210", "kr16", "abb"])
def test_torque_is_minus_gradient_of_potential_energy(name: str, request: pytest.FixtureRequest) -> None:
    robot = request.getfixturevalue(name)
    if not robot.has_dynamics:
        pytest.skip(f"{robot.name} has no dynamics")
    rng = np.random.default_rng(3)
    q = rng.uniform(robot.q_limits[:, 0] * 0.9, robot.q_limits[:, 1] * 0.9, (20, robot.n_joints))
    load = rng.uniform(0, 50, 20)
    tau = gravity_torques(robot, q, load)
    h = 1e-6
    fd = np.empty_like(tau)
    for j in range(robot.n_joints):
        e = np.zeros(robot.n_joints)
        e[j] = h
        fd[:, j] = -(potential_energy(robot, q + e, load) - potential_energy(robot, q - e, load)) / (2 * h)
    # central differences of a smooth function in rad: error ~h² · V''' ~ 1e-9 N·m; 1e-4 N·m leaves roundoff room
    np.testing.assert_allclose(tau, fd, atol=1e-4)


def test_vertical_axis_carries_no_gravity_torque_and_payload_is_linear(sr210) -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(sr210.q_limits[:, 0], sr210.q_limits[:, 1], (10, 6))
    t0 = gravity_torques(sr210, q, 0.0)
    t1 = gravity_torques(sr210, q, 100.0)
    t2 = gravity_torques(sr210, q, 200.0)
    # axis 1 is parallel to gravity ([Mao] sec. 3.3): its torque is zero up to roundoff
    assert np.abs(t0[:, 0]).max() < 1e-9 and np.abs(t2[:, 0]).max() < 1e-9
    # payload enters linearly
    np.testing.assert_allclose(t2 - t0, 2 * (t1 - t0), atol=1e-9)
    # a 200 kg payload about 2 m out loads joint 2 by kN·m (not N·m or MN·m: units are right)
    assert 500 < np.abs(t2[:, 1] - t0[:, 1]).max() < 10000


def test_bad_shapes_name_the_parameter(sr210) -> None:
    with pytest.raises(ValueError, match="'q' parameter"):
        gravity_torques(sr210, np.zeros((3, 5)))
