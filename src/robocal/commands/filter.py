"""``robocal filter PROGRAM --bundle DIR --out DIR [--temperature T ...] [--payload-kg KG] [--config FILE]
[safety.KEY=VALUE solver.KEY=VALUE ...]``: a robot program (KUKA KRL ``.src`` + ``.dat``, ABB RAPID ``.mod``) with
every target corrected by a calibration bundle, written beside the original with a per-target table (see
:mod:`robocal.cell.programs.filter`). The refusals follow the one safety policy
(:class:`robocal.compensation.safety.SafetyPolicy`), set as for ``robocal serve``: a settings YAML (a serve
config works: its ``safety`` and ``solver`` sections are read) and ``key=value`` overrides."""

from __future__ import annotations

import argparse
from typing import Any


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("program", help="KRL NAME.src (its NAME.dat and a $config.dat beside it are read) or RAPID .mod")
    p.add_argument("--bundle", required=True, help="calibration bundle directory (robocal serve --make-bundle)")
    p.add_argument("--out", required=True, help="output folder (not the program's): the filtered files + table")
    p.add_argument(
        "--temperature",
        action="append",
        metavar="DEGC|SENSOR=DEGC",
        help="the cell's temperature for a thermal bundle: one value for every sensor, or SENSOR=degC (repeat)",
    )
    p.add_argument("--payload-kg", type=float, default=0.0, help="payload for compliance and gravity effects")
    p.add_argument(
        "--tcp-from-bundle",
        metavar="TOOL",
        help="the program's TCP is this bundle tool (calibrated with the robot), not the program's tool data",
    )
    p.add_argument("--strict", action="store_true", help="fail (write nothing) when any target is refused")
    p.add_argument(
        "--config",
        default=None,
        help="settings YAML with 'safety' and 'solver' sections (a robocal serve config works); default: the "
        "safety policy's defaults",
    )
    p.add_argument("overrides", nargs="*", help="settings key=value, e.g. safety.max_correction_deg=0.3")


def load_settings(path: str | None, overrides: list[str] | None) -> tuple[Any, Any]:
    """The safety policy and solver settings from ``--config`` and the overrides (errors name the key)."""
    from robocal.commands.serve import load_config
    from robocal.errors import ConfigError
    from robocal.serve.server import ServerConfig
    from robocal.serve.settings import SERVICE_KEYS, ServiceConfig

    if path is None:
        from robocal.commands import parse_overrides

        cfg: dict[str, Any] = parse_overrides(overrides)
    else:
        cfg = load_config(path, overrides)
    transport = set(ServerConfig.__dataclass_fields__) | {"token_env"}
    unknown = sorted(k for k in cfg if k not in SERVICE_KEYS and k not in transport)
    if unknown:
        raise ConfigError(f"unknown filter setting(s) {unknown}; known: safety.KEY, solver.KEY")
    sc = ServiceConfig.from_mapping({k: cfg[k] for k in ("safety", "solver") if k in cfg})
    return sc.safety, sc.solver


def run(args: argparse.Namespace) -> int:
    from robocal.cell.programs.common import ProgramError
    from robocal.cell.programs.filter import filter_program, parse_temperatures, read_program, write_filtered
    from robocal.serve.bundle import load_bundle

    if args.payload_kg < 0:
        raise ProgramError(f"--payload-kg must be >= 0, got {args.payload_kg}")
    safety, solver = load_settings(args.config, args.overrides)
    bundle = load_bundle(args.bundle)
    temps = parse_temperatures(args.temperature, bundle.sensors)
    prog = read_program(args.program)
    res = filter_program(prog, bundle, temps, args.payload_kg, args.tcp_from_bundle, safety=safety, solver=solver)
    if args.strict and res.n_refused:
        k = res.status.index("refused")
        t = prog.targets[k]
        raise ProgramError(f"target {t.name} refused: {'; '.join(res.reasons[k])} (--strict)", t.file, t.line)
    written = write_filtered(res, args.out)
    m = len(res.status)
    print(
        f"filter: {m} targets, {m - res.n_refused - res.n_flagged} corrected, {res.n_flagged} flagged, "
        f"{res.n_refused} refused (left as written); predicted error before: mean "
        f"{res.predicted_error_mm.mean():.4f} mm, max {res.predicted_error_mm.max():.4f} mm"
    )
    for k, s in enumerate(res.status):
        if s != "ok":
            t = prog.targets[k]
            print(f"  {s}: {t.name} ({t.file.name}:{t.line}): {'; '.join(res.reasons[k])}")
    noted = [k for k, ns in enumerate(res.notes) if ns]
    if noted:  # not a flag: the correction there is the parametric one (the residual layer stops at its region)
        names = ", ".join(prog.targets[k].name for k in noted[:10]) + (" ..." if len(noted) > 10 else "")
        print(f"  note: {len(noted)} target(s) {res.notes[noted[0]][0].split(' (')[0]}: {names}")
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
