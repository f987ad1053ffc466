"""Gauss-Newton and Levenberg-Marquardt behind the optimizer protocol.

Thin wrappers of :func:`robocal.optimizers.solver.levenberg_marquardt`, and the solve step of every
gradient-family geometric fit (``robocal.calibrate``'s default: :func:`robocal.calibration.solve.solve_with`):
a :class:`~robocal.optimizers.protocol.Problem` with ``residuals`` and ``jacobian`` in, an
:class:`~robocal.optimizers.protocol.FitResult` out. Both minimise the sum of squared residuals
without bounds (a least-squares solver; ``problem.lower``/``upper`` are reported, not enforced:
``extra["inside_bounds"]``), starting from ``problem.x0``.

* ``gn``: Gauss-Newton, undamped steps with a backtracking line search (``method="gn"`` of the solver).
* ``lm``: Levenberg-Marquardt with adaptive damping from ``lam0`` (``method="lm"``; default 1e-3 here, where
  the start may be far; ``calibrate()`` passes 1e-6, :data:`robocal.calibration.solve.START_DAMPING`, from its
  converged rigid fit).

Both return the solver's :class:`~robocal.identification.result.FitResult` with the problem's fitness as
``cost`` and its history in the problem's objective.
"""

from __future__ import annotations

import math

import numpy as np

from robocal.errors import ConfigError
from robocal.optimizers.protocol import (
    EstimatorParams,
    FitResult,
    Problem,
    check_int,
    check_real,
    fitness_from_residuals,
)
from robocal.optimizers.solver import levenberg_marquardt

__all__ = ["GaussNewton", "LevenbergMarquardt", "check_problem", "history_in_objective"]


def check_problem(problem: object, owner: str) -> Problem:
    """Raise :class:`ConfigError` unless ``problem`` is a :class:`Problem`."""
    if not isinstance(problem, Problem):
        raise ConfigError(
            f"The 'problem' parameter of {owner}.minimize must be a Problem. Got {type(problem).__name__} instead."
        )
    return problem


def history_in_objective(costs: list[float], problem: Problem, m: int) -> tuple[list[float], str]:
    """Least-squares costs ``0.5 |r|²`` as the problem's fitness where that is a function of them."""
    if problem.objective == "sse":
        return [2.0 * c for c in costs], "sse"
    if problem.objective == "rms3d" and m % 3 == 0:
        return [math.sqrt(2.0 * c / max(m // 3, 1)) for c in costs], "rms3d"
    return [2.0 * c for c in costs], "sse"  # l1 / mean3d are not functions of the sum of squares


class GaussNewton(EstimatorParams):
    """Gauss-Newton (undamped steps with a backtracking line search) on ``problem.residuals`` /
    ``problem.jacobian``.

    Parameters
    ----------
    max_iter : int, optional
        Iteration budget; None takes ``problem.max_iter``.
    ftol : float, default 1e-12
        Stop when the relative cost reduction falls below it.
    xtol : float, default 1e-10
        Stop when the scaled step falls below it.
    """

    name = "gn"
    family = "gradient"
    _lam0_default = 0.0

    def __init__(self, *, max_iter: int | None = None, ftol: float = 1e-12, xtol: float = 1e-10) -> None:
        self.max_iter = max_iter
        self.ftol = ftol
        self.xtol = xtol

    def _lam0(self) -> float:
        return self._lam0_default

    def validate_params(self) -> None:
        owner = type(self).__name__
        if self.max_iter is not None:
            check_int(self.max_iter, "max_iter", owner, minimum=0)
        check_real(self.ftol, "ftol", owner, 0.0)
        check_real(self.xtol, "xtol", owner, 0.0)

    def minimize(self, problem: Problem) -> FitResult:
        """Least squares from ``problem.x0`` (required) with the analytic Jacobian (required)."""
        owner = type(self).__name__
        problem = check_problem(problem, owner)
        self.validate_params()
        if problem.residuals is None or problem.jacobian is None:
            raise ConfigError(
                f"{owner} needs a Problem with 'residuals' and 'jacobian'. Got residuals="
                f"{problem.residuals!r}, jacobian={problem.jacobian!r} instead."
            )
        if problem.x0 is None:
            raise ConfigError(f"The 'x0' parameter of Problem is required by {owner}. Got None instead.")
        res_fun, jac_fun = problem.residuals, problem.jacobian

        def fun(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            J = jac_fun(x)
            # a Jacobian held by its factors (robocal.discovery.gram.FactoredJacobian) goes to the solver as it is
            return np.asarray(res_fun(x), dtype=float).ravel(), (J if hasattr(J, "normal_equations") else
                                                                 np.asarray(J, dtype=float))  # fmt: skip

        max_iter = int(self.max_iter if self.max_iter is not None else problem.max_iter)
        lm = levenberg_marquardt(
            fun,
            problem.x0,
            np.arange(problem.n),
            1.0,
            max_iter=max_iter,
            ftol=float(self.ftol),
            xtol=float(self.xtol),
            lam0=self._lam0(),
            method=self.name,
            jac_free=True,  # the problem's Jacobian is over its own variables, whitened: the solver's, no copy
        )
        m = lm.residual.size
        cost = float(fitness_from_residuals(lm.residual[None, :], problem.objective)[0])
        history, kind = history_in_objective(list(lm.history[1:]), problem, m)
        inside = bool(np.all(lm.x >= problem.lower) and np.all(lm.x <= problem.upper))
        return lm.evolve(
            cost=cost,
            history=history,
            names=problem.names,
            extra={
                "least_squares_cost": 0.5 * lm.chi2,
                "history_kind": kind,
                "inside_bounds": inside,
                "lam0": self._lam0(),
                **{k: v for k, v in lm.extra.items() if k == "jacobian_factored"},
            },
        )


class LevenbergMarquardt(GaussNewton):
    """Levenberg-Marquardt: :class:`GaussNewton` with a configurable initial damping ``lam0``.

    Parameters
    ----------
    max_iter, ftol, xtol
        As :class:`GaussNewton`.
    lam0 : float, default 1e-3
        Initial damping (Marquardt scaling), adapted tenfold per step, as ``calibrate()`` does.
    """

    name = "lm"

    def __init__(
        self, *, max_iter: int | None = None, ftol: float = 1e-12, xtol: float = 1e-10, lam0: float = 1e-3
    ) -> None:
        super().__init__(max_iter=max_iter, ftol=ftol, xtol=xtol)
        self.lam0 = lam0

    def _lam0(self) -> float:
        return float(self.lam0)

    def validate_params(self) -> None:
        super().validate_params()
        check_real(self.lam0, "lam0", type(self).__name__, 0.0)
