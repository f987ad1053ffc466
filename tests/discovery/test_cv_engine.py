"""The cross-validation engine from sufficient statistics (issue 31) equals the dense computation it replaces.

The reference below is the dense linearised pose-grouped cross-validation as discovery computed it before: every
fold's normal equations from boolean copies of the rows, a pseudo-inverse, and each candidate's full ``(M, q)``
regressor. The engine (robocal.discovery.cv) must give the same held-out errors to 1e-10 (relative to the
residuals' scale): the two differ only in the order of floating-point sums and in Cholesky vs. eigen-solves of
well-conditioned systems, whose errors are ~1e-13 here.
"""

from __future__ import annotations

import tracemalloc
from types import SimpleNamespace

import numpy as np
import pytest

from robocal.discovery.cv import FoldCV, SymSolver, gram_by_blocks, group_labels
from robocal.discovery.grow import Variant

TOL = 1e-10  # relative to the residuals' RMS: float sums in another order, Cholesky vs pinv (see the docstring)


def fake_fit(rng: np.random.Generator, m: int = 240, d: int = 3, k: int = 9, n_joints: int = 4, prior: int = 3):
    """A joint fit as discovery holds it: whitened Jacobian / residuals row by row, joint Jacobians, a ridge on
    the last ``prior`` parameters."""
    M = m * d
    A = rng.normal(size=(M, k)) * rng.uniform(0.5, 50.0, size=k)  # columns of very different scales
    r = rng.normal(size=M)
    Jq = rng.normal(size=(m, d, n_joints))
    prec = np.zeros(k)
    prec[k - prior :] = rng.uniform(1.0, 10.0, size=prior)
    theta = rng.normal(size=k + 2) * 0.01
    free = np.arange(k)
    w = np.full(M, 1.0 / 0.015)
    model = SimpleNamespace(prior_precision=lambda: np.concatenate([prec, np.zeros(2)]))
    fit = SimpleNamespace(J_w=A, r_w=r, Jq=Jq, weights=w, free=free, theta=theta, model=model, d=d)
    return fit, np.repeat(np.arange(m) // 2, d).astype(str)  # two rows per pose


def dense_cv(fit, groups, folds, seed):
    """The dense reference: base errors, and a function giving each variant's held-out errors for a dense Z."""
    uniq, gidx, _ = group_labels(groups)  # the folds' order of the groups (natural: "2" before "10")
    perm = np.random.default_rng(seed).permutation(len(uniq))
    fold = (perm % folds)[gidx]
    A, r = fit.J_w, fit.r_w
    prec = fit.model.prior_precision()[fit.free]
    th = fit.theta[fit.free]
    base = np.zeros_like(r)
    Hinv, g = {}, {}
    for k in range(folds):
        t = fold == k
        H = A[~t].T @ A[~t] + np.diag(prec)
        g[k] = A[~t].T @ r[~t] + prec * th
        Hinv[k] = np.linalg.pinv(H, rcond=1e-12, hermitian=True)
        base[t] = r[t] - A[t] @ (Hinv[k] @ g[k])

    def variants(Z, vs):
        out = []
        for v in vs:
            cols = np.arange(Z.shape[1]) if v.columns is None else v.columns
            pz = np.zeros(len(cols)) if v.prior_rad is None else 1.0 / np.broadcast_to(v.prior_rad, len(cols)) ** 2
            err = base.copy()
            for k in range(folds):
                t = fold == k
                Zc = Z[:, cols]
                C = A[~t].T @ Zc[~t]
                W = Hinv[k] @ C
                Sz = Zc[~t].T @ Zc[~t] + np.diag(pz) - C.T @ W
                dz = -np.linalg.solve(Sz, Zc[~t].T @ r[~t] - W.T @ g[k])
                err[t] += (Zc[t] - A[t] @ W) @ dz
            out.append(err)
        return out

    return base, variants


def joint_Z(fit, blocks):
    m, d = fit.Jq.shape[:2]
    w = fit.weights.reshape(m, d)
    return np.hstack([((fit.Jq[:, :, j] * w)[:, :, None] * S[:, None, :]).reshape(m * d, -1) for j, S in blocks])


@pytest.mark.parametrize("d", [3, 6])
def test_fold_sums_equal_the_dense_cross_validation(d):
    rng = np.random.default_rng(1)
    fit, groups = fake_fit(rng, d=d)
    base, dense = dense_cv(fit, groups, 5, 7)
    cv = FoldCV(fit, groups, 5, 7)
    scale = float(np.sqrt(np.mean(fit.r_w**2)))
    assert np.max(np.abs(cv.base_err - base)) < TOL * scale
    # a dense candidate, and joint-level candidates given by their factors (two joints pooled), with variants
    Z = rng.normal(size=(len(fit.r_w), 4))
    vs = [Variant(None, None, ""), Variant(np.array([0, 2]), 0.5, "")]
    for got, ref in zip(cv.with_variants(Z, vs), dense(Z, vs), strict=True):
        assert np.max(np.abs(got - ref)) < TOL * scale
    m = fit.Jq.shape[0]
    blocks = [(1, rng.normal(size=(m, 3))), (3, rng.normal(size=(m, 2)))]
    vj = [Variant(np.arange(5), np.array([0.1, 0.2, 0.3, 0.1, 0.1]), ""), Variant(np.array([0, 1, 3]), 0.05, "")]
    for got, ref in zip(cv.with_joint_variants(blocks, vj), dense(joint_Z(fit, blocks), vj), strict=True):
        assert np.max(np.abs(got - ref)) < TOL * scale


def test_folds_read_in_place_from_the_fit_jacobian():
    """A fit that cannot evaluate its Jacobian again keeps it: the folds read it where it is (no second (M, k)
    matrix in fold order), a fold's rows the fit's rows of that fold."""
    rng = np.random.default_rng(5)
    fit, groups = fake_fit(rng, d=6)
    cv = FoldCV(fit, groups, 5, 7)
    assert cv._A is None and cv._J is fit.J_w
    for i, (s, e) in enumerate(cv.bounds):
        assert np.array_equal(cv._fold(i), fit.J_w[cv.order[s:e]])


def test_a_fit_that_can_evaluate_its_jacobian_again_gives_it_up_sorted_in_place():
    """A fit that can evaluate its Jacobian again (``Fit.release``) gives it up; its rows are put in fold order in
    its own memory (one (M, k) matrix held): the same numbers as the folds read from the fit's matrix."""
    rng = np.random.default_rng(6)
    fit, groups = fake_fit(rng, d=6)
    m = fit.Jq.shape[0]
    Z = rng.normal(size=(len(fit.r_w), 3))
    blocks = [(1, rng.normal(size=(m, 3)))]
    vs = [Variant(None, None, ""), Variant(np.array([0, 2]), 0.5, "")]
    ref = FoldCV(fit, groups, 5, 7)
    want = [ref.base_err, *ref.with_variants(Z, vs), *ref.with_joint_variants(blocks, vs),
            ref.base_err_without(np.array([0, 1, 2, 4, 6, 7]))]  # fmt: skip
    J = np.array(fit.J_w)
    own = np.vstack([fit.J_w, np.zeros((2, J.shape[1]))])  # a view of the solver's matrix, as Fit.J_w is
    own.setflags(write=False)
    released = []
    fit.J_w, fit.data, fit.rows, fit.w = own[: len(J)], object(), np.arange(m), np.ones(len(J))
    fit.release = lambda: released.append(True)
    cv = FoldCV(fit, groups, 5, 7)
    assert cv._A is not None and cv._J is None and released == [True]
    assert np.shares_memory(cv._A, own) and np.array_equal(cv._A, J[cv.order])
    got = [cv.base_err, *cv.with_variants(Z, vs), *cv.with_joint_variants(blocks, vs),
           cv.base_err_without(np.array([0, 1, 2, 4, 6, 7]))]  # fmt: skip
    scale = float(np.sqrt(np.mean(fit.r_w**2)))
    for a, b in zip(want, got, strict=True):
        assert np.max(np.abs(a - b)) < 1e-12 * scale


def _leaving_out_equals_the_reduced_refit(fit, groups, keep) -> None:
    """``FoldCV.base_err_without(keep)`` equals the dense cross-validation of the reduced fit as
    robocal.discovery.grow.replace_fit_columns forms it (first order)."""
    drop = np.setdiff1d(np.arange(len(fit.free)), keep)
    th = fit.theta.copy()
    r2 = fit.r_w - fit.J_w[:, drop] @ th[drop]
    th[drop] = 0.0
    reduced = SimpleNamespace(**{**vars(fit), "J_w": fit.J_w[:, keep], "r_w": r2, "free": fit.free[keep], "theta": th})
    base, _ = dense_cv(reduced, groups, 5, 3)
    got = FoldCV(fit, groups, 5, 3).base_err_without(keep)
    assert np.max(np.abs(got - base)) < TOL * float(np.sqrt(np.mean(fit.r_w**2)))


def test_leaving_columns_out_equals_refitting_the_reduced_fit():
    fit, groups = fake_fit(np.random.default_rng(2))
    _leaving_out_equals_the_reduced_refit(fit, groups, np.array([0, 1, 2, 3, 5, 8]))


@pytest.mark.parametrize("drop", [[7], [30, 38]])  # a plain column; one plain and one under the ridge
def test_leaving_a_small_block_out_by_bordering_equals_refitting_the_reduced_fit(drop):
    # 6 |D| below the kept columns: the bordered solve of the whole model's factorisation, not a new one
    fit, groups = fake_fit(np.random.default_rng(4), m=400, k=40, prior=5)
    _leaving_out_equals_the_reduced_refit(fit, groups, np.setdiff1d(np.arange(40), drop))


def test_chunked_gram_equals_the_dense_one_and_its_memory_does_not_grow_with_rows():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(5000, 12))
    r = rng.normal(size=5000)
    G, b = gram_by_blocks(A, r, [(0, 1234), (1234, 5000)], chunk=500)
    assert np.allclose(G[0] + G[1], A.T @ A, rtol=1e-12, atol=1e-9)
    assert np.allclose(b[1], A[1234:].T @ r[1234:], rtol=1e-12, atol=1e-9)

    def peak(rows: int) -> int:
        A = np.ones((rows, 12))
        r = np.ones(rows)
        tracemalloc.start()
        gram_by_blocks(A, r, [(0, rows)], chunk=1000)
        out = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return out

    # beyond its inputs the accumulation holds one chunk's temporaries, whatever the rows: 16x the rows, same peak
    assert peak(64_000) < 1.5 * peak(4_000) + 10_000


