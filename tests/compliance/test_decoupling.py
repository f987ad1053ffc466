"""POE decoupling: the paper's B (eq. 26) and recovery of link-length / zero-offset errors."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.compliance.decoupling import controller_parameters, decoupling_matrix, layout_lengths, with_lengths
from robocal.data import read_campaign
from robocal.errors import ConfigError
from robocal.sim.twin import load_scenario, simulate


def test_B_is_the_papers_eq_26(sr210) -> None:
    b0, b1, b2, b3 = np.zeros(6), np.eye(6)[0], np.eye(6)[1], np.eye(6)[2]
    blocks = [
        [b0, b0, b0, b0],
        [b3, b0, b0, b0],
        [b3, b1, b0, b0],
        [b0, b0, b2, b0],
        [b0, b0, b1, b3],
        [b0, b0, b2, b0],
    ]
    left = np.vstack([np.column_stack(r) for r in blocks])  # (36, 4) acting on [-dL1, dL2, dL2 + dL3, -dL1 - dL4]
    T = np.array([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 1, 1, 0], [-1, 0, 0, -1]], dtype=float)
    np.testing.assert_array_equal(decoupling_matrix(sr210), left @ T)
    np.testing.assert_array_equal(layout_lengths(sr210), [312, 1075, 235, 1282, 260])


def test_controller_parameters_recover_length_and_offset_errors(sr210, tmp_path) -> None:
    dL = np.array([1.2, -0.8, 0.5, 1.5, 0.0])
    dth = np.deg2rad([0.0, 0.05, -0.08, 0.03, 0.1, 0.0])
    true_robot = with_lengths(sr210, layout_lengths(sr210) + dL, sr210.theta_offset + dth)
    sc = load_scenario("heavy_load")
    sc.update(effects={}, noise_mm=0.0, errors={"length_mm": 0.0, "angle_deg": 0.0}, n_poses=30)
    simulate(sc, tmp_path, seed=1, robot=true_robot)
    camp = read_campaign(tmp_path, sr210)
    geo = calibrate(camp, sr210, CalibrationConfig(noise_mm=0.02))
    cp = controller_parameters(geo, camp.q, camp.target_index)
    # noise-free data from a robot that differs only in L and zero offsets: exact recovery (1e-6 mm / deg)
    np.testing.assert_allclose(cp["dL_mm"], dL, atol=1e-6)
    np.testing.assert_allclose(cp["dtheta_deg"], np.rad2deg(dth), atol=1e-6)
    assert cp["rms_mm"] < 1e-6


def test_other_layouts_are_refused(abb_poe, kr16) -> None:
    for robot in (abb_poe, kr16):
        with pytest.raises(ConfigError, match="layout"):
            layout_lengths(robot)
