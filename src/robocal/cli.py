"""The ``robocal`` command line: ``robocal <command> ...``; ``robocal <command> --help`` for each.

Help texts are plain text (``--help`` shows no reStructuredText markup: :class:`PlainFormatter`).

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


#: what ``robocal --help`` says above the commands
DESCRIPTION = (
    "robocal: calibration of industrial robots from laser-tracker measurements. "
    "Run 'robocal COMMAND --help' for the options of a command."
)


class PlainFormatter(argparse.HelpFormatter):
    """Help without reStructuredText literals: ``text`` is shown as text."""

    def _format_text(self, text: str) -> str:
        return super()._format_text(text.replace("``", ""))

    def _expand_help(self, action: argparse.Action) -> str:
        return super()._expand_help(action).replace("``", "")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="robocal", description=DESCRIPTION, formatter_class=PlainFormatter)
    from robocal import __version__

    parser.add_argument("--version", action="version", version=f"robocal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text, formatter_class=PlainFormatter)
        p.set_defaults(_module=module, _parser=p)
        importlib.import_module(module).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    from robocal.commands import not_a_setting
    from robocal.errors import RobocalError

    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if not getattr(args, "command", None):
        if extra:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        parser.print_help()
        return 2
    command_parser: argparse.ArgumentParser = args._parser
    if extra:
        # argparse leaves positional key=value overrides given after the options (--out DIR k=v) unparsed
        if hasattr(args, "overrides") and not any(a.startswith("-") for a in extra):
            args.overrides = [*(args.overrides or []), *extra]
        else:
            command_parser.error(f"unrecognized arguments: {' '.join(extra)}")
    bare = [a for a in getattr(args, "overrides", None) or [] if "=" not in a]
    if bare:  # a setting without '=' (noise_mm 0.02): say so, with the command's usage, before running anything
        command_parser.error(not_a_setting(bare[0]))
    from robocal.io import reproducible

    try:
        # same input and settings, same bytes: no timings in the files written (the console has them), floats at
        # the precision they deserve — as the pipeline's stages write theirs (newcomer pass 13: calibration.json
        # differed between two runs by its solver time)
        with reproducible():
            return int(importlib.import_module(args._module).run(args) or 0)
    except RobocalError as exc:
        print(f"robocal {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
