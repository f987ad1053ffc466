"""``robocal closed-loop [--scenario thermal] [--seed 0] [--bundle DIR] --out DIR``: drive the twin's warm-up
through the compensation service; report compensated vs uncompensated vs oracle error (plot, HTML, MLflow).

``--scenario discovered``: the twin's cell with a gear error and a backlash the geometry misses, discovered by
``robocal discover`` and served from the discovered model's bundle, against the geometry-only bundle."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scenario",
        default="thermal",
        help="twin scenario with the thermal effect (name or YAML), or 'discovered' (gear + backlash, discover)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--bundle", default=None, help="bundle to serve (default: fitted from the scenario's campaign)")
    p.add_argument("--out", default="reports/closed_loop", help="output directory")
    p.add_argument("--targets", type=int, default=60, help="joint targets per epoch")
    p.add_argument("--interval-min", type=float, default=30.0, help="minutes between two epochs")
    p.add_argument("--duration-min", type=float, default=None, help="warm-up length (default: the scenario's)")
    p.add_argument("--no-tracking", action="store_true", help="no MLflow run")


def run(args: argparse.Namespace) -> int:
    from robocal.sim.closed_loop import main_summary_line, run_closed_loop, write_report

    if args.scenario == "discovered":
        from robocal.sim.closed_loop_effects import run_discovered_closed_loop

        r = run_discovered_closed_loop(args.out, seed=args.seed, n_targets=args.targets)
        e = r["mean_error_mm"]
        print(
            f"discovered {r['effects_named']}: mean error at {r['n_compared']} targets: uncompensated "
            f"{e['uncompensated']:.4f} mm, geometric bundle {e['geometric']:.4f} mm, discovered bundle "
            f"{e['discovered']:.4f} mm, oracle {e['oracle']:.4f} mm; refused {r['refused']}"
        )
        print(f"wrote {args.out}/closed_loop_discovered.json")
        return 0 if e["discovered"] <= 1.3 * e["oracle"] else 1

    res = run_closed_loop(
        args.scenario,
        args.out,
        seed=args.seed,
        bundle=args.bundle,
        n_targets=args.targets,
        interval_min=args.interval_min,
        duration_min=args.duration_min,
    )
    html = write_report(res, args.out, tracking=not args.no_tracking)
    print(main_summary_line(res))
    print(f"wrote {html}")
    return 0 if res.summary["within_bound"] else 1
