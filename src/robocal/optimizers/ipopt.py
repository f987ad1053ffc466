"""CasADi + Ipopt on a nonlinear least-squares :class:`~robocal.optimizers.protocol.Problem`.

The problem must carry a symbolic form of its residuals (``problem.symbolic``, a
:class:`SymbolicResiduals`): a CasADi ``Function r(z, p)`` of the variables ``z`` and of a parameter vector
``p`` that holds the data. Ipopt then gets exact first and second derivatives from CasADi's automatic
differentiation. Minimised: ``0.5 |r(z)|²`` in scaled variables ``w = (z - x0) / scale``
(``problem.x0``, ``problem.scale``), within ``problem.lower``/``upper`` (infinite bounds allowed).

The data enter as parameters and the start and scale as parameters too, so the built ``nlpsol`` depends
only on ``symbolic.key`` (for the calibration: robot chain, number of targets, number of poses, free set)
and on the solver options: it is built once per process and reused by every later solve with the same key
(:func:`cache_info` counts builds and hits).
"""

from __future__ import annotations

import time
from collections.abc import Hashable
from typing import Any, Protocol, runtime_checkable

import numpy as np

from robocal.errors import ConfigError
from robocal.optimizers.gradient import check_problem, history_in_objective
from robocal.optimizers.protocol import (
    EstimatorParams,
    FitResult,
    Problem,
    check_choice,
    check_int,
    check_real,
    fitness_from_residuals,
    statistics_at,
)

__all__ = ["Ipopt", "SymbolicResiduals", "cache_info"]

HESSIANS = ("exact", "limited-memory")


@runtime_checkable
class SymbolicResiduals(Protocol):
    """What :class:`Ipopt` needs from ``problem.symbolic``.

    ``key``: hashable identity of the symbolic graph (same key -> same ``function()``, sizes included);
    ``function()``: a CasADi Function ``r(z (n,), p (n_p,)) -> (M,)``; ``parameters()``: the values of ``p``.
    """

    key: Hashable

    def function(self) -> Any: ...

    def parameters(self) -> np.ndarray: ...


_SOLVERS: dict[Hashable, Any] = {}
_STATS = {"builds": 0, "hits": 0}


def cache_info() -> dict[str, int]:
    """Number of ``nlpsol`` builds and cache hits in this process, and the cache size."""
    return {**_STATS, "size": len(_SOLVERS)}


def _solver(symbolic: SymbolicResiduals, n: int, opts: dict[str, Any]) -> Any:
    import casadi as ca

    key = (symbolic.key, n, tuple(sorted(opts.items())))
    if key in _SOLVERS:
        _STATS["hits"] += 1
        return _SOLVERS[key]
    f = symbolic.function()
    n_p = f.size1_in(1)
    w = ca.MX.sym("w", n)
    P = ca.MX.sym("P", n_p + 2 * n)
    z = P[n_p : n_p + n] + P[n_p + n :] * w
    r = f(z, P[:n_p])
    nlp = {"x": w, "p": P, "f": 0.5 * ca.sumsqr(r)}
    solver = ca.nlpsol("robocal_ipopt", "ipopt", nlp, {"print_time": False, "expand": True, **opts})
    _SOLVERS[key] = solver
    _STATS["builds"] += 1
    return solver


