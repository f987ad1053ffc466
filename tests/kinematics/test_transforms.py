"""Property tests of the rotation helpers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from robocal.kinematics.transforms import (
    homogeneous,
    inv_transform,
    kabsch,
    matrix_from_rpy,
    matrix_to_quat,
    matrix_to_rotvec,
    quat_to_matrix,
    rotvec_to_matrix,
    rpy_from_matrix,
    so3_left_jacobian_inv,
)

vec3 = arrays(np.float64, 3, elements=st.floats(-3.0, 3.0))


@settings(max_examples=200, deadline=None)
@given(vec3)
def test_rotvec_round_trip(v):
    R = rotvec_to_matrix(v)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rotvec_to_matrix(matrix_to_rotvec(R)), R, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(vec3)
def test_quaternion_round_trip(v):
    R = rotvec_to_matrix(v)
    q = matrix_to_quat(R)
    assert abs(np.linalg.norm(q) - 1) < 1e-12 and q[0] >= 0
    np.testing.assert_allclose(quat_to_matrix(q), R, atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, 3, elements=st.floats(-1.5, 1.5)))
def test_rpy_round_trip(rpy):
    R = matrix_from_rpy(rpy)
    np.testing.assert_allclose(matrix_from_rpy(rpy_from_matrix(R)), R, atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(vec3, arrays(np.float64, 3, elements=st.floats(-1000, 1000)))
def test_kabsch_recovers_a_rigid_transform(rv, t):
    rng = np.random.default_rng(0)
    src = rng.normal(0, 500, (10, 3))
    T = homogeneous(rotvec_to_matrix(rv), t)
    dst = src @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(kabsch(src, dst), T, atol=1e-8)
    np.testing.assert_allclose(inv_transform(T) @ T, np.eye(4), atol=1e-10)


def test_left_jacobian_inverse_matches_finite_differences():
    rng = np.random.default_rng(1)
    phi = rng.normal(0, 0.8, 3)
    R = rotvec_to_matrix(phi)
    h = 1e-7
    fd = np.column_stack(
        [
            (matrix_to_rotvec(rotvec_to_matrix(h * e) @ R) - matrix_to_rotvec(rotvec_to_matrix(-h * e) @ R)) / (2 * h)
            for e in np.eye(3)
        ]
    )
    np.testing.assert_allclose(so3_left_jacobian_inv(phi), fd, atol=1e-6)


def test_rotvec_round_trip_just_below_pi():
    """The case hypothesis found: |v| = pi - 8.4e-4, inside the near-pi branch (the axis was taken from
    (R + I) / 2, whose skew and cos terms cost ~2.5e-4 of accuracy)."""
    v = np.array([3.0, 0.9296875, 0.0])
    R = rotvec_to_matrix(v)
    np.testing.assert_allclose(matrix_to_rotvec(R), v, atol=1e-9)  # 1e-9: float64 round trip, ~1e5 ulp of pi
    np.testing.assert_allclose(rotvec_to_matrix(matrix_to_rotvec(R)), R, atol=1e-9)


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-9, -np.pi / 2 + 1e-7, 0.3])
def test_rpy_accurate_at_and_near_gimbal_lock(pitch):
    """One roll-pitch-yaw reading for calibration.json, URDF origins and KUKA A, B, C: the rotation it gives
    back is the one read, to rounding, also at pitch = +-90 deg where arcsin(-R20) lost half the digits."""
    R = matrix_from_rpy(np.array([0.4, pitch, -1.1]))
    rpy = rpy_from_matrix(R)
    np.testing.assert_allclose(matrix_from_rpy(rpy), R, rtol=0, atol=1e-14)  # rounding of a few products
    assert abs(rpy[1] - pitch) < 1e-14
