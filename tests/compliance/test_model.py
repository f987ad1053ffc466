"""ComplianceModel: prediction by kind, serialisation round trip, clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from robocal.compliance.model import ComplianceModel
from robocal.errors import ConfigError
from robocal.kinematics.gravity import gravity_torques


def _model(kind: str, robot=None) -> ComplianceModel:
    c = np.array([0.0, 2e-4, 3e-4, -1e-4, 2e-4, 0.0])
    se = np.array([np.nan, 1e-6, 2e-6, 3e-6, 1e-6, np.nan])
    dyn = {}
    if kind == "gravity":
        dyn = {"link_mass_kg": robot.link_mass_kg * 1.1, "link_com_mm": robot.link_com_mm}
    return ComplianceModel(kind, "sr210", tuple(f"J{j}" for j in range(1, 7)), c, se, np.isfinite(se), dyn)


def test_current_model_offsets_and_round_trip(tmp_path) -> None:
    m = _model("current")
    rng = np.random.default_rng(1)
    q = rng.normal(size=(4, 6))
    cur = rng.normal(size=(4, 6))
    np.testing.assert_array_equal(m.joint_offsets(q, 0.0, current_A=cur), cur * m.c)
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"model": m.to_dict()}))
    back = ComplianceModel.from_json(path)
    np.testing.assert_array_equal(back.c, m.c)
    np.testing.assert_array_equal(back.stderr, m.stderr)
    assert back.kind == "current" and back.unit == "rad/A"
    np.testing.assert_array_equal(back.joint_offsets(q, 0.0, current_A=cur), m.joint_offsets(q, 0.0, current_A=cur))


def test_gravity_model_uses_the_stored_masses(sr210) -> None:
    m = _model("gravity", sr210)
    back = ComplianceModel.from_dict(json.loads(json.dumps(m.to_dict())))
    q = np.deg2rad(np.array([[0, 10, 20, 30, 40, 0], [5, -20, 30, 0, -60, 10]], dtype=float))
    pl = np.array([0.0, 210.0])
    tau = gravity_torques(sr210, q, pl, link_mass_kg=sr210.link_mass_kg * 1.1)
    np.testing.assert_allclose(back.joint_offsets(q, pl), tau * m.c, rtol=1e-12)


def test_missing_signal_and_bad_input_are_clear() -> None:
    m = _model("current")
    with pytest.raises(ValueError, match="current_A"):
        m.joint_offsets(np.zeros((2, 6)), 0.0)
    with pytest.raises(ValueError, match="shape"):
        m.joint_offsets(np.zeros((2, 6)), 0.0, current_A=np.zeros((3, 6)))
    t = _model("current").to_dict()
    t["kind"] = "magic"
    with pytest.raises(ConfigError, match="kind"):
        ComplianceModel.from_dict(t)
    with pytest.raises(ConfigError, match="not a compliance model"):
        ComplianceModel.from_dict({"kind": "current"})