class Ipopt(EstimatorParams):
    """Interior-point least squares with exact derivatives (CasADi + Ipopt).

    Parameters
    ----------
    max_iter : int, optional
        Ipopt iteration budget; None takes ``problem.max_iter``.
    tol : float, default 1e-12
        Ipopt's convergence tolerance (scaled NLP error).
    hessian : {"exact", "limited-memory"}, default "exact"
        Exact Hessian of ``0.5 |r|²`` from CasADi, or L-BFGS.
    print_level : int, default 0
        Ipopt's verbosity (0-12).
    """

    name = "ipopt"
    family = "nlp"

    def __init__(
        self, *, max_iter: int | None = None, tol: float = 1e-12, hessian: str = "exact", print_level: int = 0
    ) -> None:
        self.max_iter = max_iter
        self.tol = tol
        self.hessian = hessian
        self.print_level = print_level

    def validate_params(self) -> None:
        owner = type(self).__name__
        if self.max_iter is not None:
            check_int(self.max_iter, "max_iter", owner, minimum=0)
        check_real(self.tol, "tol", owner, 0.0, low_open=True)
        check_choice(self.hessian, "hessian", owner, HESSIANS)
        check_int(self.print_level, "print_level", owner, minimum=0)

    def minimize(self, problem: Problem) -> FitResult:
        problem = check_problem(problem, "Ipopt")
        self.validate_params()
        sym = problem.symbolic
        if sym is None or not isinstance(sym, SymbolicResiduals):
            raise ConfigError(
                "Ipopt needs a Problem with a symbolic form of its residuals ('symbolic', see "
                f"robocal.optimizers.ipopt.SymbolicResiduals). Got symbolic={sym!r} instead. A calibration with "
                "several tracker stations has none yet: use optimizer=lm or gn."
            )
        if problem.objective not in ("sse", "rms3d"):
            raise ConfigError(
                "Ipopt minimises the sum of squared residuals: the 'objective' of the Problem must be 'sse' or "
                f"'rms3d' (same minimiser). Got {problem.objective!r} instead."
            )
        t0 = time.perf_counter()
        n = problem.n
        max_iter = int(self.max_iter if self.max_iter is not None else problem.max_iter)
        opts = {
            "ipopt.tol": float(self.tol),
            "ipopt.print_level": int(self.print_level),
            "ipopt.sb": "yes",
            "ipopt.hessian_approximation": str(self.hessian),
            "ipopt.max_iter": max_iter,
        }
        solver = _solver(sym, n, opts)
        x0 = np.zeros(n) if problem.x0 is None else np.asarray(problem.x0, dtype=float)
        x0 = np.where(np.isfinite(x0), x0, 0.0)
        s = np.asarray(problem.scale, dtype=float)
        p = np.concatenate([np.asarray(sym.parameters(), dtype=float).ravel(), x0, s])
        lbw = (problem.lower - x0) / s
        ubw = (problem.upper - x0) / s
        sol = solver(x0=np.zeros(n), p=p, lbx=lbw, ubx=ubw)
        stats = solver.stats()
        x = x0 + s * np.asarray(sol["x"], dtype=float).ravel()
        r = np.asarray(sym.function()(x, sym.parameters()), dtype=float).ravel()
        cost = float(fitness_from_residuals(r[None, :], problem.objective)[0])
        objs = [float(v) for v in stats.get("iterations", {}).get("obj", [])][1:]
        history, kind = history_in_objective(objs, problem, r.size)
        ok = bool(stats.get("success", False))
        status = 4 if ok else (0 if stats.get("return_status") == "Maximum_Iterations_Exceeded" else -1)
        if not np.isfinite(cost):
            status = -1
        stats_at = statistics_at(problem, x) if status >= 0 else {"chi2": float(r @ r), "ndata": int(r.size)}
        return FitResult(
            method=self.name,
            x=x,
            varied=np.arange(n),
            cost=cost,
            status=status,
            nit=int(stats.get("iter_count", len(history))),
            nfev=int(stats.get("n_call_nlp_f", 0)),
            njev=int(stats.get("n_call_nlp_grad_f", 0)),
            history=history,
            names=problem.names,
            timings={"total_s": time.perf_counter() - t0, "ipopt_s": float(stats.get("t_wall_total", np.nan))},
            extra={
                "solver_status": stats.get("return_status"),
                "history_kind": kind,
                "least_squares_cost": 0.5 * float(r @ r),
                "cache": cache_info(),
            },
            **stats_at,
        )
