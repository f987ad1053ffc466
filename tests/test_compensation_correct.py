"""One compensation entry point (issue 32): :func:`robocal.compensation.correct.correct` (``robocal.compensate``)
takes a calibration or the robot at the moment, the targets, the joint-space effects and the safety policy, and
returns one :class:`~robocal.compensation.correct.Corrected`. Thermal (drift in the robot's parameters),
compliance and discovery (joint-space effects through the protocol of :mod:`robocal.compensation.effects`) go
through it, and the correction beyond the calibration's own has one definition
(:func:`robocal.compensation.correct.beyond_own`; its one definition: tests/test_one_definition.py)."""

from __future__ import annotations

import numpy as np
import pytest

import robocal
from robocal.compensation import ActualRobot, compensate, desired_poses
from robocal.compensation.correct import Corrected, correct, zero_offsets
from robocal.compensation.effects import ComplianceEffect, Signals
from robocal.compensation.safety import SafetyPolicy
from robocal.compliance.model import ComplianceModel
from robocal.kinematics.chain import build_chain, fk
from robocal.kinematics.transforms import homogeneous, rotvec_to_matrix

#: a policy whose bound every target exceeds: the beyond-own correction is computed for every target
TIGHT = SafetyPolicy(max_correction_deg=0.0, max_error_mm=0.0)


def _robot(robot, seed=0):
    rng = np.random.default_rng(seed)
    chain = build_chain(robot)
    T = homogeneous(rotvec_to_matrix([0.01, -0.02, 2.0]), [2000.0, 500.0, -300.0])
    tool = np.array([20.0, -5.0, 150.0])
    eta = np.where(
        np.array(chain.param_kind) == "length",
        rng.normal(0, 0.5, chain.n_params),
        rng.normal(0, np.deg2rad(0.05), chain.n_params),
    )
    q = rng.uniform(robot.q_limits[:, 0], robot.q_limits[:, 1], (12, robot.n_joints)) * 0.6
    q[:, 4] = np.where(np.abs(q[:, 4]) < np.deg2rad(20), np.deg2rad(20), q[:, 4])  # away from the wrist singularity
    nominal = ActualRobot(chain, np.zeros(chain.n_params), T, tool, np.eye(3))
    return nominal, ActualRobot(chain, eta, T, tool, np.eye(3)), q, rng


def _compliance(rng, m):
    c = np.array([0.0, 2e-4, 3e-4, -1e-4, 2e-4, 0.0])  # rad/A
    model = ComplianceModel("current", "kr16_2", tuple(f"J{j}" for j in range(1, 7)), c, np.full(6, 1e-6), c != 0, {})
    return model, rng.uniform(-3.0, 3.0, (m, 6))


@pytest.fixture(scope="module")
def calibration(kr16):
    """A real geometric calibration of a 40-pose twin campaign (as tests/serve/conftest.py)."""
    import tempfile

    from robocal.data import read_campaign
    from robocal.sim.twin import load_scenario, simulate

    sc = load_scenario("geometric")
    sc.update(n_poses=40, n_validation_poses=0)
    with tempfile.TemporaryDirectory() as d:
        simulate(sc, d, seed=3)
        camp = read_campaign(d, kr16)
    return robocal.calibrate(camp, kr16)


def test_robocal_compensate_is_the_one_entry_point(calibration):
    assert robocal.compensate is correct and robocal.Corrected is Corrected
    q = np.deg2rad([[10.0, -60.0, 40.0, 20.0, 30.0, 40.0], [-35.0, -100.0, 80.0, -60.0, -50.0, 120.0]])
    c = robocal.compensate(calibration, q)
    assert isinstance(c, Corrected) and c.converged.all() and list(c.status) == ["ok", "ok"]
    # the command the nominal controller must be sent: nominal FK at the corrected joints, times the tool
    model = calibration.model
    T_tool = homogeneous(model.tool_rotations(calibration.x)[0], model.tools(calibration.x)[0])
    np.testing.assert_allclose(c.command_T, fk(model.chain, c.q) @ T_tool, rtol=0, atol=1e-12)
    # and the corrected joints put the calibrated robot (base frame) where the nominal one is at q
    real = fk(model.chain, c.q, calibration.kinematic_errors) @ T_tool
    np.testing.assert_allclose(real[:, :3, 3], (fk(model.chain, q) @ T_tool)[:, :3, 3], atol=1e-3)  # Newton 1e-4 mm


def test_bad_input_names_the_parameter(calibration):
    with pytest.raises(TypeError, match="'robot' parameter of correct"):
        correct({"x": 1}, np.zeros((1, 6)))
    _, actual, q, _ = _robot(calibration.model.robot)
    with pytest.raises(ValueError, match="'desired'"):
        correct(actual, q)


