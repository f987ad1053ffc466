"""``plan`` on 100 000 candidates (issue 15: ≤ 10 s): candidates + constraints, Jacobians, exchange, predictions.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/plan_speed.py

Times ``plan_poses`` (with the poses-needed curve) and ``write_plan`` (plan.csv, plan.json, report.html) for
each robot and criterion, N = 40, in the twin's default cell (conf/plan/default.yaml).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import yaml

from robocal.plan import plan_poses, write_plan

CONF = Path(__file__).resolve().parents[1] / "conf" / "plan" / "default.yaml"


def main() -> None:
    base = yaml.safe_load(CONF.read_text())
    print(
        "| robot | criterion | accepted of 100000 | plan_poses (s) | of which: candidates + checks | Jacobians "
        "| exchange | predictions + curve | write incl. report (s) | exchanges |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as d:
        for robot in ("kr16_2", "sr210"):
            for crit, cone in (("D", None), ("I", None), ("D", 180.0), ("I", 180.0)):
                cfg = {**base, "n_candidates": 100000, "n_poses": 40, "criterion": crit}
                if cone is not None:  # no acceptance-cone check: most of the 100 000 candidates stay in play
                    cfg["tracker"] = {**base["tracker"], "acceptance_half_angle_deg": cone}
                t0 = time.perf_counter()
                res = plan_poses(robot, cfg)
                t1 = time.perf_counter()
                write_plan(res, Path(d) / f"{robot}_{crit}")
                t2 = time.perf_counter()
                tm = res.timings
                print(
                    f"| {robot} | {crit}{' (no cone)' if cone else ''} | {res.problem.cand.n} | {t1 - t0:.2f} | {tm['candidates_s']:.2f} | "
                    f"{tm['jacobian_s']:.2f} | {tm['exchange_s']:.2f} | {tm['predictions_and_curve_s']:.2f} | "
                    f"{t2 - t1:.2f} | {res.exchange['n_exchanges']} |"
                )


if __name__ == "__main__":
    main()
