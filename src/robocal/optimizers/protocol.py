"""One optimizer protocol for every identification method: a problem in, a result out.

Two layers, as in scipy ``least_squares`` and robotics-toolbox's IK solver family:

* :class:`Problem` says *what* is minimised: bounds, a start, per-variable scale and names, and the
  residuals, given one point at a time (``residuals``, optionally ``jacobian``) for gradient methods
  (Gauss-Newton / LM, Ipopt) and/or for a whole population at once (``batch_residuals``) for the
  population methods (GOA, improved GOA, WOA). ``objective`` turns residuals into one fitness number.
* An :class:`Optimizer` says *how*: its ``__init__`` only stores keyword arguments (scikit-learn style),
  ``minimize(problem)`` validates, runs and returns a :class:`FitResult` (the one immutable result of
  every fit, :mod:`robocal.identification.result`). Every random number comes
  from ``np.random.default_rng(problem.seed)``.

:class:`SearchTracker` is the bookkeeping shared by the population methods (counting evaluations, keeping
the best-so-far, the per-iteration history, the stop rule and the callback), so that every method stops
and reports the same way.
"""

from __future__ import annotations

import inspect
import math
import numbers
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from robocal.config import SettingError
from robocal.errors import ConfigError
from robocal.identification.result import STATUS_MESSAGES, FitResult, fit_covariance

__all__ = [
    "OBJECTIVES",
    "STATUS_MESSAGES",
    "EstimatorParams",
    "FitResult",
    "IterationCallback",
    "IterationInfo",
    "Optimizer",
    "Problem",
    "SearchTracker",
    "check_bool",
    "check_callable",
    "check_choice",
    "check_int",
    "check_real",
    "evaluate",
    "evaluate_batch",
    "fitness_from_residuals",
    "other_index",
    "require_finite_bounds",
    "residual_vector",
    "statistics_at",
]

#: Fitness of a residual vector r (m,): "sse" = sum r², "l1" = sum |r| (the thermal paper's eq. 9 when
#: r = dP - J dEta), "rms3d" = sqrt(mean over points of |r_i|²) with r read as consecutive xyz triples
#: (the RMS 3-D position error, in the residual's unit), "mean3d" = mean over points of |r_i| (the thermal
#: paper's eq. 9, sum over poses of |dP_l - J_l dEta|, divided by the number of poses so that it reads as a
#: mean 3-D error: same minimiser).
OBJECTIVES = ("sse", "l1", "rms3d", "mean3d")

#: Status code -> message (one table for every method: :data:`robocal.identification.result.STATUS_MESSAGES`).


# --------------------------------------------------------------------------------------------------------
# validation helpers (also meant for optimizer wrappers written elsewhere)
# --------------------------------------------------------------------------------------------------------


