"""Logged-signal discovery on the twin (KR16-2, sigma = 0.015 mm): the false-discovery rate on null twins.

    python benchmarks/signal_null.py                      # null: 100 seeds, 80 + 20 poses, four random channels
    python benchmarks/signal_null.py --mode stand         # a compliant stand with a logged inclinometer
    (--seeds N, --poses P, --first-seed S)

null: every seed's campaign logs four channels that drive nothing (two white, two random walks over time) and two
that are functions of the joints (the commanded q2, the commanded flange x); the default discovery runs on it.
Prints the share of seeds naming any effect driven by a logged signal (goal <= 1 %), the share naming anything,
and how often the two joint functions were recognised and not used.

stand: the base tilts with the arm's load and a wander, an inclinometer logs it (robocal.sim.stand): how often
both tilts are named on the base, the gains against their truth (1) in standard errors, and the held-out error
against the same twin without the stand (its geometric calibration: the floor).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from robocal.data.contract import read_campaign
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.twin import simulate

NULL_CHANNELS = {"noise_a": "white", "noise_b": "white", "walk_a": "walk", "walk_b": "walk", "cmd_q2": "joint2",
                 "cmd_x": "commanded_x"}  # fmt: skip


def run_one(effects: dict, seed: int, tmp: Path, n_poses: int, n_val: int):  # type: ignore[no-untyped-def]
    sc = load_scenario("geometric")
    sc["effects"] = effects
    sc["n_poses"] = n_poses
    sc["n_validation_poses"] = n_val
    robot = load_robot("kr16_2")
    d = tmp / f"s{seed}_{len(effects)}"
    simulate(sc, d, seed=seed)
    camp = read_campaign(d, robot)
    t0 = time.perf_counter()
    res = discover(camp, robot)
    return res, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=["null", "stand"], default="null")
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--poses", type=int, default=80)
    ap.add_argument("--validation-poses", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=2000)
    args = ap.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        if args.mode == "null":
            n_sig, n_any, n_recognised, times, keys = 0, 0, 0, [], {}
            for s in seeds:
                res, dt = run_one({"logged_channels": {"channels": NULL_CHANNELS}}, s, tmp, args.poses,
                                  args.validation_poses)  # fmt: skip
                times.append(dt)
                sig = [a.cand.key for a in res.accepted if a.cand.effect == "signal"]
                n_sig += bool(sig)
                n_any += bool(res.accepted)
                for a in res.accepted:
                    keys[a.cand.key] = keys.get(a.cand.key, 0) + 1
                not_used = {x["column"] for x in res.extra["logged_signals"]["not_used"]}
                n_recognised += {"cmd_q2", "cmd_x"} <= not_used
                print(f"  seed {s}: signal effects {sig or 'none'}; anything named: {len(res.accepted)}; {dt:.1f} s",
                      flush=True)  # fmt: skip
            n = len(seeds)
            print(f"null twins ({args.poses} + {args.validation_poses} poses, 4 random logged channels): {n} seeds; "
                  f"naming an effect driven by a logged signal: {n_sig}/{n} = {n_sig / n:.1%} (goal <= 1 %); naming "
                  f"anything: {n_any}/{n}; keys {keys}; the joint functions (cmd_q2, cmd_x) recognised and not used: "
                  f"{n_recognised}/{n}; median run {np.median(times):.1f} s")  # fmt: skip
        else:
            n_both, z, ratio = 0, [], []
            for s in seeds:
                res, _ = run_one({"compliant_stand": {}}, s, tmp, args.poses, args.validation_poses)
                summ = summary(res, validation_errors(res))
                keys = {n["key"]: n for n in summ["named"]}
                both = {"signal:incl_x:base_rot", "signal:incl_y:base_rot"} <= set(keys)
                n_both += both
                if both:
                    for col, ax in (("incl_x", "rx"), ("incl_y", "ry")):
                        g = keys[f"signal:{col}:base_rot"]["estimates"][f"{ax}_gain"]
                        z.append((g["value"] - 1.0) / g["stderr"])
                ref, _ = run_one({}, s, tmp, args.poses, args.validation_poses)
                floor = validation_errors(ref)["geometric"]["mean_position_mm"]  # type: ignore[index]
                v = summ["validation"]
                ratio.append(v["final"]["mean_position_mm"] / floor)
                print(
                    f"  seed {s}: named {sorted(keys)}; held-out {v['final']['mean_position_mm']:.4f} mm "
                    f"(geometric {v['geometric']['mean_position_mm']:.4f}, floor {floor:.4f})",
                    flush=True,
                )
            n = len(seeds)
            za = np.abs(np.array(z))
            r = np.array(ratio)
            print(f"compliant stand: {n} seeds; both tilts named on the base: {n_both}/{n}; gain - 1 in standard "
                  f"errors: median |z| {np.median(za):.2f}, max {za.max():.2f}, within 2 SE {np.mean(za <= 2):.0%}; "
                  f"held-out / floor: median {np.median(r):.3f}, max {r.max():.3f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
