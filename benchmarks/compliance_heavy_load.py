"""Heavy-load benchmark (issue 6): the SR210 twin over several seeds, current- vs gravity-based compliance,
the paper's sequential method vs the joint refit, the load table (Mao 2021 table 4 in kind).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/compliance_heavy_load.py [--seeds 10]

Prints, per kind and method: the relative error of c per joint (median / worst over seeds), the validation
accuracy per load (mean over seeds of the per-condition mean error, mm) before and after compensation, the
full-load / unloaded ratio, and how often compensation helps at each load.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from robocal.compliance.fit import ComplianceConfig, accuracy_by_condition, fit_compliance, geometric_step, load_table
from robocal.data import read_campaign
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.twin import simulate

LOADS = (0.0, 43.0, 128.0, 210.0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    args = ap.parse_args()
    robot = load_robot("sr210")
    sc = load_scenario("heavy_load")
    res: dict[tuple[str, str], list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            d = Path(tmp) / f"s{seed}"
            truth = simulate(sc, d, seed=100 + seed)["effects"]["compliance"]
            camp = read_campaign(d, robot)
            base = ComplianceConfig.from_mapping({"geometric": {"noise_mm": 0.02}})
            geo = geometric_step(camp, robot, base)
            for kind in ("current", "gravity"):
                for method in ("sequential", "joint"):
                    cfg = ComplianceConfig.from_mapping(
                        {"geometric": {"noise_mm": 0.02}, "kind": kind, "method": method}
                    )
                    fit = fit_compliance(camp, robot, geo, cfg)
                    cond = accuracy_by_condition(camp, geo, fit, geo.start.x_init)
                    tc = np.array(truth["c_rad_per_A" if kind == "current" else "c_rad_per_Nm"])
                    rel = np.where(fit.model.identified, fit.model.c / tc - 1.0, np.nan)
                    val = {c["payload_kg"]: c for c in cond if c["split"] == "validation"}
                    res.setdefault((kind, method), []).append(
                        {
                            "rel": rel,
                            "fit_rms": fit.fit["rms_position_mm"],
                            "geo_rms": geo.fit["rms_position_mm"],
                            "nominal": {w: val[w]["nominal"]["mean_mm"] for w in LOADS},
                            "before": {w: val[w]["after_geometric"]["mean_mm"] for w in LOADS},
                            "after": {w: val[w]["after_compliance"]["mean_mm"] for w in LOADS},
                            "max_after": {w: val[w]["after_compliance"]["max_mm"] for w in LOADS},
                            "table": load_table(cond),
                        }
                    )
    print(f"SR210 heavy_load twin, {args.seeds} seeds (50 poses unloaded + 50 at 210 kg; ISO cube of 5 points)")
    print("paper: unloaded 2.36 -> 0.82 mm (geometric); full load 10.09 -> 2.42 mm (compliance)")
    summary = {}
    for (kind, method), runs in res.items():
        rel = np.array([r["rel"] for r in runs])
        print(f"\n== {kind} / {method}")
        for j in range(6):
            col = rel[:, j]
            if np.all(np.isnan(col)):
                print(f"  c{j + 1}: not identified")
                continue
            a = np.abs(col[~np.isnan(col)])
            print(
                f"  c{j + 1}: |rel. error| median {100 * np.median(a):5.2f} %  worst {100 * a.max():6.2f} %"
                f"  (identified in {len(a)}/{len(col)} seeds)"
            )
        print(
            f"  fit RMS {np.mean([r['fit_rms'] for r in runs]):.3f} mm; unloaded geometric fit RMS "
            f"{np.mean([r['geo_rms'] for r in runs]):.3f} mm"
        )
        print("  validation mean error (mm), mean over seeds:  load  nominal  geometric  +compliance  helps")
        for w in LOADS:
            nom = np.mean([r["nominal"][w] for r in runs])
            b = np.mean([r["before"][w] for r in runs])
            a = np.mean([r["after"][w] for r in runs])
            helps = sum(r["after"][w] < r["before"][w] for r in runs)
            print(f"  {w:>47g}  {nom:7.3f}  {b:9.3f}  {a:11.3f}  {helps}/{len(runs)}")
        ratio = np.array([r["after"][210.0] / r["before"][0.0] for r in runs])
        ratio_c = np.array([r["after"][210.0] / r["after"][0.0] for r in runs])
        print(
            f"  full-load after compensation / unloaded after geometric calibration: median {np.median(ratio):.2f}"
            f"  worst {ratio.max():.2f}  (<= 1.2 in {int((ratio <= 1.2).sum())}/{len(ratio)})"
        )
        print(f"  full-load / unloaded, both compensated: median {np.median(ratio_c):.2f}")
        summary[f"{kind}/{method}"] = {"ratio_median": float(np.median(ratio)), "ratio_worst": float(ratio.max())}
    print("\n" + json.dumps(summary))


if __name__ == "__main__":
    main()