def test_the_solver_falls_back_to_the_pseudo_inverse_on_a_singular_system():
    rng = np.random.default_rng(4)
    B = rng.normal(size=(6, 3))
    H = B @ B.T  # rank 3
    b = H @ rng.normal(size=6)
    s = SymSolver(H)
    assert s.pinv is not None
    assert np.allclose(s.solve(b), np.linalg.pinv(H, rcond=1e-12, hermitian=True) @ b)
    H2 = H + np.eye(6)
    assert SymSolver(H2).pinv is None
    assert np.allclose(SymSolver(H2).solve(b), np.linalg.solve(H2, b))


def dense_select_picks(Jq, w, F, r, Q, groups, max_terms, n_resamples, absorbed_tol, seed):
    """The dictionary's resampled OMP as it ran on the dense ``(M, n K)`` matrix (scikit-learn): the picks."""
    from sklearn.linear_model import orthogonal_mp

    m, d, n = Jq.shape
    Z = (Jq[:, :, :, None] * F[:, None, None, :]).reshape(m * d, n * F.shape[1]) * w[:, None]
    norms = np.linalg.norm(Z, axis=0)
    Zp = Z - Q @ (Q.T @ Z)
    pn = np.linalg.norm(Zp, axis=0)
    idx = np.flatnonzero(pn > absorbed_tol * np.maximum(norms, 1e-300))
    X = Zp[:, idx] / pn[idx]
    rng = np.random.default_rng(seed)
    uniq = np.unique(groups)
    picks = []
    for _ in range(n_resamples):
        pick = rng.choice(len(uniq), size=len(uniq) // 2, replace=False)
        rows = np.isin(groups, uniq[pick])
        picks.append(np.flatnonzero(orthogonal_mp(X[rows], r[rows], n_nonzero_coefs=max_terms, precompute=False)))
    return idx, X, picks


def test_the_dictionary_selection_picks_what_the_dense_matrix_picked():
    from robocal.discovery import dictionary

    rng = np.random.default_rng(5)
    m, d, n, K = 300, 3, 3, 7
    Jq = rng.normal(size=(m, d, n))
    w = np.full(m * d, 2.0)
    F = rng.normal(size=(m, K))
    A = rng.normal(size=(m * d, 4))
    Q = np.linalg.qr(A)[0]
    Z = (Jq[:, :, :, None] * F[:, None, None, :]).reshape(m * d, n * K) * w[:, None]
    r = 0.8 * Z[:, 2 * K + 3] + 0.5 * Z[:, 4] + rng.normal(size=m * d)
    groups = np.repeat(np.arange(m), d).astype(str)
    idx, X, picks = dense_select_picks(Jq, w, F, r, Q, groups, 2, 12, 1e-3, 9)
    basis = dictionary._Basis(Q, m, d)
    Xf = dictionary._Projected(Jq * w.reshape(m, d)[:, :, None], F, basis, Q.T @ Z, np.arange(n * K), np.ones(1))
    assert np.allclose(Xf.rmatvec(r), Z.T @ r - (Q.T @ Z).T @ (Q.T @ r))  # the factored product, unnormalised
    rng2 = np.random.default_rng(9)
    uniq = np.unique(groups)
    B = Q.T @ Z
    pn = np.linalg.norm(Z - Q @ B, axis=0)
    Xp = dictionary._Projected(Jq * w.reshape(m, d)[:, :, None], F, basis, B, idx, pn[idx])
    assert np.allclose(Xp.columns(np.arange(len(idx))), X, atol=1e-12)
    for ref in picks:
        pick = rng2.choice(len(uniq), size=len(uniq) // 2, replace=False)
        rows = np.isin(groups, uniq[pick])
        got = np.sort(dictionary._omp(Xp, rows, np.where(rows, r, 0.0), 2))
        assert got.tolist() == ref.tolist()
    # and the proposal: joint 3's atom 3 and joint 1's atom 4, stable in every resample
    props = dictionary.select(Jq, w, F, r, Q, groups, 2, 12, 0.7, 1e-3, 9)
    assert sorted((p.joint, a) for p in props for a in p.atoms) == [(1, 4), (3, 3)]


def test_a_held_out_difference_at_round_off_is_no_evidence():
    """A candidate the model absorbs changes the per-pose held-out sums by ~1e-12 relative: the paired t-test on
    that noise gave any p-value (on the UR10 it accepted a logged signal's joint offset). It is no evidence."""
    from robocal.discovery.grow import paired_log10_p

    rng = np.random.default_rng(6)
    sse0 = rng.uniform(1e3, 1e4, size=200)
    noise = sse0 * (1e-13 + 1e-13 * rng.uniform(size=200))  # a consistent "gain" of 1e-13 relative
    assert paired_log10_p(sse0, sse0 - noise) == 0.0
    real = sse0 * 1e-3 * (1.0 + rng.normal(size=200))  # a real gain of 0.1 % is still seen
    assert paired_log10_p(sse0, sse0 - real) < -10
