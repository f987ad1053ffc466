"""Closed-loop warm-up through the compensation service on several twin seeds (issue 8).

    python benchmarks/closed_loop_seeds.py [--seeds 6] [--targets 60]

Per seed: mean error of the uncompensated, compensated and oracle arms over the warm-up, the worst per-epoch
ratio compensated / oracle (the issue's bound: 1.3), and the refused corrections.
"""

from __future__ import annotations

import argparse
import os
import tempfile

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from robocal.sim.closed_loop import run_closed_loop


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--targets", type=int, default=60)
    args = ap.parse_args()
    worst = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            s = run_closed_loop("thermal", f"{tmp}/{seed}", seed=seed, n_targets=args.targets).summary
            o = s["overall_mean_mm"]
            worst.append(s["max_ratio"])
            print(
                f"seed {seed}: uncompensated {o['uncompensated']:.3f} mm, compensated {o['compensated']:.4f} mm, "
                f"oracle {o['oracle']:.4f} mm; ratio per epoch {np.round(s['ratio_compensated_to_oracle'], 2)}; "
                f"max {s['max_ratio']:.3f}; refused {sum(s['refused'])}",
                flush=True,
            )
    w = np.array(worst)
    print(f"within 1.3x at every epoch: {int((w <= 1.3).sum())}/{len(w)} seeds; median worst ratio {np.median(w):.3f}")


if __name__ == "__main__":
    main()
