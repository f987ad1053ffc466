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
from robocal.discovery.gram import FactoredSpace
from robocal.discovery.model import Accepted, Fit
from robocal.discovery.scoring import Score, regressor
from robocal.identification.model import FitData
from robocal.numerics import sorted_tied

#: a fit's Jacobian up to this size is copied into column order for the QR; a larger one is let go and evaluated
#: again in column order (issue 31: the copy doubled the peak memory at UR10 A's 12 000 rows, 0.44 GB each)
COPY_BYTES = 64 * 2**20


class ColumnSpace:
    """The column space of a fit's whitened Jacobian ``A (M, k)``: an orthonormal basis ``B`` of the directions whose
    singular value is above 1e-10 of the largest, held as the Householder factors of ``A``'s QR (LAPACK
    ``geqrf`` on ``A`` in column order, in place) and applied by ``ormqr``: ``B`` itself (``M x r``) is formed only
    when asked for (:meth:`matrix`, in the factors' place). At full rank ``B = Q``; otherwise ``Q U_r`` with ``U_r``
    the kept left singular vectors of ``R`` (those of ``A``): the subspace of numpy's ``svd`` of ``A`` (projections
    equal to ~1e-15).

    Issue 31: numpy's ``svd`` held five ``(M, k)`` matrices (0.9 GB at UR10 A's 12 000 rows); the QR's ``Q`` (LAPACK
    ``orgqr``) was still one more beside the factors and twice the factorisation's time: forming it cost more
    than every product with it the search makes (a few hundred columns), now each a pass of the reflectors."""

    def __init__(self, fit: Fit) -> None:
        from scipy import linalg

        held = fit.__dict__.get("J_w")
        if held is not None and (held.nbytes <= COPY_BYTES or not fit.release_jacobian()):
            a = np.asfortranarray(held)  # a copy (the fit's own matrix is read-only)
            fit.release_jacobian()  # its matrix let go (evaluated again when read), its joint-level factors kept
        else:  # let go first, then evaluated in column order for the QR in place: never two (M, k) at once
            fit.release_jacobian()
            a = fit.evaluate_jacobian(order="F")
        del held
        self.M, self.k = a.shape
        self.U: np.ndarray | None = None
        self.B: np.ndarray | None = None  # the basis itself once :meth:`matrix` formed it (the factors gone)
        if self.k == 0:
            self.qr, self.tau, self.rank = a, np.zeros(0), 0
            return
        (qr, tau), _ = linalg.qr(a, mode="raw", overwrite_a=True, check_finite=False)
        del a
        self.qr, self.tau = qr, tau
        n = min(self.M, self.k)
        U, sv, _ = np.linalg.svd(np.triu(qr[:n, : self.k]))
        keep = sv > 1e-10 * sv[0]
        self.rank = int(keep.sum())
        if not keep.all():
            self.U = U[:, keep]

    def _ormqr(self, trans: str, C: np.ndarray, own: bool = False) -> np.ndarray:
        """``Qᵀ C`` or ``Q C`` (``trans`` "T" / "N") of the full ``M x M`` ``Q``, in a Fortran copy of ``C`` (never
        ``C`` itself: a one-column array is also Fortran-ordered, and LAPACK would overwrite the caller's), or in
        ``C`` itself when ``own`` (a Fortran-ordered temporary of the caller's: one ``M x q`` less)."""
        from scipy.linalg import lapack

        if not (own and C.dtype == float and C.flags.f_contiguous):
            C = np.array(C, dtype=float, order="F", copy=True)
        out, _, info = lapack.dormqr("L", trans, self.qr, self.tau, C, lwork=max(1, 64 * C.shape[1]), overwrite_c=1)
        if info != 0:
            raise np.linalg.LinAlgError(f"LAPACK dormqr failed (info {info})")
        return np.asarray(out)

    def coefficients(self, Z: np.ndarray) -> np.ndarray:
        """``Bᵀ Z`` (``r x q``) of ``Z (M, q)`` (or ``(M,)``)."""
        Z2 = Z.reshape(self.M, -1)
        if self.k == 0:
            return np.zeros((0, Z2.shape[1]))
        if self.B is not None:
            c = self.B.T @ Z2
        else:
            c = self._ormqr("T", Z2)[: min(self.M, self.k)]
            c = c if self.U is None else self.U.T @ c
        return c if Z.ndim == 2 else c[:, 0]

    def combine(self, W: np.ndarray) -> np.ndarray:
        """``B W`` (``M x q``) of coefficients ``W (r, q)`` (or ``(r,)``)."""
        W2 = W.reshape(self.rank, -1)
        if self.B is not None:
            C = self.B @ W2
        else:
            C = np.zeros((self.M, W2.shape[1]), order="F")
            if self.k:
                C[: min(self.M, self.k)] = W2 if self.U is None else self.U @ W2
                C = self._ormqr("N", C, own=True)  # in place: C is this method's own
        return C if W.ndim == 2 else C[:, 0]

    def project(self, Z: np.ndarray) -> np.ndarray:
        """``B Bᵀ Z``: the part of ``Z`` in the column space."""
        return self.combine(self.coefficients(Z))

    def remove(self, Z: np.ndarray) -> None:
        """``Z -= B Bᵀ Z`` in place: the part of ``Z (M, q)`` off the column space."""
        Z -= self.project(Z)

    def matrix(self) -> np.ndarray:
        """``B`` itself (``M x r``): for products with a regressor held by its factors (the dictionary's ``v ⊗ F``,
        :func:`robocal.discovery.dictionary.select`), which pass the rows once where a pass of the reflectors
        would need the regressor dense. Formed once, in the factors' own memory (LAPACK ``orgqr`` in place, then
        ``Q U_r`` row block by row block into its first ``r`` columns): the space holds ``B`` instead of its
        factors from then on (its products ``Bᵀ Z`` and ``B W``; issue 31: never the factors, ``Q`` and ``Q U_r``
        at once, ~0.55 GB at UR10 A's 12 000 rows)."""
        from scipy.linalg import lapack

        if self.B is not None:
            return self.B
        n = min(self.M, self.k)
        if n == 0:
            return np.zeros((self.M, 0))
        q, _, info = lapack.dorgqr(self.qr[:, :n], self.tau[:n], lwork=max(1, 64 * n), overwrite_a=1)
        if info != 0:
            raise np.linalg.LinAlgError(f"LAPACK dorgqr failed (info {info})")
        self.qr = self.tau = None  # type: ignore[assignment]  # overwritten: B from here on
        q = np.asarray(q)
        if self.U is not None:
            for s in range(0, self.M, ROW_BLOCK):
                q[s : s + ROW_BLOCK, : self.rank] = q[s : s + ROW_BLOCK, :n] @ self.U
            q = q[:, : self.rank]
        self.B = q
        return q


