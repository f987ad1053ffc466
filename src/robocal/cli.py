"""The ``robocal`` command line: ``robocal <command> ...``; ``robocal <command> --help`` for each.

Each command lives in its own module under :mod:`robocal.commands` with ``add_arguments(parser)``
and ``run(args) -> int``; modules are imported only when their command runs.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

# Small dense solves are fastest single-threaded (and do not fight other jobs on the machine).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

#: command name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("robocal.commands.simulate", "write a twin measurement campaign (data contract + truth)"),
    "calibrate": ("robocal.commands.calibrate", "geometric calibration of a campaign"),
    "serve": ("robocal.commands.serve", "online compensation service (TCP JSON lines) over a calibration bundle"),
    "closed-loop": ("robocal.commands.closed_loop", "drive the twin's warm-up through the compensation service"),
    "discover": ("robocal.commands.discover", "name the effects the calibration model is missing (discovery)"),
    "compliance": ("robocal.commands.compliance", "heavy-load joint compliance and compensation (Mao 2021)"),
    "thermal": ("robocal.commands.thermal", "thermal fit, screening and compensation of a warm-up campaign"),
    "plan": ("robocal.commands.plan", "plan the calibration poses before measuring (D/A/I-optimal, constraints)"),
    "filter": ("robocal.commands.filter", "a KRL or RAPID program with every target corrected by a calibration bundle"),
    "urdf": ("robocal.commands.urdf", "the calibrated kinematics written as a URDF (+ the calibration as YAML)"),
    "fleet": ("robocal.commands.fleet", "calibrate a fleet of robots over time (local or Ray), track, flag, report"),
    "iso9283": ("robocal.commands.iso9283", "ISO 9283 pose characteristics before / after calibration, certificate"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="robocal", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        importlib.import_module(module).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    from robocal.errors import RobocalError

    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        # argparse leaves positional key=value overrides given after the options (--out DIR k=v) unparsed
        if hasattr(args, "overrides") and all("=" in a and not a.startswith("-") for a in extra):
            args.overrides = [*(args.overrides or []), *extra]
        else:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except RobocalError as exc:
        print(f"robocal {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
