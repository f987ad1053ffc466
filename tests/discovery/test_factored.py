"""A refit holding its Jacobian by its factors (issue 31): the residual layer's columns ``v ⊗ S`` are never formed,
and the fit, its covariance and its cross-validation are those of the dense matrix (to rounding).

The reference is the same refit with the Jacobian dense (:data:`robocal.discovery.model.FACTOR_BYTES` above its
size); the factored one is forced by setting it to zero."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.start import fit_data, present_stations, present_targets
from robocal.discovery import model as model_module
from robocal.discovery.cv import FoldCV, pose_groups
from robocal.discovery.grow import Variant
from robocal.discovery.model import Accepted, ExtendedModel, fit_model

from .conftest import joint_candidate, make_campaign

SIGMA = 0.015


@pytest.fixture(scope="module", params=[False, True], ids=["position", "pose"])
def problem(request, tmp_path_factory):
    """A twin campaign (positions, or positions and orientations) and an extended model: a 2-column joint effect
    without a prior and two 40-column ones under a prior on two joints (the residual layer's kind), one of them on
    the joint of the first (two blocks of one joint)."""
    effects = {"backlash": {"joints": {3: 0.008}}}
    tmp = tmp_path_factory.mktemp("factored")
    camp, robot, _ = make_campaign(tmp, "geometric", 5, effects, n_poses=300, orientation=request.param)
    rows = np.flatnonzero(camp.split == "calibration")
    cal = camp.subset(rows)
    geo = calibrate(cal, robot, CalibrationConfig(noise_mm=SIGMA))
    data = fit_data(cal, use_orientation=request.param, targets=present_targets(cal), stations=present_stations(cal))
    rng = np.random.default_rng(1)
    q3 = camp.q[:, 2]
    accepted = [
        Accepted(joint_candidate("h:j3", 3, np.column_stack([np.sin(q3), np.cos(q3)]), None)),
        Accepted(joint_candidate("wide:j2", 2, rng.normal(size=(camp.n_rows, 40)), 1e-4)),
        Accepted(joint_candidate("wide:j3", 3, rng.normal(size=(camp.n_rows, 40)), 1e-4)),
    ]
    model = ExtendedModel(robot, geo.model.target_names, geo.model.T_ref, accepted, like=geo.model)
    theta0 = model.map_from(geo.names, geo.x)
    sigma_rad = 1e-4 if request.param else None
    groups = np.repeat(pose_groups(cal.pose_id, cal.q), model.per_row(data))
    return model, theta0, data, rows, sigma_rad, groups


def _fit(problem, factor_bytes, monkeypatch):
    model, theta0, data, rows, sigma_rad, _ = problem
    monkeypatch.setattr(model_module, "FACTOR_BYTES", factor_bytes)
    return fit_model(model, theta0, data, rows, SIGMA, set(), 1e-6, 100, sigma_rad=sigma_rad)


@pytest.fixture()
def pair(problem, monkeypatch):
    dense = _fit(problem, 2**62, monkeypatch)
    factored = _fit(problem, 0, monkeypatch)
    return dense, factored


def test_the_factored_refit_is_the_dense_one(pair):
    dense, factored = pair
    assert dense.factored is None and factored.factored is not None
    assert "J_w" not in factored.__dict__  # never formed whole
    # the same solver steps on normal equations equal to rounding: parameters to ~1e-9 of their size
    np.testing.assert_allclose(factored.theta, dense.theta, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(factored.r_w, dense.r_w, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(factored.cov, dense.cov, rtol=1e-6, atol=1e-14 * np.max(np.abs(dense.cov)))
    # the factors are the dense matrix (to rounding), and read whole the fit evaluates it as the dense fit's
    J = factored.factored.dense()[: factored.M]
    np.testing.assert_allclose(J, dense.evaluate_jacobian(), rtol=1e-9, atol=1e-9 * np.max(np.abs(J)))
    np.testing.assert_allclose(factored.J_w, dense.evaluate_jacobian(), rtol=1e-7, atol=1e-7 * np.max(np.abs(J)))


def test_the_cross_validation_of_a_factored_fit_is_the_dense_ones(problem, pair):
    groups = problem[5]
    dense, factored = pair
    cd, cf = FoldCV(dense, groups, 5, 3), FoldCV(factored, groups, 5, 3)
    assert cf._F is not None and cf._A is None and cf._J is None
    scale = np.max(np.abs(cd.base_err))
    np.testing.assert_allclose(cf.base_err, cd.base_err, atol=1e-6 * scale)
    # leaving out a wide block (bordering or a new factorisation) and the small one
    for lo, hi in ((2 + 40, 2 + 80), (0, 2)):
        keep = np.array([i for i, p in enumerate(dense.free) if not (dense.model.nb + lo <= p < dense.model.nb + hi)])
        np.testing.assert_allclose(cf.base_err_without(keep), cd.base_err_without(keep), atol=1e-6 * scale)
    # a joint-level candidate (products with the folds' rows through the factors)
    q1 = factored.data.q[:, 0]
    blocks = [(0, np.column_stack([np.sin(q1), np.cos(q1)])), (2, np.column_stack([np.sin(2 * q1), np.cos(q1)]))]
    variants = [Variant(None, None, "free"), Variant(np.arange(2), 1e-4, "one")]
    for a, b in zip(cf.with_joint_variants(blocks, variants), cd.with_joint_variants(blocks, variants), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6 * scale)
    Z = np.random.default_rng(4).normal(size=(factored.M, 3))
    for a, b in zip(cf.with_variants(Z, variants[:1]), cd.with_variants(Z, variants[:1]), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6 * scale)


def test_the_column_space_from_the_factors_is_the_dense_ones(pair, monkeypatch):
    from robocal.discovery import gram
    from robocal.discovery.ftest import basis

    dense, factored = pair
    monkeypatch.setattr(gram, "SPACE_BLOCK_BYTES", 8 * factored.d * factored.k * 37)  # several blocks of 37 rows
    Z = np.random.default_rng(5).normal(size=(factored.M, 4))
    want = basis(dense).project(Z)
    got = factored.factored.space()
    assert got.rank == basis(dense).rank
    # a projection to ~1e-11 of its size (refined once: without, A V Σ⁻¹ alone loses the condition number's digits)
    np.testing.assert_allclose(got.project(Z), want, atol=1e-11 * np.max(np.abs(want)))


def test_the_folds_reorder_the_factors_the_fit_gives_up_where_they_are(problem, pair):
    """The fold order of a fit's own factors is put where they are (at 8 000 UR10 rows with the residual layer a copy
    was 94 MB beside them): the fold CV reads the fit's arrays, their rows in fold order, and the fit lets them go."""
    _, factored = pair
    F = factored.factors()
    D, S, V = F.D, F.gram.S, F.gram.V
    before = [a.copy() for a in (D, *S, *V)]
    cv = FoldCV(factored, problem[5], 5, 3)
    assert factored.factored is None and factored.gram is None  # given up
    rows = cv.order[:: cv.d] // cv.d
    assert cv._F.D is D and all(a is b for a, b in zip(cv._F.gram.S, S, strict=True))
    m = len(rows)
    np.testing.assert_array_equal(D.reshape(m, cv.d, -1), before[0].reshape(m, cv.d, -1)[rows])
    for now, was in zip((*S, *V), before[1:], strict=True):
        np.testing.assert_array_equal(now, was[rows])  # a response two blocks share is reordered once


