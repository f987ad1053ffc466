"""Which region a plan is good for (issue 23, item 14): `robocal plan --robot kr16_2 --n 40` (its defaults) against
50 random poses, validated over the robot's working range.

For each seed s: the plan of conf/plan/default.yaml with seed s and n_poses 40 (exactly what
``robocal plan --robot kr16_2 --n 40 seed=s`` plans), and 50 random poses drawn from the same accepted candidates
(the poses the tracker can measure in the same cell). A twin with other errors than anything the plan assumed
(conf/scenario/geometric.yaml, twin seed 1000 + s: random joint-level errors 0.3 mm / 0.02 deg, the tracker frame,
15 um noise) measures both pose sets; robocal calibrates each; the calibrated model's error (noise-free
measurement of the same true robot) is averaged over 200 random poses drawn uniformly over the robot's working
range (joint limits less 5 deg, tracker or not: the robot works there).

``--set key=value`` changes the plan settings (e.g. ``--set region.kind=cell --set criterion=D``, the planner's
behaviour before this issue), so old and new defaults can be compared on the same twins:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/plan_region.py [--seeds 3] [--set key=value ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.validation import validate
from robocal.commands import parse_overrides
from robocal.commands.simulate import merge_overrides
from robocal.data.contract import read_campaign
from robocal.plan import PlanConfig, plan_poses, predict, random_poses
from robocal.plan.problem import rng_stream
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.twin import simulate

ROOT = Path(__file__).resolve().parents[1]


def model_errors(
    sc: dict[str, Any], twin_seed: int, q_cal: np.ndarray, q_val: np.ndarray, robot: Any, tmp: Path, draws: int
) -> np.ndarray:
    """Mean 3-D error (mm) at ``q_val`` of the model calibrated from ``q_cal``, for ``draws`` realisations of the
    tracker's noise: the twin (seed ``twin_seed``: its true errors) measures every pose noise-free once; each draw
    adds N(0, noise_mm) per coordinate to the calibration rows, calibrates, and compares the calibrated model
    with the noise-free measurement of the same true robot at the validation rows (the model's own error)."""
    s = dict(sc)
    s["poses_deg"] = np.round(np.rad2deg(q_cal), 6).tolist()
    s["validation_poses_deg"] = np.round(np.rad2deg(q_val), 6).tolist()
    simulate(dict(s, noise_mm=0.0), tmp / "exact", seed=twin_seed, robot=robot)
    exact = read_campaign(tmp / "exact", robot)
    cal = exact.split != "validation"
    rng = np.random.default_rng(np.random.SeedSequence(entropy=twin_seed, spawn_key=(7,)))
    out = []
    for _ in range(draws):
        noise = rng.normal(0.0, sc["noise_mm"], exact.p_mm.shape) * cal[:, None]
        res = calibrate(
            dataclasses.replace(exact, p_mm=exact.p_mm + noise), robot, CalibrationConfig(noise_mm=sc["noise_mm"])
        )
        out.append(float(validate(res, exact)["mean_position_mm"]))
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--random", type=int, default=50)
    ap.add_argument("--validation", type=int, default=200)
    ap.add_argument("--draws", type=int, default=20, help="tracker-noise realisations per seed and pose set")
    ap.add_argument("--set", action="append", default=[], help="plan setting key=value")
    args = ap.parse_args()
    robot = load_robot("kr16_2")
    cfg0 = yaml.safe_load((ROOT / "conf" / "plan" / "default.yaml").read_text())
    cfg0.pop("measured_by_twin", None)
    cfg0 = merge_overrides(cfg0, parse_overrides(args.set))
    sc = load_scenario("geometric")
    lim = robot.q_limits + np.deg2rad(5.0) * np.array([1.0, -1.0])
    print(f"plan settings changed: {args.set or 'none (the defaults)'}")
    print(
        f"| seed | planned {args.n} (mm) | random {args.random} (mm) | planned / random "
        "| predicted RMS over the region, planned / random (mm) | region the plan was made for |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    ratios = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        for s in range(args.seeds):
            cfg = PlanConfig.from_mapping({**cfg0, "n_poses": args.n, "seed": s})
            plan = plan_poses(robot, cfg, curve=False)
            pr = plan.problem
            i_rand = random_poses(pr, args.random, rng_stream(s, "benchmark-random"))
            q_rand = pr.cand.q[i_rand]
            pred = (predict(pr, plan.idx).get("region_rms_mm"), predict(pr, i_rand).get("region_rms_mm"))
            vrng = np.random.default_rng(np.random.SeedSequence(entropy=s, spawn_key=(23, 14)))
            q_val = vrng.uniform(lim[:, 0], lim[:, 1], size=(args.validation, robot.n_joints))
            e_plan = float(np.mean(model_errors(sc, 1000 + s, plan.q, q_val, robot, Path(d), args.draws)))
            e_rand = float(np.mean(model_errors(sc, 1000 + s, q_rand, q_val, robot, Path(d), args.draws)))
            ratios.append(e_plan / e_rand)
            print(
                f"| {s} | {e_plan:.5f} | {e_rand:.5f} | {e_plan / e_rand:.3f} | {pred[0]:.4f} / {pred[1]:.4f} "
                f"| {cfg.region.describe(cfg.joint_margin_deg)} |"
            )
    r = np.array(ratios)
    print(
        f"planned {args.n} vs random {args.random}: worst ratio {r.max():.2f}, mean {r.mean():.2f}; "
        f"planned no worse than random on {int(np.sum(r <= 1.0))}/{len(r)} seeds ({time.perf_counter() - t0:.0f} s)"
    )


if __name__ == "__main__":
    main()