def test_the_deprecated_wrapper_is_correct(calibration):
    from robocal.discovery.effects import compensate_targets

    q = np.deg2rad([[10.0, -60.0, 40.0, 20.0, 30.0, 40.0]])
    with pytest.warns(DeprecationWarning, match="robocal.compensate"):
        old, command = compensate_targets(calibration, q)
    new = correct(calibration, q)
    np.testing.assert_array_equal(old.q, new.q)
    np.testing.assert_array_equal(command, new.command_T)


def test_thermal_drift_is_the_robots_parameters(calibration):
    """The thermal path is the entry point with the drift in the robot's parameters: the same joints and statuses
    as correct() on the calibrated robot at ``eta + deta`` (tracker frame), to 1e-12 rad."""
    from robocal.thermal.compensate import calibrated_robot, compensate_targets, nominal_robot

    q = np.deg2rad([[10.0, -60.0, 40.0, 20.0, 30.0, 40.0], [-35.0, -100.0, 80.0, -60.0, -50.0, 120.0]])
    th = compensate_targets(calibration, None, None, q, ["T1", "T1"], limits=TIGHT)
    c = correct(
        calibrated_robot(calibration, "T1"), q, None, TIGHT, desired=desired_poses(nominal_robot(calibration, "T1"), q)
    )
    np.testing.assert_allclose(th.q_corrected, c.q, rtol=0, atol=1e-12)
    assert list(th.status) == c.status == ["refused", "refused"]
    assert th.reason[0].startswith("; ".join(c.reasons[0]))
    deta = np.where(np.array(calibration.model.chain.param_kind) == "length", 0.05, 0.0)  # 50 um on every length
    warm = correct(
        calibrated_robot(calibration, "T1", deta), q, desired=desired_poses(nominal_robot(calibration, "T1"), q)
    )
    assert np.abs(warm.q - c.q).max() > 1e-7  # the drift moves the correction


def test_compliance_effect_through_the_protocol_equals_its_hook(kr16):
    """Compliance supplies its deflection as a joint-space effect (ComplianceEffect + Signals, the protocol the
    service uses) or as the per-row hook compliance_rows builds: the same corrected joints, to 1e-12 rad, and the
    same bound figures."""
    nominal, actual, q, rng = _robot(kr16)
    model, cur = _compliance(rng, len(q))
    p_d, R_d = desired_poses(nominal, q)
    pay = np.full(len(q), 10.0)
    hooked = correct(
        ActualRobot(actual.chain, actual.eta, actual.tracker_T_base, actual.tool_mm, actual.tool_R,
                    lambda qq: model.joint_offsets(qq, pay, cur)),
        q, None, TIGHT, desired=(p_d, R_d),
    )  # fmt: skip
    proto = correct(actual, q, [ComplianceEffect(model)], TIGHT, desired=(p_d, R_d),
                    signals=Signals(pay, current_A=cur))  # fmt: skip
    assert hooked.converged.all() and np.abs(hooked.correction_deg).max() > 0.01
    np.testing.assert_allclose(proto.q, hooked.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(proto.excess_deg, hooked.excess_deg, rtol=0, atol=1e-12)
    np.testing.assert_allclose(proto.rest_mm, hooked.rest_mm, rtol=0, atol=1e-12)


def test_the_beyond_own_correction_against_its_definition(kr16):
    """Two ways of computing one quantity: correct()'s bound figures against the definition written out here
    (the robot commanded with only the calibration's own correction: minus its zero offsets, minus the effects)."""
    nominal, actual, q, rng = _robot(kr16, seed=1)
    model, cur = _compliance(rng, len(q))
    pay = np.zeros(len(q))
    p_d, R_d = desired_poses(nominal, q)
    c = correct(actual, q, [ComplianceEffect(model)], TIGHT, desired=(p_d, R_d), signals=Signals(pay, current_A=cur))
    zero = zero_offsets(actual.chain, actual.eta)
    assert np.abs(zero).max() > 1e-4  # the random errors move the joint zeros

    def own(qq):
        return -zero - model.joint_offsets(qq, pay, cur)

    beyond = np.rad2deg(np.abs(c.q - q - own(c.q)).max(axis=1))
    p_own, _, _ = ActualRobot(actual.chain, actual.eta, actual.tracker_T_base, actual.tool_mm, actual.tool_R,
                              lambda qq: model.joint_offsets(qq, pay, cur)).pose(q + own(q))  # fmt: skip
    rest = np.linalg.norm(p_own - p_d, axis=1)
    # 1e-12: the same arithmetic in another order (deg of a max, norms)
    np.testing.assert_allclose(c.excess_deg, np.minimum(np.abs(c.correction_deg).max(axis=1), beyond), atol=1e-12)
    np.testing.assert_allclose(c.rest_mm, np.minimum(c.error_before_norm_mm, rest), atol=1e-12)
    # the raw Newton step is the same one
    np.testing.assert_array_equal(
        compensate(
            ActualRobot(actual.chain, actual.eta, actual.tracker_T_base, actual.tool_mm, actual.tool_R,
                        lambda qq: model.joint_offsets(qq, pay, cur)), q, p_d, R_d,
        ).q,
        c.q,
    )  # fmt: skip
