"""One error-statistics type, one orientation error, one noise floor (robocal.metrics)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robocal.kinematics.transforms import rotvec_to_matrix
from robocal.metrics import ErrorStats, noise_floor, orientation_errors_deg


def test_error_stats_of_vectors_and_norms():
    err = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0], [1.0, 2.0, 2.0]])  # row errors 5, 1, 3 mm
    s = ErrorStats.of(err)
    assert (s.n, s.mean_mm, s.max_mm) == (3, 3.0, 5.0)
    assert s.rms_mm == pytest.approx(math.sqrt(35.0 / 3.0), rel=1e-15)  # sqrt((25 + 1 + 9) / 3), float rounding
    assert ErrorStats.of(np.array([5.0, 1.0, 3.0])) == s  # row errors given directly: the same statistics
    assert not s.has_orientation and s.orientation() == {}


def test_error_stats_keys_keep_the_files_names_and_orders():
    s = ErrorStats.of(np.array([1.0, 2.0]), np.array([0.5, 1.5]))
    assert list(s.position()) == ["mean_position_mm", "rms_position_mm", "max_position_mm"]
    assert list(s.position(("rms", "mean", "max"))) == ["rms_position_mm", "mean_position_mm", "max_position_mm"]
    assert s.position(("mean", "max"), scheme="short") == {"mean_mm": 1.5, "max_mm": 2.0}
    assert s.orientation(("mean", "max")) == {"mean_orientation_deg": 1.0, "max_orientation_deg": 1.5}
    assert list(s.to_dict()) == [*s.position(), *s.orientation()]


def test_error_stats_of_no_rows_is_nan():
    s = ErrorStats.of(np.zeros((0, 3)), np.zeros(0))
    assert s.n == 0 and all(math.isnan(v) for v in s.to_dict().values())


def test_orientation_error_is_the_angle_between_the_rotations():
    R_meas = rotvec_to_matrix(np.array([[0.3, -0.2, 0.1], [0.0, 0.0, 0.0]]))
    turn = rotvec_to_matrix(np.array([[0.0, 0.0, np.deg2rad(10.0)], [np.deg2rad(-4.0), 0.0, 0.0]]))
    e = orientation_errors_deg(turn @ R_meas, R_meas)
    np.testing.assert_allclose(e, [10.0, 4.0], rtol=1e-12)  # float rounding of the rotation vector


def test_noise_floor_formulas():
    # rms: sigma sqrt(3 dof / M); mean: sigma sqrt(8/pi) sqrt(dof / M); per-point sigma: their RMS
    assert noise_floor(0.02, 240, 27) == pytest.approx(0.02 * math.sqrt(3 * 213 / 240), rel=1e-15)
    assert noise_floor(0.02, 240, 27, "mean") == pytest.approx(0.02 * math.sqrt(8 / math.pi * 213 / 240), rel=1e-15)
    assert noise_floor(np.array([0.01, 0.03]), 6, 1) == pytest.approx(math.sqrt(0.0005) * math.sqrt(15 / 6))
    assert noise_floor(0.02, 30, 40) == pytest.approx(0.02 * math.sqrt(3 / 30))  # no dof left: dof = 1
    with pytest.raises(ValueError, match="statistic"):
        noise_floor(0.02, 3, 1, "median")
