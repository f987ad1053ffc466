"""A second session on the twin: is a calibration made in one session good in the next one?

For each seed the twin writes the ``second_session`` scenario (conf/scenario/second_session.yaml: the first
session S1, then S2 four months later from another tracker placement, with the tool re-seated and the cell 4 °C
warmer; the air temperature logged). Printed per seed, mean 3-D error on S2's validation rows (mm):

* ``within S1``: S1's calibration on S1's own validation rows (its tracker registered on its calibration rows) —
  the floor a session reaches;
* ``S1 -> S2 tracker``: S1's calibration in S2, S2's tracker registered on S2's calibration rows (the model
  frozen); the re-seated tool is still S1's;
* ``S1 -> S2 tracker+tool``: the tool re-measured in S2 too (robocal.discovery.sessions, ``tool=True``);
* ``discovered``: the same two with ``robocal discover``'s model of S1 (nothing to find in S1: it must not add
  effects that hurt S2);
* ``both sessions``: ``robocal discover`` on S1 + S2 as one campaign of two tracker stations: what it names, its
  leave-one-session-out estimate and the systematic misfits it reports.

The expansion the registration cannot take (a scale about the base, 46 ppm at 4 °C: ~0.05 mm at 1 m) stays in
the S1 -> S2 figures; the truth's size of it is printed beside them.

    python benchmarks/second_session.py [--seeds 3] [key=value scenario overrides ...]
    python benchmarks/second_session.py --null --seeds 100   # the same two sessions, tool and air unchanged

``--null``: the tool left alone, the cell at the same temperature in both sessions and the robot not growing with
it (only the tracker placement differs; the air still logged, driving nothing): the share of seeds whose discovery
over both sessions names a re-seated tool (goal <= 1 %) or anything.
"""

from __future__ import annotations

import argparse
import json
import tempfile

import numpy as np

import robocal
from robocal.commands import parse_overrides
from robocal.data.campaign import SplitConfig
from robocal.data.contract import read_campaign
from robocal.discovery.effects import extended_calibration
from robocal.discovery.sessions import session_validation
from robocal.discovery.summary import summary
from robocal.sim.scenario import load_scenario


def run_seed(scenario: dict, seed: int) -> dict:
    rob = robocal.load_robot(scenario["robot"])
    with tempfile.TemporaryDirectory() as d:
        truth = robocal.simulate(scenario, d, seed=seed)
        camp = read_campaign(d, rob, split=SplitConfig.from_mapping({"method": "none"}))
    st = np.asarray(camp.station).astype(str)
    s1, s2 = camp.subset(st == "S1"), camp.subset(st != "S1")
    geo = robocal.calibrate(s1, rob)
    out: dict = {"seed": seed}
    out["within S1"] = session_validation(geo, s1)["final"]["mean_position_mm"]
    for tool in (False, True):
        key = "tracker+tool" if tool else "tracker"
        out[f"S1 -> S2 {key}"] = session_validation(geo, s2, tool=tool)["final"]["mean_position_mm"]
    res = robocal.discover(s1, rob)
    cal = robocal.load_calibration(extended_calibration(res.final, rob, {}), rob)
    out["discovered in S1"] = [n["key"] for n in summary(res)["named"]]
    for tool in (False, True):
        key = "tracker+tool" if tool else "tracker"
        out[f"discovered S1 -> S2 {key}"] = session_validation(cal, s2, tool=tool)["final"]["mean_position_mm"]
    both = robocal.discover(camp, rob)
    sb = summary(both)
    cv = sb.get("cross_validation", {})
    out["both sessions: named"] = [n["key"] for n in sb["named"]]
    out["both sessions: new-session estimate"] = (cv.get("session_cv") or {}).get("mean_position_mm")
    out["both sessions: systematic misfits"] = [m.get("condition") for m in sb.get("systematic_misfit", [])]
    e = truth["effects"]["second_session"]
    out["truth"] = {"tool_shift_mm": float(np.linalg.norm(e["tool_shift_mm"])), "air_C": e["air_C_mean"]}
    return out


def null(scenario: dict, seeds: int) -> int:
    """Discovery over two sessions that differ only by the tracker's placement, over ``seeds`` seeds."""
    quiet = {"tool_shift_mm": [0.0, 0.0, 0.0], "air_C": [20.0, 20.0], "expansion_ppm_per_C": 0.0}
    sc = {**scenario, "effects": {"second_session": {**scenario["effects"]["second_session"], **quiet}}}
    rob = robocal.load_robot(sc["robot"])
    n_session = n_any = 0
    for seed in range(seeds):
        with tempfile.TemporaryDirectory() as d:
            robocal.simulate(sc, d, seed=seed)
            camp = read_campaign(d, rob)
        named = [a.cand.key for a in robocal.discover(camp, rob).accepted]
        n_session += any(k.startswith("session:") for k in named)
        n_any += bool(named)
        if named:
            print(f"seed {seed}: named {named}", flush=True)
    print(
        f"{seeds} null twins of two sessions: a re-seated tool named in {n_session} ({n_session / seeds:.1%}), "
        f"anything named in {n_any} ({n_any / seeds:.1%})"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--scenario", default="second_session")
    ap.add_argument("overrides", nargs="*", help="scenario key=value overrides")
    ap.add_argument("--null", action="store_true", help="no re-seat, no warming: the false-discovery rate")
    args = ap.parse_args(argv)
    scenario = load_scenario(args.scenario)
    scenario.update(parse_overrides(args.overrides))
    if args.null:
        return null(scenario, args.seeds)
    rows = []
    for seed in range(args.seeds):
        r = run_seed(scenario, seed)
        rows.append(r)
        print(json.dumps(r, default=float), flush=True)
    keys = [k for k in rows[0] if isinstance(rows[0][k], float)]
    print("mean over seeds: " + ", ".join(f"{k} {np.mean([r[k] for r in rows]):.4f} mm" for k in keys))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
