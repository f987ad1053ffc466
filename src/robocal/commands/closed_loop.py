"""``robocal closed-loop [--scenario thermal] [--seed 0] [--bundle DIR] --out DIR``: drive the twin's warm-up
through the compensation service; report compensated vs uncompensated vs oracle error (plot, HTML, MLflow)."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="thermal", help="twin scenario with the thermal effect (name or YAML)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--bundle", default=None, help="bundle to serve (default: fitted from the scenario's campaign)")
    p.add_argument("--out", default="reports/closed_loop", help="output directory")
    p.add_argument("--targets", type=int, default=60, help="joint targets per epoch")
    p.add_argument("--interval-min", type=float, default=30.0, help="minutes between two epochs")
    p.add_argument("--duration-min", type=float, default=None, help="warm-up length (default: the scenario's)")
    p.add_argument("--no-tracking", action="store_true", help="no MLflow run")


def run(args: argparse.Namespace) -> int:
    from robocal.serve.closed_loop import main_summary_line, run_closed_loop, write_report

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
