"""Per-iteration overhead of the population optimizers, excluding the objective.

    python benchmarks/bench_metaheuristics.py [--population 1000] [--iters 200] [--poses 100] [--params 30]

Problem of the real size: 100 poses x 3 residuals, 30 variables, population 1000, 200 iterations.
Two measurements per optimizer (median of --repeat runs, single BLAS thread):

* toy: a vectorised linear residual ``R = X A^T - b`` (pop, 300); the time spent inside the residual
  callable is measured and subtracted, so "overhead" is everything else (population updates, random
  draws, fitness reduction of the residuals, selection, bookkeeping);
* cheap: a trivially cheap residual ``X - c`` (pop, 30): total time per iteration.

The objective for the real robot (nonlinear model, ~25-35 k evaluations/s in numpy) comes on top; the
"evals/iter" column says how many it needs per iteration.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from robocal.optimizers import Problem, make_optimizer


class Timed:
    """Residual callable that accumulates its own run time."""

    def __init__(self, fun) -> None:
        self.fun = fun
        self.seconds = 0.0

    def __call__(self, X: np.ndarray) -> np.ndarray:
        t = time.perf_counter()
        out = self.fun(X)
        self.seconds += time.perf_counter() - t
        return out


def run(name: str, population: int, iters: int, fun, n: int, seed: int) -> tuple[float, float, float]:
    timed = Timed(fun)
    problem = Problem(n=n, lower=-1.0, upper=1.0, batch_residuals=timed, seed=seed, max_iter=iters)
    opt = make_optimizer({"name": name, "population": population, "max_iter": iters})
    t = time.perf_counter()
    res = opt.minimize(problem)
    total = time.perf_counter() - t
    return total / res.nit, timed.seconds / res.nit, res.nfev / res.nit


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--population", type=int, default=1000)
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--poses", type=int, default=100)
    ap.add_argument("--params", type=int, default=30)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    m, n = 3 * args.poses, args.params
    A = rng.standard_normal((m, n))
    b = A @ rng.uniform(-0.5, 0.5, n)
    c = rng.uniform(-0.5, 0.5, n)

    buf = np.empty((2 * args.population, m))  # reused output: no page faults from fresh 2 MB arrays

    def toy(X: np.ndarray) -> np.ndarray:
        out = buf[: X.shape[0]]
        np.matmul(X, A.T, out=out)
        out -= b
        return out

    def cheap(X: np.ndarray) -> np.ndarray:
        return X - c

    print(
        f"population {args.population}, {args.iters} iterations, {args.poses} poses x 3 residuals, {n} variables, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, median of {args.repeat}"
    )
    head = ("optimizer", "evals/iter", "toy total", "objective", "overhead", "cheap total")
    print("{:>9} | {:>10} | {:>9} {:>9} {:>9} | {:>11}".format(*head))
    for name in ("goa", "igoa", "woa"):
        toy_runs = np.array([run(name, args.population, args.iters, toy, n, s) for s in range(args.repeat)])
        cheap_runs = np.array([run(name, args.population, args.iters, cheap, n, s) for s in range(args.repeat)])
        total, obj, evals = np.median(toy_runs, axis=0)
        print(
            f"{name:>9} | {evals:10.0f} | {1e3 * total:7.2f}ms {1e3 * obj:7.2f}ms {1e3 * (total - obj):7.2f}ms | "
            f"{1e3 * np.median(cheap_runs[:, 0]):9.2f}ms"
        )


if __name__ == "__main__":
    main()
