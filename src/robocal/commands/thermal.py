"""``robocal thermal DATA_DIR --robot NAME_OR_YAML --out DIR [key=value ...]``: thermal fit -> screening -> validation.

The campaign's calibration rows hold a warm-up (pose set measured cold and at later temperature states), its
validation rows (column ``split``) a second warm-up from cold. Writes ``DIR/thermal.json`` (``selected``,
``model``, ``validation`` rows none / traditional / proposed / all / oracle), ``DIR/thermal_model.json`` (the
proposed model, :class:`robocal.thermal.model.ThermalModel`), the thermal-fit files, a controller CSV of the
compensated validation poses at the paper's 90-min state and ``DIR/report.html``.
"""

from __future__ import annotations

import argparse

from robocal.commands import ROBOT_HELP, parse_overrides


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data_dir", help="campaign directory in the data contract, with temperatures.csv")
    p.add_argument("--robot", required=True, help=ROBOT_HELP)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report")
    p.add_argument(
        "overrides",
        nargs="*",
        help="thermal settings key=value (conf/thermal/default.yaml), e.g. proposed=all regression.max_order=1; "
        "screen.<key>=value for the screening",
    )


def run(args: argparse.Namespace) -> int:
    from robocal.workflows import thermal

    ov = parse_overrides(args.overrides)
    screen = ov.pop("screen", None)
    out = thermal.run(args.data_dir, args.robot, args.out, ov, screen=screen, report=not args.no_report)
    print(f"selected ({out['selected_from']}): {', '.join(out['selected'])}")
    for m, s in out["validation"].items():
        line = f"  {m:12s} mean {s['mean_position_mm']:.4f} / max {s['max_position_mm']:.4f} mm"
        if "mean_orientation_deg" in s:
            line += f", {s['mean_orientation_deg']:.4f} / {s['max_orientation_deg']:.4f} deg"
        print(line)
    for w in out.get("warnings", []):
        print(f"WARNING: {w}")
    print(f"wrote {args.out}/thermal.json, thermal_model.json, report.html")
    return 0
