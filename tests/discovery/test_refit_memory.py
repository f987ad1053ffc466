"""Discovery's joint refit without copies of its Jacobian (issue 31): the same fit, a fraction of the memory.

The refit builds only the free columns of the extended model's Jacobian, whitened in place; the solver takes that
matrix as its own (no weighted copy, no copy into the result) and forms its normal equations in row chunks. The
reference below is the refit as it was: the full ``(M, n)`` Jacobian, weighted and sliced by the solver.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.start import fit_data, present_stations, present_targets
from robocal.discovery.model import Accepted, ExtendedModel, fit_model
from robocal.identification import robust
from robocal.optimizers import solver
from robocal.optimizers.solver import levenberg_marquardt

from .conftest import joint_candidate, make_campaign

SIGMA = 0.015


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    """A twin campaign, its geometric fit, and an extended model: a 2-column joint effect (no prior) and a
    200-column one under a prior (the residual layer's kind: most of the Jacobian's columns; fewer columns than
    rows, so that the fit without its prior is well determined too)."""
    camp, robot, _ = make_campaign(tmp_path_factory.mktemp("refit"), "geometric", 5,
                                   {"backlash": {"joints": {3: 0.008}}}, n_poses=600)  # fmt: skip
    rows = np.flatnonzero(camp.split == "calibration")
    cal = camp.subset(rows)
    geo = calibrate(cal, robot, CalibrationConfig(noise_mm=SIGMA))
    data = fit_data(cal, use_orientation=False, targets=present_targets(cal), stations=present_stations(cal))
    rng = np.random.default_rng(1)
    q3 = camp.q[:, 2]
    accepted = [
        Accepted(joint_candidate("h:j3", 3, np.column_stack([np.sin(q3), np.cos(q3)]), None)),
        Accepted(joint_candidate("wide:j2", 2, rng.normal(size=(camp.n_rows, 200)), 1e-4)),
    ]
    model = ExtendedModel(robot, geo.model.target_names, geo.model.T_ref, accepted, like=geo.model)
    theta0 = model.map_from(geo.names, geo.x)
    return model, theta0, data, rows


def _fit(problem):
    model, theta0, data, rows = problem
    return fit_model(model, theta0, data, rows, SIGMA, set(), 1e-6, 100)


def test_the_jacobian_on_chosen_columns_is_those_of_the_full_one(problem):
    model, theta0, data, rows = problem
    th = theta0 + 1e-5 * np.random.default_rng(2).normal(size=model.n)
    r, J, Jx, Jq = model.residuals_and_jacobian(th, data, rows)
    # some base columns, part of the 2-column effect, every other column of the wide one
    cols = np.sort(
        np.concatenate([[0, 3, 7], [model.slices[0].start + 1], np.arange(model.slices[1].start, model.n, 2)])
    )
    r2, J2, Jx2, Jq2 = model.residuals_and_jacobian(th, data, rows, extra_rows=4, cols=cols)
    assert np.array_equal(r, r2) and np.array_equal(Jx, Jx2) and np.array_equal(Jq, Jq2)
    assert J2.shape == (len(r) + 4, len(cols))
    assert np.array_equal(J2[: len(r)], J[:, cols]) and not J2[len(r) :].any()
    r3, J3, _, _ = model.residuals_and_jacobian(th, data, rows, cols=np.zeros(0, dtype=int))
    assert np.array_equal(r, r3) and J3.shape == (len(r), 0)


def test_the_refit_equals_the_refit_on_the_full_weighted_jacobian(problem):
    """The same operations on the same numbers (one chunk of normal equations at this size): equal to round-off
    (the solver's products run on another matrix in memory, whose alignment may pick another BLAS kernel path:
    3e-14 of a standard error seen)."""
    model, theta0, data, rows = problem
    fit = _fit(problem)
    assert fit.k > 200
    prec = model.prior_precision()
    ridge = np.flatnonzero(prec > 0)
    sq = np.sqrt(prec[ridge])

    def fun(th):  # the refit's evaluation as it was: every column, weighted by the solver
        r, J, _, _ = model.residuals_and_jacobian(th, data, rows, extra_rows=len(ridge))
        J[len(r) + np.arange(len(ridge)), ridge] = sq
        return np.concatenate([r, sq * th[ridge]]), J

    w_all = np.concatenate([fit.weights, np.ones(len(ridge))])
    ref = levenberg_marquardt(fun, theta0, fit.free, w_all, max_iter=100, ftol=1e-12, xtol=1e-10)
    assert np.array_equal(ref.varied, fit.free)
    se = np.sqrt(np.diag(fit.cov))
    assert np.all(np.abs(ref.x - fit.theta)[fit.free] <= 1e-10 * se)  # round-off (3e-14 seen): see the docstring
    assert np.allclose(ref.residual[: fit.M], fit.r_w, rtol=0, atol=1e-9)  # whitened: 1e-9 of the noise
    assert np.allclose(ref.jacobian[: fit.M], fit.J_w, rtol=0, atol=1e-12 * np.abs(fit.J_w).max())
    assert np.all(np.abs(ref.covariance - fit.cov) <= 1e-8 * np.outer(se, se))


def test_normal_equations_in_row_chunks(problem, monkeypatch):
    """Chunks of 97 rows: the same normal equations to round-off, and the same refit to far below its own
    uncertainty (1e-9 of a standard error; the sums only change order)."""
    fit = _fit(problem)
    s = 1.0 / np.linalg.norm(fit.J_w, axis=0)
    g1, H1 = solver._normal_equations(fit.J_w, s, fit.r_w)
    monkeypatch.setattr(solver, "NORMAL_CHUNK", 97)
    g2, H2 = solver._normal_equations(fit.J_w, s, fit.r_w)
    assert np.allclose(H1, H2, rtol=0, atol=1e-12 * np.abs(H1).max())
    # g ~ 0 at the minimum: its round-off is relative to |A_j| |r|
    assert np.all(np.abs(g1 - g2) <= 1e-12 * np.sqrt(np.diag(H1)) * np.linalg.norm(fit.r_w))
    fit2 = _fit(problem)
    se = np.sqrt(np.diag(fit.cov))
    assert np.all(np.abs(fit2.theta[fit.free] - fit.theta[fit.free]) <= 1e-9 * se)


def test_the_row_test_in_chunks_is_the_same(problem, monkeypatch):
    fit = _fit(problem)
    m = fit.M // fit.d
    row_of = np.repeat(np.arange(m), fit.d)
    kept = np.ones(m, dtype=bool)
    kept[::17] = False
    t1 = robust.row_test(fit.r_w, fit.J_w, row_of, m, kept, 0.01)
    monkeypatch.setattr(robust, "ROW_CHUNK", 40)  # 13 rows of 3 residuals per chunk
    t2 = robust.row_test(fit.r_w, fit.J_w, row_of, m, kept, 0.01)
    assert np.allclose(t1.F, t2.F, rtol=1e-9, atol=0)  # the kept rows' Gram summed in another order
    assert np.array_equal(t1.flagged, t2.flagged)
    # the Jacobian given a chunk of rows at a time (discovery's gross-error test: never the (M, k) matrix): the
    # same chunks, the same numbers
    J, d = np.asarray(fit.J_w), fit.d
    asked = []

    def rows_jacobian(a, b):
        asked.append((a, b))
        return J[a * d : b * d].copy()

    t3 = robust.row_test(fit.r_w, rows_jacobian, row_of, m, kept, 0.01, n_params=fit.k)
    assert np.array_equal(t3.F, t2.F) and np.array_equal(t3.flagged, t2.flagged)
    assert max(b - a for a, b in asked) == 13 and len(asked) == 2 * -(-m // 13)  # two passes of 13-row chunks
    # a large model's chunk is fewer rows: ROW_CHUNK_BYTES of Jacobian at most (here 5 rows of k columns)
    monkeypatch.setattr(robust, "ROW_CHUNK_BYTES", 5 * d * fit.k * 8)
    asked.clear()
    t4 = robust.row_test(fit.r_w, rows_jacobian, row_of, m, kept, 0.01, n_params=fit.k)
    assert max(b - a for a, b in asked) == 5
    assert np.allclose(t4.F, t1.F, rtol=1e-9, atol=0) and np.array_equal(t4.flagged, t1.flagged)


def test_the_gross_error_test_evaluates_its_jacobian_by_chunks_of_rows(problem, monkeypatch):
    """Discovery's gross-error test evaluates the model's Jacobian a chunk of rows at a time (each row's own
    numbers: bitwise those of the whole campaign's matrix) and gives the row test of the whole matrix."""
    from robocal.discovery import gross

    fit = _fit(problem)
    model, _, data, rows = problem
    m = fit.M // fit.d
    kept = np.ones(m, dtype=bool)
    kept[::11] = False
    r, J, _, _ = model.residuals_and_jacobian(fit.theta, data, rows, cols=fit.free)
    w = np.tile(fit.weights[: fit.d], m)
    prec = model.prior_precision()[fit.free]
    monkeypatch.setattr(robust, "ROW_CHUNK_BYTES", 50 * fit.d * fit.k * 8)  # 50-row chunks
    want = robust.row_test(r * w, J * w[:, None], np.repeat(np.arange(m), fit.d), m, kept, 0.01, prior=prec)
    cal = type("Cal", (), {"n_rows": m})()
    test, _, _ = gross.retest(fit, data, rows, cal, kept, 0.01)
    assert np.array_equal(test.F, want.F) and np.array_equal(test.p_value, want.p_value)


def test_the_refit_holds_no_copy_of_its_jacobian(problem):
    """Peak memory of the refit beyond its inputs: at most about two of its ``(M, k)`` Jacobians (the solver's
    current one and a trial's); the refit as it was held four to five (the full ``(M, n)`` matrix, the solver's
    column copy, its weighted copy, the scaled one of the normal equations, the result's two copies)."""
    model = problem[0]
    _fit(problem)  # warm caches (chain compilation, imports)
    tracemalloc.start()
    fit = _fit(problem)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    one = (fit.M + int(np.sum(model.prior_precision() > 0))) * fit.k * 8  # the solver's matrix, prior rows too
    # 2.7 here (the two matrices and the evaluation's temporaries); 5.5 as it was
    assert peak < 3.6 * one, (peak / one, one)


def test_the_gross_error_test_takes_the_prior_so_round_off_cannot_decide(problem, monkeypatch):
    """An effect determined by its prior alone (a constant among its signals: the joint's own offset again, as
    the residual layer's kernels sum to nearly one) leaves the kept rows' JᵀJ singular; the row test then takes
    the fit's prior into its leverages (as calibrate's does) and its verdict no longer follows the round-off of
    the Jacobian (on the UR10's 3 000 rows, without the prior, a relative change of 1e-15 changed 61 of 2 094
    verdicts)."""
    from robocal.discovery import gross

    model, theta0, data, rows = problem
    wide = model.accepted[1].cand
    S = np.column_stack([np.ones(len(wide.S)), wide.S[:, :60]])
    acc = [model.accepted[0], Accepted(joint_candidate("const:j2", 2, S, 1e-4))]
    model2 = ExtendedModel(model.robot, model.base.target_names, model.base.T_ref, acc, like=model.base)
    fit = fit_model(model2, model2.map_from(model.names, theta0), data, rows, SIGMA, set(), 1e-6, 100)
    J = np.asarray(fit.J_w)
    sv = np.linalg.svd(J / np.linalg.norm(J, axis=0), compute_uv=False)
    assert sv[-1] < 1e-12 * sv[0]  # the premise: singular without the prior
    m = fit.M // fit.d
    row_of = np.repeat(np.arange(m), fit.d)
    kept = np.ones(m, dtype=bool)
    prec = model2.prior_precision()[fit.free]
    J2 = J * (1.0 + 1e-15 * np.random.default_rng(3).normal(size=J.shape))
    t1 = robust.row_test(fit.r_w, J, row_of, m, kept, 0.01, prior=prec)
    t2 = robust.row_test(fit.r_w, J2, row_of, m, kept, 0.01, prior=prec)
    assert np.allclose(t1.F, t2.F, rtol=1e-8, atol=0) and np.array_equal(t1.flagged, t2.flagged)
    # discovery's gross-error test passes the fit's prior
    seen = {}
    real = robust.row_test

    def spy(*a, **k):
        seen.update(k)
        return real(*a, **k)

    monkeypatch.setattr(robust, "row_test", spy)
    cal = type("Cal", (), {"n_rows": m})()
    gross.retest(fit, data, rows, cal, kept, 0.01)
    assert np.array_equal(seen["prior"], prec)


def test_the_column_basis_spans_numpys_svd_without_holding_the_fits_jacobian(problem):
    """The F-tests' and the dictionary's basis of the model's column space (``ftest.basis``, a QR in place) spans
    what numpy's SVD of the fit's Jacobian spans (orthonormal, the same projections to round-off), while the fit
    gives its own matrix up (evaluated again, the same numbers, when read later) and keeps the joint-level factors
    its folds' sums are formed from. numpy's ``svd`` held the Jacobian, its copy, ``U`` and a workspace of two more:
    0.9 GB at UR10 A's 12 000 rows, the search's peak. A rank-deficient matrix keeps the rank the SVD keeps."""
    from robocal.discovery.ftest import basis

    fit = _fit(problem)
    J = np.array(fit.J_w)
    U, s, _ = np.linalg.svd(J, full_matrices=False)
    want = U[:, s > 1e-10 * s[0]]
    gram = fit.gram
    assert gram is not None  # the fit has joint-level effects
    space = basis(fit)
    assert "J_w" not in fit.__dict__ and fit.gram is gram
    assert space.rank == want.shape[1]
    # the same projector as the SVD's, by the reflectors (1e-12: round-off of a QR against an SVD of a matrix whose
    # condition number is ~1e6 here; a wrong subspace differs by O(1)); coefficients and their combination agree
    Z = np.random.default_rng(3).normal(size=(len(J), 5))
    assert np.max(np.abs(space.project(Z) - want @ (want.T @ Z))) < 1e-12 * np.max(np.abs(Z))
    assert np.max(np.abs(space.project(Z[:, 0]) - want @ (want.T @ Z[:, 0]))) < 1e-12 * np.max(np.abs(Z))
    one = Z[:, :1].copy()  # one column: C- and Fortran-ordered at once; LAPACK overwrote it in place (the
    before = one.copy()  # real ABB's compliance candidates then came out "absorbed" by -108 %)
    space.project(one)
    assert np.array_equal(one, before)
    c = space.coefficients(Z)
    Q = space.matrix()  # the basis itself (the dictionary's products): orthonormal, the same projections
    assert Q.shape == want.shape
    assert np.allclose(Q.T @ Q, np.eye(Q.shape[1]), atol=1e-12)
    assert np.allclose(Q.T @ Z, c, atol=1e-12 * np.max(np.abs(Z)))
    # formed in the factors' place: the space works from the basis from then on, the same projections
    assert space.qr is None and space.matrix() is Q
    assert np.max(np.abs(space.project(Z) - want @ (want.T @ Z))) < 1e-12 * np.max(np.abs(Z))
    assert np.array_equal(fit.J_w, J)  # evaluated again at the fit's parameters


def test_a_large_jacobian_is_let_go_before_the_basis_evaluates_it_in_column_order(problem, monkeypatch):
    """Above ``COPY_BYTES`` the fit's Jacobian is not copied into column order (two (M, k) matrices at once: the
    peak at UR10 A's 12 000 rows) but let go and evaluated again in column order: the same numbers, so the same
    factorisation and projections (bitwise)."""
    from robocal.discovery import ftest

    Z = np.random.default_rng(5).normal(size=(_fit(problem).M, 4))
    small = ftest.basis(_fit(problem))
    monkeypatch.setattr(ftest, "COPY_BYTES", 0)
    fit = _fit(problem)
    J = np.array(fit.J_w)
    large = ftest.basis(fit)
    assert "J_w" not in fit.__dict__
    assert np.array_equal(large.qr, small.qr) and np.array_equal(large.project(Z), small.project(Z))
    F = fit.evaluate_jacobian(order="F")
    assert F.flags.f_contiguous and np.array_equal(F, J)


def test_the_column_basis_of_a_rank_deficient_jacobian_keeps_the_svds_rank():
    from types import SimpleNamespace

    from robocal.discovery.ftest import basis

    rng = np.random.default_rng(4)
    A = rng.normal(size=(300, 6))
    J = np.column_stack([A, A[:, :2] @ np.array([[1.0], [2.0]])])  # 7 columns of rank 6
    fit = SimpleNamespace(J_w=J, release_jacobian=lambda: True)
    space = basis(fit)
    U, s, _ = np.linalg.svd(J, full_matrices=False)
    want = U[:, s > 1e-10 * s[0]]
    assert space.rank == 6 == want.shape[1]
    P = space.project(np.eye(300))
    assert np.max(np.abs(P - want @ want.T)) < 1e-12
    Q = space.matrix()
    assert Q.shape == (300, 6) and np.max(np.abs(Q @ Q.T - want @ want.T)) < 1e-12
