"""The service corrects exactly as the offline compensation does, for every kind of bundle.

Regression test of the geometry-only bug (a bundle with no thermal model answered ``correction_deg`` 0 and
``predicted_error_mm`` 0 for every target: the chain was compiled with zero parameter errors whenever no
temperatures were given). The reference is :func:`robocal.compensation.compensate` on the bundle's own
calibrated model: values are compared, not transport.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import LOADERS, StandinCompliance, standin_thermal
from robocal.compensation import ActualRobot, compensate, desired_poses
from robocal.serve.bundle import load_bundle, write_bundle
from robocal.serve.protocol import Service, ServiceConfig, SolverConfig

QS = np.array(
    [
        [10.0, -60.0, 40.0, 20.0, 30.0, 40.0],  # the target of the bug report
        [10.0, -80.0, 60.0, 20.0, 40.0, 30.0],
        [-35.0, -100.0, 80.0, -60.0, -50.0, 120.0],
        [60.0, -45.0, 100.0, 90.0, 60.0, -90.0],
    ]
)


@pytest.fixture(scope="module", params=["geometric", "thermal", "compliance", "thermal+compliance"])
def bundle(request, tmp_path_factory, calibration_file, kr16):
    d = tmp_path_factory.mktemp("bundle_" + request.param.replace("+", "_"))
    th = co = None
    if "thermal" in request.param:
        th = standin_thermal(kr16).to_json(d / "th_src.json")
    if "compliance" in request.param:
        co = StandinCompliance(np.array([0.0, 2e-5, 1.5e-5, 0.0, 1e-5, 0.0])).to_json(d / "co_src.json")
    return load_bundle(write_bundle(d / "bundle", "kr16_2", calibration_file, th, co), loaders=LOADERS)


def _offline(b, temps, payload, mode):
    eta = b.eta0.copy()
    if b.thermal is not None:
        eta = eta + b.thermal.deta(np.array([[temps[s] for s in b.sensors]]))[0]
    defl = None
    if b.compliance is not None:

        def defl(q):
            return b.compliance.joint_offsets(q, np.full(len(q), payload), None, None)

    tool = b.tools[b.default_tool]
    # the service works in the robot base frame: identity tracker frame on both sides
    actual = ActualRobot(b.chain, eta, np.eye(4), tool[:3, 3], tool[:3, :3], defl)
    nominal = ActualRobot(b.chain, np.zeros_like(eta), np.eye(4), tool[:3, 3], tool[:3, :3])
    q_t = np.deg2rad(QS)
    p_d, R_d = desired_poses(nominal, q_t)
    comp = compensate(actual, q_t, p_d, R_d if mode == "pose" else None, max_iter=50, tol_mm=1e-11, tol_rad=1e-13)
    assert comp.converged.all()
    return comp, actual, p_d


@pytest.mark.parametrize("mode", ["pose", "position"])
def test_service_equals_offline_compensation(bundle, mode):
    temps = {s: 33.0 for s in bundle.sensors}
    payload = 6.0
    # tight solver tolerances so both sides reach the same fixed point to round-off
    cfg = ServiceConfig(solver=SolverConfig(max_iter=50, tol_mm=1e-11, tol_deg=1e-11))
    req = {"targets": [{"q_deg": q.tolist()} for q in QS], "payload_kg": payload, "mode": mode}
    if bundle.thermal is not None:
        req["temperatures"] = temps
    reply = json.loads(Service(bundle, cfg).handle_line(json.dumps(req).encode()))
    assert reply["ok"] and reply["n_refused"] == 0, reply
    comp, actual, p_d = _offline(bundle, temps, payload, mode)
    res = reply["results"]

    before = np.linalg.norm(comp.error_before_mm, axis=1)
    # the calibrated errors of the fixture (a twin with ~0.3 mm errors) are a real correction: not zero
    assert before.min() > 0.05
    assert np.allclose([r["predicted_error_mm"] for r in res], before, rtol=0, atol=1e-6)  # reply rounds to 1e-7 mm

    q_srv = np.array([r["q_deg"] for r in res])
    q_off = np.rad2deg(comp.q)
    # corrected joints: the reply rounds them to 1e-9 deg
    assert np.abs(q_srv - q_off).max() < 2e-9
    assert np.abs(np.array([r["correction_deg"] for r in res]) - (q_off - QS)).max() < 2e-9
    # where the service's joints put the calibrated robot vs the offline ones: the same point to 1e-9 mm beyond
    # the reply's joint rounding (1e-9 deg at <= 2.5 m reach is <= 4.4e-8 mm)
    p_srv, _, _ = actual.pose(np.deg2rad(q_srv))
    p_off, _, _ = actual.pose(comp.q)
    assert np.abs(p_srv - p_off).max() < 4.4e-8 + 1e-9
    assert np.abs(p_off - p_d).max() < 1e-9  # the offline solution reaches the nominal pose
