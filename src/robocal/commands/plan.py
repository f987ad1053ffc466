"""``robocal plan --robot NAME_OR_YAML --n 40 --out DIR [key=value ...]``."""

from __future__ import annotations

import argparse
from pathlib import Path

from robocal.commands import ROBOT_HELP


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True, help=ROBOT_HELP)
    p.add_argument("--n", type=int, default=None, help="number of poses (default: the config's n_poses)")
    p.add_argument("--out", required=True, help="output directory: plan.csv, plan.json, report.html")
    p.add_argument("--config", default=None, help="plan settings YAML (default: conf/plan/default.yaml)")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report")
    p.add_argument(
        "overrides",
        nargs="*",
        help="plan settings key=value, e.g. criterion=I seed=3 tracker.acceptance_half_angle_deg=40",
    )


def run(args: argparse.Namespace) -> int:
    import yaml

    from robocal.commands import parse_overrides
    from robocal.commands.simulate import merge_overrides
    from robocal.errors import ConfigError
    from robocal.plan.output import run_plan

    path = Path(args.config) if args.config else Path(__file__).resolve().parents[3] / "conf" / "plan" / "default.yaml"
    if not path.exists():
        raise ConfigError(f"plan settings file {path} does not exist")
    cfg = yaml.safe_load(path.read_text()) or {}
    cfg = merge_overrides(cfg, parse_overrides(args.overrides))
    if args.n is not None:
        cfg["n_poses"] = args.n
    m = run_plan(args.robot, cfg, args.out, report=False if args.no_report else None)
    rnd = m["random_region_rms_mm"]
    lo, hi = m["region_tool_point_min_mm"], m["region_tool_point_max_mm"]
    box = ", ".join(f"{a} {lo[k]:.0f}..{hi[k]:.0f}" for k, a in enumerate("xyz"))
    print(
        f"planned {m['n_poses']} poses from {m['candidates_accepted']} accepted candidates, "
        f"{m['n_identifiable']} identifiable parameters; {m['total_s']:.1f} s"
    )
    if m["criterion"] == "I":
        print(f"optimal for: {m['region']}; the tool point there spans {box} mm")
    else:
        print(
            f"{m['criterion']}-optimal (parameter precision, whatever the region); predicted error reported over "
            f"{m['region']} (tool point {box} mm); criterion=I plans for the region"
        )
    print(
        f"predicted RMS error over that region {m['predicted_region_rms_mm']:.4f} mm "
        f"(random poses of the same cell: {rnd:.4f} mm); choose the region with region.kind=joints|box|poses "
        "(conf/plan/default.yaml)"
    )
    print(f"wrote {args.out}/plan.csv and plan.json")
    return 0
