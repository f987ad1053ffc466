"""The library search's tests of one candidate: the projected nested F-test (with a BIC change and the share of
the excess chi² a candidate would remove), its linearised pose-grouped cross-validation, the Wald test of an
accepted effect, one forward step and the backward check that drops an effect the newest made redundant
(:func:`robocal.discovery.search.discover` runs them in turn)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import stats

from robocal.discovery.candidates import Candidate
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.cv import group_labels
from robocal.discovery.model import Accepted, Fit
from robocal.discovery.scoring import Score, regressor
from robocal.identification.model import FitData
from robocal.numerics import sorted_tied


def basis(fit: Fit) -> np.ndarray:
    """An orthonormal basis ``(M, r)`` of the column space of the fit's whitened Jacobian: the directions whose
    singular value is above 1e-10 of the largest. From a Householder QR of the matrix's Fortran copy, in place
    (LAPACK ``geqrf`` / ``orgqr``), while the fit gives its own up (:meth:`Fit.release_jacobian`, evaluated again
    when read later; its joint-level factors kept): one ``(M, k)`` matrix held besides the basis itself, where
    numpy's ``svd`` held five (0.9 GB at UR10 A's 12 000 rows, the search's peak; issue 31) and took a third
    longer. The rank is decided by the singular values of ``R`` (those of the matrix): at full rank the basis is
    ``Q`` itself; otherwise ``Q`` times ``R``'s kept left singular vectors. The same subspace as the left singular
    vectors of ``np.linalg.svd`` (projections equal to ~1e-15)."""
    from scipy import linalg

    a = np.asfortranarray(fit.J_w)
    fit.release_jacobian()
    if a.shape[1] == 0:
        return a
    Q, R = linalg.qr(a, mode="economic", overwrite_a=True, check_finite=False)
    del a
    U, s, _ = np.linalg.svd(R)
    keep = s > 1e-10 * s[0]
    return Q if keep.all() else Q @ U[:, keep]


def score_candidate(
    cand: Candidate, Z: np.ndarray, Q: np.ndarray, fit: Fit, cfg: DiscoveryConfig, log_thr: float
) -> tuple[Score, np.ndarray]:
    """Projected nested F-test, BIC and excess-chi² share of one candidate. Returns the score and the kept
    directions of the projected regressor (``(M, q')``)."""
    norms = np.linalg.norm(Z, axis=0)
    norms[norms == 0] = 1.0
    Zn = Z / norms
    Zp = Zn - Q @ (Q.T @ Zn)
    absorbed = float(1.0 - np.mean(np.sum(Zp**2, axis=0)))
    U, s, _ = np.linalg.svd(Zp, full_matrices=False)
    keep = s > cfg.absorbed_tol
    if not keep.any():
        return Score(cand.key, cand.label, "unidentifiable", absorbed), U[:, :0]
    Uk = U[:, keep]
    q = int(keep.sum())
    r = fit.r_w
    rss = fit.rss
    M = fit.M
    d = float(np.sum((Uk.T @ r) ** 2))
    dof1 = M - fit.k - q
    if dof1 < 1:
        return Score(cand.key, cand.label, "unidentifiable", absorbed, q), Uk
    F = (d / q) / max((rss - d) / dof1, 1e-300)
    log10_p = float(stats.f.logsf(F, q, dof1) / np.log(10.0))
    dbic = float(M * np.log(max(rss - d, 1e-300) / rss) + q * np.log(M))
    excess = rss - fit.dof
    share = d / excess if excess > 0 else float("inf")
    passes = bool(log10_p < log_thr and dbic < 0 and share >= cfg.min_excess_share)
    return Score(cand.key, cand.label, "tested", absorbed, q, float(F), log10_p, dbic, float(share), passes), Uk


def cross_validation_gain(fit: Fit, Uk: np.ndarray, groups: np.ndarray, folds: int, seed: int) -> float:
    """Relative drop of the held-out (whole poses) squared error when the candidate's directions are added.

    Linearised at the current fit: each fold refits the model's free parameters (with / without the candidate)
    on the other poses and predicts the held-out residuals. Positive = the candidate predicts better.
    """
    r = fit.r_w
    A0 = fit.J_w
    A1 = np.hstack([A0, Uk])
    rng = np.random.default_rng(seed)
    uniq, gidx, _ = group_labels(groups)
    perm = rng.permutation(len(uniq))
    f = (perm % folds)[gidx]
    sse0 = sse1 = 0.0
    for k in range(folds):
        test = f == k
        train = ~test
        if not test.any() or not train.any():
            continue
        for A, acc in ((A0, 0), (A1, 1)):
            delta = np.linalg.lstsq(A[train], -r[train], rcond=1e-10)[0]
            e = float(np.sum((r[test] + A[test] @ delta) ** 2))
            if acc == 0:
                sse0 += e
            else:
                sse1 += e
    return float((sse0 - sse1) / sse0) if sse0 > 0 else 0.0


def leave_to_cv(scored: list[tuple[Score, Candidate, np.ndarray, tuple[str, ...]]]) -> None:
    """Candidates the F-test may not accept (``extra["selection"] == "cv"``: a measurement-side signal that follows
    a robot-side one, see :mod:`robocal.discovery.candidates`) are marked so; the cross-validated selection offers
    them after the robot's own effects."""
    for sc, cand, _, _ in scored:
        if sc.passes and cand.extra.get("selection") == "cv":
            sc.passes = False
            sc.status = "left to the cross-validated selection"


def wald_log10_p(fit: Fit, acc: Accepted) -> float:
    names = list(acc.coef_names)
    if acc.cand.shape == "structure":
        names = [f"beta{acc.cand.joint}"]
    idx = [int(np.flatnonzero(fit.free == fit.model.index(n))[0]) for n in names if fit.model.index(n) in fit.free]
    if not idx:
        return 0.0
    c = fit.theta[fit.free[idx]]
    C = fit.cov[np.ix_(idx, idx)]
    try:
        w = float(c @ np.linalg.solve(C, c))
    except np.linalg.LinAlgError:
        return 0.0
    q = len(idx)
    return float(stats.f.logsf(w / q, q, fit.dof) / np.log(10.0))


def best_candidate(
    remaining: list[Candidate],
    fit: Fit,
    rows: np.ndarray,
    data: FitData,
    cfg: DiscoveryConfig,
    log_thr: float,
    groups: np.ndarray,
    unident: dict[str, float],
    log_thr_signal: float | None = None,
) -> tuple[list[Score], tuple[Candidate, tuple[str, ...]] | None]:
    """One forward step: every remaining candidate scored against ``fit`` (the unidentifiable ones noted in
    ``unident``), and the most significant one that also lowers the pose-grouped cross-validated error, or None."""
    Q = basis(fit)
    scored: list[tuple[Score, Candidate, np.ndarray, tuple[str, ...]]] = []
    for cand in remaining:
        Z, params = regressor(cand, fit, rows, data)
        thr = log_thr_signal if log_thr_signal is not None and cand.effect == "signal" else log_thr
        sc, Uk = score_candidate(cand, Z, Q, fit, cfg, thr)
        if sc.status == "unidentifiable":
            unident.setdefault(cand.key, sc.absorbed_share)
        scored.append((sc, cand, Uk, params))
    leave_to_cv(scored)
    passing = sorted_tied((s for s in scored if s[0].passes), key=lambda s: s[0].log10_p)
    chosen = None
    for sc, cand, Uk, params in passing:
        if cfg.cv_folds >= 2:
            sc.cv_gain = cross_validation_gain(fit, Uk, groups, cfg.cv_folds, cfg.seed)
            if sc.cv_gain <= 0:
                sc.status = "failed cross-validation"
                continue
        sc.status = "accepted"
        chosen = (cand, params)
        break
    return [s[0] for s in scored], chosen


def backward_check(
    accepted: list[Accepted],
    fit: Fit,
    log_thr: float,
    refit: Callable[[list[Accepted], Fit | None], Fit],
    log_thr_signal: float | None = None,
) -> tuple[list[Accepted], Fit, list[str]]:
    """An earlier effect the newest one made redundant (its Wald test no longer passes) is dropped, the least
    significant first, until every earlier effect passes (an effect of a logged signal at its family's threshold
    ``log_thr_signal``): ``(accepted, fit, dropped keys)``."""
    dropped: list[str] = []
    while True:
        weak = [(a, wald_log10_p(fit, a)) for a in accepted[:-1]]
        weak = [
            (a, lp)
            for a, lp in weak
            if lp > (log_thr_signal if log_thr_signal is not None and a.cand.effect == "signal" else log_thr)
        ]
        if not weak:
            return accepted, fit, dropped
        worst = max(weak, key=lambda t: t[1])[0]
        accepted = [a for a in accepted if a is not worst]
        dropped.append(worst.cand.key)
        fit = refit(accepted, fit)