def test_the_dictionary_reads_the_basis_from_the_factors_as_the_dense_one(pair):
    """The dictionary's products with the model's column space from the factors (no (M, k) basis formed) are the
    dense basis's: the bases differ by a rotation, so what the selection reads of them — each column's part in the
    space, its norm, inner products with a residual — is compared."""
    from robocal.discovery.dictionary import _Basis
    from robocal.discovery.ftest import basis

    dense, factored = pair
    m, d = factored.M // factored.d, factored.d
    rng = np.random.default_rng(6)
    v, F, u = rng.normal(size=(m, d)), rng.normal(size=(m, 4)), rng.normal(size=factored.M)
    a, b = _Basis(basis(dense).matrix(), m, d), _Basis(factored.factors().space(), m, d)
    assert a.rank == b.rank
    Ba, Bb = a.joint(v, F), b.joint(v, F)
    # to ~1e-9 of their size: the factored basis A W is orthonormal to the condition number's digits
    np.testing.assert_allclose(np.sum(Bb**2, axis=0), np.sum(Ba**2, axis=0), rtol=1e-9)
    np.testing.assert_allclose(Bb.T @ b.t(u), Ba.T @ a.t(u), rtol=1e-8, atol=1e-9 * np.abs(Ba.T @ a.t(u)).max())
    np.testing.assert_allclose(b.times(Bb), a.times(Ba), atol=1e-8 * np.abs(a.times(Ba)).max())
    # the summary's projection taken off in place (two steps in turn) is the projection's
    Z = rng.normal(size=(factored.M, 3))
    want = Z - basis(dense).project(Z)
    factored.factors().space().remove(Z)
    np.testing.assert_allclose(Z, want, atol=1e-9 * np.abs(want).max())
