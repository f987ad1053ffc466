"""The real-robot table of docs/results.md ("Real robots: the validation table"), computed, not typed.

    python benchmarks/readme_figures.py                                   # every dataset in ../shared/data/
    python benchmarks/readme_figures.py --data ../shared/data/ur10-ipa --data ../shared/data/abb-irb120

For each dataset (a folder with poses.csv and its own robot.yaml): the mean position error of the held-out
validation rows before calibration (nominal model, best rigid fit), after robocal calibrate's geometric model and
after the discovered final model (the one the service applies) -- exactly what ``robocal discover DATA --robot
DATA/robot.yaml`` reports, with the shipped defaults (src/robocal/discovery/default.yaml) -- the pose-grouped
cross-validated estimate on the calibration poses, and the held-out range test (joint 2's top quarter never
calibrated, validated on: geometric -> final; one more discovery, skipped with ``--no-range``). Prints one
markdown row per dataset, in the columns of that table.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from robocal.calibration.validation import validate
from robocal.data.campaign import Campaign
from robocal.data.contract import read_campaign
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors
from robocal.robot import RobotDescription, load_robot

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data"
HEADER = (
    "| data (its own description, no masses), mean mm | before | geometric | final | CV estimate "
    "| held-out range: geometric → final |\n| --- | --- | --- | --- | --- | --- |"
)


def figures(camp: Campaign, robot: RobotDescription) -> dict[str, Any]:
    """Validation means (mm) before / geometric / final, the CV estimate, and the final model's layer."""
    res = discover(camp, robot)
    val = validation_errors(res)
    if val is None:
        raise SystemExit(f"{camp.source} has no validation rows")
    summ = summary(res, val)
    geo = res.extra["geometric_calibration"]
    before = validate(geo, camp, x=geo.start.x_init)
    cv = summ.get("cross_validation") or {}
    return {
        "n_cal": int(np.sum(camp.split == "calibration")),
        "n_val": int(val["geometric"]["n_rows"]),
        "before": before["mean_position_mm"],
        "geometric": val["geometric"]["mean_position_mm"],
        "final": val["final"]["mean_position_mm"],
        "layer": val["final"]["layer"],
        "cv": cv.get("cv_mean_position_mm"),
        "named": [n["key"] for n in summ["named"]],
    }


def held_out_range(camp: Campaign, robot: RobotDescription, joint: int = 2) -> tuple[float, float]:
    """Geometric and final mean (mm) on joint ``joint``'s top quarter, calibrated on the rest."""
    lim = np.quantile(camp.q[:, joint - 1], 0.75)
    split = np.where(camp.q[:, joint - 1] <= lim, "calibration", "validation")
    f = figures(replace(camp, split=split), robot)
    return f["geometric"], f["final"]


def row(path: Path, with_range: bool = True) -> str:
    robot = load_robot(path / "robot.yaml")
    camp = read_campaign(path, robot)
    f = figures(camp, robot)
    cv = "" if f["cv"] is None else f"{f['cv']:.3f}"
    rng = ""
    if with_range:
        g, fin = held_out_range(camp, robot)
        rng = f"{g:.3f} → {fin:.3f}"
    label = f"`{path.name}` ({f['n_cal']:,} / {f['n_val']:,} rows)".replace(",", " ")
    print(
        f"  {path.name}: named {len(f['named'])}: {', '.join(f['named'])}; residual layer {f['layer']}", file=sys.stderr
    )
    return f"| {label} | {f['before']:.3f} | {f['geometric']:.3f} | {f['final']:.3f} | {cv} | {rng} |"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, action="append", help="a dataset folder (default: every one in ../shared)")
    ap.add_argument("--no-range", action="store_true", help="leave out the held-out range test (one discovery less)")
    args = ap.parse_args(argv)
    paths = args.data or sorted(p for p in SHARED.glob("*") if (p / "robot.yaml").exists())
    if not paths:
        print(f"no real datasets under {SHARED}")
        return 0
    print(HEADER)
    for p in paths:
        print(row(p, not args.no_range), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
