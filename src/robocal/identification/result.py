"""The one result of a fit: what every optimizer and the least-squares core return.

:class:`FitResult` is immutable (a frozen dataclass whose arrays are read-only): the point found, its
covariance and standard errors, the goodness of fit (χ², reduced χ², AIC, BIC, as lmfit reports them),
the stopping status, the rows left out as gross errors and the timings. Gauss-Newton / Levenberg-Marquardt
(:func:`robocal.optimizers.solver.levenberg_marquardt`, and through it ``calibrate``, the compliance
and discovery fits), Ipopt and the population methods (GOA, improved GOA, WOA) all return one.

Conventions
-----------
* Residuals are *whitened* (divided by their standard deviation): ``chi2 = Σ r²`` over the rows that took
  part in the fit (rows left out weigh zero and are not counted in ``ndata``).
* ``covariance`` is over the varied parameters (``varied``), in the parameters' units:
  ``s² (JᵀJ)⁻¹`` with ``s²`` the reduced χ² (the residual variance the data show), or 1 (the stated
  noise) when no degree of freedom is left — the scaling lmfit applies by default (``scale_covar``).
* ``aic = N ln(χ²/N) + 2k`` and ``bic = N ln(χ²/N) + k ln N`` with N = ``ndata``, k = ``nvarys``
  (lmfit's definitions, for comparing models fitted to the same data).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from robocal.numerics import normal_equations

__all__ = ["STATUS_MESSAGES", "FitResult", "fit_covariance", "normal_inverse"]

#: Status code -> message, shared by every method (scipy ``least_squares``' codes 1-3, then the others').
#: ``success`` is ``status > 0``.
STATUS_MESSAGES = {
    -1: "the residual, Jacobian or fitness was not finite",
    0: "the maximum number of iterations was reached",
    1: "the relative cost reduction fell below ftol",
    2: "the scaled step fell below xtol",
    3: "no damped (lm) or shortened (gn) step reduced the cost (at a minimum to working precision)",
    4: "the solver reported convergence (see extra['solver_status'])",
    5: "the best fitness fell below the target",
    6: "the iteration budget (max_iter) was used up; no target was set",
    7: "stopped by the callback",
}


def normal_inverse(J: np.ndarray) -> np.ndarray:
    """``(JᵀJ)⁻¹`` of a (whitened) Jacobian, the pseudo-inverse when it is singular: the covariance of the
    parameters up to the residual variance ``s²`` (every fit's standard errors come from here)."""
    return normal_matrix_inverse(normal_equations(J)[0])


def normal_matrix_inverse(N: np.ndarray) -> np.ndarray:
    """``N⁻¹`` of a normal matrix (``JᵀJ``, ``XᵀC⁻¹X``), the pseudo-inverse when it is singular: the one
    covariance fallback of the library (:func:`normal_inverse` when the Jacobian itself is at hand)."""
    try:
        return np.linalg.inv(N)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(N)


def fit_covariance(r: np.ndarray, J: np.ndarray, ndata: int | None = None) -> np.ndarray:
    """``s² (JᵀJ)⁻¹`` from whitened residuals ``r`` (M,) and Jacobian ``J`` (M, k) on the varied parameters;
    ``s² = Σr² / (N - k)`` (N = ``ndata``, default M; rows left out carry r = 0 and J = 0), 1 when N <= k."""
    n = int(r.size if ndata is None else ndata)
    k = J.shape[1]
    s2 = float(r @ r) / (n - k) if n > k else 1.0
    return s2 * normal_inverse(J)


def _frozen(a: Any, dtype: Any = float) -> np.ndarray | None:
    if a is None:
        return None
    if isinstance(a, np.ndarray) and a.base is None and not a.flags.writeable and a.dtype == np.dtype(dtype):
        return a  # read-only and owning its data: nobody can change it, so no copy (a large Jacobian)
    v = np.array(a, dtype=dtype)  # a copy: the caller's array stays theirs
    v.setflags(write=False)
    return v


#: How the constructor (and :meth:`FitResult.evolve`) normalises each field: arrays copied and read-only,
#: numbers as float, sequences as tuples, mappings as read-only views of a copy.
_NORMAL: dict[str, Callable[[Any], Any]] = {
    "x": _frozen,
    "varied": lambda a: _frozen(a, int),
    "covariance": _frozen,
    "residual": _frozen,
    "jacobian": _frozen,  # (never None: see the field's default)
    "cost": float,
    "chi2": float,
    "history": lambda h: tuple(float(v) for v in h),
    "names": tuple,
    "outliers": lambda o: tuple(int(i) for i in o),
    "timings": lambda t: MappingProxyType({k: float(v) for k, v in t.items()}),
    "extra": lambda e: MappingProxyType(dict(e)),
}


@dataclass(frozen=True, kw_only=True, eq=False)
class FitResult:
    """An immutable fit (see the module docstring for the conventions).

    Attributes
    ----------
    method : str
        The optimizer's name (``"lm"``, ``"gn"``, ``"ipopt"``, ``"goa"``, ``"igoa"``, ``"woa"``).
    x : ndarray, shape (n,)
        The point found (every variable; fixed ones as given).
    varied : ndarray of int, shape (k,)
        Indices of the variables that were fitted.
    cost : float
        The method's objective at ``x`` (``0.5 χ²`` for least squares; the problem's fitness, e.g. the RMS 3-D
        error in mm, for the optimizer protocol).
    chi2 : float
        Sum of squared whitened residuals at ``x`` over the fitted rows (NaN when unknown).
    ndata : int
        Number of residuals that took part in the fit.
    covariance : ndarray, shape (k, k) or None
        Over ``varied``; None when the method has no Jacobian to give one.
    status, message : int, str
        Stopping reason (:data:`STATUS_MESSAGES`); ``success`` is ``status > 0``.
    nit, nfev, njev : int
        Iterations, residual evaluations (points), Jacobian evaluations.
    history : tuple of float
        The objective after each iteration (for least squares the first entry is the start's).
    names : tuple of str
        Variable names when known.
    residual, jacobian : ndarray
        Whitened residuals (M,) of every row at ``x`` and the whitened Jacobian (M, k) on ``varied``; rows
        left out are included (as predictions), ``outliers`` says which. Empty when unknown (a fit that
        ended on a non-finite point; a problem without a Jacobian has ``jacobian`` empty).
    outliers : tuple of int
        Rows (0-based, of the caller's row numbering) left out of the fit as gross errors.
    timings : mapping str -> float
        Seconds, by phase (``"total_s"`` always).
    extra : mapping
        Method-specific details (population size, Ipopt's status, the initial cost, ...).
    """

    method: str
    x: np.ndarray
    varied: np.ndarray
    cost: float
    chi2: float
    ndata: int
    covariance: np.ndarray | None
    status: int
    nit: int
    nfev: int
    njev: int = 0
    history: Sequence[float] = ()  # stored as a tuple
    names: tuple[str, ...] = ()
    residual: np.ndarray = field(default_factory=lambda: np.empty(0))
    jacobian: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    outliers: tuple[int, ...] = ()
    timings: Mapping[str, float] = field(default_factory=dict)
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        put = object.__setattr__  # frozen: normalise once, here
        for name, normal in _NORMAL.items():
            put(self, name, normal(getattr(self, name)))
        self._check_status()

    def _check_status(self) -> None:
        if self.status not in STATUS_MESSAGES:
            raise ValueError(f"FitResult: unknown status {self.status!r}; known: {sorted(STATUS_MESSAGES)}")

    # ---- the stopping status --------------------------------------------------------------------------
    @property
    def success(self) -> bool:
        return self.status > 0

    @property
    def message(self) -> str:
        return STATUS_MESSAGES[self.status]

    @property
    def wall_time_s(self) -> float:
        return float(self.timings.get("total_s", math.nan))

    # ---- goodness of fit ------------------------------------------------------------------------------
    @property
    def nvarys(self) -> int:
        return int(self.varied.size)

    @property
    def dof(self) -> int:
        """Residual degrees of freedom ``ndata - nvarys`` (>= 0)."""
        return max(self.ndata - self.nvarys, 0)

    @property
    def redchi(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    def _log_likelihood_term(self) -> float:
        n = max(self.ndata, 1)
        return n * math.log(max(self.chi2, 1e-300) / n)

    @property
    def aic(self) -> float:
        return self._log_likelihood_term() + 2.0 * self.nvarys

    @property
    def bic(self) -> float:
        return self._log_likelihood_term() + math.log(max(self.ndata, 1)) * self.nvarys

    # ---- uncertainties --------------------------------------------------------------------------------
    @property
    def stderr(self) -> np.ndarray:
        """Standard error of every variable (n,), NaN where not varied or without a covariance."""
        s = np.full(self.x.size, np.nan)
        if self.covariance is not None:
            s[self.varied] = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        s.setflags(write=False)
        return s

    @property
    def correlation(self) -> np.ndarray | None:
        """Correlation matrix (k, k) of the varied parameters."""
        if self.covariance is None:
            return None
        d = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        d[d == 0] = 1.0
        c = self.covariance / np.outer(d, d)
        c.setflags(write=False)
        return c

    # ---- derived results ------------------------------------------------------------------------------
    def evolve(self, **changes: Any) -> FitResult:
        """A copy with ``changes`` (the result itself never changes): the changed fields normalised as by the
        constructor, the others shared (they are read-only already: no array is copied twice)."""
        unknown = sorted(set(changes) - set(self.__dataclass_fields__))
        if unknown:
            raise TypeError(f"FitResult.evolve: unknown field(s) {unknown}")
        new = object.__new__(type(self))  # a shallow copy (copy.copy's reduce protocol costs more than the fit)
        new.__dict__.update(self.__dict__)
        for name, value in changes.items():
            normal = _NORMAL.get(name)
            object.__setattr__(new, name, value if normal is None else normal(value))
        new._check_status()
        return new

    def summary(self) -> dict[str, Any]:
        """The scalar figures as plain JSON types (no arrays)."""

        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        return {
            "method": self.method,
            "success": self.success,
            "status": self.status,
            "message": self.message,
            "cost": num(self.cost),
            "chi2": num(self.chi2),
            "redchi": num(self.redchi),
            "aic": num(self.aic),
            "bic": num(self.bic),
            "ndata": self.ndata,
            "nvarys": self.nvarys,
            "nit": self.nit,
            "nfev": self.nfev,
            "njev": self.njev,
            "n_outliers": len(self.outliers),
        }
