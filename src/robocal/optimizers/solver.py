"""Gauss-Newton / Levenberg-Marquardt for small dense nonlinear least squares.

Works on a subset of free variables, in scaled units, with whitened residuals. Two methods:

* ``"lm"`` (Levenberg-Marquardt): every step solves ``(JᵀJ + λ diag(JᵀJ)) dz = -Jᵀr`` (Marquardt scaling),
  starting from ``λ = lam0`` (1e-6 by default: Madsen, Nielsen & Tingleff's choice when the start is believed
  close to the minimum, as calibrate's converged rigid fit is; 1e-3 when it is not); λ shrinks tenfold after a
  step that lowers the cost and grows tenfold until one does;
* ``"gn"`` (Gauss-Newton): the undamped step ``JᵀJ dz = -Jᵀr`` with a backtracking line search (halved until
  the cost falls).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from robocal.identification.result import FitResult, fit_covariance, normal_inverse
from robocal.numerics import column_norms, has_gram, normal_equations

__all__ = ["FitResult", "levenberg_marquardt", "normal_inverse"]


def levenberg_marquardt(
    fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x0: np.ndarray,
    free: np.ndarray,
    weights: np.ndarray | float = 1.0,
    scale: np.ndarray | None = None,
    max_iter: int = 100,
    ftol: float = 1e-12,
    xtol: float = 1e-10,
    lam0: float | None = None,
    method: str = "lm",
    jac_free: bool = False,
) -> FitResult:
    """Minimise ``0.5 * |w * r(x)|²`` over ``x[free]``; a :class:`~robocal.identification.result.FitResult`.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> (r, J)`` with ``r`` of shape (M,) and ``J`` of shape (M, n).
    x0 : ndarray, shape (n,)
    free : ndarray of int, shape (k,)
        Indices of the variables to fit.
    weights : float or ndarray, shape (M,)
        Residual weights (1 / sigma).
    scale : ndarray, shape (n,), optional
        Typical magnitude per variable; steps are measured in ``x / scale``. Default: column norms.
    lam0 : initial damping of ``"lm"`` (default 1e-6); ignored by ``"gn"``.
    method : ``"lm"`` or ``"gn"`` (module docstring).
    jac_free : ``fun``'s Jacobian holds only the free columns, in the order of ``free`` (a large model need not
        build, nor this solver copy, the columns of the fixed variables); the Jacobian is then the result's
        own (read-only, no copy).
    """
    if method not in ("lm", "gn"):
        raise ValueError(f"The 'method' parameter must be 'lm' or 'gn'. Got {method!r} instead.")
    damped = method == "lm"
    t0 = time.perf_counter()
    x = np.array(x0, dtype=float)
    free = np.asarray(free, dtype=int)
    w = np.asarray(weights, dtype=float)
    # unit weights (residuals whitened by the caller: the optimizer protocol's Problem) and every column free:
    # no product and no column copy per evaluation (the same numbers: 1.0 * v is v)
    unit = w.ndim == 0 and float(w) == 1.0
    every = bool(free.size) and np.array_equal(free, np.arange(free.size))

    def weighted(r: np.ndarray) -> np.ndarray:
        return r if unit else w * r

    def weighted_jacobian(J: np.ndarray) -> np.ndarray:
        Jc = J if jac_free or (every and J.shape[1] == free.size) else J[:, free]
        return Jc if unit else (w[:, None] if w.ndim else w) * Jc

    # (Jf is the evaluation's Jacobian or its weighted copy: the evaluation's own is not held through the steps)
    r, Jf = _first(fun, x, weighted, weighted_jacobian)
    nfev = njev = 1
    J_new: np.ndarray | None = None
    cost = 0.5 * float(r @ r)
    history = [cost]
    s = _column_scale(Jf, scale, free)
    lam = (1e-6 if lam0 is None else float(lam0)) if damped else 0.0
    status, nit = 0, 0
    if not (np.all(np.isfinite(r)) and _finite(Jf)):
        return _result(method, x, free, w, r, Jf, cost, 0, nfev, njev, -1, t0, history)
    for nit in range(1, max_iter + 1):
        g, H = _normal_equations(Jf, s, r)
        accepted = False
        # predicted reduction of the undamped Gauss-Newton step: stop without another evaluation when
        # even the full step cannot lower the cost by more than ftol (at a minimum to working precision)
        if _predicted_reduction(H, g) <= ftol * max(cost, 1e-300):
            status = 1
            nit -= 1
            break
        # the trials need only g and H: the accepted Jacobian is let go before a trial builds its own (one (M, k)
        # matrix at a time), read again at x if no trial is accepted
        alpha, Jf = 1.0, None  # type: ignore[assignment]
        for _ in range(30):
            if damped or alpha == 1.0:
                dz_full = _damped_step(H, g, lam)
            dz = dz_full if damped else alpha * dz_full
            J_new = None  # a rejected trial's Jacobian let go before the next is built
            x_new, r_new, J_new, cost_new = _trial(fun, x, free, s * dz, weighted)
            nfev += 1
            njev += 1
            if np.isfinite(cost_new) and cost_new <= cost * (1.0 + 1e-14):
                accepted = True
                break
            if damped:
                lam = max(lam * 10.0, 1e-6)
            else:
                alpha /= 2.0
        if not accepted:
            status, J_new = 3, None  # (the rejected trial's Jacobian let go)
            break
        if damped:
            lam = lam / 10.0 if lam > 1e-12 else 0.0
        dcost = cost - cost_new
        x, r, cost = x_new, r_new, cost_new
        assert J_new is not None  # an accepted trial's
        Jf, J_new = weighted_jacobian(J_new), None
        history.append(cost)
        if dcost <= ftol * max(cost, 1e-300):
            status = 1
            break
        if np.linalg.norm(dz) <= xtol * (xtol + np.linalg.norm(x[free] / s)):
            status = 2
            break
    Jf = _kept_or_again(Jf, fun, x, weighted, weighted_jacobian)
    return _result(method, x, free, w, r, Jf, cost, nit, nfev, njev, status, t0, history, own=jac_free)


def _kept_or_again(
    Jf: np.ndarray | None,
    fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x: np.ndarray,
    weighted: Callable[[np.ndarray], np.ndarray],
    weighted_jacobian: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """The Jacobian at ``x``: ``Jf`` when held, else (no trial accepted: the last one was let go before the
    trials) evaluated again — the same numbers, not counted as an evaluation."""
    return Jf if Jf is not None else _first(fun, x, weighted, weighted_jacobian)[1]


def _first(
    fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x: np.ndarray,
    weighted: Callable[[np.ndarray], np.ndarray],
    weighted_jacobian: Callable[[np.ndarray], np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """The weighted residuals and Jacobian at the start ``x``."""
    r, J = fun(x)
    return weighted(r), weighted_jacobian(J)


def _finite(Jf: np.ndarray) -> bool:
    """Whether every entry of the Jacobian is finite (one held by its factors answers itself)."""
    return bool(np.all(np.isfinite(Jf))) if isinstance(Jf, np.ndarray) else bool(Jf.all_finite())


def _column_scale(Jf: np.ndarray, scale: np.ndarray | None, free: np.ndarray) -> np.ndarray:
    """Typical magnitude of each free variable: ``scale[free]``, by default the inverse column norms of ``Jf``."""
    if scale is None:
        d = column_norms(Jf) if isinstance(Jf, np.ndarray) else np.array(Jf.column_norms())
        d[d == 0] = 1.0
        return 1.0 / d
    return np.asarray(scale, dtype=float)[free]


def _trial(
    fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x: np.ndarray,
    free: np.ndarray,
    dx: np.ndarray,
    weighted: Callable[[np.ndarray], np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``x`` moved by ``dx`` on the free variables, its whitened residuals (``weighted``), its Jacobian and its
    cost."""
    x_new = x.copy()
    x_new[free] += dx
    r_new, J_new = fun(x_new)
    r_new = weighted(r_new)
    return x_new, r_new, J_new, 0.5 * float(r_new @ r_new)


