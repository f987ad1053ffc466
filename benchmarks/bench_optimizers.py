"""Speed of the calibration objectives and of the optimizers, and our WOA against mealpy's.

    python benchmarks/bench_optimizers.py [--poses 100] [--population 500] [--seconds 3] [--mealpy]

On the twin's geometric campaign (KR16-2, 15 um noise), with the identifiable parameter set:

1. fitness evaluations per second, population ``--population`` on ``--poses`` poses: nonlinear objective
   (numba kernel, numpy kernel, the model's own ``batch_position_residuals``) and linearised (eq. 9);
2. improved GOA, population 1000 x 200 iterations, nonlinear objective: wall time;
3. Gauss-Newton and Ipopt (first solve with the build, then cached);
4. with ``--mealpy`` (``pip install mealpy``, benchmark-only): our WOA vs mealpy's ``OriginalWOA`` on the
   same objective (nonlinear RMS 3-D error, same bounds) and the same budget (population 500 x 200
   iterations), 3 seeds: final error and wall time.

Timings are medians; the machine's load varies, run it twice.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.problem import calibration_problem
from robocal.calibration.start import fit_data, present_targets
from robocal.data.contract import read_campaign
from robocal.optimizers import make_optimizer
from robocal.optimizers.fastfk import HAVE_NUMBA, PopulationPositions
from robocal.optimizers.protocol import evaluate_batch
from robocal.robot import load_robot
from robocal.sim.scenario import load_scenario
from robocal.sim.twin import simulate


def rate(fun, X: np.ndarray, seconds: float) -> float:
    """Median evaluations per second of ``fun(X)`` over repeated blocks of ~seconds/5."""
    fun(X)
    rates = []
    for _ in range(5):
        t = time.perf_counter()
        n = 0
        while time.perf_counter() - t < seconds / 5:
            fun(X)
            n += 1
        rates.append(n * X.shape[0] / (time.perf_counter() - t))
    return float(np.median(rates))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=100)
    ap.add_argument("--population", type=int, default=500)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--mealpy", action="store_true", help="also run mealpy's WOA (pip install mealpy)")
    args = ap.parse_args()

    robot = load_robot("kr16_2")
    sc = load_scenario("geometric")
    sc.update(n_poses=args.poses, n_validation_poses=0)
    with tempfile.TemporaryDirectory() as d:
        simulate(sc, d, seed=args.seed)
        camp = read_campaign(d, robot)
    base = calibrate(camp, robot, CalibrationConfig(max_iter=0))
    free = np.flatnonzero(base.identified)
    data = fit_data(camp, False, present_targets(camp))
    x_init = base.start.x_init
    problem, search = calibration_problem(base.model, data, x_init, free, max_iter=200)
    lin, _ = calibration_problem(base.model, data, x_init, free, objective="linearized", max_iter=200)
    rng = np.random.default_rng(0)
    Z = problem.lower + (problem.upper - problem.lower) * rng.random((args.population, problem.n))
    print(f"{args.poses} poses, {problem.n} free parameters, population {args.population}, numba={HAVE_NUMBA}")
    print("\n1. fitness evaluations per second")
    rows = []
    if HAVE_NUMBA:
        rows.append(
            ("nonlinear, numba kernel (fitness incl.)", rate(lambda X: evaluate_batch(problem, X), Z, args.seconds))
        )
    pn = PopulationPositions(base.model, search.data, backend="numpy")
    rows.append(("nonlinear, numpy kernel", rate(lambda X: pn(search.full(X)), Z, args.seconds)))
    rows.append(
        (
            "nonlinear, CalibrationModel.batch_position_residuals",
            rate(lambda X: base.model.batch_position_residuals(search.full(X), search.data), Z, args.seconds),
        )
    )
    rows.append(("linearized eq. 9 (fitness incl.)", rate(lambda X: evaluate_batch(lin, X), Z, args.seconds)))
    for name, r in rows:
        print(f"  {name:55s} {r / 1e3:8.1f} k/s")

    print("\n2. improved GOA, population 1000 x 200 iterations, nonlinear")
    times = []
    for seed in range(3):
        opt = make_optimizer({"name": "igoa", "population": 1000, "max_iter": 200})
        t = time.perf_counter()
        res = opt.minimize(replace(problem, seed=seed))
        times.append(time.perf_counter() - t)
        print(f"  seed {seed}: {times[-1]:.2f} s, {res.nfev} evaluations, RMS {res.cost:.4f} mm")
    print(f"  median {np.median(times):.2f} s")

    print("\n3. gradient methods")
    unb, _ = calibration_problem(base.model, data, x_init, free, bounded=False)
    for name, cfg in (("gn", {"name": "gn", "max_iter": 30}), ("ipopt", {"name": "ipopt", "max_iter": 100})):
        for k in range(2):
            t = time.perf_counter()
            res = make_optimizer(cfg).minimize(unb)
            print(f"  {name} solve {k + 1}: {time.perf_counter() - t:.3f} s, RMS {res.cost:.5f} mm, nit {res.nit}")

    if args.mealpy:
        mealpy_vs_ours(problem)


def mealpy_vs_ours(problem) -> None:
    try:
        from mealpy import FloatVar
        from mealpy.swarm_based.WOA import OriginalWOA
    except ImportError:
        print("\n4. mealpy is not installed (pip install mealpy): skipped")
        return
    print("\n4. WOA: ours vs mealpy OriginalWOA, population 500 x 200 iterations, nonlinear RMS 3-D (mm)")

    def fit_one(z: np.ndarray) -> float:
        return float(evaluate_batch(problem, np.asarray(z, dtype=float)[None, :])[0])

    ours_t, ours_e, theirs_t, theirs_e, greedy_e, greedy_t = [], [], [], [], [], []
    for seed in range(3):
        opt = make_optimizer({"name": "woa", "population": 500, "max_iter": 200})
        t = time.perf_counter()
        res = opt.minimize(replace(problem, seed=seed, target=None))
        ours_t.append(time.perf_counter() - t)
        ours_e.append(res.cost)
        # the same algorithm with mealpy's greedy selection (keep a move only if it improves)
        opt = make_optimizer({"name": "woa", "population": 500, "max_iter": 200, "greedy": True})
        t = time.perf_counter()
        res_g = opt.minimize(replace(problem, seed=seed, target=None))
        greedy_t.append(time.perf_counter() - t)
        greedy_e.append(res_g.cost)
        model = OriginalWOA(epoch=200, pop_size=500)
        spec = {
            "obj_func": fit_one,
            "bounds": FloatVar(lb=problem.lower.tolist(), ub=problem.upper.tolist()),
            "minmax": "min",
            "log_to": None,
        }
        t = time.perf_counter()
        best = model.solve(spec, seed=seed)
        theirs_t.append(time.perf_counter() - t)
        theirs_e.append(float(best.target.fitness))
        print(
            f"  seed {seed}: ours {ours_e[-1]:.4f} mm in {ours_t[-1]:.2f} s ({res.nfev} evals); "
            f"ours greedy {greedy_e[-1]:.4f} mm in {greedy_t[-1]:.2f} s; "
            f"mealpy {theirs_e[-1]:.4f} mm in {theirs_t[-1]:.2f} s"
        )
    print(
        f"  median: ours {np.median(ours_e):.4f} mm, {np.median(ours_t):.2f} s; mealpy {np.median(theirs_e):.4f} mm, "
        f"{np.median(theirs_t):.2f} s; speed ratio {np.median(theirs_t) / np.median(ours_t):.0f}x"
    )
    print(
        f"  greedy (same selection as mealpy): ours {np.median(greedy_e):.4f} mm, {np.median(greedy_t):.2f} s; "
        f"speed ratio {np.median(theirs_t) / np.median(greedy_t):.0f}x"
    )


if __name__ == "__main__":
    main()
