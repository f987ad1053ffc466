"""``robocal fleet FLEET_DIR --out DIR [--engine ray|local] [--workers N] [key=value ...]``: calibrate a fleet
(one folder per robot, campaigns by date), track it in MLflow, flag parameters that moved, write the fleet report.

``robocal fleet --simulate N [--campaigns 3] [--seed S] --out FLEET_DIR`` writes a twin fleet instead;
``robocal fleet FLEET_DIR --write-dvc`` writes the fleet's DVC pipeline (``FLEET_DIR/dvc.yaml``)."""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("fleet_dir", nargs="?", help="fleet folder: <serial>/robot.yaml + <serial>/YYYY-MM-DD/ campaigns")
    p.add_argument("--out", help="output folder (with --simulate: the fleet folder to write)")
    p.add_argument("--engine", choices=("local", "ray"), default="local", help="in this process, or Ray tasks")
    p.add_argument("--workers", type=int, default=2, help="Ray: CPUs of the local Ray instance (default 2)")
    p.add_argument("--address", default=None, help="Ray: address of an existing cluster (e.g. auto)")
    p.add_argument("--robot", action="append", default=None, help="only this serial (repeatable); no fleet files")
    p.add_argument("--config", default=None, help="fleet settings YAML (default conf/fleet/default.yaml)")
    p.add_argument(
        "--tracking-uri", default=None, help="MLflow tracking URI (default $MLFLOW_TRACKING_URI or mlflow.db)"
    )
    p.add_argument("--no-tracking", action="store_true", help="do not log to MLflow")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--simulate", type=int, metavar="N", default=None, help="write a twin fleet of N robots into --out")
    p.add_argument("--campaigns", type=int, default=3, help="with --simulate: campaigns per robot (default 3)")
    p.add_argument("--seed", type=int, default=0, help="with --simulate: seed of the fleet (default 0)")
    p.add_argument("--write-dvc", action="store_true", help="write FLEET_DIR/dvc.yaml (foreach over the robots)")
    p.add_argument("overrides", nargs="*", help="settings key=value, e.g. drift.alpha=0.05 twin.n_poses=60")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from robocal.commands import parse_overrides
    from robocal.errors import ConfigError
    from robocal.fleet.run import load_settings

    if args.fleet_dir and "=" in args.fleet_dir and not Path(args.fleet_dir).exists():
        # `robocal fleet --simulate N --out D k=v`: argparse gives the first key=value to the optional FLEET_DIR
        args.overrides = [args.fleet_dir, *(args.overrides or [])]
        args.fleet_dir = None
    settings = load_settings(args.config, parse_overrides(args.overrides))
    if args.simulate is not None:
        return _simulate(args, settings)
    if not args.fleet_dir:
        raise ConfigError("give the fleet folder (robocal fleet FLEET_DIR --out DIR) or --simulate N --out FLEET_DIR")
    if args.write_dvc:
        from robocal.fleet.dvc import write_dvc_pipeline

        path = write_dvc_pipeline(args.fleet_dir, args.out or "out")
        print(f"wrote {path}: run `dvc repro` in {path.parent} (a git + DVC repository)")
        return 0
    if not args.out:
        raise ConfigError("--out DIR is required")
    if args.no_tracking:
        settings.setdefault("tracking", {})["enabled"] = False
    if args.tracking_uri:  # the flag wins over $MLFLOW_TRACKING_URI (which robocal.tracking puts first)
        os.environ["MLFLOW_TRACKING_URI"] = args.tracking_uri
        settings.setdefault("tracking", {})["uri"] = args.tracking_uri
    from robocal.fleet.run import run_fleet

    res = run_fleet(
        args.fleet_dir,
        args.out,
        settings,
        engine=args.engine,
        workers=args.workers,
        address=args.address,
        serials=args.robot,
        progress=not args.no_progress,
    )
    computed = len(res["computed"])
    print(f"calibrated {computed} campaign(s), {res['n_cached']} cached", file=sys.stderr)
    return _print_outcome(res, args.out) if "counts" in res else 0


def _simulate(args: argparse.Namespace, settings: dict[str, Any]) -> int:
    """``--simulate N``: write a twin fleet into ``--out``."""
    from robocal.errors import ConfigError
    from robocal.fleet.twin import simulate_fleet

    if not args.out:
        raise ConfigError("--simulate N needs --out FLEET_DIR (where to write the fleet)")
    truth = simulate_fleet(args.out, args.simulate, args.campaigns, args.seed, settings.get("twin"))
    n_ev = sum(len(r["events"]) for r in truth["robots"].values())
    print(f"wrote a twin fleet of {args.simulate} robots x {args.campaigns} campaigns ({n_ev} events) to {args.out}")
    return 0


def _print_outcome(res: dict[str, Any], out: str) -> int:
    """The fleet's counts, flagged parameters, the twin's truth and every failed campaign; 1 when one failed."""
    c = res["counts"]
    print(
        f"{c['robots']} robots, {c['campaigns']} campaigns: {c['accepted']} accepted, {c['rejected']} rejected, "
        f"{c['errors']} errors; {len(res['trends']['flags'])} flagged parameter(s); report: {out}/report.html"
    )
    for f in res["trends"]["flags"]:
        print(f"  {f['serial']} {f['parameter']}: {f['kind']}: {f['explanation']}")
    if "truth" in res:
        t = res["truth"]
        print(
            f"  twin truth: {t['n_detected']}/{t['n_events']} events flagged ({t['n_right_kind']} of the right "
            f"kind), {t['n_false_flags']} false flag(s)"
        )
    if not c["errors"]:
        return 0
    for r in res["robots"]:
        for s in r["campaigns"]:
            if s["status"] == "error":
                print(f"robocal fleet: error: {r['serial']} {s['campaign']}: {s['reason']}", file=sys.stderr)
    return 1