#: Jacobian rows per chunk of the normal equations (bounds their temporary: chunk x k floats); a problem of at most
#: this many rows is one product, as before
NORMAL_CHUNK = 16384


def _normal_equations(Jf: np.ndarray, s: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``g = Aᵀ r`` and ``H = Aᵀ A`` of the scaled Jacobian ``A = Jf s``, accumulated over row chunks of
    :data:`NORMAL_CHUNK` (``A`` is never formed whole: an ``(M, k)`` matrix the trial evaluation need not hold
    beside its own Jacobian)."""
    M = Jf.shape[0]
    if has_gram(Jf):  # its owner forms them from its structure (robocal.numerics.attach_gram)
        G, b = normal_equations(Jf, r)
        assert b is not None
        return s * b, G * s[:, None] * s[None, :]
    if M <= NORMAL_CHUNK:
        A = Jf * s
        return A.T @ r, A.T @ A
    g = np.zeros(Jf.shape[1])
    H = np.zeros((Jf.shape[1], Jf.shape[1]))
    for c0 in range(0, M, NORMAL_CHUNK):
        A = Jf[c0 : c0 + NORMAL_CHUNK] * s
        g += A.T @ r[c0 : c0 + NORMAL_CHUNK]
        H += A.T @ A
    return g, H


def _predicted_reduction(H: np.ndarray, g: np.ndarray) -> float:
    """The cost reduction the undamped Gauss-Newton step ``H dz = -g`` predicts (inf when ``H`` is singular)."""
    try:
        dz_gn = -np.linalg.solve(H, g)
        return -(g @ dz_gn + 0.5 * dz_gn @ (H @ dz_gn))
    except np.linalg.LinAlgError:
        return np.inf


def _damped_step(H: np.ndarray, g: np.ndarray, lam: float) -> np.ndarray:
    """The step ``(H + λ diag(H)) dz = -g`` (Cholesky; least squares when that fails)."""
    Hd = H + lam * np.diag(np.diag(H)) if lam > 0 else H
    try:
        L = np.linalg.cholesky(Hd)
        return -np.linalg.solve(L.T, np.linalg.solve(L, g))
    except np.linalg.LinAlgError:
        return -np.linalg.lstsq(Hd, g, rcond=None)[0]


def _result(
    method: str,
    x: np.ndarray,
    free: np.ndarray,
    w: np.ndarray,
    r: np.ndarray,
    Jf: np.ndarray,
    cost: float,
    nit: int,
    nfev: int,
    njev: int,
    status: int,
    t0: float,
    history: list[float],
    own: bool = False,
) -> FitResult:
    factored = not isinstance(Jf, np.ndarray)  # held by its factors: the result's ``extra["jacobian_factored"]``
    if own and not factored and Jf.base is None:
        # the solver's own matrix (``jac_free``): the result takes it read-only, without a copy (FitResult keeps
        # such an array as it is)
        Jf.setflags(write=False)
    # rows weighted zero (left out by the caller) are not data
    ndata = int(np.count_nonzero(w)) if w.ndim else (r.size if w != 0 else 0)
    finite = status >= 0
    cov = fit_covariance(r, Jf, ndata) if finite else None
    return FitResult(
        method=method,
        x=x,
        varied=free,
        cost=cost,
        chi2=2.0 * cost,
        ndata=ndata,
        covariance=cov,
        status=status,
        nit=nit,
        nfev=nfev,
        njev=njev,
        history=history,
        residual=r,
        jacobian=np.empty((0, Jf.shape[1])) if factored else Jf,
        timings={"total_s": time.perf_counter() - t0},
        extra={"jacobian_factored": Jf} if factored else {},
    )
