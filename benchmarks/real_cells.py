"""Real cells (issue 12): gross errors, false flags, the four-effect campaign, real ABB data, true "before".

    python benchmarks/real_cells.py [--gross-seeds 20] [--clean-seeds 100] [--four-seeds 5]

1. KR16-2 twin, 80 poses, 3 gross errors of 0.5-3 mm per campaign (random rows, random directions), over
   ``--gross-seeds`` seeds: every gross error flagged?, fit RMS on the kept rows over the noise floor, share of
   (parameter, seed) pairs within 3 standard errors of the truth (the equivalent truth of the identified set).
2. The same twin without gross errors over ``--clean-seeds`` seeds: campaigns with any flag (false-flag rate).
3. The four-effect campaign (compliance j2, j3, j5 from gravity torques, gear j4) with 2 gross errors: named
   effects, flagged rows, RMS over the floor.
4. ``../shared/data/abb-irb120`` (skipped without it): calibrate's outliers, the true "before" beside the old
   figure (registration alternations stopped after ``registration_iters``), discovery's validation on T4.
5. The default campaign (conf/scenario/thermal.yaml): true "before" beside the old figure.
"""

from __future__ import annotations

import argparse
import copy
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.start import fit_data, present_targets, register_frames
from robocal.data import read_campaign
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors
from robocal.identification.model import CalibrationModel
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.truth import z_scores
from robocal.sim.twin import simulate

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"

FOUR = {
    "compliance": {
        "c_rad_per_Nm": [0.0, 1.5e-6, 2.0e-6, 0.0, 3.0e-6, 0.0],
        "torque_constant_Nm_per_A": [1.0] * 6,
        "calibration_loads_kg": [0.0, 16.0],
        "validation_loads_kg": [0.0, 16.0],
        "report_currents": False,
        "report_directions": False,
        "mass_error_sd": 0.0,
    },
    "gear": {"joint": 4, "harmonics": [{"harmonic": 1, "amplitude_deg": 0.005, "phase_deg": 30.0}]},
}


def _camp(sc: dict, seed: int, robot):
    d = Path(tempfile.mkdtemp(prefix="rc_"))
    truth = simulate(sc, d, seed=seed, robot=robot)
    return read_campaign(d, robot), truth


def old_before(camp, robot, iters: int = 20) -> float:
    """The figure reported before this change: nominal kinematics at the registration after ``iters``
    alternations (mean 3-D error of the calibration rows)."""
    cal = camp.calibration() if np.any(camp.split == "validation") else camp
    targets = present_targets(cal)
    data = fit_data(cal, False, targets)
    model = CalibrationModel(robot, targets, orientation=False)
    T, tools = register_frames(model, data, iters)
    m2 = CalibrationModel(robot, targets, orientation=False, T_ref=T)
    x = m2.zeros()
    x[m2.n_chain : m2.n_chain + 3 * len(targets)] = tools.ravel()
    r = m2.residuals(x, data).reshape(-1, 3)
    return float(np.linalg.norm(r, axis=1).mean())


def gross(seeds: int, robot) -> None:
    sc = copy.deepcopy(load_scenario("geometric"))
    sc["gross_errors"] = {"n": 3, "min_mm": 0.5, "max_mm": 3.0}
    all_found = 0
    ratios, z_in, z_all, off_ratio = [], 0, 0, []
    for seed in range(seeds):
        camp, truth = _camp(sc, seed, robot)
        res = calibrate(camp, robot)
        flagged = {o["row"] for o in res.fit["outliers"]}
        true = {g["row"] for g in truth["gross_errors"]}
        all_found += true <= flagged
        extra = flagged - true
        ratios.append(res.fit["rms_position_mm"] / res.fit["noise_floor_rms_mm"])
        cal = camp.calibration()
        kept = res.start.kept
        z = np.array(list(z_scores(res, truth, cal.q[kept], cal.target_index[kept]).values()))
        z_in += int(np.sum(np.abs(z) <= 3))
        z_all += len(z)
        off = calibrate(camp, robot, CalibrationConfig(outliers="off"))
        off_ratio.append(off.fit["rms_position_mm"] / off.fit["noise_floor_rms_mm"])
        if extra:
            print(f"  seed {seed}: extra flags {sorted(extra)}")
    r = np.array(ratios)
    print(
        f"1. gross errors ({seeds} seeds x 3, 0.5-3 mm): all flagged in {all_found}/{seeds}; fit RMS / floor on kept "
        f"rows: mean {r.mean():.3f}, max {r.max():.3f} (outliers off: mean {np.mean(off_ratio):.1f}x); "
        f"(parameter, seed) pairs within 3 SE: {z_in}/{z_all} = {100 * z_in / z_all:.2f} %"
    )


