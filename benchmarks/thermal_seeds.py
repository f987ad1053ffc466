"""Thermal compensation on the twin over several seeds: the table-5 equivalent next to the paper's.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/thermal_seeds.py [seed ...]      (default seeds 1 2 3)

For every seed: simulate conf/scenario/thermal.yaml, thermal fit -> screening -> validation; prints the mean /
max position and orientation errors of none / traditional / proposed / all / oracle over the whole validation
warm-up and at the 90-min state, the closed-loop errors, the selected set, and the z-scores of the length
expansion coefficients against the truth (true sensors given).
"""

from __future__ import annotations

import sys
import tempfile
import time

import numpy as np

from robocal.data import read_campaign
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.twin import simulate
from robocal.thermal import fit as wf
from robocal.thermal.compensate import extrapolation_summary
from robocal.thermal.model import ThermalModel
from robocal.thermal.report import PAPER_TABLE5
from robocal.thermal.validate import reorder

LENGTHS = {"d1": ["T_l1_C"], "d4": ["T_l4_C"], "d6": ["T_j6_C"], "a2": ["T_j2_C"], "a3": ["T_j3_C"]}


def row(name: str, s: dict, paper: dict | None = None) -> str:
    txt = f"  {name:12s} {s['mean_position_mm']:.4f} / {s['max_position_mm']:.4f} mm"
    if "mean_orientation_deg" in s:
        txt += f"   {s['mean_orientation_deg']:.4f} / {s['max_orientation_deg']:.4f} deg"
    if paper:
        txt += (
            f"   | paper {paper['mean_position_mm']:.4f} / {paper['max_position_mm']:.4f} mm, "
            f"{paper['mean_orientation_deg']:.4f} / {paper['max_orientation_deg']:.4f} deg"
        )
    return txt


def main(seeds: list[int]) -> None:
    robot = load_robot("kr16_2")
    z_all = []
    for seed in seeds:
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as d:
            truth = simulate(load_scenario("thermal"), d, seed=seed)
            camp = read_campaign(d, robot)
        fit = wf.fit_thermal(camp, robot, wf.ThermalConfig())
        scr = wf.run_screening(fit, None)
        selected, source = wf.choose_selected(fit, scr)
        proposed, _, _ = wf.fit_selected(fit, selected)
        ev = wf.validate_thermal(fit, proposed, truth)
        drift = truth["effects"]["thermal"]["tool_drift"][-1]
        print(
            f"seed {seed}: steady tool drift mean |x|/|y|/|z| = {drift['mean_abs_x_mm']:.3f} / "
            f"{drift['mean_abs_y_mm']:.3f} / {drift['mean_abs_z_mm']:.3f} mm; selected ({source}): "
            f"{', '.join(selected)}; drifting (all-fit): {', '.join(fit.model_all.names)}"
        )
        print(" whole validation warm-up (mean / max):")
        for m, s in ev["table"].items():
            print(row(m, s))
        print(f" at {ev['at_state_min']:.0f} min (paper's table 5 beside):")
        for m, s in ev["at_state"].items():
            print(row(m, s, PAPER_TABLE5.get(m)))
        print(" closed loop on the twin (no tracker noise):")
        for m, s in ev["closed_loop"].items():
            print(row(m, s))
        tab = ev["table"]
        print(f"  proposed / oracle = {tab['proposed']['mean_position_mm'] / tab['oracle']['mean_position_mm']:.3f}")
        print(
            "  refused / flagged in the closed loop: "
            + ", ".join(
                f"{m} " + "/".join(str(s[k]) for k in ("n_not_converged", "n_too_large", "n_out_of_range"))
                for m, s in ev["closed_loop"].items()
            )
            + " (not_converged / too_large / out_of_range)"
        )
        val = camp.validation()
        T_val = reorder(val.temperatures, val.sensor_names, proposed.sensors)
        ext = extrapolation_summary(proposed, T_val, ev["state"], ev["t_min"], fit.cfg.limits.range_margin_C)
        print(
            f"  extrapolation (margin {ext['margin_C']:g} degC): {ext['n_rows_out_of_range']} of {ext['n_rows']} "
            f"validation rows, largest excess {ext['max_excess_C']:.2f} degC"
        )
        print("  screening, borderline parameters:")
        for w in scr.what_if:
            print(f"    {w['text']}")
        cfg = wf.ThermalConfig.from_mapping({"regression": {"candidates": LENGTHS}})
        fit2 = wf.fit_thermal(camp, robot, cfg)
        m2, _, _ = wf.fit_selected(fit2, list(LENGTHS))
        tm = ThermalModel.from_dict(truth["effects"]["thermal"]["model"])
        zs = {
            n: float((m2.parameter(n).coefficients[0] - tm.parameter(n).coefficients[0]) / m2.parameter(n).stderr[0])
            for n in LENGTHS
        }
        z_all += list(zs.values())
        print(
            "  length coefficient z-scores: "
            + ", ".join(f"{k} {v:+.2f}" for k, v in zs.items())
            + f"   ({time.perf_counter() - t0:.1f} s)"
        )
    z = np.abs(np.array(z_all))
    print(f"all seeds: {len(z)} length coefficients, |z| < 1.96 for {np.mean(z < 1.96):.0%}, max |z| {z.max():.2f}")


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [1, 2, 3])
