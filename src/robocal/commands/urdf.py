"""``robocal urdf --robot ROBOT --calibration FILE --out DIR``: the calibrated kinematics as a URDF (joint origins
corrected, the calibration's tools as fixed frames) plus the calibration as a small YAML
(see :mod:`robocal.cell.urdf`). ROBOT is ``path/robot.urdf#BASE:TIP`` (the original URDF is copied with its
joint origins corrected, never modified) or any robot name / YAML (a fresh URDF is written). A URDF holds the
geometry only: the discovered effects of a ``robocal discover`` calibration are named on the console and in the YAML
(``not_in_urdf``), with why and where they are compensated instead."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True, help="robot.urdf#BASE:TIP, a conf/robot name or a YAML path")
    p.add_argument("--calibration", required=True, help="calibration.json (robocal calibrate or discover)")
    p.add_argument("--out", required=True, help="output folder: <name>.urdf and <name>.yaml")
    p.add_argument("--name", default="robot_calibrated", help="file name stem (default robot_calibrated)")


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from robocal.calibration.load import load_calibration
    from robocal.cell.urdf import export_calibration, not_in_urdf
    from robocal.errors import ConfigError
    from robocal.robot import load_robot

    robot = load_robot(args.robot)
    path = Path(args.calibration)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        cal = load_calibration(data, robot)
    except ConfigError as exc:  # e.g. a calibration of another robot: the error names both
        raise ConfigError(f"{path}: {exc}") from None
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"cannot load the calibration {path}: {type(exc).__name__}: {exc}") from None
    other = data.get("effects_not_compensated") or ()
    u, y = export_calibration(cal, args.out, name=args.name, not_compensated=other)
    print(f"urdf: wrote {u} (the geometry: calibrated joint origins, tools {list(cal.tools)} as fixed frames) and {y}")
    missing = not_in_urdf(cal.effects, other)
    if missing:
        print(f"urdf: NOT in the URDF (a URDF holds fixed joint origins only): {len(missing)} discovered effect(s)")
        for e in missing:
            print(f"  {e['key']}: {e['why']}; compensated by: {e['compensated_by']}")
        print(f"urdf: the same list is in {y} under not_in_urdf")
    return 0
