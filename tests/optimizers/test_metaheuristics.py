"""Contract of the population optimizers (GOA, improved GOA, WOA) and of the optimizer protocol.

One mixin, :class:`MetaheuristicContract`, is run against every metaheuristic (scipy's least_squares test
layout): the subclasses only say which registry name to build and which tolerances to expect.
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
import yaml

from robocal.errors import ConfigError
from robocal.optimizers import (
    GOA,
    STATUS_MESSAGES,
    WOA,
    FitResult,
    ImprovedGOA,
    IterationInfo,
    Optimizer,
    Problem,
    evaluate,
    evaluate_batch,
    make_optimizer,
    pipeline_options,
    register,
    registered,
    unregister,
)
from robocal.optimizers.goa import tent_map, tent_population
from robocal.optimizers.registry import PIPELINE_KEYS

CONF = Path(__file__).resolve().parents[2] / "conf" / "optimizer"

# Shifted sphere in 10-D: minimum 0 at C_SPHERE, inside the box [-5, 5]^10, away from the origin
# (WOA is known to be biased toward the origin, so an unshifted sphere would flatter it).
C_SPHERE = np.linspace(-2.0, 3.0, 10)

# L1 fit of a linear model, like the thermal paper's eq. 9 (sum |dP - J dEta|): noise-free, so the
# minimum is 0 at X_TRUE, which lies inside the box [-2, 2]^6.
_rng = np.random.default_rng(42)
A_L1 = _rng.standard_normal((30, 6))
X_TRUE = _rng.uniform(-1.0, 1.0, 6)
B_L1 = A_L1 @ X_TRUE

BUDGET = {"population": 100, "max_iter": 200}  # 20 100 evaluations (GOA ~20 k, improved GOA ~35 k)


def sphere_problem(seed: int = 0, **kw) -> Problem:
    args = {"n": 10, "lower": -5.0, "upper": 5.0, "batch_residuals": lambda X: X - C_SPHERE, "seed": seed}
    args.update(kw)
    return Problem(**args)


def l1_problem(seed: int = 0, **kw) -> Problem:
    args = {
        "n": 6,
        "lower": -2.0,
        "upper": 2.0,
        "batch_residuals": lambda X: X @ A_L1.T - B_L1,
        "objective": "l1",
        "seed": seed,
    }
    args.update(kw)
    return Problem(**args)


class CountingResiduals:
    """Wraps batch residuals: counts calls and points, asserts every evaluated point lies in the bounds."""

    def __init__(self, fun, lower, upper) -> None:
        self.fun = fun
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.calls = 0
        self.points = 0

    def __call__(self, X: np.ndarray) -> np.ndarray:
        assert X.ndim == 2
        assert np.all(X >= self.lower) and np.all(X <= self.upper), "evaluated a point outside the bounds"
        self.calls += 1
        self.points += X.shape[0]
        return self.fun(X)


class MetaheuristicContract:
    """Every population method must pass these. Subclasses set ``method`` and the tolerances."""

    method: ClassVar[str]
    cls: ClassVar[type]
    batch_calls_per_iter: ClassVar[int]  # batch calls per iteration (sub-steps needing fresh fitness)
    sphere_tol: ClassVar[float]  # median over 5 seeds of the final fitness
    l1_tol: ClassVar[float]  # median over 5 seeds of max |x - x_true|

    def make(self, **kw) -> Optimizer:
        cfg = {"name": self.method, **BUDGET}
        cfg.update(kw)
        return make_optimizer(cfg)

    # -- accuracy within a budget --------------------------------------------------------------------

    def test_shifted_sphere_reaches_tolerance(self):
        costs = [self.make().minimize(sphere_problem(seed)).cost for seed in range(5)]
        assert np.median(costs) < self.sphere_tol, costs

    def test_l1_linear_fit_recovers_x(self):
        errs = [np.abs(self.make().minimize(l1_problem(seed)).x - X_TRUE).max() for seed in range(5)]
        assert np.median(errs) < self.l1_tol, errs

    # -- bounds, determinism, bookkeeping ------------------------------------------------------------

    def test_respects_bounds_at_every_iteration(self):
        # optimum outside the box in two coordinates: the search presses against the bounds
        c = C_SPHERE.copy()
        c[0], c[1] = 7.0, -9.0
        lower, upper = np.full(10, -5.0), np.full(10, 5.0)
        lower[3] = upper[3] = 0.5  # a fixed variable (zero width) is allowed
        wrapped = CountingResiduals(lambda X: X - c, lower, upper)
        seen = []

        def watch(info: IterationInfo) -> None:
            assert np.all(info.population >= lower) and np.all(info.population <= upper)
            seen.append(info.nit)

        opt = self.make(population=40, max_iter=30, callback=watch)
        res = opt.minimize(Problem(n=10, lower=lower, upper=upper, batch_residuals=wrapped, seed=1))
        assert seen == list(range(1, 31))
        assert np.all(res.x >= lower) and np.all(res.x <= upper)
        assert res.x[3] == 0.5
        assert res.x[0] > 4.0 and res.x[1] < -4.0  # pushed toward the violated bounds

    def test_same_seed_same_result_different_seed_different(self):
        a = self.make(population=30, max_iter=20).minimize(sphere_problem(seed=7))
        b = self.make(population=30, max_iter=20).minimize(sphere_problem(seed=7))
        c = self.make(population=30, max_iter=20).minimize(sphere_problem(seed=8))
        np.testing.assert_array_equal(a.x, b.x)
        assert a.cost == b.cost and a.history == b.history and a.nfev == b.nfev
        assert not np.array_equal(a.x, c.x)

    def test_history_is_best_so_far(self):
        res = self.make(population=30, max_iter=50).minimize(l1_problem(3))
        h = np.asarray(res.history)
        assert len(h) == res.nit == 50
        assert np.all(np.diff(h) <= 0.0)
        assert h[-1] == res.cost
        assert h[0] <= res.extra["initial_cost"]

    def test_nfev_counts_every_evaluated_point(self):
        wrapped = CountingResiduals(lambda X: X - C_SPHERE, -5.0, 5.0)
        res = self.make(population=25, max_iter=15).minimize(sphere_problem(batch_residuals=wrapped))
        assert res.nfev == wrapped.points
        assert res.extra["nbatch"] == wrapped.calls
        # vectorised: one batch call for the start, then a fixed number per iteration, never one per point
        # (+1: the statistics of the result at the best point, a batch of one)
        assert wrapped.calls == 1 + self.batch_calls_per_iter * res.nit + 1

    def test_stops_early_at_target(self):
        target = 5.0  # reached within a few dozen iterations by every method (initial best ~35)
        res = self.make(population=40, max_iter=200).minimize(sphere_problem(2, target=target))
        assert res.status == 5 and res.success
        assert res.cost < target and res.nit < 200
        assert res.history[-1] < target
        assert all(h >= target for h in res.history[:-1])  # stopped at the first iteration below target

    def test_target_met_by_the_start(self):
        res = self.make(population=10, max_iter=50).minimize(sphere_problem(target=1e9))
        assert (res.status, res.nit, res.history, res.nfev) == (5, 0, (), 11)  # 10 + the statistics at x

    def test_result_fields_complete(self):
        res = self.make(population=20, max_iter=5).minimize(sphere_problem())
        assert isinstance(res, FitResult)
        assert res.x.shape == (10,) and res.x.dtype == float
        assert isinstance(res.cost, float) and res.cost == pytest.approx(evaluate(sphere_problem(), res.x))
        assert res.status == 6 and res.success is True  # no target: the budget is the stop rule
        assert res.message == STATUS_MESSAGES[res.status]
        assert res.nit == 5 and res.njev == 0 and res.nfev > 20
        assert res.wall_time_s > 0
        assert res.method == self.method == self.make().name
        assert res.covariance is None
        assert res.extra["population"] == 20 and res.extra["max_iter"] == 5
        unreachable = self.make(population=20, max_iter=5).minimize(sphere_problem(target=-1.0))
        assert unreachable.status == 0 and unreachable.success is False

    def test_max_iter_defaults_to_the_problem(self):
        res = self.make(population=10, max_iter=None).minimize(sphere_problem(max_iter=7))
        assert res.nit == 7

    def test_x0_seeds_the_population(self):
        res = self.make(population=10, max_iter=3).minimize(sphere_problem(x0=C_SPHERE))
        assert res.cost == 0.0
        np.testing.assert_array_equal(res.x, C_SPHERE)

    def test_nan_fitness_is_never_selected(self):
        def fun(X):
            R = X - C_SPHERE
            R[X[:, 0] < -1.0] = np.nan  # the model "cannot be evaluated" there, around the optimum (-2)
            return R

        res = self.make(population=30, max_iter=20).minimize(sphere_problem(batch_residuals=fun))
        assert np.isfinite(res.cost) and res.x[0] >= -1.0

    def test_is_an_optimizer(self):
        opt = self.make()
        assert isinstance(opt, Optimizer) and isinstance(opt, self.cls)
        assert opt.get_params()["population"] == BUDGET["population"]

    # -- bad input -----------------------------------------------------------------------------------

    def test_infinite_bounds_rejected(self):
        with pytest.raises(ConfigError, match="'upper' parameter of Problem must be finite"):
            self.make().minimize(sphere_problem(upper=np.inf))

    def test_bad_parameters_rejected(self):
        # one error format (robocal.config): the config's key when built from a config ...
        with pytest.raises(ConfigError, match=r"^optimizer\.population: must be an integer >= \d; got 1$"):
            self.make(population=1)
        with pytest.raises(ConfigError, match=r"^optimizer\.max_iter: must be an integer >= 1; got 0$"):
            self.make(max_iter=0)
        opt = self.cls(population=2.5)  # __init__ only stores; minimize validates
        # ... the class's own parameter when built in Python
        with pytest.raises(
            ConfigError, match=rf"^{self.cls.__name__}\.population: must be an integer >= \d; got 2\.5$"
        ):
            opt.minimize(sphere_problem())

    def test_bad_residual_shape_rejected(self):
        with pytest.raises(ConfigError, match="'batch_residuals'"):
            self.make(population=10, max_iter=2).minimize(sphere_problem(batch_residuals=lambda X: X[0]))


# Tolerances: medians over seeds 0-4 at 100 individuals x 200 iterations. When the tests were written,
# the worst such median over 8 groups of 5 seeds (40 runs) was: sphere 0.0042 (GOA), 0.0012 (improved
# GOA), 1.2 (WOA); L1 |x - x_true| 0.0089, 0.0044, 0.16. Each tolerance is 2-5x that worst value, so a
# correct implementation passes for any seed while a broken one (lost exploitation, wrong sign, no
# elitism) does not: uniform random search with the same 20 100 evaluations reaches only ~11 on the
# sphere and 0.41 on the L1 fit (medians; best of 40: 5.4 and 0.20). GOA cannot go much lower in this
# budget: its exploration step is a constant 5 % of the box width (0.5 here) and never shrinks, so it
# refines only by halving steps toward the leader. WOA encircles the best via C * X*, which scales about
# the origin; on shifted problems it stalls (1e-40 on the unshifted sphere, see TestWOA), hence its
# loose tolerances: the thermal paper also ranks it last.


class TestGOA(MetaheuristicContract):
    method = "goa"
    cls = GOA
    batch_calls_per_iter = 2  # moved goats, then re-drawn worst 20 %
    sphere_tol = 0.02
    l1_tol = 0.03


class TestImprovedGOA(MetaheuristicContract):
    method = "igoa"
    cls = ImprovedGOA
    batch_calls_per_iter = 3  # DE trials (+ stale selected goats), moved goats, re-drawn worst 20 %
    sphere_tol = 0.005
    l1_tol = 0.015

    def test_de_and_tent_parameters_validated(self):
        for key, bad in [("de_share", 1.5), ("de_cr", -0.1), ("tent_b", 1.0), ("tent_mu", 0.0), ("tent_steps", 60)]:
            with pytest.raises(ConfigError, match=rf"^optimizer\.{key}: must be"):
                self.make(**{key: bad})

    def test_needs_three_goats(self):
        with pytest.raises(ConfigError, match=r"^optimizer\.population: must be an integer >= 3; got 2$"):
            self.make(population=2)


class TestWOA(MetaheuristicContract):
    method = "woa"
    cls = WOA
    batch_calls_per_iter = 1  # every whale moves every iteration
    sphere_tol = 3.0
    l1_tol = 0.3

    def test_unshifted_sphere_to_machine_precision(self):
        # the contraction A -> 0 works: on a sphere centred at the origin WOA converges geometrically
        res = self.make(population=50).minimize(sphere_problem(batch_residuals=lambda X: X))
        assert res.cost < 1e-20

    def test_greedy_selection_converges_further(self):
        # on the shifted sphere (where the plain WOA stalls at ~1, see sphere_tol) greedy selection goes much
        # further: median over 5 seeds, a factor 10 at least (measured ~1e3)
        plain = [self.make(**BUDGET).minimize(sphere_problem(seed=k)).cost for k in range(5)]
        greedy = [self.make(greedy=True, **BUDGET).minimize(sphere_problem(seed=k)).cost for k in range(5)]
        assert np.median(greedy) < 0.1 * np.median(plain), (plain, greedy)

    def test_greedy_must_be_a_bool(self):
        with pytest.raises(ConfigError, match=r"^optimizer\.greedy: must be true or false; got 'yes'$"):
            self.make(greedy="yes").minimize(sphere_problem())


# ---------------------------------------------------------------------------------------------------------
# Tent map
# ---------------------------------------------------------------------------------------------------------


def test_tent_population_has_no_collapsed_rows():
    z = tent_population(np.random.default_rng(0), 1500, 40, mu=2.0, b=0.5, steps=10)
    assert z.shape == (1500, 40)
    assert np.all((z > 0.0) & (z < 1.0))
    assert not np.any(np.all(z == 0.0, axis=1))
    assert np.unique(z, axis=0).shape[0] == 1500  # no duplicate rows
    assert np.unique(z).size > 0.99 * z.size  # hardly any repeated value at all
    # uniform in distribution (the tent map at mu = 2 preserves the uniform measure)
    assert abs(z.mean() - 0.5) < 0.01 and abs(z.std() - np.sqrt(1 / 12)) < 0.01


def test_improved_goa_initial_population_spans_the_box():
    seen = {}

    def fun(X):
        seen.setdefault("first", X.copy())
        return X

    ImprovedGOA(population=1500, max_iter=1).minimize(Problem(n=40, lower=-3.0, upper=7.0, batch_residuals=fun))
    X0 = seen["first"]
    assert X0.shape == (1500, 40) and np.unique(X0, axis=0).shape[0] == 1500
    assert X0.min() > -3.0 and X0.max() < 7.0 and abs(X0.mean() - 2.0) < 0.1


def test_naive_long_tent_sequence_collapses_in_float64():
    # the pitfall the short per-individual sequences avoid: one sequence of 1500 steps at mu = 2 hits 0
    x = np.random.default_rng(0).random(40)
    rows = []
    for _ in range(1500):
        x = tent_map(x)
        rows.append(x)
    rows = np.array(rows)
    assert np.all(rows[100:] == 0.0)


def test_tent_map_at_paper_values_is_the_classic_tent_map():
    x = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(tent_map(x, 2.0, 0.5), 2.0 * np.minimum(x, 1.0 - x))
    assert np.all(tent_map(x, 1.6, 0.3) <= 0.8 + 1e-15)  # stays in [0, 1] for mu < 2 and skewed b


# ---------------------------------------------------------------------------------------------------------
# Problem and objectives
# ---------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("change", "name"),
    [
        ({"n": 0}, "'n'"),
        ({"n": 2.0}, "'n'"),
        ({"lower": np.zeros(3)}, "'lower' parameter of Problem must have shape \\(10,\\)"),
        ({"upper": np.zeros((10, 1))}, "'upper' parameter of Problem must have shape \\(10,\\)"),
        ({"lower": np.r_[np.zeros(9), 6.0]}, "'lower' parameter of Problem must be <= 'upper'.*lower\\[9\\]"),
        ({"lower": np.full(10, np.nan)}, "'lower' parameter of Problem must not contain NaN"),
        ({"x0": np.zeros(4)}, "'x0'"),
        ({"x0": np.full(10, 9.0)}, "'x0' parameter of Problem must lie within"),
        ({"scale": -np.ones(10)}, "'scale'"),
        ({"names": ("a", "b")}, "'names'"),
        ({"names": tuple("aaaaaaaaaa")}, "'names'"),
        ({"batch_residuals": None}, "'residuals'"),
        ({"batch_residuals": 3}, "'batch_residuals'"),
        ({"objective": "l2"}, "'objective'"),
        ({"target": float("nan")}, "'target'"),
        ({"max_iter": 0}, "'max_iter'"),
        ({"seed": -1}, "'seed'"),
        ({"seed": True}, "'seed'"),
    ],
)
def test_bad_problem_raises_config_error_naming_the_argument(change, name):
    # the Problem's own checks ('objective' ...) or the shared ones (Problem.max_iter: ...): the key is named
    with pytest.raises(ConfigError, match=rf"{name}|Problem\.{name.strip(chr(39))}: "):
        sphere_problem(**change)


def test_problem_is_frozen_and_normalised():
    p = sphere_problem()
    assert p.lower.shape == (10,) and not p.lower.flags.writeable
    assert p.names == tuple(f"x{i}" for i in range(10)) and np.all(p.scale == 1.0)
    with pytest.raises(AttributeError):
        p.n = 3  # type: ignore[misc]


def test_objectives():
    R = np.array([[3.0, 4.0, 0.0, 0.0, 0.0, 12.0], [1.0, -1.0, 1.0, -1.0, 1.0, -1.0]])
    X = np.zeros((2, 1))
    p = {"n": 1, "lower": -1, "upper": 1, "batch_residuals": lambda _: R}
    np.testing.assert_allclose(evaluate_batch(Problem(**p), X), [169.0, 6.0])
    np.testing.assert_allclose(evaluate_batch(Problem(**p, objective="l1"), X), [19.0, 6.0])
    # rms3d: points (3,4,0) and (0,0,12) -> sqrt((25 + 144) / 2)
    np.testing.assert_allclose(evaluate_batch(Problem(**p, objective="rms3d"), X), [np.sqrt(84.5), np.sqrt(3.0)])
    bad = Problem(n=1, lower=-1, upper=1, batch_residuals=lambda X: np.ones((X.shape[0], 4)), objective="rms3d")
    with pytest.raises(ConfigError, match=r"'objective'.*rms3d.*m=4"):
        evaluate_batch(bad, X)


def test_residuals_only_problem_falls_back_to_a_loop():
    single = Problem(n=6, lower=-2, upper=2, residuals=lambda x: A_L1 @ x - B_L1, objective="l1")
    X = np.random.default_rng(1).uniform(-2, 2, (7, 6))
    np.testing.assert_allclose(evaluate_batch(single, X), evaluate_batch(l1_problem(), X))
    res = GOA(population=20, max_iter=5).minimize(single)
    assert res.nfev > 0 and res.cost == pytest.approx(evaluate(single, res.x))


# ---------------------------------------------------------------------------------------------------------
# Registry and configs
# ---------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("stem", "cls"), [("goa", GOA), ("igoa", ImprovedGOA), ("woa", WOA)])
def test_config_files_build_their_optimizer_with_the_code_defaults(stem, cls):
    cfg = yaml.safe_load((CONF / f"{stem}.yaml").read_text())
    opt = make_optimizer(cfg)
    assert type(opt) is cls and opt.name == cfg["name"] == stem
    assert cfg["_target_"] == f"{cls.__module__}.{cls.__name__}"
    assert pipeline_options(cfg) == {
        "polish": False,
        "objective": "nonlinear",
        "bound_mm": 1.0,
        "bound_deg": 0.1,
        "stop_error": None,
    }
    # every coefficient is in the file, with the value the class uses by default
    defaults = {k: p.default for k, p in inspect.signature(cls.__init__).parameters.items() if k != "self"}
    coefficients = {k: v for k, v in cfg.items() if k not in PIPELINE_KEYS}
    assert set(coefficients) == set(defaults) - {"callback"}
    for key, value in coefficients.items():
        if key != "max_iter":  # None in code (take the problem's), 200 in the config
            assert value == defaults[key], key


def test_registry_by_target_and_errors():
    assert isinstance(make_optimizer({"_target_": "robocal.optimizers.woa.WOA"}), WOA)
    with pytest.raises(ConfigError, match=r"must be one of \['gn', 'goa', 'igoa', 'ipopt', 'lm', 'woa'\]"):
        make_optimizer({"name": "pso"})
    with pytest.raises(ConfigError, match="arbitrary classes are not instantiated"):
        make_optimizer({"_target_": "os.system"})
    with pytest.raises(ConfigError, match="must match its 'name'"):
        make_optimizer({"name": "goa", "_target_": "robocal.optimizers.woa.WOA"})
    with pytest.raises(ConfigError, match=r"^optimizer\.alpah: unknown setting; got 0\.1\. Did you mean 'alpha'\?"):
        make_optimizer({"name": "goa", "alpah": 0.1})
    with pytest.raises(ConfigError, match=r"^optimizer\.objective: must be one of"):
        pipeline_options({"name": "goa", "objective": "both"})


def test_register_more_optimizers():
    class Fixed:
        name = "fixed"

        def __init__(self, *, value: float = 0.0) -> None:
            self.value = value

        def minimize(self, problem: Problem) -> FitResult:
            x = np.full(problem.n, self.value)
            return FitResult(
                method=self.name,
                x=x,
                varied=np.arange(problem.n),
                cost=evaluate(problem, x),
                chi2=np.nan,
                ndata=0,
                covariance=None,
                status=6,
                nit=0,
                nfev=1,
            )

    register("fixed-test", Fixed, target="tests.Fixed")
    try:
        assert "fixed-test" in registered()
        opt = make_optimizer({"name": "fixed-test", "value": 1.0, "polish": True})
        assert opt.minimize(sphere_problem()).x[0] == 1.0
        assert isinstance(make_optimizer({"_target_": "tests.Fixed"}), Fixed)
        with pytest.raises(ConfigError, match="already registered"):
            register("fixed-test", Fixed)
    finally:
        unregister("fixed-test")
    assert "fixed-test" not in registered()


def test_omegaconf_config_is_accepted():
    omegaconf = pytest.importorskip("omegaconf")
    cfg = omegaconf.OmegaConf.load(CONF / "igoa.yaml")
    opt = make_optimizer(cfg)
    assert isinstance(opt, ImprovedGOA) and opt.de_share == 0.5
