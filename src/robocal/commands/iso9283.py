"""``robocal iso9283 CAMPAIGN --robot R --calibration calibration.json --out DIR [--after DIR] [key=value ...]``;
``robocal iso9283 --program DIR --robot R [key=value ...]``: the test's visits for the cell (``iso_program.csv``)."""

from __future__ import annotations

import argparse

from robocal.commands import ROBOT_HELP, parse_overrides


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "campaign", nargs="?", help="ISO test campaign (data contract + iso_pose, cycle, cmd_x_mm .. columns)"
    )
    p.add_argument("--robot", required=True, help=ROBOT_HELP)
    p.add_argument("--calibration", help="calibration.json (robocal calibrate): registers the tracker to the base")
    p.add_argument("--out", help="output directory: iso9283.json, iso9283_after.json, report.html")
    p.add_argument(
        "--after",
        default=None,
        help="the test measured again after compensation (default: CAMPAIGN/after when it exists, else the "
        "calibrated model's prediction, labelled as predicted)",
    )
    p.add_argument("--program", metavar="DIR", help="write the test's visits (iso_program.csv) into DIR instead")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    p.add_argument(
        "overrides",
        nargs="*",
        help="settings of conf/iso9283/default.yaml, e.g. certificate.serial=123 test.volume.side_mm=500",
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from robocal.errors import ConfigError
    from robocal.iso9283.settings import IsoSettings

    if args.campaign is not None and "=" in args.campaign and not Path(args.campaign).exists():
        args.overrides = [args.campaign, *(args.overrides or [])]  # a key=value taken for the optional CAMPAIGN
        args.campaign = None
    st = IsoSettings.load(parse_overrides(args.overrides))
    if args.program is not None:
        from robocal.iso9283.program import write_program
        from robocal.robot import load_robot

        if args.campaign is not None:
            raise ConfigError("--program writes the test's visits; give no CAMPAIGN with it")
        path = write_program(args.program, load_robot(args.robot), st)
        print(f"wrote {path} ({st.test.cycles} cycles x {len(st.test.approaches)} approaches x 5 poses)")
        return 0
    missing = [n for n, v in (("CAMPAIGN", args.campaign), ("--calibration", args.calibration), ("--out", args.out))
               if v is None]  # fmt: skip
    if missing:
        raise ConfigError(f"robocal iso9283 needs {', '.join(missing)} (or --program DIR)")
    from robocal.iso9283.run import run_iso9283

    res = run_iso9283(args.campaign, args.robot, args.calibration, args.out, args.after, st, not args.no_report)
    print(f"frame of the figures: {res.before.frame.get('figures_frame')}")
    for p in res.before.poses:
        a = next((x for x in res.after.poses if x.pose == p.pose), None)
        after = "" if a is None else f"; {res.after_kind} after: AP_p {a.AP_p_mm:.4f} mm, RP_l {a.RP_l_mm:.4f} mm"
        print(f"{p.pose}: {p.n_cycles} cycles, AP_p {p.AP_p_mm:.4f} mm, RP_l {p.RP_l_mm:.4f} mm{after}")
    print(f"{len(res.before.left_out)} row(s) left out; wrote {args.out}/iso9283.json, iso9283_after.json")
    return 0