def clean(seeds: int, robot) -> None:
    sc = copy.deepcopy(load_scenario("geometric"))
    any_flag = 0
    for seed in range(1000, 1000 + seeds):
        camp, _ = _camp(sc, seed, robot)
        res = calibrate(camp, robot)
        if res.fit["outliers"]:
            any_flag += 1
            print(f"  clean seed {seed}: false flags {[o['row'] for o in res.fit['outliers']]}")
    print(
        f"2. clean campaigns ({seeds} seeds): {any_flag} with any flag = {100 * any_flag / seeds:.1f} % "
        "(family-wise alpha 0.1 %)"
    )


def four(seeds: int, robot) -> None:
    for seed in range(seeds):
        sc = copy.deepcopy(load_scenario("geometric"))
        sc["effects"] = FOUR
        sc["gross_errors"] = {"n": 2, "min_mm": 0.5, "max_mm": 3.0}
        camp, truth = _camp(sc, seed, robot)
        t = time.perf_counter()
        res = discover(camp, robot)
        s = summary(res, validation_errors(res))
        named = sorted(f"{n['effect']} j{n['joint']}" for n in s["named"])
        print(
            f"3. four effects + 2 gross errors, seed {seed}: named {named}; flagged "
            f"{sorted(o['row'] for o in s['outliers'])} (true {sorted(g['row'] for g in truth['gross_errors'])}); "
            f"RMS {s['rms_after_mm']:.4f} mm, floor {s['noise_floor_mm']:.4f} mm; validation mean "
            f"{s['validation']['geometric']['mean_position_mm']:.4f} -> "
            f"{s['validation']['discovered']['mean_position_mm']:.4f} mm ({time.perf_counter() - t:.2f} s)"
        )


def abb() -> None:
    d = SHARED / "data" / "abb-irb120"
    if not (d / "poses.csv").is_file():
        print("4. ../shared/data/abb-irb120 not found: skipped")
        return
    for name in (str(d / "robot.yaml"), "abb_irb120"):
        robot = load_robot(name)
        camp = read_campaign(d, robot)
        res = calibrate(camp, robot)
        if name == "abb_irb120":
            flagged = [(o["row"], o["pose_id"], o["target"]) for o in res.fit["outliers"]]
            print(
                f"4. ABB IRB 120 calibrate: outliers {flagged};"
                f" before (true) mean {res.fit['before']['mean_position_mm']:.4f} mm vs old figure "
                f"{old_before(camp, robot):.4f} mm"
            )
        s = summary(r := discover(camp, robot), validation_errors(r))
        v = s["validation"]
        print(
            f"   discover with {Path(name).name if name.endswith('yaml') else 'conf/robot/' + name}: named "
            f"{[n['key'] for n in s['named']]}; T4 validation mean {v['geometric']['mean_position_mm']:.4f} -> "
            f"{v['discovered']['mean_position_mm']:.4f} mm, max {v['geometric']['max_position_mm']:.4f} -> "
            f"{v['discovered']['max_position_mm']:.4f} mm; outliers {[o['row'] for o in s['outliers']]}"
        )
        for n in s["named"]:
            print(f"     {n['key']}: {n['estimates']}")


def default_campaign() -> None:
    sc = load_scenario("thermal")
    robot = load_robot(sc["robot"])
    camp, _ = _camp(sc, int(sc.get("seed", 0)), robot)
    res = calibrate(camp, robot)
    print(
        f"5. default campaign: before (true) mean {res.fit['before']['mean_position_mm']:.4f} mm vs old figure "
        f"{old_before(camp, robot):.4f} mm; outliers {[o['row'] for o in res.fit['outliers']]}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gross-seeds", type=int, default=20)
    ap.add_argument("--clean-seeds", type=int, default=100)
    ap.add_argument("--four-seeds", type=int, default=5)
    args = ap.parse_args()
    robot = load_robot("kr16_2")
    gross(args.gross_seeds, robot)
    clean(args.clean_seeds, robot)
    four(args.four_seeds, robot)
    abb()
    default_campaign()


if __name__ == "__main__":
    main()
