"""One compensation path: a joint-space effect listed once (Bundle.joint_effects) reaches the service and the program
filter, and counts as the calibration's own correction for the one safety policy; the thermal CSV, the service and
the filter share that policy and its defaults."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from robocal.compensation.effects import Signals


@dataclass(frozen=True)
class PeriodicGear:
    """A new joint-space effect as the residual work will add it: a per-joint periodic error (rad)."""

    amplitude: np.ndarray
    name: str = "periodic gear"
    needs: frozenset[str] = frozenset()

    def offsets(self, q: np.ndarray, s: Signals) -> np.ndarray:
        return self.amplitude * np.sin(2.0 * q)


@pytest.fixture()
def geo(geometric_bundle):
    from robocal.serve.bundle import load_bundle

    return load_bundle(geometric_bundle)


def _with(bundle, effect):
    """The bundle with one more joint-space effect, added where a bundle lists them (Bundle.joint_effects)."""
    import copy

    b = copy.copy(bundle)
    listed = bundle.joint_effects()
    object.__setattr__(b, "joint_effects", lambda: [*listed, effect])
    return b


def test_a_new_effect_reaches_the_service_and_the_filter_and_the_policy(geo, tmp_path):
    from robocal.cell.programs.filter import filter_program, read_program
    from robocal.cell.programs.make import rapid_module
    from robocal.kinematics.ik import compile_chain
    from robocal.serve.protocol import Service

    amp = np.deg2rad([0.0, 1.5, 1.0, 0.0, 0.0, 0.0])  # up to 1.3 deg: above the 0.5 deg bound unless counted as own
    gear = PeriodicGear(amp)
    bundle = _with(geo, gear)
    q_deg = np.array([[10.0, -80.0, 70.0, 20.0, 45.0, 30.0], [-25.0, -60.0, 50.0, -40.0, 60.0, -100.0]])
    req = {"targets": [{"q_deg": q.tolist()} for q in q_deg]}
    plain = json.loads(Service(geo).handle_line(json.dumps(req).encode()))["results"]
    geared = json.loads(Service(bundle).handle_line(json.dumps(req).encode()))["results"]
    assert [r["status"] for r in geared] == ["ok", "ok"], geared  # the effect is the calibration's own
    for a, b in zip(plain, geared, strict=True):
        shift = np.array(b["correction_deg"]) - np.array(a["correction_deg"])
        # the robot now turns by the effect at the commanded joints more: the correction takes it back
        effect = np.rad2deg(gear.offsets(np.deg2rad(np.array(b["q_deg"]))[None], None)[0])
        assert np.abs(effect).max() > 0.5
        assert np.abs(shift + effect).max() < 0.01  # the geometric correction's own change with the pose
    # the filter: the same effect through the same code
    cc = compile_chain(geo.chain)
    (tmp_path / "M.mod").write_text(rapid_module("M", cc, np.deg2rad(q_deg), np.eye(4), np.eye(4)))
    prog = read_program(tmp_path / "M.mod")
    f_plain = filter_program(prog, geo)
    f_geared = filter_program(prog, bundle)
    assert f_geared.status == ["ok"] * len(prog.targets)
    assert np.abs(f_geared.q_corrected_deg - f_plain.q_corrected_deg).max() > 0.1


def test_one_policy_with_one_set_of_defaults():
    from robocal.compensation.safety import SafetyPolicy
    from robocal.serve.protocol import ServiceConfig
    from robocal.thermal.compensate import ThermalCompensation
    from robocal.thermal.fit import ThermalConfig

    assert ServiceConfig().safety == SafetyPolicy()
    # the thermal stage sets only its temperature margin; the correction bound is the service's 0.5 deg
    th = ThermalConfig.from_mapping({"compensation": {"temperature_margin_C": 1.0}}).limits
    assert th.max_correction_deg == SafetyPolicy().max_correction_deg == 0.5
    assert ThermalCompensation.__dataclass_fields__["limits"].type in ("SafetyPolicy", SafetyPolicy)


def test_outside_the_residual_layer_the_service_and_the_filter_say_so(geo, tmp_path):
    """A bundle whose discovered effects include a residual layer calibrated around one configuration: a target
    there gets the layer; a target far from it the parametric correction only, and the service's reply, the
    filter's result and its table say so (a note, not a flag)."""
    import csv
    import dataclasses

    from robocal.cell.programs.filter import filter_program, read_program
    from robocal.cell.programs.make import rapid_module
    from robocal.compensation.discovered import LAYER_NOTE
    from robocal.kinematics.ik import compile_chain
    from robocal.serve.protocol import Service

    inside = np.array([10.0, -80.0, 70.0, 20.0, 45.0, 30.0])
    outside = np.array([-100.0, -30.0, 20.0, -120.0, 90.0, -150.0])
    layer = {"key": "layer:j2", "effect": "layer", "joint": 2, "signal": "layer", "coefficients": [1e-4],
             "centres_rad": [np.deg2rad(inside).tolist()], "length_rad": 0.3, "inside_rad": 0.2}  # fmt: skip
    bundle = dataclasses.replace(geo, effects=(layer,))
    req = {"targets": [{"q_deg": q.tolist()} for q in (inside, outside)]}
    res = json.loads(Service(bundle).handle_line(json.dumps(req).encode()))["results"]
    assert "notes" not in res[0], res[0]
    assert res[1]["notes"] and res[1]["notes"][0].startswith(LAYER_NOTE), res[1]
    assert [r["status"] for r in res] == ["ok", "ok"]  # a note is not a flag
    cc = compile_chain(geo.chain)
    (tmp_path / "M.mod").write_text(
        rapid_module("M", cc, np.deg2rad(np.vstack([inside, outside])), np.eye(4), np.eye(4))
    )
    prog = read_program(tmp_path / "M.mod")
    f = filter_program(prog, bundle)
    far = np.abs(f.q_nominal_deg - outside).max(axis=1) < 0.01  # the module's targets at the outside joints
    assert far.any() and not far.all()
    assert all(bool(n) == bool(o) for n, o in zip(f.notes, far, strict=True)), f.notes
    assert all(n[0].startswith(LAYER_NOTE) for n in f.notes if n)
    rows = list(csv.DictReader(f.table.splitlines()))
    assert [bool(r["notes"]) for r in rows] == far.tolist()