#: rows of ``Q`` multiplied by ``U_r`` at a time when the basis is formed in place (bounds the temporary)
ROW_BLOCK = 4096


def f_log10_sf(F: float, d1: float, d2: float) -> float:
    """``log10 P(X > F)`` of the F(d1, d2) distribution, finite where scipy's ``logsf`` underflows to -inf (F ~ 300
    at 10 and 2 000 degrees of freedom: a strong effect's p-value was written as null and the report could not be
    written). There: ``I_x(a, b) = x^a (1-x)^b / (a B(a, b)) 2F1(a+b, 1; a+1; x)``, ``x = d2 / (d2 + d1 F)``,
    ``a = d2/2``, ``b = d1/2`` (an identity of the regularised incomplete beta; equal to logsf to 1e-13 where both
    are finite)."""
    from scipy import special

    v = float(stats.f.logsf(F, d1, d2))
    if np.isfinite(v) or not F > 0:
        return v / float(np.log(10.0))
    a, b = d2 / 2.0, d1 / 2.0
    x = d2 / (d2 + d1 * F)
    ln = (
        a * np.log(x)
        + b * np.log1p(-x)
        - np.log(a)
        - special.betaln(a, b)
        + np.log(special.hyp2f1(a + b, 1.0, a + 1.0, x))
    )
    return float(ln / np.log(10.0))


def basis(fit: Fit) -> ColumnSpace:
    """The column space of the fit's whitened Jacobian (:class:`ColumnSpace`); the fit lets its own matrix go."""
    return ColumnSpace(fit)


#: columns of candidates' regressors projected off the model's column space together: one pass of the reflectors
#: for all of them (a pass reads the (M, k) factors: 15 ms at UR10 A's 12 000 rows, ~100 candidates a step)
BATCH_COLUMNS = 64


