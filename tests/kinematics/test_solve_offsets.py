"""The compensation's Newton with joint offsets: the two-stage solve (the compiled Newton to the joints the robot
must reach, then the offsets inverted in joint space) gives the one-stage loop's answer, and the service's
tabulated discovered effects are the records' exact sum."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.kinematics import compiled
from robocal.kinematics.chain import build_chain
from robocal.kinematics.ik import compile_chain, forward, solve
from robocal.robot import load_robot

pytestmark = pytest.mark.skipif(not compiled.AVAILABLE, reason="the two-stage solve needs numba")


def _offset(q: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """A real robot's kind of joint effect: a transmission error (17 and 40 cycles per revolution, 0.01 deg
    each) and a deflection that follows joints 2 and 3 together (0.05 deg)."""
    a = np.deg2rad(0.01)
    dq = a * (np.sin(17 * q + 0.3) + np.cos(40 * q))
    dq[:, 1] += np.deg2rad(0.05) * np.cos(q[:, 1] + q[:, 2])
    return dq


def test_the_two_stage_solve_is_the_one_stage_answer():
    robot = load_robot("kr16_2")
    cc = compile_chain(build_chain(robot), np.zeros(len(build_chain(robot).param_names)))
    rng = np.random.default_rng(4)
    q_t = np.deg2rad(rng.uniform(-60.0, 60.0, (40, 6)))
    q_t[:, 4] = np.where(np.abs(q_t[:, 4]) < np.deg2rad(15), np.deg2rad(30), q_t[:, 4])  # off the wrist singularity
    tool = np.eye(4)
    tool[:3, 3] = [0.0, 0.0, 150.0]
    p, R, _, _ = forward(cc, q_t, tool)
    two = solve(cc, tool, q_t, p, R, _offset, tol_mm=1e-6, tol_rad=1e-9)
    one = solve(cc, tool, q_t, p, R, _offset, tol_mm=1e-6, tol_rad=1e-9, compiled=False)
    assert two.converged.all() and one.converged.all()
    # the same commanded joints: both stop within 1e-6 mm / 1e-9 rad of the pose, which near a wrist
    # singularity leaves joints 4 and 6 free by up to ~1e-7 rad (seen: 6e-8); elsewhere they agree to ~1e-10
    dq = np.abs(two.q - one.q).max(axis=1)
    assert dq.max() < 1e-6 and np.median(dq) < 1e-9
    assert np.abs(two.error_before_mm - one.error_before_mm).max() < 1e-9  # the same start
    # and the robot, sent them, reaches the pose
    p2, R2, _, _ = forward(cc, two.q + _offset(two.q, np.arange(len(q_t))), tool)
    assert np.abs(p2 - p).max() < 1e-5
    assert np.abs(two.residual_mm).max() < 1e-5 and np.abs(two.residual_rad).max() < 1e-8
    R_err = np.einsum("mij,mkj->mik", R2, R)  # R2 R^T: the identity when the orientation is reached
    assert np.abs(R_err - np.eye(3)).max() < 1e-8


def test_the_tabulated_discovered_effects_are_the_records_sum():
    from robocal.compensation.discovered import TABLE_TOL_RAD, DiscoveredEffects, joint_offsets
    from robocal.compensation.effects import Signals

    robot = load_robot("kr16_2")
    h = list(range(6, 31))
    rng = np.random.default_rng(2)
    records = [
        {"key": "transmission:j2", "effect": "transmission", "joint": 2, "signal": "transmission",
         "harmonics": h, "visited_deg": [[10.0, 80.0], [95.0, 100.0], [300.0, 340.0]], "taper_deg": 2.0,
         "centre": rng.normal(0, 0.1, 2 * len(h)).tolist(), "coefficients": rng.normal(0, 1e-4, 2 * len(h)).tolist()},
        {"key": "gear:j2:h1", "effect": "gear", "joint": 2, "harmonic": 1, "signal": "angle",
         "coefficients": [2e-4, -1e-4]},
        {"key": "gear:j5:h2", "effect": "gear", "joint": 5, "harmonic": 2, "signal": "angle",
         "coefficients": [1e-4, 3e-4]},
    ]  # fmt: skip
    de = DiscoveredEffects(tuple(records), robot)
    q = rng.uniform(-7.0, 7.0, (3000, 6))
    q[:5, 1] = np.deg2rad([10.0, 80.0, 78.0, 82.0, 340.0])  # on and beside the windows' edges
    exact = joint_offsets(records, robot, q)
    fast = de.offsets(q, Signals(np.zeros(len(q))))
    assert np.abs(fast - exact).max() <= TABLE_TOL_RAD
    tables, _weights, rest = de._tables
    assert tables is not None and sorted(tables[0].tolist()) == [1, 4] and rest == []  # both joints tabulated


def test_the_discovered_effects_in_one_compiled_call_are_the_records_sum():
    """Tables, weight effects and the residual layer together go through one compiled kernel (the service's
    path); a record that is none of them (a torque effect) takes the term-by-term sum. Both equal the records
    evaluated one by one."""
    from robocal.compensation.discovered import TABLE_TOL_RAD, DiscoveredEffects, joint_offsets, layer_coverage
    from robocal.compensation.effects import Signals

    robot = load_robot("kr16_2")
    rng = np.random.default_rng(5)
    n = robot.n_joints
    weight = [
        {"key": f"weight:j{j}", "effect": "weight", "joint": j, "signal": "weight",
         "basis": np.linalg.qr(rng.normal(size=(4 * n, 3)))[0].tolist(), "scale": [30.0, 8.0, 2.0],
         "prior_deg": 0.05, "coefficients": rng.normal(0, 1e-4, 3).tolist()}
        for j in (2, 3)
    ]  # fmt: skip
    gear = [{"key": "gear:j1:h3", "effect": "gear", "joint": 1, "harmonic": 3, "signal": "angle",
             "coefficients": [2e-4, -1e-4]}]  # fmt: skip
    q = rng.uniform(-3.0, 3.0, (500, n))
    centres = q[rng.choice(len(q), 40, replace=False)] + rng.normal(0, 0.05, (40, n))
    layer = [
        {"key": f"layer:j{j}", "effect": "layer", "joint": j, "signal": "layer", "centres_rad": centres.tolist(),
         "length_rad": 0.5, "inside_rad": 0.8, "coefficients": rng.normal(0, 1e-4, 40).tolist()}
        for j in (1, 4, 4)
    ]  # fmt: skip
    for records in (weight, weight + gear, layer, weight + gear + layer):
        de = DiscoveredEffects(tuple(records), robot)
        assert de._fused is not None  # the one-call path
        exact = joint_offsets(records, robot, q)
        assert np.abs(exact).max() > 1e-5  # the effects are there: the check below means something
        # the weight effects and the layer are the same sums in another order (1e-15; the layer's distances
        # without scikit-learn's expansion, 1e-16 rad relative); the tables within their tolerance
        assert np.abs(de.offsets(q, Signals(np.zeros(len(q)))) - exact).max() <= TABLE_TOL_RAD
    # the layer's coverage (the notes) is the records' gate: some targets inside, some outside, some between
    cover = layer_coverage(layer, q)
    assert cover is not None and (cover == 1).any() and (cover == 0).any() and ((cover > 0) & (cover < 1)).any()
    de = DiscoveredEffects(tuple(layer), robot)
    assert [bool(x) for x in de.notes(q)] == [bool(c < 1.0) for c in cover]
    torque = {"key": "compliance:j2", "effect": "compliance", "joint": 2, "signal": "torque",
              "coefficients": [1e-5]}  # fmt: skip
    de = DiscoveredEffects((*weight, torque), robot)
    assert de._fused is None  # a record neither tabulated nor a weight effect: term by term
    tau = rng.normal(0, 50.0, q.shape)
    exact = joint_offsets([*weight, torque], robot, q, tau_Nm=tau)
    assert np.abs(de.offsets(q, Signals(np.zeros(len(q)), tau_Nm=tau)) - exact).max() <= 1e-14
