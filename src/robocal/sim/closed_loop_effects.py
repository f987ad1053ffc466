"""Closed loop of a discovered effect: the twin's cell with a gear error (and backlash) the geometric model
misses, driven through the compensation service.

The campaign is simulated once; ``robocal discover`` finds the effects and writes the extended model as a
calibration (:func:`robocal.workflows.discovery.write_product`); two bundles are served over TCP, the
geometric calibration alone and the discovered model. New joint targets (well conditioned, each with a random
approach direction per joint) are corrected by each service, commanded to the simulated robot (true geometry +
true gear error + true backlash for that approach) and measured with the tracker's noise. Four arms against
the nominal controller's pose in the calibrated cell frame: *uncompensated*, *geometric* (the geometry-only
bundle), *discovered* (the discovered model's bundle) and *oracle* (the true model, same Newton).
"""

from __future__ import annotations

import copy
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.io import write_json
from robocal.kinematics.ik import compile_chain, forward, solve
from robocal.kinematics.transforms import homogeneous
from robocal.serve.bundle import load_bundle, write_bundle
from robocal.serve.client import Client
from robocal.serve.server import Server, ServerConfig, ServerThread
from robocal.serve.settings import ServiceConfig
from robocal.sim.closed_loop import well_conditioned_targets

#: the default cell: the KR16-2 twin with a joint-4 gear error and a joint-2 backlash the geometry misses
DEFAULT_EFFECTS = {
    "gear": {"joint": 4, "harmonics": [{"harmonic": 1, "amplitude_deg": 0.02, "phase_deg": 30.0}]},
    "backlash": {"joints": {2: 0.01}},
}


def true_joint_error(truth: dict[str, Any], q: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """The twin's joint-level error ``dq (m, n)`` rad at commanded joints (gear and backlash effects)."""
    dq = np.zeros_like(q)
    eff = truth.get("effects", {})
    if "gear" in eff:
        j = int(eff["gear"]["joint"]) - 1
        for h in eff["gear"]["harmonics"]:
            dq[:, j] += np.deg2rad(h["amplitude_deg"]) * np.sin(h["harmonic"] * q[:, j] + np.deg2rad(h["phase_deg"]))
    if "backlash" in eff:
        for jn, band in eff["backlash"]["band_deg"].items():
            j = int(jn) - 1
            dq[:, j] += direction[:, j] * np.deg2rad(band) / 2.0
    return dq


def run_discovered_closed_loop(
    out_dir: str | Path,
    seed: int = 0,
    effects: dict[str, Any] | None = None,
    n_targets: int = 60,
    n_poses: int = 80,
) -> dict[str, Any]:
    """Run the loop (module docstring); writes ``closed_loop_discovered.json`` into ``out_dir``; returns it."""
    from robocal.calibration.fit import calibrate
    from robocal.data import read_campaign
    from robocal.kinematics.chain import build_chain
    from robocal.robot import load_robot
    from robocal.sim.scenario import load_scenario
    from robocal.sim.twin import simulate
    from robocal.workflows import discovery

    sc = copy.deepcopy(load_scenario("geometric"))
    sc["effects"] = copy.deepcopy(effects if effects is not None else DEFAULT_EFFECTS)
    unknown = set(sc["effects"]) - {"gear", "backlash"}
    if unknown:
        raise ConfigError(f"the discovered-effect closed loop simulates gear and backlash only; got {sorted(unknown)}")
    sc.update(n_poses=n_poses, n_validation_poses=20)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot = load_robot(sc["robot"])
    chain = build_chain(robot)
    with tempfile.TemporaryDirectory() as tmp:
        camp_dir = Path(tmp) / "campaign"
        truth = simulate(sc, camp_dir, seed=seed, robot=robot)
        camp = read_campaign(camp_dir, robot)
        summ = discovery.run(camp_dir, robot, out / "discovery", report=False, campaign=camp)
        geo = calibrate(camp, robot)
        geo_file = write_json(out / "geometric" / "calibration.json", geo.to_dict())
    bundles = {
        "geometric": write_bundle(out / "bundle_geometric", robot.name, geo_file),
        "discovered": write_bundle(out / "bundle_discovered", robot.name, out / "discovery" / "calibration.json"),
    }
    b = load_bundle(bundles["discovered"])
    eta_true = np.array([truth["kinematic_errors"][n] for n in chain.param_names])
    T_true = np.array(truth["tracker_T_base"])
    tname = b.default_tool
    tool_true = homogeneous(np.array(truth["tool_rotations"][tname]), np.array(truth["tools_mm"][tname]))
    rng = np.random.default_rng(seed + 104729)
    q_t = well_conditioned_targets(robot, chain, b.tools[tname], n_targets, rng, sc.get("joint_ranges_deg"))
    direction = rng.choice(np.array([-1.0, 1.0]), size=q_t.shape)
    p_des, _, _, _ = forward(compile_chain(chain, None, b.tracker_T_base), q_t, b.tools[tname])
    cc_true = compile_chain(chain, eta_true, T_true)

    def true_point(q_cmd: np.ndarray) -> np.ndarray:
        p, _, _, _ = forward(cc_true, q_cmd + true_joint_error(truth, q_cmd, direction), tool_true)
        return p

    # the oracle: the true model's own correction (gear and backlash as joint offsets)
    def true_offset(qc: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return true_joint_error(truth, qc, direction[rows])

    # position only: the campaign measured positions, so the calibrated tool frame's orientation is not the true one
    oracle = solve(cc_true, tool_true, q_t, p_des, None, true_offset, tol_mm=1e-6)
    cfg = ServiceConfig.from_mapping({"safety": {"max_correction_deg": 2.0}})
    commanded = {"uncompensated": q_t, "oracle": oracle.q}
    refused: dict[str, int] = {}
    targets = [
        {"q_deg": np.rad2deg(q).tolist(), "dir": d.astype(int).tolist()} for q, d in zip(q_t, direction, strict=True)
    ]
    accepted = np.ones(n_targets, dtype=bool)
    for arm, bdir in bundles.items():
        with ServerThread(Server(bdir, ServerConfig(port=0), cfg)) as st, Client("127.0.0.1", st.port) as client:
            info = client.info()
            tg = targets if info["effects"] else [{"q_deg": t["q_deg"]} for t in targets]
            reply = client.correct(None, targets=tg)
        q_c = q_t.copy()
        ok = np.array([r["status"] != "refused" for r in reply["results"]])
        for k, r in enumerate(reply["results"]):
            if ok[k]:
                q_c[k] = np.deg2rad(r["q_deg"])
        refused[arm] = int((~ok).sum())
        accepted &= ok
        commanded[arm] = q_c
    noise = rng.normal(0.0, float(truth.get("noise_mm", 0.015)), (n_targets, 3))
    # paired: every arm on the targets both services accepted (a refused correction is never commanded)
    errors = {arm: np.linalg.norm(true_point(q) + noise - p_des, axis=1)[accepted] for arm, q in commanded.items()}
    result = {
        "seed": seed,
        "effects_simulated": sc["effects"],
        "effects_named": [n["key"] for n in summ["named"]],
        "bundle_effects": list(b.info()["effects"]),
        "n_targets": n_targets,
        "mean_error_mm": {a: float(e.mean()) for a, e in errors.items()},
        "max_error_mm": {a: float(e.max()) for a, e in errors.items()},
        "refused": refused,
        "n_compared": int(accepted.sum()),
    }
    write_json(out / "closed_loop_discovered.json", result)
    return result
