"""Weighted nonlinear least squares over a subset of variables, through the one optimizer protocol.

:func:`least_squares` is what every fit outside the geometric calibration's own solve step calls (the rigid fit and
the Cauchy IRLS of a calibration's start and screening, the compliance fit and its decoupling, discovery's joint
refit, the twin's truth fit): ``fun(x) -> (r, J)`` over the full vector ``x``, the variables ``free`` fitted, the
residuals weighted by ``weights``. It states the problem as a :class:`~robocal.optimizers.protocol.Problem` over
the free variables (whitened residuals and Jacobian, evaluated together once per point) and hands it to the
registered gradient optimizer ``method`` (:func:`~robocal.optimizers.registry.make_optimizer`: one place owns the
solver), then maps the result back to the full vector as a least-squares :class:`FitResult` (``cost`` the half sum
of squared whitened residuals, rows weighted zero not counted as data).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from robocal.identification.result import FitResult, fit_covariance
from robocal.optimizers.protocol import Problem
from robocal.optimizers.registry import make_optimizer

__all__ = ["Whitened", "least_squares"]

#: Levenberg-Marquardt's initial damping when none is given (Madsen, Nielsen & Tingleff: a start believed close)
DAMPING = 1e-6


class Whitened:
    """``w r(x)`` and ``w J(x)[:, free]`` at the free variables ``z`` (the others held at ``x0``), for a Problem's
    ``residuals`` and ``jacobian``: the model gives both in one evaluation, the protocol asks for them one at a
    time, so the last point's pair is kept (a gradient step costs one model evaluation). :meth:`evaluate` is the
    pair at a point (a subclass adds rows: the calibration's prior, :class:`robocal.calibration.problem.
    WhitenedResiduals`)."""

    def __init__(
        self,
        fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
        x0: np.ndarray,
        free: np.ndarray,
        weights: np.ndarray | float,
        jac_free: bool = False,
    ) -> None:
        self.fun = fun
        self.jac_free = bool(jac_free)  # fun's Jacobian holds only the free columns, in their order
        self.x0 = np.array(x0, dtype=float)
        self.free = np.asarray(free, dtype=int)
        self.weights = np.asarray(weights, dtype=float)
        # unit weights and every column free: no product and no column copy (the same numbers: 1.0 * v is v)
        self.unit = self.weights.ndim == 0 and float(self.weights) == 1.0
        self.every = bool(self.free.size) and np.array_equal(self.free, np.arange(self.free.size))
        self._key: bytes | None = None  # the bytes of the last point (cheaper to compare than np.array_equal)
        self._pair: tuple[np.ndarray, np.ndarray] = (np.empty(0), np.empty((0, 0)))

    def full(self, z: np.ndarray) -> np.ndarray:
        """The full vector with the free entries ``z``."""
        x = self.x0.copy()
        x[self.free] = z
        return x

    def evaluate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The whitened residuals and Jacobian (free columns) at ``z``, evaluated."""
        r, J = self.fun(self.full(z))
        w = self.weights
        Jc = J if self.jac_free or (self.every and J.shape[1] == self.free.size) else J[:, self.free]
        if self.unit:
            return r, Jc
        return w * r, (w[:, None] if w.ndim else w) * Jc

    def _at(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = np.ascontiguousarray(z, dtype=float).tobytes()
        if key != self._key:
            # the last point's pair let go first: its Jacobian is not held while the next is built
            self._key, self._pair = None, (np.empty(0), np.empty((0, 0)))
            self._pair = self.evaluate(z)
            self._key = key
        return self._pair

    def residuals(self, z: np.ndarray) -> np.ndarray:
        return self._at(z)[0]

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        return self._at(z)[1]


def least_squares(
    fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x0: np.ndarray,
    free: np.ndarray,
    weights: np.ndarray | float = 1.0,
    *,
    method: str = "lm",
    max_iter: int = 100,
    ftol: float = 1e-12,
    xtol: float = 1e-10,
    lam0: float | None = None,
    jac_free: bool = False,
) -> FitResult:
    """Minimise ``0.5 |w r(x)|²`` over ``x[free]`` from ``x0`` with the registered gradient optimizer ``method``
    (``"lm"``: Levenberg-Marquardt from the damping ``lam0``, default :data:`DAMPING`; ``"gn"``: Gauss-Newton).
    ``jac_free``: ``fun``'s Jacobian holds only the free columns, in the order of ``free`` (a large model need not
    build the fixed variables' columns; with unit weights no copy of it is made on the way to the solver).

    Returns a :class:`FitResult` over the full vector (``x`` of length ``len(x0)``, ``varied`` = ``free``): the
    whitened residuals and Jacobian (free columns) at the end, ``cost`` = ``0.5 χ²``, ``history`` the costs of the
    accepted points, ``ndata`` the residuals weighted non-zero and the covariance over them.
    """
    x_start = np.array(x0, dtype=float)
    free = np.asarray(free, dtype=int)
    w = np.asarray(weights, dtype=float)
    wr = Whitened(fun, x_start, free, w, jac_free)
    z0 = x_start[free]
    problem = Problem(
        n=int(free.size),
        lower=np.full(free.size, -np.inf),
        upper=np.full(free.size, np.inf),
        x0=z0,
        residuals=wr.residuals,
        jacobian=wr.jacobian,
        objective="sse",
    )
    r0 = wr.residuals(z0)  # kept for the optimizer's first evaluation (the same point)
    settings: dict[str, object] = {"name": method, "max_iter": max_iter, "ftol": ftol, "xtol": xtol}
    if method == "lm":
        settings["lam0"] = DAMPING if lam0 is None else float(lam0)
    res = make_optimizer(settings).minimize(problem)
    chi2 = float(res.chi2)
    # the optimizer reports its fitness (χ²) and the history of the accepted steps in it: the least squares' own
    # cost is half of it, its history starts at the start's
    history = [0.5 * float(r0 @ r0), *(0.5 * h for h in res.history)]
    # (a Jacobian held by its factors is the result's extra["jacobian_factored"], its ``jacobian`` empty)
    factored = {k: v for k, v in res.extra.items() if k == "jacobian_factored"}
    out = res.evolve(x=wr.full(res.x), varied=free, cost=0.5 * chi2, history=history, names=(), extra=factored)
    ndata = int(np.count_nonzero(w)) if w.ndim else (res.residual.size if float(w) != 0 else 0)
    if ndata != res.ndata:  # rows weighted zero are left out, not data
        J = factored.get("jacobian_factored", res.jacobian)
        cov = fit_covariance(res.residual, J, ndata) if res.status >= 0 else None
        out = out.evolve(ndata=ndata, covariance=cov)
    return out
