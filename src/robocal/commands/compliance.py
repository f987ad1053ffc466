"""``robocal compliance DATA_DIR --robot NAME_OR_YAML --out DIR [key=value ...]``: heavy-load calibration."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from robocal.commands import ROBOT_HELP, parse_overrides


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data_dir", help="campaign directory in the data contract (payload_kg, i1_A.. or tau1_Nm..)")
    p.add_argument("--robot", required=True, help=ROBOT_HELP)
    p.add_argument("--out", required=True, help="output directory: compliance.json, compensation.csv, report.html")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report")
    p.add_argument(
        "overrides",
        nargs="*",
        help="compliance settings key=value (conf/compliance/default.yaml), e.g. kind=gravity method=sequential "
        "'joints=[2,3,4,5]' geometric.noise_mm=0.02 split.method=none",
    )


def run(args: argparse.Namespace) -> int:
    from robocal.workflows import compliance

    ov = parse_overrides(args.overrides)
    split = ov.pop("split", None)
    truth_file = Path(args.data_dir) / "truth.json"
    truth = json.loads(truth_file.read_text()) if truth_file.is_file() else None
    s = compliance.run(args.data_dir, args.robot, args.out, ov, split=split, report=not args.no_report, truth=truth)
    print(f"compliance ({s['kind']}, {s['method']}), {s['unit']}:")
    for name, v in s["compliance"].items():
        if v["identified"]:
            print(f"  {name}: {v['c']:.4e} +- {v['stderr']:.2e}")
    for row in s["load_table"]:
        print(
            f"  {row['payload_kg']:>6g} kg: {row['position_before_mm']:.3f} -> {row['position_after_mm']:.3f} mm "
            f"({row['verdict']})"
        )
    print(f"wrote {args.out}/compliance.json")
    return 0
