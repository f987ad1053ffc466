"""External axes on the twin (issue 34): the track and column scenarios checked end to end against the truth.

For each scenario (``conf/scenario/track.yaml``: a KR16-2 on a 6 m track with straightness and pitch errors;
``conf/scenario/column.yaml``: on a lifting column that leans as it extends and bends under the arm's weight) and
seed, the twin writes the campaign; ``robocal.calibrate`` fits the kinematics of the axis and the arm;
:func:`robocal.calibration.axes.fit_axis_errors` fits the axis's own errors along its travel; discovery runs;
:func:`robocal.compensation.axes.compensate_axes` corrects fresh targets (the axis kept), judged on the twin's truth.
Printed per scenario and seed: held-out mean / max (mm) of the calibration alone and with the axis errors, the
chosen order, the largest |z| of the recovered coefficients against the truth (the truth's terms, and zero for the
others), whether every true term was chosen, the effects discovery named, and the compensated targets' error on
the twin (mean / max, mm) without and with the axis errors.

    python benchmarks/external_axes.py [--scenarios track column] [--seeds 1] [--poses 120]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

import robocal
from robocal.calibration.axes import axis_errors, fit_axis_errors, term_named
from robocal.calibration.validation import validate
from robocal.compensation.axes import compensate_axes
from robocal.data.contract import read_campaign
from robocal.discovery.config import DiscoveryConfig
from robocal.kinematics.axes import augment
from robocal.kinematics.chain import build_chain, fk, propagate
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario, sample_poses
from robocal.sim.twin import simulate


def true_points(robot, truth, q):
    chain = build_chain(robot)
    eta = np.array([truth["kinematic_errors"][n] for n in chain.param_names])
    terms = [term_named(robot, n) for n in truth["axis_errors"]]
    E = axis_errors(robot, q, np.zeros(len(q)), terms, np.array(list(truth["axis_errors"].values())))
    st = propagate(augment(chain, [0]), np.concatenate([q, E], axis=1), eta, np.array(truth["tracker_T_base"]))
    t = np.array(truth["tools_mm"]["T1"])
    return st.o + st.x * t[0] + st.y * t[1] + st.z * t[2]


def one(name: str, seed: int, poses: int, tmp: Path) -> None:
    sc = dict(load_scenario(name), n_poses=poses, n_validation_poses=poses // 3)
    robot = load_robot(sc["robot"])
    out = tmp / f"{name}_{seed}"
    truth = simulate(sc, out, seed=seed, robot=robot)
    camp = read_campaign(out, robot)
    res = robocal.calibrate(camp, robot)
    v = validate(res, camp)
    fit = fit_axis_errors(camp, res)
    names = [t.name for t in fit.terms]
    true = truth["axis_errors"]
    z = np.abs([(fit.coef[k] - true.get(n, 0.0)) / fit.stderr[k] for k, n in enumerate(names)])
    disc = robocal.discover(camp, robot, DiscoveryConfig.from_mapping({"report": False}))
    named = sorted(a.cand.key for a in disc.accepted)
    q_t = sample_poses(robot, 50, np.random.default_rng(1000 + seed), 0.8)
    errs = []
    for af in (None, fit):
        c = compensate_axes(res, q_t, axis_fit=af)
        x = res.x if af is None else af.x
        T = res.model.base_transform(x) @ fk(build_chain(robot), q_t)
        p_des = T[:, :3, 3] + T[:, :3, :3] @ res.model.tools(x)[0]
        ok = c.converged
        errs.append(np.linalg.norm(true_points(robot, truth, c.q[ok]) - p_des[ok], axis=1))
    va = fit.validation
    print(
        f"{name} seed {seed}: held-out mean/max {v.stats.mean_mm:.4f}/{v.stats.max_mm:.4f} mm -> with axes "
        f"{va['mean_position_mm']:.4f}/{va['max_position_mm']:.4f} mm; order {fit.order}, bending {fit.bending}, "
        f"{len(names)} terms, max |z| {z.max():.2f}, true terms chosen {set(true) <= set(names)}; discovery "
        f"{named}; compensated on the twin: kinematics {errs[0].mean():.4f}/{errs[0].max():.4f} mm, with axes "
        f"{errs[1].mean():.4f}/{errs[1].max():.4f} mm ({len(errs[1])} of 50 converged)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["track", "column"])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--poses", type=int, default=120)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        for name in args.scenarios:
            for seed in range(args.seeds):
                one(name, seed, args.poses, Path(d))


if __name__ == "__main__":
    main()
