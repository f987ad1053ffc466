"""``robocal simulate SCENARIO --out DIR [--seed N]``; ``robocal simulate iso9283 --out DIR [--bundle B]``: the
twin runs an ISO 9283 pose test (:mod:`robocal.iso9283.twin`)."""

from __future__ import annotations

import argparse

from robocal.commands import parse_overrides


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "scenario",
        help="scenario name (conf/scenario/<name>.yaml) or a YAML path; 'iso9283': an ISO 9283 pose test "
        "(settings conf/iso9283/default.yaml, overrides test.cycles=.. twin.scenario=..; others go to the scenario)",
    )
    p.add_argument("--out", required=True, help="output directory (created)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.add_argument(
        "--bundle", default=None, help="iso9283 only: also run the test compensated by this bundle into OUT/after"
    )
    p.add_argument("overrides", nargs="*", help="scenario overrides key=value (dotted keys nest)")


def merge_overrides(base: dict, over: dict) -> dict:
    """``over`` on top of ``base`` (a scenario and its key=value overrides), nested mappings merged key by key."""
    out = dict(base)
    for k, v in over.items():
        out[k] = merge_overrides(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def run(args: argparse.Namespace) -> int:
    from robocal.sim.scenario import load_scenario
    from robocal.sim.twin import simulate

    if args.scenario == "iso9283":
        return _iso9283(args)
    if args.bundle is not None:
        from robocal.errors import ConfigError

        raise ConfigError("--bundle is for 'robocal simulate iso9283' (the compensated ISO test)")
    sc = merge_overrides(load_scenario(args.scenario), parse_overrides(args.overrides))
    truth = simulate(sc, args.out, seed=args.seed)
    print(
        f"wrote campaign {sc.get('name', args.scenario)!r} (robot {truth['robot']}, seed {truth['seed']}) to {args.out}"
    )
    return 0


def _iso9283(args: argparse.Namespace) -> int:
    from robocal.iso9283.settings import SECTIONS, IsoSettings
    from robocal.iso9283.twin import simulate_iso
    from robocal.sim.scenario import load_scenario

    ov = parse_overrides(args.overrides)
    st = IsoSettings.load({k: v for k, v in ov.items() if k in SECTIONS})
    sc = merge_overrides(load_scenario(st.twin.scenario), {k: v for k, v in ov.items() if k not in SECTIONS})
    truth = simulate_iso(st, args.out, sc, seed=args.seed, bundle=args.bundle)
    iso = truth["iso9283"]
    print(
        f"wrote ISO 9283 test (robot {truth['robot']}, scenario {truth['scenario']!r}, seed {truth['seed']}, "
        f"{iso['cycles']} cycles x {len(iso['approaches'])} approaches x 5 poses) to {args.out}"
        + ("" if args.bundle is None else f"; compensated by {args.bundle} to {args.out}/after")
    )
    return 0
