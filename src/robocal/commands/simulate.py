"""``robocal simulate SCENARIO --out DIR [--seed N]``."""

from __future__ import annotations

import argparse

from robocal.commands import parse_overrides


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario name (conf/scenario/<name>.yaml) or a YAML path")
    p.add_argument("--out", required=True, help="output directory (created)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.add_argument("overrides", nargs="*", help="scenario overrides key=value (dotted keys nest)")


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def run(args: argparse.Namespace) -> int:
    from robocal.sim.twin import load_scenario, simulate

    sc = _merge(load_scenario(args.scenario), parse_overrides(args.overrides))
    truth = simulate(sc, args.out, seed=args.seed)
    print(
        f"wrote campaign {sc.get('name', args.scenario)!r} (robot {truth['robot']}, seed {truth['seed']}) to {args.out}"
    )
    return 0