def _got(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _key(owner: str, name: str) -> str:
    """The dotted key of parameter ``name`` of ``owner`` (a class name, or a config section such as
    ``optimizer``) in the one error format of :mod:`robocal.config`."""
    return f"{owner}.{name}"


def check_int(value: Any, name: str, owner: str, minimum: int | None = None, maximum: int | None = None) -> int:
    """Return ``value`` as int or raise :class:`~robocal.config.SettingError` naming ``owner.name``."""
    ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if ok and (minimum is None or int(value) >= minimum) and (maximum is None or int(value) <= maximum):
        return int(value)
    bounds = [f">= {minimum}" if minimum is not None else "", f"<= {maximum}" if maximum is not None else ""]
    need = " and ".join(b for b in bounds if b)
    raise SettingError(_key(owner, name), f"must be an integer{' ' + need if need else ''}", value)


def check_choice(value: Any, name: str, owner: str, choices: Any) -> Any:
    """Return ``value`` if it is one of ``choices``, else raise :class:`~robocal.config.SettingError`."""
    if value in tuple(choices):
        return value
    raise SettingError(_key(owner, name), f"must be one of {', '.join(map(repr, choices))}", value)


def check_bool(value: Any, name: str, owner: str) -> bool:
    if isinstance(value, bool):
        return value
    raise SettingError(_key(owner, name), "must be true or false", value)


def check_callable(value: Any, name: str, owner: str) -> None:
    if value is not None and not callable(value):
        raise SettingError(_key(owner, name), "must be a callable or None", value)


def check_real(
    value: Any,
    name: str,
    owner: str,
    low: float = -math.inf,
    high: float = math.inf,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """Return ``value`` as a finite float in the interval, or raise :class:`~robocal.config.SettingError`
    naming ``owner.name``."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(float(value))
    if ok:
        v = float(value)
        ok = (v > low if low_open else v >= low) and (v < high if high_open else v <= high)
        if ok:
            return v
    if math.isinf(low) and math.isinf(high):
        need = "must be a finite number"
    elif math.isinf(high):
        need = f"must be {'>' if low_open else '>='} {low:g}"
    elif math.isinf(low):
        need = f"must be {'<' if high_open else '<='} {high:g}"
    else:
        need = f"must be in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    raise SettingError(_key(owner, name), need, value)


def _vector(value: Any, name: str, n: int, *, allow_inf: bool) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(
            f"The {name!r} parameter of Problem must be array_like of floats with shape ({n},). "
            f"Got {_got(value)} instead."
        ) from None
    if arr.ndim == 0:
        arr = np.full(n, float(arr))  # a scalar applies to every variable, as scipy's bounds
    if arr.shape != (n,):
        raise ConfigError(f"The {name!r} parameter of Problem must have shape ({n},). Got shape {arr.shape} instead.")
    bad = np.isnan(arr) if allow_inf else ~np.isfinite(arr)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        what = "NaN" if allow_inf else "finite"
        need = f"must not contain {what}" if allow_inf else f"must be {what}"
        raise ConfigError(f"The {name!r} parameter of Problem {need}. Got {name}[{i}]={arr[i]} instead.")
    arr.setflags(write=False)
    return arr


def _optional_callable(value: Any, name: str) -> None:
    if value is not None and not callable(value):
        raise ConfigError(f"The {name!r} parameter of Problem must be a callable or None. Got {_got(value)} instead.")


# --------------------------------------------------------------------------------------------------------
# the problem
# --------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False, kw_only=True)
class Problem:
    """A bounded minimisation problem given by its residuals.

    Parameters
    ----------
    n : int
        Number of variables.
    lower, upper : array_like, shape (n,) or scalar
        Bounds, ``lower <= upper`` elementwise; ``-inf`` / ``inf`` allowed (gradient methods), the
        population methods need finite bounds. Stored as read-only float arrays.
    x0 : array_like, shape (n,), optional
        Start (gradient methods) or one seeded individual of the initial population (population methods).
        Must lie within the bounds.
    scale : array_like, shape (n,), optional
        Typical magnitude of each variable (> 0); optimizers may work in ``x / scale``. Default ones.
    names : sequence of str, length n, optional
        Variable names (default ``x0 .. x{n-1}``), unique.
    residuals : callable ``f(x) -> r``, x shape (n,), r shape (m,), optional
    jacobian : callable ``J(x) -> (m, n)``, optional
        Analytic Jacobian of ``residuals`` (gradient methods).
    batch_residuals : callable ``F(X) -> R``, X shape (pop, n), R shape (pop, m), optional
        ``residuals`` vectorised over a population. At least one of ``residuals`` and
        ``batch_residuals`` is required; :func:`evaluate_batch` falls back to a loop over
        ``residuals`` when ``batch_residuals`` is missing.
    objective : {"sse", "l1", "rms3d"}
        Fitness of a residual vector, see :data:`OBJECTIVES`.
    target : float, optional
        Stop as soon as the best fitness is below it (strictly).
    max_iter : int
        Iteration budget (>= 1). An optimizer's own ``max_iter`` keyword, when set, overrides it.
    seed : int
        Seed (>= 0) of ``np.random.default_rng``: the only source of randomness.
    symbolic : object, optional
        A symbolic form of ``residuals`` for solvers that differentiate it themselves (CasADi + Ipopt):
        see :class:`robocal.optimizers.ipopt.SymbolicResiduals`.
    """

    n: int
    lower: np.ndarray
    upper: np.ndarray
    x0: np.ndarray | None = None
    scale: np.ndarray | None = None
    names: tuple[str, ...] = ()
    residuals: Callable[[np.ndarray], np.ndarray] | None = None
    jacobian: Callable[[np.ndarray], np.ndarray] | None = None
    batch_residuals: Callable[[np.ndarray], np.ndarray] | None = None
    objective: str = "sse"
    target: float | None = None
    max_iter: int = 200
    seed: int = 0
    symbolic: Any = None

    def __post_init__(self) -> None:
        put = object.__setattr__  # frozen: normalise once, here
        n = check_int(self.n, "n", "Problem", minimum=1)
        put(self, "n", n)
        lower = _vector(self.lower, "lower", n, allow_inf=True)
        upper = _vector(self.upper, "upper", n, allow_inf=True)
        if (lower > upper).any():
            i = int(np.flatnonzero(lower > upper)[0])
            raise ConfigError(
                "The 'lower' parameter of Problem must be <= 'upper' elementwise. "
                f"Got lower[{i}]={lower[i]} > upper[{i}]={upper[i]} instead."
            )
        put(self, "lower", lower)
        put(self, "upper", upper)
        if self.x0 is not None:
            x0 = _vector(self.x0, "x0", n, allow_inf=False)
            outside = (x0 < lower) | (x0 > upper)
            if outside.any():
                i = int(np.flatnonzero(outside)[0])
                raise ConfigError(
                    "The 'x0' parameter of Problem must lie within [lower, upper]. "
                    f"Got x0[{i}]={x0[i]} outside [{lower[i]}, {upper[i]}] instead."
                )
            put(self, "x0", x0)
        if self.scale is None:
            scale = np.ones(n)
            scale.setflags(write=False)
        else:
            scale = _vector(self.scale, "scale", n, allow_inf=False)
            if (scale <= 0).any():
                i = int(np.flatnonzero(scale <= 0)[0])
                raise ConfigError(f"The 'scale' parameter of Problem must be > 0. Got scale[{i}]={scale[i]} instead.")
        put(self, "scale", scale)
        if self.names is None or len(self.names) == 0:
            names = tuple(f"x{i}" for i in range(n))
        elif isinstance(self.names, str) or not all(isinstance(s, str) for s in self.names):
            raise ConfigError(
                f"The 'names' parameter of Problem must be a sequence of {n} str. Got {_got(self.names)} instead."
            )
        else:
            names = tuple(self.names)
            if len(names) != n or len(set(names)) != n:
                raise ConfigError(
                    f"The 'names' parameter of Problem must hold {n} unique names. "
                    f"Got {len(names)} names ({len(set(names))} unique) instead."
                )
        put(self, "names", names)
        _optional_callable(self.residuals, "residuals")
        _optional_callable(self.jacobian, "jacobian")
        _optional_callable(self.batch_residuals, "batch_residuals")
        if self.residuals is None and self.batch_residuals is None:
            raise ConfigError(
                "The 'residuals' parameter of Problem must be given when 'batch_residuals' is not. Got None instead."
            )
        if self.objective not in OBJECTIVES:
            raise ConfigError(
                f"The 'objective' parameter of Problem must be one of {list(OBJECTIVES)}. "
                f"Got {_got(self.objective)} instead."
            )
        if self.target is not None:
            put(self, "target", check_real(self.target, "target", "Problem"))
        put(self, "max_iter", check_int(self.max_iter, "max_iter", "Problem", minimum=1))
        put(self, "seed", check_int(self.seed, "seed", "Problem", minimum=0))

    @property
    def bounded(self) -> bool:
        """True when every bound is finite (required by the population methods)."""
        return bool(np.isfinite(self.lower).all() and np.isfinite(self.upper).all())


def require_finite_bounds(problem: Problem, method: str) -> None:
    """Raise :class:`ConfigError` unless every bound of ``problem`` is finite (population methods)."""
    for name, arr in (("lower", problem.lower), ("upper", problem.upper)):
        bad = ~np.isfinite(arr)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ConfigError(
                f"The {name!r} parameter of Problem must be finite for {method} (it samples the box). "
                f"Got {name}[{i}]={arr[i]} instead."
            )


def fitness_from_residuals(R: np.ndarray, objective: str) -> np.ndarray:
    """Fitness of each row of ``R`` (pop, m) -> (pop,), see :data:`OBJECTIVES`."""
    if objective == "sse":
        return np.einsum("ij,ij->i", R, R)
    if objective == "l1":
        return np.abs(R).sum(axis=1)
    if objective in ("rms3d", "mean3d"):
        m = R.shape[1]
        if m % 3:
            raise ConfigError(
                f"The 'objective' parameter of Problem is {objective!r}, which needs residuals in xyz triples "
                f"(m divisible by 3). Got m={m} instead."
            )
        if objective == "rms3d":
            return np.sqrt(np.einsum("ij,ij->i", R, R) / max(m // 3, 1))
        R3 = R.reshape(R.shape[0], -1, 3)
        return np.sqrt(np.einsum("ijk,ijk->ij", R3, R3)).mean(axis=1)
    raise ConfigError(f"The 'objective' parameter of Problem must be one of {list(OBJECTIVES)}. Got {objective!r}.")


def evaluate_batch(problem: Problem, X: np.ndarray) -> np.ndarray:
    """Fitness of a population ``X`` (pop, n) -> (pop,), from ``batch_residuals`` (or a loop over ``residuals``)."""
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or X.shape[1] != problem.n:
        raise ConfigError(f"The 'X' parameter of evaluate_batch must have shape (pop, {problem.n}). Got {X.shape}.")
    pop = X.shape[0]
    if problem.batch_residuals is not None:
        R = np.asarray(problem.batch_residuals(X), dtype=float)
        source = "batch_residuals"
    else:
        assert problem.residuals is not None  # guaranteed by Problem.__post_init__
        R = np.array([np.asarray(problem.residuals(x), dtype=float).ravel() for x in X]).reshape(pop, -1)
        source = "residuals"
    if R.ndim != 2 or R.shape[0] != pop:
        raise ConfigError(
            f"The {source!r} parameter of Problem must return an array of shape (pop, m) = ({pop}, m). "
            f"Got shape {R.shape} instead."
        )
    return fitness_from_residuals(R, problem.objective)


def residual_vector(problem: Problem, x: np.ndarray) -> np.ndarray:
    """Residuals (m,) at one point, from ``residuals`` or from ``batch_residuals`` on a population of one."""
    x = np.asarray(x, dtype=float)
    if problem.residuals is not None:
        return np.asarray(problem.residuals(x), dtype=float).ravel()
    assert problem.batch_residuals is not None
    return np.asarray(problem.batch_residuals(x[None, :]), dtype=float)[0]


def evaluate(problem: Problem, x: np.ndarray) -> float:
    """Fitness of one point."""
    return float(fitness_from_residuals(residual_vector(problem, x)[None, :], problem.objective)[0])


# --------------------------------------------------------------------------------------------------------
# the result and the protocol
# --------------------------------------------------------------------------------------------------------


def statistics_at(problem: Problem, x: np.ndarray) -> dict[str, Any]:
    """The fit statistics of ``problem`` at ``x`` for a :class:`FitResult`: residuals, χ² (sum of squared
    residuals, in the problem's units), ``ndata`` and, when the problem has a Jacobian, the covariance
    ``s² (JᵀJ)⁻¹`` (one evaluation, not counted in ``nfev``)."""
    r = residual_vector(problem, x)
    out: dict[str, Any] = {"residual": r, "chi2": float(r @ r), "ndata": int(r.size), "covariance": None}
    if problem.jacobian is not None and np.all(np.isfinite(r)):
        J = np.asarray(problem.jacobian(np.asarray(x, dtype=float)), dtype=float)
        if np.all(np.isfinite(J)):
            out["jacobian"] = J
            out["covariance"] = fit_covariance(r, J)
    return out


@runtime_checkable
class Optimizer(Protocol):
    """A minimiser of :class:`Problem` s.

    ``__init__`` only stores keyword arguments; ``minimize`` validates them and the problem, runs, and
    returns a :class:`FitResult`. Randomness only from ``np.random.default_rng(problem.seed)``.
    """

    name: str

    def minimize(self, problem: Problem) -> FitResult: ...


@dataclass(frozen=True)
class IterationInfo:
    """What a population method passes to its ``callback`` after each iteration.

    ``population`` (pop, n) and ``fitness`` (pop,) are read-only views of the optimizer's working arrays,
    valid during the call only (copy them to keep them); ``best_x`` is a copy.
    """

    nit: int
    nfev: int
    best_x: np.ndarray
    best_cost: float
    population: np.ndarray
    fitness: np.ndarray


IterationCallback = Callable[[IterationInfo], "bool | None"]


def _readonly(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.flags.writeable = False
    return v


class SearchTracker:
    """Shared bookkeeping of the population methods.

    Counts evaluated points (``nfev``) and batch calls, maps NaN fitness to ``inf`` (a point whose model
    cannot be evaluated is never selected), keeps the best-so-far, records ``history`` and decides when
    to stop: best < ``problem.target`` (status 5), callback asked to stop (7), budget used up (0 with a
    target, 6 without).
    """

    def __init__(self, problem: Problem, method: str, max_iter: int, callback: IterationCallback | None = None) -> None:
        self.problem = problem
        self.method = method
        self.max_iter = max_iter
        self.callback = callback
        self.t0 = time.perf_counter()
        self.nfev = 0
        self.nbatch = 0
        self.nit = 0
        self.best_x = np.asarray(problem.x0 if problem.x0 is not None else problem.lower, dtype=float).copy()
        self.best_cost = math.inf
        self.history: list[float] = []
        self.status: int | None = None
        self.initial_cost = math.inf

    def evaluate(self, X: np.ndarray) -> np.ndarray:
        """Fitness (pop,) of the rows of ``X``, one batch call (none for an empty ``X``), counted."""
        if X.shape[0] == 0:
            return np.empty(0)
        f = evaluate_batch(self.problem, _readonly(X))  # the population is not the callee's to change
        self.nfev += X.shape[0]
        self.nbatch += 1
        return np.where(np.isnan(f), np.inf, f)

    def offer(self, X: np.ndarray, f: np.ndarray) -> None:
        """Keep the best of the evaluated rows ``X`` with fitness ``f`` if it beats the best-so-far."""
        if f.size == 0:
            return
        i = int(np.argmin(f))
        if f[i] < self.best_cost:
            self.best_cost = float(f[i])
            self.best_x = X[i].copy()

    def start(self) -> bool:
        """Call after evaluating the initial population; True when the target is already met."""
        self.initial_cost = self.best_cost
        target = self.problem.target
        if target is not None and self.best_cost < target:
            self.status = 5
            return True
        return False

    def end_iteration(self, population: np.ndarray, fitness: np.ndarray) -> bool:
        """Record the iteration; True when the search must stop (``status`` is then set)."""
        self.nit += 1
        self.history.append(self.best_cost)
        target = self.problem.target
        if target is not None and self.best_cost < target:
            self.status = 5
        elif self.callback is not None and self.callback(
            IterationInfo(
                self.nit, self.nfev, self.best_x.copy(), self.best_cost, _readonly(population), _readonly(fitness)
            )
        ):
            self.status = 7
        elif self.nit >= self.max_iter:
            self.status = 0 if target is not None else 6
        return self.status is not None

    def result(self, extra: dict[str, Any] | None = None) -> FitResult:
        status = self.status if self.status is not None else 0
        if not math.isfinite(self.best_cost):
            status = -1
        stats: dict[str, Any] = {"chi2": math.nan, "ndata": 0}
        if status >= 0:  # the statistics at the best point: one more evaluated point, counted
            stats = statistics_at(self.problem, self.best_x)
            self.nfev += 1
            self.nbatch += self.problem.residuals is None  # a batch call of one
        info = {"nbatch": self.nbatch, "initial_cost": self.initial_cost, "max_iter": self.max_iter}
        info.update(extra or {})
        return FitResult(
            method=self.method,
            x=self.best_x,
            varied=np.arange(self.problem.n),
            cost=self.best_cost,
            status=status,
            nit=self.nit,
            nfev=self.nfev,
            njev=0,
            history=self.history,
            names=self.problem.names,
            timings={"total_s": time.perf_counter() - self.t0},
            extra=info,
            **stats,
        )


def other_index(rng: np.random.Generator, n_pop: int, me: np.ndarray) -> np.ndarray:
    """For each index in ``me`` a uniformly random index in [0, n_pop) different from it (population moves)."""
    r = rng.integers(0, n_pop - 1, size=me.shape)
    return r + (r >= me)


class EstimatorParams:
    """scikit-learn-style helpers for optimizers whose ``__init__`` only stores keyword arguments."""

    def get_params(self) -> dict[str, Any]:
        """The constructor's keyword arguments, as stored."""
        names = [p.name for p in inspect.signature(type(self).__init__).parameters.values() if p.name != "self"]
        return {k: getattr(self, k) for k in names}

    def __repr__(self) -> str:
        sig = inspect.signature(type(self).__init__).parameters
        given = [f"{k}={v!r}" for k, v in self.get_params().items() if sig[k].default is not v and sig[k].default != v]
        return f"{type(self).__name__}({', '.join(given)})"
