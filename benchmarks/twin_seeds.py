"""Known-truth recovery over many seeds (issue 2): fit RMS vs the noise floor, chi² bands, z-scores.

    python benchmarks/twin_seeds.py [--seeds 20] [--scenario geometric]

Prints one line per seed and the totals: mean fit RMS / floor, seeds inside their chi² 95 % band,
and the share of (parameter, seed) pairs within 3 standard errors of the truth (in the identified
parameterisation, see robocal.sim.truth).
"""

from __future__ import annotations

import argparse
import os
import tempfile

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from robocal.data import read_campaign
from robocal.identification.calibrate import calibrate
from robocal.robot import load_robot
from robocal.sim.truth import z_scores
from robocal.sim.twin import load_scenario, simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--scenario", default="geometric")
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    robot = load_robot(sc.get("robot", "kr16_2"))
    ratios, inside, zs = [], 0, []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        with tempfile.TemporaryDirectory() as d:
            truth = simulate(sc, d, seed=seed)
            camp = read_campaign(d, robot)
        res = calibrate(camp, robot)
        cal = camp.calibration()
        z = np.array(list(z_scores(res, truth, cal.q, cal.target_index).values()))
        fit = res.fit
        ratios.append(fit["rms_position_mm"] / fit["noise_floor_rms_mm"])
        inside += fit["chi2_within_band"]
        zs.append(z)
        print(
            f"seed {seed:3d}: RMS {fit['rms_position_mm']:.5f} mm (floor {fit['noise_floor_rms_mm']:.5f}), "
            f"chi2 {fit['chi2']:.1f}/{fit['dof']} {'in' if fit['chi2_within_band'] else 'OUT'}, "
            f"max|z| {np.abs(z).max():.2f}, {len(z)} params"
        )
    allz = np.abs(np.concatenate(zs))
    n = args.seeds
    print(f"\nmean fit RMS / noise floor: {np.mean(ratios):.4f}  (issue: within 5 %)")
    print(f"seeds inside their chi2 95 % band: {inside}/{n}  (expected ~{0.95 * n:.0f} for a correct model)")
    print(f"(parameter, seed) pairs within 3 SE: {np.mean(allz < 3) * 100:.2f} % of {allz.size}  (issue: >= 99 %)")


if __name__ == "__main__":
    main()
