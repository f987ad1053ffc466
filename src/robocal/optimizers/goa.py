"""Goat Optimization Algorithm (GOA) and the thermal paper's improved GOA (Tent-map start + DE step).

Two layers: :func:`goat_search` and :func:`tent_population` work on arrays; :class:`GOA` and
:class:`ImprovedGOA` are thin, scikit-learn-style classes over them (``__init__`` stores keyword
arguments, ``minimize`` validates and runs). Both are vectorised over the population: no Python loop
over individuals, one batch call of ``problem.batch_residuals`` per sub-step that needs fresh fitness.

Classic GOA (Nozari et al. 2025, arXiv 2503.02331; public MATLAB code, MathWorks File Exchange 180278),
per goat and iteration, with constant coefficients (no schedules):

1. exploration, with probability ``explore_prob`` (0.5): ``X += alpha * G * (UB - LB)``, G ~ N(0, 1) per
   dimension, ``alpha`` = 0.05 (eq. 10 of Guo et al. 2026);
2. exploitation, if r2 >= 1 - ``exploit_prob`` (r2 >= 0.5): ``X += alpha_exploit * (X_leader - X)``,
   ``alpha_exploit`` = 0.5, the leader being the best-so-far (eq. 11);
3. jump, with probability ``jump_prob`` = J = 0.1: ``X += jump_coef * (X_rand - X)``, ``jump_coef`` = h = 0.1
   (eq. 12);
4. clip to the bounds, evaluate;
5. parasite avoidance: the worst ``floor(parasite_share * N)`` goats (0.2 N) are re-drawn uniformly in the
   box (eq. 13) and evaluated; the best-so-far is kept apart from the population (elitism).

Choices where the sources leave room (all documented here, none changes a coefficient):

* The updates are synchronous over the population: ``X_rand`` in the jump is another goat's position
  after this iteration's exploration/exploitation (a per-goat MATLAB loop sees a mix of old and new
  positions); the random goat is never the goat itself (that would be a null move).
* The worst 20 % are ranked by fitness evaluated *after* this iteration's moves, and the re-drawn goats
  are evaluated at once (a second, smaller batch call), so every goat in the population always has a
  known fitness. This costs ``floor(0.2 N)`` extra evaluations per iteration.
* Goats that did not move in an iteration (no exploration, exploitation or jump: 22.5 % of them at the
  default probabilities) keep their fitness and are not re-evaluated: the objective is deterministic.
  ``nfev`` counts the points actually evaluated.
* If ``problem.x0`` is given it replaces the first individual of the initial population.

Improved GOA (Guo et al. 2026, section 2.2, eq. 14-17, steps (1)-(9)); see :class:`ImprovedGOA` for the
points where the paper is ambiguous and what was chosen.
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
    check_callable,
    check_int,
    check_real,
    other_index,
    require_finite_bounds,
)

__all__ = ["GOA", "ImprovedGOA", "goat_search", "tent_map", "tent_population"]


# --------------------------------------------------------------------------------------------------------
# array layer
# --------------------------------------------------------------------------------------------------------


def tent_map(x: np.ndarray, mu: float = 2.0, b: float = 0.5) -> np.ndarray:
    """One step of the tent map on values in [0, 1] (eq. 14 of Guo et al. 2026, read as below).

    ``T(x) = (mu / 2) * x / b`` for ``x <= b`` and ``(mu / 2) * (1 - x) / (1 - b)`` otherwise.

    Eq. 14 as printed, ``mu * x / b``, gives ``4 x`` at the paper's mu = 2, b = 0.5 and leaves (0, 1) after
    one step, so it cannot be meant literally; it mixes the two usual forms (``mu * x`` with mu in (0, 2],
    and the skew tent map ``x / b``). Scaling the skew tent map by ``mu / 2`` covers both: at mu = 2,
    b = 0.5 it is the classic ``2 * min(x, 1 - x)``, which is what both readings give there.
    """
    x = np.asarray(x, dtype=float)
    return (0.5 * mu) * np.where(x <= b, x / b, (1.0 - x) / (1.0 - b))


def tent_population(
    rng: np.random.Generator, population: int, n: int, mu: float = 2.0, b: float = 0.5, steps: int = 10
) -> np.ndarray:
    """Initial population (population, n) in (0, 1) from short Tent-map sequences, one per individual.

    The textbook construction iterates one chaotic sequence across the individuals. At mu = 2 in float64
    that sequence collapses: each step is an exact doubling that drops one of the 53 mantissa bits, so
    any start reaches 0 (and stays there) after at most ~53 steps, and a population of 1500 would be
    mostly zero rows. Here every individual and dimension gets its own short sequence instead: a seed
    drawn from ``rng`` (uniform in (0, 1), 53 random bits), iterated ``steps`` times (default 10, keeping
    >= 43 random bits); the rare value that still lands on 0 or 1 is re-drawn.

    Note: at mu = 2 the tent map preserves the uniform distribution, so this population is uniform in
    distribution, like GOA's. The map is kept for fidelity to the paper; whatever the improved GOA gains
    over GOA comes from the DE step, not from the distribution of the start.
    """
    z = rng.random((population, n))
    z[z == 0.0] = 1.0 / 3.0  # rng.random() is in [0, 1); 0 is a fixed point
    for _ in range(steps):
        z = tent_map(z, mu, b)
    bad = (z <= 0.0) | (z >= 1.0)
    if bad.any():
        z[bad] = rng.uniform(np.nextafter(0.0, 1.0), 1.0, size=int(bad.sum()))
    return z


def _two_other_indices(rng: np.random.Generator, n_pop: int, me: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each index c in ``me`` two random indices r1 != r2, both != c (needs n_pop >= 3)."""
    r1 = other_index(rng, n_pop, me)
    lo = np.minimum(me, r1)
    hi = np.maximum(me, r1)
    r2 = rng.integers(0, n_pop - 2, size=me.shape)
    r2 = r2 + (r2 >= lo)
    r2 = r2 + (r2 >= hi)
    return r1, r2


