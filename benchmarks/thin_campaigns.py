"""Thin campaigns on the twin: is the held-out error near its cross-validation estimate, with and without the
prior toward the nominal robot?

For each seed the twin writes the ``thin`` scenario (conf/scenario/thin.yaml: 15 calibration configurations,
independent validation configurations); ``robocal.calibrate`` fits it with ``prior: off`` and ``prior: auto``
(:mod:`robocal.identification.thin`). Printed per seed: the validation (held-out) mean 3-D error of both fits,
the leave-one-configuration-out CV estimate of both (the auto fit's record: with the chosen strength and with
no prior), the chosen strength, and the ratio held-out / CV estimate. The summary: the mean of each, the
seeds where the prior's held-out error is within ``--tolerance`` (20 %) of its CV estimate, and where the prior
beats the un-regularised fit.

    python benchmarks/thin_campaigns.py [--seeds 10] [--scenario thin] [key=value scenario overrides ...]
    python benchmarks/thin_campaigns.py --real ../shared/data/abb-irb120 --configurations 12 [--seeds 10]

With ``--real`` a real campaign is thinned instead: per seed, that many of its calibration configurations
(drawn at random) are the calibration, every other row is held out.
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

import robocal
from robocal.commands import parse_overrides
from robocal.data.campaign import Campaign, SplitConfig
from robocal.data.contract import read_campaign
from robocal.identification.thin import configuration_groups
from robocal.robot import RobotDescription


def twin_campaign(scenario: dict, seed: int) -> tuple[Campaign, RobotDescription]:
    """The twin's campaign of ``scenario`` and ``seed`` (its own calibration / validation split)."""
    rob = robocal.load_robot(scenario["robot"])
    with tempfile.TemporaryDirectory() as d:
        robocal.simulate(scenario, d, seed=seed)
        return read_campaign(d, rob, split=SplitConfig.from_mapping({"method": "none"})), rob


def real_campaign(folder: str, n_configurations: int, seed: int) -> tuple[Campaign, RobotDescription]:
    """A real campaign thinned: ``n_configurations`` of its calibration configurations drawn at random (seed)
    stay calibration rows, every other row (the other configurations and the validation rows) is held out."""
    rob = robocal.load_robot(str(Path(folder) / "robot.yaml"))
    camp = read_campaign(folder, rob)
    cal = np.flatnonzero(camp.split == "calibration")
    n, group = configuration_groups(camp.q[cal])
    keep = np.random.default_rng(seed).choice(n, size=min(n_configurations, n), replace=False)
    split = np.full(camp.n_rows, "validation", dtype=object)
    split[cal[np.isin(group, keep)]] = "calibration"
    return replace(camp, split=split), rob


def run_seed(camp: Campaign, rob: RobotDescription, seed: int) -> dict[str, float]:
    """One campaign fitted with and without the prior; the held-out and CV figures (mm)."""
    out: dict[str, float] = {"seed": seed}
    for rule in ("off", "auto"):
        res = robocal.calibrate(camp, rob, robocal.CalibrationConfig.from_mapping({"prior": rule}))
        val = robocal.validate(res, camp)
        out[f"held_{rule}"] = float(val["mean_position_mm"])
        e = np.linalg.norm(val["errors_mm"][val["kept_rows"]], axis=1)
        out[f"held_se_{rule}"] = float(np.std(e, ddof=1) / np.sqrt(len(e)))
        rec = res.fit.get("configurations") or {}
        prior = rec.get("prior")
        if rule == "auto":
            out["configurations"] = rec.get("n", np.nan)
            out["needed"] = rec.get("needed", np.nan)
            if isinstance(prior, dict) and "cv_mean_position_mm" in prior:  # strength 0: the CV preferred none
                out["strength"] = prior["strength"]
                out["cv_auto"] = prior["cv_mean_position_mm"]
                out["cv_se"] = prior["cv_mean_position_se_mm"]
                out["cv_off"] = prior["cv_mean_position_mm_without_prior"]
            else:  # not a thin campaign: no prior considered
                out["strength"] = 0.0
                out["cv_auto"] = out["cv_off"] = out["cv_se"] = np.nan
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--scenario", default="thin")
    ap.add_argument("--tolerance", type=float, default=0.2, help="held-out within this share of the CV estimate")
    ap.add_argument(
        "--real", default=None, help="a real campaign folder (with robot.yaml) thinned to --configurations instead"
    )
    ap.add_argument("--configurations", type=int, default=12, help="with --real: calibration configurations kept")
    ap.add_argument("overrides", nargs="*", help="scenario overrides key=value")
    args = ap.parse_args(argv)
    sc = robocal.load_scenario(args.scenario)
    sc.update(parse_overrides(args.overrides))
    if args.real:
        print(f"{args.real}: {args.configurations} calibration configurations drawn per seed, every other row held out")
    else:
        print(
            f"scenario {sc.get('name')!r}: robot {sc['robot']}, {sc['n_poses']} calibration configurations x "
            f"{len(sc['targets'])} target(s), {sc['n_validation_poses']} validation configurations, noise "
            f"{sc['noise_mm']} mm"
        )
    head = "seed  held-out off  CV off   held-out prior  CV prior  strength  held/CV prior  held/CV off"
    print(head)
    rows = []
    for seed in range(args.seeds):
        camp, rob = real_campaign(args.real, args.configurations, seed) if args.real else twin_campaign(sc, seed)
        r = run_seed(camp, rob, seed)
        rows.append(r)
        print(
            f"{seed:4d}  {r['held_off']:12.4f}  {r['cv_off']:7.4f}  {r['held_auto']:14.4f}  {r['cv_auto']:8.4f}  "
            f"{r['strength']:8.3g}  {r['held_auto'] / r['cv_auto']:13.2f}  {r['held_off'] / r['cv_off']:11.2f}"
        )

    def col(k: str) -> np.ndarray:
        return np.array([r[k] for r in rows], dtype=float)

    if np.all(np.isnan(col("cv_auto"))):
        print("not a thin campaign in any seed: no prior considered (fit.configurations has no record)")
        return 0
    ratio = col("held_auto") / col("cv_auto")
    ratio_off = col("held_off") / col("cv_off")
    within = np.abs(ratio - 1.0) <= args.tolerance
    better = col("held_auto") < col("held_off")
    # the two estimates' own uncertainty: the CV's over its held-out rows, the validation's over its rows
    spread = np.sqrt(col("cv_se") ** 2 + col("held_se_auto") ** 2)
    within_se = np.abs(col("held_auto") - col("cv_auto")) <= 2 * spread
    print(
        f"mean  {np.nanmean(col('held_off')):12.4f}  {np.nanmean(col('cv_off')):7.4f}  "
        f"{np.nanmean(col('held_auto')):14.4f}  {np.nanmean(col('cv_auto')):8.4f}"
    )
    print(
        f"prior on in {int(np.sum(col('strength') > 0))} of {len(rows)} seeds; held-out within "
        f"{args.tolerance:.0%} of the CV estimate in {int(within.sum())} of {len(rows)} (mean |held/CV - 1| "
        f"{np.nanmean(np.abs(ratio - 1)):.1%}; without the prior {np.nanmean(np.abs(ratio_off - 1)):.1%}); "
        f"within 2 standard errors of the two means in {int(within_se.sum())} of {len(rows)}; "
        f"the prior's held-out error below the un-regularised fit's in {int(better.sum())} of {len(rows)} "
        f"(mean {np.nanmean(col('held_auto')):.4f} vs {np.nanmean(col('held_off')):.4f} mm)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
