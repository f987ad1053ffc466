"""A positioner carrying the part (issue 34): the turntable's axis identified with the arm on the twin.

For each seed, the twin writes the ``positioner`` scenario (``conf/scenario/positioner.yaml``: a KR16-2 beside a
one-axis turntable whose axis is moved 0.94 mm across itself and tilted 0.058 deg); ``robocal.calibrate`` fits
the arm on the tool's rows and :func:`robocal.calibration.positioner.fit_positioner` the turntable with it on
the part's rows. Printed per seed: the recovered axis line against the truth in the tracker frame (tilt in urad
and shift in mm across the true line, and their chi2 with 4 degrees of freedom; the 0.999 quantile is 18.5), the
same for the declared (nominal) line, and the part's held-out mean / max error against the noise floor of the
mean (mm).

    python benchmarks/positioner.py [--seeds 10] [--angles 12]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from robocal.calibration.fit import calibrate
from robocal.calibration.positioner import fit_positioner, line_distance, part_rows
from robocal.data import read_campaign
from robocal.kinematics.positioner import part_frames
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.twin import simulate


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--angles", type=int, default=12)
    a = ap.parse_args()
    robot = load_robot("kr16_2_positioner")
    sc = load_scenario("positioner")
    sc["effects"]["positioner"]["angles"] = a.angles
    chi, ratio = [], []
    with tempfile.TemporaryDirectory() as d:
        for seed in range(a.seeds):
            truth = simulate(sc, Path(d) / str(seed), seed=seed, robot=robot)
            camp = read_campaign(Path(d) / str(seed), robot)
            fit = fit_positioner(camp, calibrate(camp.subset(~part_rows(camp, robot)), robot))
            T = np.array(truth["tracker_T_base"])
            lines = {}
            for name, th in (("true", np.array(list(truth["positioner"]["parameters"].values()))),
                             ("nominal", np.zeros(4))):  # fmt: skip
                F = part_frames(robot.positioner, np.zeros((1, 1)), th)[0]
                lines[name] = line_distance(fit, 0, T[:3, :3] @ F[:3, 2], T[:3, :3] @ F[:3, 3] + T[:3, 3])
            (dv, c2), (_, c2n) = lines["true"], lines["nominal"]
            v = fit.validation
            chi.append(c2)
            ratio.append(v["mean_position_mm"] / v["noise_floor_mean_mm"])
            print(
                f"seed {seed}: tilt {1e6 * np.hypot(*dv[:2]):.1f} urad, shift {np.hypot(*dv[2:]):.4f} mm across the "
                f"true line (chi2 {c2:.2f}; the declared line's {c2n:.0f}); held-out mean {v['mean_position_mm']:.4f}"
                f" / max {v['max_position_mm']:.4f} mm, floor {v['noise_floor_mean_mm']:.4f} mm"
            )
    print(f"chi2: mean {np.mean(chi):.2f} (4 expected), max {np.max(chi):.2f}; held-out mean / floor: mean "
          f"{np.mean(ratio):.2f}, max {np.max(ratio):.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