def goat_search(
    problem: Problem,
    *,
    population: int,
    max_iter: int,
    alpha: float = 0.05,
    alpha_exploit: float = 0.5,
    explore_prob: float = 0.5,
    exploit_prob: float = 0.5,
    jump_prob: float = 0.1,
    jump_coef: float = 0.1,
    parasite_share: float = 0.2,
    tent: tuple[float, float, int] | None = None,
    de: tuple[float, float, float] | None = None,
    callback: IterationCallback | None = None,
    method: str = "goa",
) -> FitResult:
    """GOA main loop; with ``tent=(mu, b, steps)`` and ``de=(share, F, CR)`` the improved GOA.

    Arguments are assumed valid (the classes validate them). See the module docstring for the update
    order and :class:`ImprovedGOA` for the DE step.
    """
    rng = np.random.default_rng(problem.seed)
    lb = np.asarray(problem.lower, dtype=float)
    ub = np.asarray(problem.upper, dtype=float)
    width = ub - lb
    n_pop, n = population, problem.n
    n_reset = int(np.floor(parasite_share * n_pop + 1e-9))

    # (1) initial population: uniform (GOA) or Tent map (improved GOA), mapped into the bounds
    if tent is None:
        X = lb + width * rng.random((n_pop, n))
    else:
        X = lb + width * tent_population(rng, n_pop, n, *tent)
    if problem.x0 is not None:
        X[0] = problem.x0
    tracker = SearchTracker(problem, method, max_iter, callback)
    # (2) fitness of every individual and the global best
    fit = tracker.evaluate(X)
    tracker.offer(X, fit)
    if tracker.start():
        return tracker.result(_extra(n_pop, tent, de))

    while True:
        dirty = np.zeros(n_pop, dtype=bool)  # moved since its fitness was last evaluated
        # (3) exploration (eq. 10)
        explore = rng.random(n_pop) < explore_prob
        k = int(explore.sum())
        if k:
            X[explore] += alpha * rng.standard_normal((k, n)) * width
            dirty |= explore
        # (4) DE on a random share of the population (eq. 15-17), improved GOA only
        if de is not None:
            np.clip(X, lb, ub, out=X)  # the greedy selection evaluates these positions
            _de_step(rng, tracker, X, fit, dirty, lb, ub, *de)
        # (5) exploitation toward the leader = best-so-far (eq. 11)
        exploit = rng.random(n_pop) >= 1.0 - exploit_prob
        X[exploit] += alpha_exploit * (tracker.best_x - X[exploit])
        dirty |= exploit
        # (6) jump toward another random goat (eq. 12), synchronous snapshot
        jumpers = np.flatnonzero(rng.random(n_pop) < jump_prob)
        if jumpers.size:
            partners = other_index(rng, n_pop, jumpers)
            X[jumpers] += jump_coef * (X[partners] - X[jumpers])
            dirty[jumpers] = True
        np.clip(X, lb, ub, out=X)
        moved = np.flatnonzero(dirty)
        fit[moved] = tracker.evaluate(X[moved])
        tracker.offer(X[moved], fit[moved])
        # (7) parasite avoidance: re-draw the worst floor(0.2 N) uniformly (eq. 13); (8) their fitness
        if n_reset:
            worst = np.argpartition(fit, n_pop - n_reset)[n_pop - n_reset :]
            X[worst] = lb + width * rng.random((n_reset, n))
            fit[worst] = tracker.evaluate(X[worst])
            tracker.offer(X[worst], fit[worst])
        # (9) stop rule
        if tracker.end_iteration(X, fit):
            break
    return tracker.result(_extra(n_pop, tent, de))


