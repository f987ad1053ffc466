"""``robocal calibrate DATA_DIR --robot NAME_OR_YAML --out DIR [key=value ...]``."""

from __future__ import annotations

import argparse

from robocal.commands import parse_overrides


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data_dir", help="campaign directory in the data contract")
    p.add_argument("--robot", required=True, help="robot name (conf/robot/<name>.yaml) or a YAML path")
    p.add_argument("--out", required=True, help="output directory: calibration.json, summary.json, report.html")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report")
    p.add_argument(
        "overrides",
        nargs="*",
        help="calibration settings key=value, e.g. noise_mm=0.02 'fixed=[beta2]' split.method=none",
    )


def run(args: argparse.Namespace) -> int:
    from robocal.workflows.geometric import run_calibration

    ov = parse_overrides(args.overrides)
    split = ov.pop("split", None)
    summary = run_calibration(args.data_dir, args.robot, args.out, ov, split=split, report=not args.no_report)
    fit = summary["fit"]
    line = (
        f"fit: {fit['n_rows']} rows, RMS {fit['rms_position_mm']:.4f} mm, {summary['n_identified']} identified, "
        f"{len(summary['eliminated'])} eliminated"
    )
    if "validation" in summary and summary["validation"].get("n_rows"):
        v = summary["validation"]
        line += f"; validation mean {v['mean_position_mm']:.4f} / max {v['max_position_mm']:.4f} mm"
    print(line)
    from robocal.identification.robust import outlier_line

    print(outlier_line(fit.get("outliers", []), fit.get("n_rows_total")))
    print(f"wrote {args.out}/calibration.json and summary.json")
    return 0
