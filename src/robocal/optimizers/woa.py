"""Whale Optimization Algorithm (Mirjalili & Lewis 2016, Adv. Eng. Softw. 95:51-67), vectorised.

Per iteration t = 0 .. max_iter - 1, with ``a = a_max * (1 - t / max_iter)`` falling linearly 2 -> 0 and,
per whale, ``A = 2 a r1 - a``, ``C = 2 r2``, p ~ U[0, 1], l ~ U[-1, 1]:

* p < 0.5 and |A| < 1, encircling the prey: ``D = |C X* - X|``, ``X <- X* - A D`` (paper eq. 2.1-2.2),
  X* the best-so-far;
* p < 0.5 and |A| >= 1, search for prey: the same with a random whale ``X_rand`` of the population in
  place of X* (eq. 2.7-2.8);
* p >= 0.5, bubble-net spiral: ``X <- |X* - X| e^{b l} cos(2 pi l) + X*`` with b = 1 (eq. 2.5).

Then clip to the bounds and evaluate every whale (one batch call, N evaluations per iteration). The
best-so-far is kept apart from the population. By default there is no greedy selection, as in the paper;
``greedy=True`` keeps a whale's new position only when it improves its fitness, which is what mealpy's
``OriginalWOA`` does (it also draws the "random whale" from the box rather than the population). Greedy
selection converges much further on calibration problems (see benchmarks/bench_optimizers.py --mealpy).

Choices where the sources leave room:

* r1, r2 (hence A and C) are scalars per whale, as in the authors' MATLAB code, which makes the test
  |A| < 1 well defined (the paper writes A and C as vectors; a per-dimension r is also common).
* l ~ U[-1, 1] as in the paper (the authors' code draws l in [a2, 1] with a2 falling -1 -> -2).
* Updates are synchronous: X_rand is a random *other* whale's position at the start of the iteration.
* If ``problem.x0`` is given it replaces the first whale of the initial population.
"""

from __future__ import annotations

import numpy as np

from robocal.errors import ConfigError
from robocal.optimizers.protocol import (
    EstimatorParams,
    FitResult,
    IterationCallback,
    Problem,
    SearchTracker,
    check_bool,
    check_callable,
    check_int,
    check_real,
    other_index,
    require_finite_bounds,
)

__all__ = ["WOA", "whale_search"]


def whale_search(
    problem: Problem,
    *,
    population: int,
    max_iter: int,
    a_max: float = 2.0,
    spiral_b: float = 1.0,
    spiral_prob: float = 0.5,
    greedy: bool = False,
    callback: IterationCallback | None = None,
    method: str = "woa",
) -> FitResult:
    """WOA main loop (arguments assumed valid; :class:`WOA` validates them)."""
    rng = np.random.default_rng(problem.seed)
    lb = np.asarray(problem.lower, dtype=float)
    ub = np.asarray(problem.upper, dtype=float)
    width = ub - lb
    n_pop, n = population, problem.n
    X = lb + width * rng.random((n_pop, n))
    if problem.x0 is not None:
        X[0] = problem.x0
    tracker = SearchTracker(problem, method, max_iter, callback)
    fit = tracker.evaluate(X)
    tracker.offer(X, fit)
    extra = {"population": n_pop}
    if tracker.start():
        return tracker.result(extra)

    everyone = np.arange(n_pop)
    t = 0
    while True:
        a = a_max * (1.0 - t / max_iter)
        r1 = rng.random(n_pop)
        r2 = rng.random(n_pop)
        p = rng.random(n_pop)
        ell = rng.uniform(-1.0, 1.0, n_pop)
        A = 2.0 * a * r1 - a
        C = 2.0 * r2
        best = tracker.best_x
        shrink = p < 1.0 - spiral_prob
        # reference point of the shrinking-encircling moves: the best, or a random other whale if |A| >= 1
        ref = np.broadcast_to(best, (n_pop, n)).copy()
        search = shrink & (np.abs(A) >= 1.0)
        if search.any():
            ref[search] = X[other_index(rng, n_pop, everyone[search])]
        X_new = np.empty_like(X)
        s = np.flatnonzero(shrink)
        X_new[s] = ref[s] - A[s, None] * np.abs(C[s, None] * ref[s] - X[s])
        q = np.flatnonzero(~shrink)
        X_new[q] = np.abs(best - X[q]) * (np.exp(spiral_b * ell[q]) * np.cos(2.0 * np.pi * ell[q]))[:, None] + best
        np.clip(X_new, lb, ub, out=X_new)
        fit_new = tracker.evaluate(X_new)
        tracker.offer(X_new, fit_new)
        if greedy:  # keep a whale's move only if it improved (NaN fitness never replaces a finite one)
            better = ~(fit_new >= fit) & np.isfinite(fit_new)
            X = np.where(better[:, None], X_new, X)
            fit = np.where(better, fit_new, fit)
        else:
            X, fit = X_new, fit_new
        t += 1
        if tracker.end_iteration(X, fit):
            break
    return tracker.result(extra)


