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
from scipy import stats

from robocal.calibration.fit import calibrate
from robocal.data import read_campaign
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.truth import z_scores
from robocal.sim.twin import simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--scenario", default="geometric")
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    robot = load_robot(sc.get("robot", "kr16_2"))
    ratios, inside, zs, chi2s, dofs = [], 0, [], [], []
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
        chi2s.append(fit["chi2"])
        dofs.append(fit["dof"])
        zs.append(z)
        print(
            f"seed {seed:3d}: RMS {fit['rms_position_mm']:.5f} mm (floor {fit['noise_floor_rms_mm']:.5f}), "
            f"chi2 {fit['chi2']:.1f}/{fit['dof']} {'in' if fit['chi2_within_band'] else 'OUT'}, "
            f"max|z| {np.abs(z).max():.2f}, {len(z)} params"
        )
    allz = np.abs(np.concatenate(zs))
    n = args.seeds
    print(f"\nmean fit RMS / noise floor: {np.mean(ratios):.4f}  (issue: within 5 %)")
    out = n - inside
    # a correct model leaves each seed outside its 95 % band with probability 0.05: how surprising is `out`?
    p_out = float(stats.binom.sf(out - 1, n, 0.05)) if out else 1.0
    print(
        f"seeds inside their chi2 95 % band: {inside}/{n}  (a correct model: ~{0.95 * n:.0f}; "
        f"P(>= {out} outside | correct) = {p_out:.2f})"
    )
    # the chi² values as a sample: uniform p-values if the noise model and the fit are right
    pv = stats.chi2.sf(np.array(chi2s), np.array(dofs))
    print(f"chi2 p-values vs U(0, 1): Kolmogorov-Smirnov p = {stats.kstest(pv, 'uniform').pvalue:.3f}")
    print(f"(parameter, seed) pairs within 3 SE: {np.mean(allz < 3) * 100:.2f} % of {allz.size}  (issue: >= 99 %)")
    print(f"z-scores: RMS {np.sqrt(np.mean(allz**2)):.3f} (1 for honest standard errors), max {allz.max():.2f}")


if __name__ == "__main__":
    main()
