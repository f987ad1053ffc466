"""The gross-error screen of a large campaign on twins (issue 31): null twins stay silent, planted effects and
gross errors are found.

    python benchmarks/outlier_screen.py                       # 10 null seeds of 6 000 rows
    python benchmarks/outlier_screen.py --rows 12000 --seeds 3 --effects

Each seed writes the twin's ``geometric`` scenario with ``--rows`` rows (80 % calibration), 20 gross errors of
0.5-2 mm on calibration rows and, with ``--effects``, a joint-4 gear error and joint-2/5 backlash (as
``bench_scale.py``'s twin); ``robocal.discover`` runs with the defaults (a campaign over
``discovery.outlier_screen_rows`` kept rows is screened on a sample first). Printed per seed: the searches run,
the effects named, how many planted gross errors were listed and how many other rows were, and the rows the
final search's own test flagged among those it fitted (``gross_error_screen.flagged_by_final_model``).
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from robocal.data import read_campaign
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.search import discover
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.twin import simulate

PLANTED = {"backlash:j2", "backlash:j5", "gear:j4:h1"}  # the keys discovery names for EFFECTS
EFFECTS = {
    "gear": {"joint": 4, "harmonics": [{"harmonic": 1, "amplitude_deg": 0.005, "phase_deg": 40.0}]},
    "backlash": {"joints": {2: 0.006, 5: 0.02}},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=6000)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=11)
    ap.add_argument("--effects", action="store_true", help="plant a gear error and backlash (else a null twin)")
    a = ap.parse_args()
    right = found_all = 0
    for seed in range(a.first_seed, a.first_seed + a.seeds):
        d = Path(tempfile.mkdtemp(prefix="outlier_screen_")) / "campaign"
        sc = load_scenario("geometric")
        n_cal = (4 * a.rows) // 5
        sc.update(n_poses=n_cal, n_validation_poses=a.rows - n_cal, effects=EFFECTS if a.effects else {},
                  gross_errors={"n": 20, "min_mm": 0.5, "max_mm": 2.0})  # fmt: skip
        truth = simulate(sc, d, seed=seed)
        robot = load_robot(sc["robot"])
        camp = read_campaign(d, robot)
        res = discover(camp, robot, DiscoveryConfig())
        planted = {g["pose_id"] for g in truth["gross_errors"]}
        listed = {o["pose_id"] for o in res.extra["outliers"]}
        named = [a_.cand.key for a_ in res.accepted]
        flagged = res.extra.get("gross_error_screen", {}).get("flagged_by_final_model", [])
        right += set(named) == (PLANTED if a.effects else set())
        found_all += planted <= listed
        print(
            f"seed {seed}: {camp.n_rows} rows, {res.extra['outlier_searches']} searches, named {named}, planted gross "
            f"errors listed {len(planted & listed)}/{len(planted)}, other rows listed {len(listed - planted)}, "
            f"flagged by the final model {len(flagged)}",
            flush=True,
        )
    what = "named exactly the planted effects" if a.effects else "named nothing"
    print(f"{a.seeds} seeds: {right} {what}; every planted gross error listed in {found_all}")


if __name__ == "__main__":
    main()