class WOA(EstimatorParams):
    """Whale Optimization Algorithm (Mirjalili & Lewis 2016).

    Parameters
    ----------
    population : int, default 500
        Number of whales (>= 2).
    max_iter : int, optional
        Iteration budget; None takes ``problem.max_iter``. Also sets the slope of ``a``.
    a_max : float, default 2.0
        Start value of ``a``, which falls linearly to 0 over ``max_iter`` iterations.
    spiral_b : float, default 1.0
        Shape constant b of the logarithmic spiral.
    spiral_prob : float, default 0.5
        Probability of the spiral move (p >= 0.5 in the paper).
    greedy : bool, default False
        Keep a whale's new position only if it improves its fitness (mealpy's variant; not in the paper).
    callback : callable, optional
        ``callback(IterationInfo) -> bool | None`` after each iteration; True stops (status 7).

    Notes
    -----
    Needs finite bounds; ``problem.scale`` is not used (moves are differences of positions). See the
    module docstring for the update and the choices made.
    """

    name = "woa"
    family = "population"

    def __init__(
        self,
        *,
        population: int = 500,
        max_iter: int | None = None,
        a_max: float = 2.0,
        spiral_b: float = 1.0,
        spiral_prob: float = 0.5,
        greedy: bool = False,
        callback: IterationCallback | None = None,
    ) -> None:
        self.population = population
        self.max_iter = max_iter
        self.a_max = a_max
        self.spiral_b = spiral_b
        self.spiral_prob = spiral_prob
        self.greedy = greedy
        self.callback = callback

    def validate_params(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid keyword argument."""
        owner = type(self).__name__
        check_int(self.population, "population", owner, minimum=2)
        if self.max_iter is not None:
            check_int(self.max_iter, "max_iter", owner, minimum=1)
        check_real(self.a_max, "a_max", owner, 0.0)
        check_real(self.spiral_b, "spiral_b", owner)
        check_real(self.spiral_prob, "spiral_prob", owner, 0.0, 1.0)
        check_bool(self.greedy, "greedy", owner)
        check_callable(self.callback, "callback", owner)

    def minimize(self, problem: Problem) -> FitResult:
        """Minimise ``problem``'s fitness within its bounds; see the class docstring."""
        if not isinstance(problem, Problem):
            raise ConfigError(
                f"The 'problem' parameter of WOA.minimize must be a Problem. Got {type(problem).__name__} instead."
            )
        self.validate_params()
        require_finite_bounds(problem, "WOA")
        return whale_search(
            problem,
            population=int(self.population),
            max_iter=int(self.max_iter if self.max_iter is not None else problem.max_iter),
            a_max=float(self.a_max),
            spiral_b=float(self.spiral_b),
            spiral_prob=float(self.spiral_prob),
            greedy=bool(self.greedy),
            callback=self.callback,
            method=self.name,
        )