def _normalised(Z: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(Z, axis=0)
    norms[norms == 0] = 1.0
    return Z / norms


def off_space(Q: ColumnSpace | FactoredSpace, Zs: list[np.ndarray]) -> list[np.ndarray]:
    """Each regressor of ``Zs`` with its columns normalised and projected off the column space ``Q``, in one pass
    for all of them (:data:`BATCH_COLUMNS` at most)."""
    if not Zs:
        return []
    cuts = np.cumsum([z.shape[1] for z in Zs])
    allz = np.empty((Zs[0].shape[0], int(cuts[-1])))
    for Z, a, b in zip(Zs, np.concatenate([[0], cuts[:-1]]), cuts, strict=True):
        allz[:, a:b] = _normalised(Z)
    allz -= Q.project(allz)  # in place: (M, 64) temporaries are what a 24 000-row library step holds at its peak
    return list(np.split(allz, cuts[:-1], axis=1))


def score_candidate(
    cand: Candidate,
    Z: np.ndarray,
    Q: ColumnSpace | FactoredSpace | None,
    fit: Fit,
    cfg: DiscoveryConfig,
    log_thr: float,
    Zp: np.ndarray | None = None,
) -> tuple[Score, np.ndarray]:
    """Projected nested F-test, BIC and excess-chi² share of one candidate. Returns the score and the kept
    directions of the projected regressor (``(M, q')``). ``Zp``: the regressor already normalised and projected
    off the model's column space (:func:`off_space`), else projected here by ``Q``."""
    if Zp is None:
        assert Q is not None
        (Zp,) = off_space(Q, [Z])
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
    log10_p = f_log10_sf(float(F), q, dof1)
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
        # each fold's rows of [A0 Uk] formed from the two (the whole widened matrix beside A0 was one more M x k)
        for acc in (0, 1):
            At = A0[train] if acc == 0 else np.hstack([A0[train], Uk[train]])
            delta = np.linalg.lstsq(At, -r[train], rcond=1e-10)[0]
            del At
            Ah = A0[test] if acc == 0 else np.hstack([A0[test], Uk[test]])
            e = float(np.sum((r[test] + Ah @ delta) ** 2))
            if acc == 0:
                sse0 += e
            else:
                sse1 += e
    return float((sse0 - sse1) / sse0) if sse0 > 0 else 0.0


def time_blocks(t: np.ndarray, n: int, d: int) -> np.ndarray:
    """Per residual (``d`` per row), the one of ``n`` consecutive spans of the rows' times ``t`` (equal counts) its
    row lies in: the folds a drift in time is cross-validated on. Poses held out at random leave their neighbours
    in time to interpolate the drift between, so a trend that stands for something else the measurement order
    follows (the configurations measured one after the other) passed; a span held out whole is predicted only by a
    drift that holds beyond the rows fitted (a drift named on 18 configurations measured in turn, applied 90
    minutes on: 0.84 mm held out where the geometry had 0.65)."""
    order = np.argsort(t, kind="stable")
    block = np.empty(len(t), dtype=int)
    block[order] = np.arange(len(t)) * n // max(len(t), 1)
    return np.repeat(np.char.add("t", block.astype(str)), d)


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
    return f_log10_sf(float(w / q), q, fit.dof)


def family_threshold(cand: Candidate, log_thr: float, log_thr_signal: float | None) -> float:
    """The log10 p-value a candidate must pass: its own family's (a scanned tracker step's ``family_log10_p``,
    :mod:`robocal.discovery.steps`), the logged signals' (``log_thr_signal``), or the library's (``log_thr``)."""
    if "family_log10_p" in cand.extra:
        return float(cand.extra["family_log10_p"])
    return log_thr_signal if log_thr_signal is not None and cand.effect == "signal" else log_thr


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
    batch: list[tuple[Candidate, np.ndarray, tuple[str, ...]]] = []

    def score(batch: list[tuple[Candidate, np.ndarray, tuple[str, ...]]]) -> None:
        for (cand, Z, params), Zp in zip(batch, off_space(Q, [Z for _, Z, _ in batch]), strict=True):
            thr = family_threshold(cand, log_thr, log_thr_signal)
            sc, Uk = score_candidate(cand, Z, None, fit, cfg, thr, Zp=Zp)
            if sc.status == "unidentifiable":
                unident.setdefault(cand.key, sc.absorbed_share)
            # the directions (M x q) kept only where the cross-validation may read them: every candidate's held
            # at once grew with the rows (47 library candidates, 70 MB at 24 000 twin rows)
            scored.append((sc, cand, Uk if sc.passes else np.empty((0, Uk.shape[1])), params))

    for cand in remaining:
        Z, params = regressor(cand, fit, rows, data)
        batch.append((cand, Z, params))
        if sum(z.shape[1] for _, z, _ in batch) >= BATCH_COLUMNS:
            score(batch)
            batch = []
    score(batch)
    leave_to_cv(scored)
    passing = sorted_tied((s for s in scored if s[0].passes), key=lambda s: s[0].log10_p)
    chosen = None
    for sc, cand, Uk, params in passing:
        if cfg.cv_folds >= 2:
            g = time_blocks(cand.S[rows, 0], cfg.cv_folds, fit.d) if cand.effect == "drift" else groups
            sc.cv_gain = cross_validation_gain(fit, Uk, g, cfg.cv_folds, cfg.seed)
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
        weak = [(a, lp) for a, lp in weak if lp > family_threshold(a.cand, log_thr, log_thr_signal)]
        if not weak:
            return accepted, fit, dropped
        worst = max(weak, key=lambda t: t[1])[0]
        accepted = [a for a in accepted if a is not worst]
        dropped.append(worst.cand.key)
        fit = refit(accepted, fit)
