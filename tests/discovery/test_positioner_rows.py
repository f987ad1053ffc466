"""Discovery on a campaign with a part on a positioner (issue 34's twin): the part's rows are calibrate's.

Before, ``robocal discover`` fitted the arm's model to the part's rows as if the reflectors were on the flange:
RMS 221 mm, validation mean 172 mm, and it still wrote calibration.json and compensation.csv."""

from __future__ import annotations

import robocal
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors
from robocal.sim.scenario import load_scenario


def test_discovery_models_the_arm_and_leaves_the_parts_rows_to_calibrate(tmp_path):
    sc = load_scenario("positioner")
    robocal.simulate(sc, tmp_path, seed=0)
    robot = robocal.load_robot(sc["robot"])
    camp = robocal.read_campaign(tmp_path, robot)
    res = discover(camp, robot)
    s = summary(res, validation_errors(res))
    n_part = int(sum(t in robot.positioner.targets for t in camp.target.astype(str)))
    assert n_part > 0 and s["positioner_part_rows_left_out"] == n_part
    # the twin's noise is 0.015 mm per coordinate (a mean 3-D error of ~0.024 mm): the arm's rows at that floor
    assert s["validation"]["final"]["mean_position_mm"] < 0.05, s["validation"]["final"]