def _de_step(
    rng: np.random.Generator,
    tracker: SearchTracker,
    X: np.ndarray,
    fit: np.ndarray,
    dirty: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    share: float,
    f_mut: float,
    cr: float,
) -> None:
    """DE/best/1/bin on ``round(share * N)`` random goats, in place on ``X``, ``fit`` and ``dirty``.

    One batch call evaluates the trial vectors together with the selected goats whose fitness is stale
    (they explored in this iteration), so that the greedy selection compares fresh values.
    """
    n_pop, n = X.shape
    m = min(n_pop, round(share * n_pop))
    if m == 0:
        return
    sel = rng.permutation(n_pop)[:m]
    r1, r2 = _two_other_indices(rng, n_pop, sel)
    mutant = tracker.best_x + f_mut * (X[r1] - X[r2])  # eq. 15
    cross = rng.random((m, n)) <= cr  # eq. 16, with one forced dimension
    cross[np.arange(m), rng.integers(0, n, size=m)] = True
    trial = np.where(cross, mutant, X[sel])
    np.clip(trial, lb, ub, out=trial)
    stale = sel[dirty[sel]]
    batch = np.concatenate([X[stale], trial])
    f_batch = tracker.evaluate(batch)
    tracker.offer(batch, f_batch)
    fit[stale] = f_batch[: stale.size]
    dirty[stale] = False
    f_trial = f_batch[stale.size :]
    better = f_trial < fit[sel]  # eq. 17, greedy selection
    winners = sel[better]
    X[winners] = trial[better]
    fit[winners] = f_trial[better]


def _extra(n_pop: int, tent: tuple[float, float, int] | None, de: tuple[float, float, float] | None) -> dict:
    extra: dict[str, object] = {"population": n_pop, "init": "uniform" if tent is None else "tent"}
    if de is not None:
        extra["de_share"] = de[0]
    return extra


# --------------------------------------------------------------------------------------------------------
# classes
# --------------------------------------------------------------------------------------------------------


