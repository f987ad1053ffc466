"""A column's bending without link masses (issue 34): the column twin read with a description that has none.

For each seed, the twin writes the ``column`` scenario (its truth bends under the description's masses); the
campaign is calibrated and its axis errors fitted (:func:`robocal.calibration.axes.fit_axis_errors`) three
ways: with the masses (the bending's moment computed), without them (one coefficient per unknown mass parameter)
and without any bending. Printed: the held-out mean error of each (mm; the noise floor of the mean is 0.024 mm)
and the number of terms of the mass-free model.

    python benchmarks/column_without_masses.py [--seeds 3] [--poses 60]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

from robocal.calibration.axes import fit_axis_errors
from robocal.calibration.fit import calibrate
from robocal.data import read_campaign
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.twin import simulate


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--poses", type=int, default=60)
    a = ap.parse_args()
    robot = load_robot("kr16_2_column")
    bare = dataclasses.replace(robot, link_mass_kg=None, link_com_mm=None)
    with tempfile.TemporaryDirectory() as d:
        for seed in range(a.seeds):
            sc = dict(load_scenario("column"), n_poses=a.poses, n_validation_poses=20)
            simulate(sc, Path(d) / str(seed), seed=seed, robot=robot)
            camp = read_campaign(Path(d) / str(seed), robot)
            base = calibrate(camp, bare)
            free = fit_axis_errors(camp, base, {"max_order": 2})
            none = fit_axis_errors(camp, base, {"max_order": 2, "bending": False})
            masses = fit_axis_errors(camp, calibrate(camp, robot), {"max_order": 2})
            print(
                f"seed {seed}, {a.poses} poses: held-out mean with the masses "
                f"{masses.validation['mean_position_mm']:.4f} mm, without them "
                f"{free.validation['mean_position_mm']:.4f} mm ({len(free.terms)} terms, bending "
                f"{free.bending}), without a bending {none.validation['mean_position_mm']:.4f} mm"
            )


if __name__ == "__main__":
    main()
