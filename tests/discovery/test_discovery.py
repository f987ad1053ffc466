"""Discovery on twin data with one hidden effect: named correctly, RMS to the noise floor, estimates within
3 standard errors of the truth; nothing named without an effect; an out-of-library effect is "unexplained"."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.errors import ConfigError
from robocal.sim.twin import EFFECTS

from .conftest import make_campaign, named

# RMS after must be within 1.1x the noise floor (the criterion): the floor is sigma sqrt(3 dof / M),
# and with ~240 residuals the RMS of pure noise scatters by ~5 % around it.
FLOOR_FACTOR = 1.1
# estimates must be within 3 standard errors of the truth (the criterion; 3 sigma = 99.7 % two-sided).
Z_MAX = 3.0


def _z(est: dict[str, Any], truth: float) -> float:
    return abs(est["value"] - truth) / est["stderr"]


@pytest.mark.parametrize("seed", [1, 2])
def test_gear_joint4_first_harmonic(tmp_path, seed):
    eff = {"gear": {"joint": 4, "harmonics": [{"harmonic": 1, "amplitude_deg": 0.005, "phase_deg": 40.0 * seed}]}}
    camp, robot, truth = make_campaign(tmp_path, "geometric", seed, eff)
    res = discover(camp, robot)
    s = summary(res)
    assert named(s) == [("gear", 4, 1)]
    assert s["rms_after_mm"] <= FLOOR_FACTOR * s["noise_floor_mm"]
    assert not s["unexplained"]
    h = truth["effects"]["gear"]["harmonics"][0]
    est = s["named"][0]["estimates"]
    assert _z(est["sin_deg"], h["sin_deg"]) < Z_MAX
    assert _z(est["cos_deg"], h["cos_deg"]) < Z_MAX


def test_backlash(tmp_path):
    camp, robot, truth = make_campaign(tmp_path, "geometric", 3, {"backlash": {"joints": {2: 0.006, 5: 0.02}}})
    s = summary(discover(camp, robot))
    assert sorted(named(s)) == [("backlash", 2, None), ("backlash", 5, None)]
    assert s["rms_after_mm"] <= FLOOR_FACTOR * s["noise_floor_mm"]
    for n in s["named"]:
        assert _z(n["estimates"]["band_deg"], truth["effects"]["backlash"]["band_deg"][n["joint"]]) < Z_MAX


def test_backlash_same_direction_is_skipped(tmp_path):
    """Every pose approached the same way: the backlash is a constant joint offset, and the candidate is skipped."""
    camp, robot, _ = make_campaign(tmp_path, "geometric", 4, {"backlash": {"joints": {3: 0.01}}})
    from dataclasses import replace

    assert camp.direction is not None
    d = camp.direction.copy()
    d[:, 2] = 1.0
    s = summary(discover(replace(camp, direction=d), robot))
    assert any(k["key"] == "backlash:j3" and "same way" in k["reason"] for k in s["skipped"])
    assert ("backlash", 3, None) not in named(s)


def test_drift(tmp_path):
    eff = {"drift": {"rate_mm_per_h": [0.3, -0.2, 0.25]}}
    camp, robot, truth = make_campaign(tmp_path, "geometric", 5, eff)
    s = summary(discover(camp, robot))
    assert named(s) == [("drift", None, None)]
    assert s["rms_after_mm"] <= FLOOR_FACTOR * s["noise_floor_mm"]
    est = s["named"][0]["estimates"]
    for a, axis in enumerate("xyz"):
        assert _z(est[f"tracker_{axis}_mm_per_h"], truth["effects"]["drift"]["rate_mm_per_h"][a]) < Z_MAX


def test_compliance_gravity_torque(tmp_path):
    """KR16-2 with two payloads, no torques or currents reported: the signal is the gravity torque."""
    eff = {
        "compliance": {
            "c_rad_per_Nm": [0.0, 1.5e-6, 2.0e-6, 0.0, 0.0, 0.0],
            "torque_constant_Nm_per_A": [1.0] * 6,
            "calibration_loads_kg": [0.0, 16.0],
            "validation_loads_kg": [0.0, 16.0],
            "report_currents": False,
            "report_directions": False,
            "mass_error_sd": 0.0,
        }
    }
    camp, robot, truth = make_campaign(tmp_path, "geometric", 6, eff, n_poses=50, n_validation_poses=10)
    assert camp.current_A is None and camp.tau_Nm is None
    s = summary(discover(camp, robot))
    assert sorted(named(s)) == [("compliance", 2, None), ("compliance", 3, None)]
    assert s["rms_after_mm"] <= FLOOR_FACTOR * s["noise_floor_mm"]
    c = truth["effects"]["compliance"]["c_rad_per_Nm"]
    for n in s["named"]:
        assert _z(n["estimates"]["c_rad_per_Nm"], c[n["joint"] - 1]) < Z_MAX


def test_compliance_currents_heavy_load(tmp_path):
    """SR210 at 0 / 210 kg with motor currents (the heavy-load scenario without friction and with a quiet
    current reading): every loaded joint named, coefficients per ampere within 3 SE."""
    over = {"coulomb_Nm": [0.0] * 6, "viscous_Nm_s_per_deg": [0.0] * 6, "current_noise_A": 0.001}
    from robocal.sim.twin import load_scenario

    eff = load_scenario("heavy_load")["effects"]
    eff["compliance"].update(over)
    camp, robot, truth = make_campaign(tmp_path, "heavy_load", 7, eff)
    s = summary(discover(camp, robot, DiscoveryConfig(noise_mm=0.02)))
    assert {e for e, _, _ in named(s)} == {"compliance"}
    assert {j for _, j, _ in named(s)} >= {2, 3, 4, 5}
    assert s["rms_after_mm"] <= FLOOR_FACTOR * s["noise_floor_mm"]
    c = truth["effects"]["compliance"]["c_rad_per_A"]
    for n in s["named"]:
        assert _z(n["estimates"]["c_rad_per_A"], c[n["joint"] - 1]) < Z_MAX


def test_thermal_warm_up(tmp_path):
    """The thermal twin (warm-up, drift of several parameters with their own sensors): 'thermal' is named, the
    RMS reaches the floor, and the modelled tool-point drift matches the true one where the geometry cannot
    absorb it."""
    camp, robot, _ = make_campaign(tmp_path, "thermal", 1)
    res = discover(camp, robot)
    s = summary(res)
    assert named(s) == [("thermal", None, None)]
    assert s["rms_after_mm"] <= FLOOR_FACTOR * s["noise_floor_mm"]
    assert s["rms_before_mm"] > 2 * s["noise_floor_mm"]  # the effect was really there


@pytest.mark.parametrize("seed", [2, 3])
def test_thermal_drift_at_the_tool_within_3_standard_errors(tmp_path, seed):
    """The thermal candidate's coefficients (parameters on principal components of the temperatures) have no
    one-to-one truth; its drift at the tool does. Per measurement state, relative to each pose's first
    measurement: the modelled drift (discovery.json estimates.drift_by_state) against the twin's true drift
    (true robot with the true thermal model at the same rows), within 3 standard errors on every axis."""
    from robocal.discovery.summary import state_drift
    from robocal.kinematics.chain import build_chain
    from robocal.thermal.compensate import true_robot
    from robocal.thermal.model import ThermalModel
    from robocal.thermal.validate import reorder

    camp, robot, truth = make_campaign(tmp_path, "thermal", seed)
    res = discover(camp, robot)
    s = summary(res)
    assert named(s) == [("thermal", None, None)]
    acc = res.accepted[0]
    sd = state_drift(res, acc)
    assert s["named"][0]["estimates"]["drift_by_state"] == sd["states"]
    cal = camp.subset(res.final.rows)
    chain = build_chain(robot)
    tm = ThermalModel.from_dict(truth["effects"]["thermal"]["model"])
    d_true = tm.deta(reorder(cal.temperatures, cal.sensor_names, tm.sensors))
    p_true = np.array(
        [
            true_robot(truth, chain, str(cal.target[i]), d_true[i]).pose(cal.q[i : i + 1])[0][0]
            for i in range(cal.n_rows)
        ]
    )
    state, ref = sd["_state"], sd["_ref"]
    zs = []
    for k, entry in enumerate(sd["states"]):
        sel = state == k
        true_k = (p_true[sel] - p_true[ref[sel]]).mean(axis=0)
        for a, axis in enumerate("xyz"):
            est = entry[f"{axis}_mm"]
            if k == 0:  # the reference state itself: zero by construction
                assert abs(est["value"]) < 1e-12 and abs(true_k[a]) < 1e-12
                continue
            zs.append(_z(est, true_k[a]))
    assert len(zs) == 3 * (len(sd["states"]) - 1) and len(zs) >= 12
    assert max(zs) < Z_MAX, zs
    # and the drift is far from zero: the check has power (~0.2 mm of z drift against SEs of ~3 um)
    assert max(abs(e["z_mm"]["value"]) for e in sd["states"]) > 20 * max(e["z_mm"]["stderr"] for e in sd["states"])


def test_null_names_nothing(tmp_path):
    """No hidden effect: nothing named on several seeds (the 200-seed figure is benchmarks/discovery_null.py)."""
    for seed in (11, 12, 13, 14):
        camp, robot, _ = make_campaign(tmp_path, "geometric", seed, {})
        s = summary(discover(camp, robot))
        assert named(s) == [], seed
        assert s["steps"][0]["accepted"] is None


def test_out_of_library_is_unexplained_without_the_dictionary(tmp_path):
    assert "test_q1q5" in EFFECTS
    for seed in (21, 22, 23):
        camp, robot, _ = make_campaign(tmp_path, "geometric", seed, {"test_q1q5": {"amplitude_deg": 0.02}})
        s = summary(discover(camp, robot, DiscoveryConfig(dictionary=False)))
        assert s["proposed"] == []
        assert named(s) == [], seed
        assert s["unexplained"], seed
        # where it lives: a joint-angle error is located on joint 4 or confused with one neighbour (a position
        # residual cannot always tell joint 4 from another joint's smooth error: top 2 of 6 is the honest claim)
        assert 4 in [j["joint"] for j in s["unexplained_where"]["joints"][:2]], seed


def test_absorbed_candidate_is_unidentifiable_never_chosen(tmp_path):
    """All poses at one payload and torques constant would be skipped; a gear harmonic of a joint held at two
    angles only is absorbed by its offset: reported unidentifiable."""
    camp, robot, _ = make_campaign(tmp_path, "geometric", 8, {})
    from dataclasses import replace

    q = camp.q.copy()
    q[:, 5] = np.where(np.arange(len(q)) % 2 == 0, 0.1, 0.1)  # joint 6 never moves
    s = summary(discover(replace(camp, q=q), robot))
    assert any(k["key"].startswith("gear:j6") and "does not move" in k["reason"] for k in s["skipped"])


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="alpha"):
        DiscoveryConfig.from_mapping({"alpha": 0})
    with pytest.raises(ConfigError, match=r"discovery\.alpah: unknown setting"):
        DiscoveryConfig.from_mapping({"alpah": 0.1})
    with pytest.raises(ConfigError, match="effects"):
        DiscoveryConfig.from_mapping({"effects": ["gear", "wobble"]})


def test_cli_writes_discovery_json(tmp_path):
    from robocal.cli import main
    from robocal.sim.twin import load_scenario, simulate

    sc = load_scenario("geometric")
    sc["effects"] = {"backlash": {"joints": {3: 0.01}}}
    simulate(sc, tmp_path / "data", seed=9)
    rc = main(["discover", str(tmp_path / "data"), "--robot", "kr16_2", "--out", str(tmp_path / "out")])
    assert rc == 0
    d = json.loads((tmp_path / "out" / "discovery.json").read_text())
    for key in ("named", "steps", "rms_before_mm", "rms_after_mm", "noise_floor_mm", "unexplained", "skipped"):
        assert key in d
    assert [(n["effect"], n["joint"], n["harmonic"]) for n in d["named"]] == [("backlash", 3, None)]
    assert set(d["named"][0]["estimates"]["band_deg"]) == {"value", "stderr", "unit"}
    assert d["steps"][0]["rms_after_mm"] < d["steps"][0]["rms_before_mm"]
    assert (tmp_path / "out" / "report.html").stat().st_size > 10_000


def test_out_of_library_effect_gets_its_equation(tmp_path):
    """The same hidden effect with the dictionary on: proposed (not named) as dθ4 = A · sin(2q1)·cos(q5), with
    the amplitude within 3 standard errors, and the residual back at the floor."""
    for seed in (21, 22):
        camp, robot, _ = make_campaign(tmp_path, "geometric", seed, {"test_q1q5": {"amplitude_deg": 0.025}})
        s = summary(discover(camp, robot))
        assert named(s) == [], seed
        assert len(s["proposed"]) == 1, s["proposed"]
        p = s["proposed"][0]
        assert p["joint"] == 4 and [t["signal"] for t in p["terms"]] == ["sin(2q1)·cos(q5)"], p
        c = p["terms"][0]["coefficient_deg"]
        assert abs(c["value"] - 0.025) < 3 * c["stderr"], c
        assert p["equation"].startswith("dθ4 = 0.0") and "sin(2q1)·cos(q5)" in p["equation"]
        assert p["selection"]["log10_p"] < p["selection"]["threshold_log10_p"]
        assert not s["unexplained"]
        assert s["rms_after_mm"] < 1.1 * s["noise_floor_mm"]


def test_dictionary_proposes_nothing_on_clean_campaigns(tmp_path):
    # 200 null seeds: none proposed (benchmarks/discovery_null.py --mode dictionary); four here
    for seed in (31, 32, 33, 34):
        camp, robot, _ = make_campaign(tmp_path, "geometric", seed, {})
        s = summary(discover(camp, robot))
        assert s["proposed"] == [] and named(s) == [], seed


def test_the_mass_free_weight_model_competes_with_given_masses(tmp_path):
    """A description with link masses that are off (50 % per link, as a vendor's estimates or a URDF without the
    tool's mass): the weight model (the torque of those masses and the combinations that correct them) is offered
    beside the compliance from the masses (newcomer pass 9: it was not, compliance j2, j3 from the given masses
    0.137 mm held out, the weight model without the masses 0.059; now 0.055)."""
    from robocal.discovery.validate import validation_errors

    eff = {
        "compliance": {
            "c_rad_per_Nm": [0.0, 1.5e-6, 2.0e-6, 0.0, 0.0, 0.0], "torque_constant_Nm_per_A": [1.0] * 6,
            "calibration_loads_kg": [0.0], "validation_loads_kg": [0.0], "report_currents": False,
            "report_directions": False, "mass_error_sd": 0.5,
        }
    }  # fmt: skip
    camp, robot, _ = make_campaign(tmp_path, "geometric", 7, eff, n_poses=60, n_validation_poses=30)
    assert robot.has_dynamics
    res = discover(camp, robot)
    s = summary(res, validation_errors(res))
    offered = {c["key"] for st in s["steps"] for c in st.get("candidates", [])}
    assert {"weight:j2", "weight:j3"} <= offered
    assert {e for e, _, _ in named(s)} == {"compliance", "weight"}  # seed 7: without it compliance j2 alone
    # held out near the noise floor (0.015 mm per coordinate: 0.0239 mm mean 3-D; 0.0281 here, 0.0312 before)
    assert s["validation"]["final"]["mean_position_mm"] < 1.25 * 0.0239


def test_an_effect_the_held_out_check_drops_gives_the_library_another_pass():
    """A heavy arm in 18 configurations (tests/discovery/campaigns/fanuc_com_behind): the library took a gear
    harmonic of joint 2 before the weight on joint 3, the held-out check dropped the harmonic and joint 3 was left
    without a model (0.307 mm held out). An effect the library took and the check drops gives the library another
    pass without it, its additions checked the same way. (The weight's links split into the one the joint turns
    and those beyond it now carry the shoulder without the harmonic: weight j2, j3, 0.158 mm; 0.259 with the
    harmonic kept.) A threshold that drops the library's effects shows the second pass and its check."""
    from pathlib import Path

    from robocal.data.contract import read_campaign
    from robocal.discovery.validate import validation_errors
    from robocal.robot import load_robot

    folder = Path(__file__).parent / "campaigns" / "fanuc_com_behind"
    robot = load_robot(str(folder / "robot.yaml"))
    camp = read_campaign(folder, robot)
    res = discover(camp, robot)
    s = summary(res, validation_errors(res))
    assert s["validation"]["final"]["mean_position_mm"] < 0.20  # 0.158 (0.307, then 0.259 before; geometric 0.834)
    # (the counterbalance's columns off: the search path this mechanism was shown on; a gain of 300 % asked of each
    # effect: the check drops the library's)
    res = discover(camp, robot, DiscoveryConfig(min_held_out_gain=3.0, counterbalance="off"))
    phases = [st["phase"] for st in summary(res)["steps"]]
    first = phases.index("held-out check of the parametric model")
    # the library once more after the check (its steps), and the check once more on what it added
    again = phases.index("library F-test search", first + 1)
    assert "held-out check of the parametric model" in phases[again + 1 :]


def test_the_same_configurations_measured_in_another_order_give_the_same_model(tmp_path):
    """Newcomer pass 10: the configurations of each station measured in another order (times reassigned) changed
    the model — the held-out check judges an effect in a session left out, each half of its poses registering the
    tracker for the other, and a loss there dropped effects by chance (weight j3: 0.158 -> 0.256 mm on one arm; a
    false drift accepted on this one, 0.431 mm). A loss in the session left out counts only when pose by pose it is
    more than chance (the selection's paired test at cv_alpha)."""
    import shutil
    from pathlib import Path

    import pandas as pd

    from robocal.data.contract import read_campaign
    from robocal.discovery.validate import validation_errors
    from robocal.robot import load_robot

    folder = Path(__file__).parent / "campaigns" / "fanuc_com_behind"
    robot = load_robot(str(folder / "robot.yaml"))
    d = pd.read_csv(folder / "poses.csv")
    block = d.groupby(["split", "station"], sort=False).ngroup()
    ids = d.pose_id.unique()
    rank = dict(zip(ids, np.random.default_rng(3).permutation(len(ids)), strict=True))
    d = d.assign(_b=block, _o=d.pose_id.map(rank)).sort_values(["_b", "_o", "target"], kind="stable")
    t0 = pd.Timestamp(d.timestamp.iloc[0])
    d["timestamp"] = [(t0 + pd.Timedelta(seconds=30 * i)).isoformat().replace("+00:00", "Z") for i in range(len(d))]
    other = tmp_path / "reordered"
    other.mkdir()
    d.drop(columns=["_b", "_o"]).to_csv(other / "poses.csv", index=False)
    shutil.copy(folder / "robot.yaml", other / "robot.yaml")
    out = []
    # the counterbalance's choice off: offered, the reordered campaign's search with it takes a false linear drift
    # of the tracker (0.525 mm held out) and the choice keeps the search without it (weight j2, gear j2 h2: 0.2592
    # mm), where the original order keeps the one with it (weight j2, j3: 0.2496): a drift order-dependence this
    # test does not cover (the closing note of 2026-11-27's third stop)
    cfg = DiscoveryConfig(counterbalance="off")
    for f in (folder, other):
        res = discover(read_campaign(f, robot), robot, cfg)
        s = summary(res, validation_errors(res))
        out.append((sorted(n["key"] for n in s["named"]), s["validation"]["final"]["mean_position_mm"]))
    assert out[0][0] == out[1][0]
    assert abs(out[0][1] - out[1][1]) < 0.01  # mm (0.2592 both; 0.256 / 0.431 before)


def test_the_parameters_calibrate_holds_as_poorly_determined_stay_held_in_the_discovery(tmp_path):
    """Newcomer pass 16 (D1): a column arm with one reflector on the wrist's axis: calibrate holds theta6 and alpha7
    at their start (the data cannot determine them); discovery's refits freed them, and they wandered with the
    effects (a7 34 mm, theta6 6.9 deg) while the held-out positions showed nothing (0.1732 mm) — compensation.csv
    turned the wrist by a median 9.7 deg (max 30) and refused 3 of 30 targets. Held there too: 0.1694 mm, the
    corrections under 1.5 deg, none refused."""
    import json
    from pathlib import Path

    import pandas as pd

    from robocal.workflows.discovery import run

    folder = Path(__file__).parent / "campaigns" / "column_dh_one_prism"
    s = run(folder, str(folder / "robot.yaml"), tmp_path, report=False)
    cal = json.loads((tmp_path / "calibration.json").read_text())
    ke = cal["kinematic_errors"]
    assert ke["theta6"] == 0.0 and ke["alpha7"] == 0.0, {k: ke[k] for k in ("theta6", "alpha7", "a7", "d6")}
    assert abs(ke["a7"]) < 2.0  # mm: 0.49 (the truth's tool offsets are within 0.5 mm); freed it reached 34
    comp = pd.read_csv(tmp_path / "compensation.csv")
    # a few tenths of a degree: the geometry's 0.1-0.5 mm and the tilt; 9.7 deg median freed
    # judged by the service's policy (its 0.5 deg bound), the position alone matched (a point reflector: the tool's
    # orientation is not the data's; matched, the wrist chased it, 0.57-1.38 deg, 9 of 30 refused): max 0.30
    assert comp["correction_max_deg"].max() < 0.5 and (comp["status"] != "refused").all()
    assert s["validation"]["final"]["mean_position_mm"] < 0.18  # 0.1694 (0.1732 freed; oracle 0.144, floor 0.16)


def test_a_column_without_masses_or_accelerometers_bends_by_its_links_shape_not_by_gross_errors(tmp_path):
    """Newcomer pass 16 (D2): the same column arm without its accelerometers, given as a DH table (no masses): the
    bending's only form was one coefficient per unknown mass parameter (24 here, no growth with the extension),
    which 25 placements could not carry — nothing named, 0.556 mm held out, and three top-height rows (1.9 mm) left
    out as gross errors. The moment of links shaped like the arm's, and times the extension (4 coefficients), is
    its compact form: named, no row called a gross error, held out 0.241 mm (oracle 0.144, floor 0.16)."""
    import shutil
    from pathlib import Path

    import pandas as pd

    from robocal.workflows.discovery import run

    src = Path(__file__).parent / "campaigns" / "column_dh_one_prism"
    d = tmp_path / "noacc"
    d.mkdir()
    shutil.copy(src / "robot.yaml", d / "robot.yaml")
    poses = pd.read_csv(src / "poses.csv", dtype=str, keep_default_na=False)
    poses.drop(columns=["acc_x_g", "acc_y_g", "acc_z_g"]).to_csv(d / "poses.csv", index=False)
    s = run(d, str(d / "robot.yaml"), tmp_path / "out", report=False)
    assert "column:bending_rods" in [n["key"] for n in s["named"]]
    assert s["outliers"] == [] and s["geometric_calibration"]["outlier_rows"] == []
    assert s["validation"]["final"]["mean_position_mm"] < 0.3  # 0.241 (0.556 before; geometric 0.582)
    assert "compensation.csv" in s["written"]  # the service's axis model reads the rods' terms