class GOA(EstimatorParams):
    """Goat Optimization Algorithm (Nozari et al. 2025), as in the authors' MATLAB code.

    Parameters
    ----------
    population : int, default 500
        Number of goats N (>= 2). The thermal paper compares 500, 1000 and 1500.
    max_iter : int, optional
        Iteration budget; None takes ``problem.max_iter``.
    alpha : float, default 0.05
        Exploration step as a fraction of ``UB - LB`` per N(0, 1) draw (eq. 10).
    alpha_exploit : float, default 0.5
        Exploitation step toward the leader, alpha' (eq. 11).
    explore_prob, exploit_prob : float, default 0.5
        Probability that a goat explores / exploits in an iteration (r1 < 0.5, r2 >= 0.5).
    jump_prob : float, default 0.1
        Probability J of a jump (eq. 12).
    jump_coef : float, default 0.1
        Jump step h toward a random goat (eq. 12); the MATLAB code uses h = J.
    parasite_share : float, default 0.2
        Share of the worst goats re-drawn uniformly each iteration, floor(share * N) of them (eq. 13).
    callback : callable, optional
        ``callback(IterationInfo) -> bool | None`` after each iteration; True stops (status 7).

    Notes
    -----
    Needs finite bounds. Works in the problem's own variables: every step is a multiple of the box width
    or of a difference of positions, so per-variable scaling changes nothing and ``problem.scale`` is not
    used. Evaluations per iteration: the goats that moved (~0.775 N) plus floor(0.2 N) re-drawn ones.
    """

    name = "goa"
    family = "population"

    def __init__(
        self,
        *,
        population: int = 500,
        max_iter: int | None = None,
        alpha: float = 0.05,
        alpha_exploit: float = 0.5,
        explore_prob: float = 0.5,
        exploit_prob: float = 0.5,
        jump_prob: float = 0.1,
        jump_coef: float = 0.1,
        parasite_share: float = 0.2,
        callback: IterationCallback | None = None,
    ) -> None:
        self.population = population
        self.max_iter = max_iter
        self.alpha = alpha
        self.alpha_exploit = alpha_exploit
        self.explore_prob = explore_prob
        self.exploit_prob = exploit_prob
        self.jump_prob = jump_prob
        self.jump_coef = jump_coef
        self.parasite_share = parasite_share
        self.callback = callback

    _min_population = 2

    def validate_params(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid keyword argument."""
        owner = type(self).__name__
        check_int(self.population, "population", owner, minimum=self._min_population)
        if self.max_iter is not None:
            check_int(self.max_iter, "max_iter", owner, minimum=1)
        check_real(self.alpha, "alpha", owner, 0.0)
        check_real(self.alpha_exploit, "alpha_exploit", owner, 0.0, 1.0)
        check_real(self.explore_prob, "explore_prob", owner, 0.0, 1.0)
        check_real(self.exploit_prob, "exploit_prob", owner, 0.0, 1.0)
        check_real(self.jump_prob, "jump_prob", owner, 0.0, 1.0)
        check_real(self.jump_coef, "jump_coef", owner, 0.0, 1.0)
        check_real(self.parasite_share, "parasite_share", owner, 0.0, 1.0, high_open=True)
        check_callable(self.callback, "callback", owner)

    def _common(self, problem: Problem) -> dict:
        if not isinstance(problem, Problem):
            raise ConfigError(
                f"The 'problem' parameter of {type(self).__name__}.minimize must be a Problem. "
                f"Got {type(problem).__name__} instead."
            )
        self.validate_params()
        require_finite_bounds(problem, type(self).__name__)
        return {
            "population": int(self.population),
            "max_iter": int(self.max_iter if self.max_iter is not None else problem.max_iter),
            "alpha": float(self.alpha),
            "alpha_exploit": float(self.alpha_exploit),
            "explore_prob": float(self.explore_prob),
            "exploit_prob": float(self.exploit_prob),
            "jump_prob": float(self.jump_prob),
            "jump_coef": float(self.jump_coef),
            "parasite_share": float(self.parasite_share),
            "callback": self.callback,
            "method": self.name,
        }

    def minimize(self, problem: Problem) -> FitResult:
        """Minimise ``problem``'s fitness within its bounds; see the class docstring."""
        return goat_search(problem, **self._common(problem))


class ImprovedGOA(GOA):
    """Improved GOA of Guo et al. 2026 (section 2.2): Tent-map start and a DE step inside GOA.

    Parameters
    ----------
    population, max_iter, alpha, alpha_exploit, explore_prob, exploit_prob, jump_prob, jump_coef,
    parasite_share, callback
        As :class:`GOA` (population >= 3: the DE step needs two other goats).
    tent_mu : float, default 2.0
        Tent-map control parameter mu, in (0, 2] (eq. 14; the paper's value is 2).
    tent_b : float, default 0.5
        Tent-map breakpoint b, in (0, 1) (eq. 14; the paper's value is 0.5).
    tent_steps : int, default 10
        Length of the short Tent-map sequence of each individual (see :func:`tent_population`).
    de_share : float, default 0.5
        Share of the population that goes through the DE step each iteration (the paper: 50 %).
    de_f : float, default 0.5
        DE mutation factor F (eq. 15). The paper names it but gives no value: standard DE value.
    de_cr : float, default 0.9
        DE crossover probability CR (eq. 16). Not given by the paper either: standard DE value.

    Notes
    -----
    Order per iteration, steps (3)-(9) of section 2.2: exploration, clip, DE (mutation, crossover,
    selection), exploitation, jump, clip, evaluation, parasite avoidance, stop rule. Where the paper is
    ambiguous:

    * Step (9) says "if not finished, go back to step (5)", which would run exploration and DE only in the
      first iteration. The text just before ("the DE strategy is executed after GOA's exploration phase and
      before its exploitation phase") and the claimed early-convergence gain both describe DE as part of
      every iteration, so the loop goes back to step (3).
    * Step (4) lists "crossover, mutation, selection"; eq. 15-17 give the usual mutation, crossover,
      selection order, which is used (the other order does not define a trial vector).
    * Step (3) says "every individual explores", eq. 10 has no probability; GOA's reference code explores
      with probability 0.5. The improved GOA keeps GOA's probabilities so that the comparison with GOA
      isolates the two improvements; ``explore_prob=1.0`` gives the literal reading.
    * Which 50 % go through DE is not said: a fresh uniformly random half each iteration.
    * "Two different individuals" r1, r2: distinct from each other and from the target goat, drawn from
      the whole (post-exploration) population; ``gbest`` is the best-so-far before the DE evaluation.
    * The greedy selection (eq. 17) needs the fitness of the explored positions: the selected goats that
      explored are evaluated together with the trial vectors in one batch call. Trial vectors are clipped
      to the bounds.
    * Eq. 14 as printed does not stay in (0, 1) at mu = 2, b = 0.5: see :func:`tent_map`.
    * Evaluations per iteration: ~0.25 N (stale selected goats) + 0.5 N (trials), then the goats that
      moved afterwards, then floor(0.2 N) re-drawn goats: about 1.75 N against GOA's ~0.98 N. The paper's
      "25 % less time than GOA" must therefore come from fewer iterations to the stop threshold.
    """

    name = "igoa"
    _min_population = 3

    def __init__(
        self,
        *,
        population: int = 500,
        max_iter: int | None = None,
        alpha: float = 0.05,
        alpha_exploit: float = 0.5,
        explore_prob: float = 0.5,
        exploit_prob: float = 0.5,
        jump_prob: float = 0.1,
        jump_coef: float = 0.1,
        parasite_share: float = 0.2,
        tent_mu: float = 2.0,
        tent_b: float = 0.5,
        tent_steps: int = 10,
        de_share: float = 0.5,
        de_f: float = 0.5,
        de_cr: float = 0.9,
        callback: IterationCallback | None = None,
    ) -> None:
        super().__init__(
            population=population,
            max_iter=max_iter,
            alpha=alpha,
            alpha_exploit=alpha_exploit,
            explore_prob=explore_prob,
            exploit_prob=exploit_prob,
            jump_prob=jump_prob,
            jump_coef=jump_coef,
            parasite_share=parasite_share,
            callback=callback,
        )
        self.tent_mu = tent_mu
        self.tent_b = tent_b
        self.tent_steps = tent_steps
        self.de_share = de_share
        self.de_f = de_f
        self.de_cr = de_cr

    def validate_params(self) -> None:
        super().validate_params()
        owner = type(self).__name__
        check_real(self.tent_mu, "tent_mu", owner, 0.0, 2.0, low_open=True)
        check_real(self.tent_b, "tent_b", owner, 0.0, 1.0, low_open=True, high_open=True)
        # each step at mu = 2 drops one of 53 mantissa bits: at most 40 keeps >= 13 random bits
        check_int(self.tent_steps, "tent_steps", owner, minimum=0, maximum=40)
        check_real(self.de_share, "de_share", owner, 0.0, 1.0)
        check_real(self.de_f, "de_f", owner, 0.0, 2.0)
        check_real(self.de_cr, "de_cr", owner, 0.0, 1.0)

    def minimize(self, problem: Problem) -> FitResult:
        """Minimise ``problem``'s fitness within its bounds; see the class docstring."""
        common = self._common(problem)
        return goat_search(
            problem,
            **common,
            tent=(float(self.tent_mu), float(self.tent_b), int(self.tent_steps)),
            de=(float(self.de_share), float(self.de_f), float(self.de_cr)),
        )
