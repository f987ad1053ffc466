"""One immutable fit result (issue 18): every optimizer and the least-squares core return a FitResult whose
statistics are those of the fit, consistent across methods and with scipy."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.problem import calibration_problem
from robocal.calibration.start import fit_data, present_targets
from robocal.data.contract import read_campaign
from robocal.identification.result import FitResult
from robocal.optimizers import make_optimizer, registered
from robocal.optimizers.solver import levenberg_marquardt
from robocal.sim.twin import load_scenario, simulate


@pytest.fixture(scope="module")
def twin(tmp_path_factory, kr16):
    out = tmp_path_factory.mktemp("fitresult")
    sc = load_scenario("geometric")
    sc.update(n_poses=40, n_validation_poses=0)
    simulate(sc, out, seed=3)
    camp = read_campaign(out, kr16)
    cfg = CalibrationConfig(outliers="off")
    base = calibrate(camp, kr16, dataclasses.replace(cfg, max_iter=0))
    lm = calibrate(camp, kr16, cfg)
    data = fit_data(camp, False, present_targets(camp))
    return camp, base, lm, data


def _problem(twin, bounded):
    _, base, _, data = twin
    return calibration_problem(
        base.model, data, base.start.x_init, np.flatnonzero(base.identified), bounded=bounded, max_iter=5
    )


@pytest.mark.parametrize("name", registered())
def test_every_optimizer_returns_the_one_fit_result(twin, name):
    population = name in registered("population")
    problem, _search = _problem(twin, bounded=population)
    opts = {"name": name, "max_iter": 5 if population else 50}
    if population:
        opts["population"] = 12
    res = make_optimizer(opts).minimize(problem)
    assert isinstance(res, FitResult) and res.method == name
    assert res.x.shape == (problem.n,) and res.names == problem.names
    # the statistics are those at x, whatever the method: chi2 = sum of squared residuals, N - k dof
    r = problem.residuals(res.x)
    assert res.chi2 == pytest.approx(float(r @ r), rel=1e-12)  # the same evaluation, rounding only
    assert res.ndata == r.size and res.dof == r.size - problem.n
    assert res.redchi == pytest.approx(res.chi2 / res.dof, rel=1e-15)
    n = res.ndata
    assert res.aic == pytest.approx(n * math.log(res.chi2 / n) + 2 * problem.n, rel=1e-12)  # lmfit's definition
    assert res.bic == pytest.approx(n * math.log(res.chi2 / n) + math.log(n) * problem.n, rel=1e-12)
    # the problem has a Jacobian, so every method reports a covariance, standard errors and correlations
    assert res.covariance is not None and res.covariance.shape == (problem.n, problem.n)
    assert np.all(np.isfinite(res.stderr)) and np.allclose(np.diag(res.correlation), 1.0)
    assert res.wall_time_s > 0 and res.timings["total_s"] == res.wall_time_s
    # immutable: no field can be rebound and no array written
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.x = np.zeros(problem.n)  # type: ignore[misc]
    for a in (res.x, res.covariance, res.residual, res.stderr):
        with pytest.raises(ValueError):
            a[0] = 1.0
    with pytest.raises(TypeError):
        res.extra["x"] = 1  # type: ignore[index]


def test_gauss_newton_covariance_is_the_calibrations(twin):
    """The optimizer protocol's Gauss-Newton (mm residuals) and calibrate (whitened residuals) report the same
    covariance: s² (JᵀJ)⁻¹ does not depend on the residuals' scale."""
    _, _, lm, _ = twin
    problem, search = _problem(twin, bounded=False)
    res = make_optimizer({"name": "gn", "max_iter": 50}).minimize(problem)
    free = search.free
    np.testing.assert_array_equal(np.flatnonzero(lm.identified), free)
    assert lm.solver is not None and lm.solver.covariance is not None
    np.testing.assert_allclose(lm.covariance, lm.solver.covariance, rtol=0, atol=0)  # calibrate's is the solver's
    # both at their own converged minimum (same start, same model): equal to 1e-6 relative (convergence)
    np.testing.assert_allclose(res.covariance, lm.covariance, rtol=1e-6)
    np.testing.assert_allclose(res.stderr, lm.stderr[free], rtol=1e-6)


def test_solver_statistics_agree_with_scipy(twin):
    _, base, _, data = twin
    model, x0, free = base.model, base.start.x_init, np.flatnonzero(base.identified)
    w = 1.0 / 0.015

    def fun(x):
        return model.residuals_and_jacobian(x, data)

    res = levenberg_marquardt(fun, x0, free, w)

    def resid(z):
        x = x0.copy()
        x[free] = z
        return w * model.residuals(x, data)

    def jac(z):
        x = x0.copy()
        x[free] = z
        return w * model.residuals_and_jacobian(x, data)[1][:, free]

    ref = least_squares(resid, x0[free], jac=jac, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    chi2 = float(ref.fun @ ref.fun)
    assert res.chi2 == pytest.approx(chi2, rel=1e-9)  # both at the minimum: cost to convergence precision
    cov = np.linalg.inv(ref.jac.T @ ref.jac) * chi2 / (ref.fun.size - free.size)
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-6)  # Jacobians at minima 1e-9 apart


def test_rows_left_out_are_not_data(twin):
    """A row weighted zero by the robust fit is listed in outliers and counted neither in N nor in chi2."""
    _, base, _, data = twin
    from robocal.calibration.start import least_squares_on

    model, x0, free = base.model, base.start.x_init, np.flatnonzero(base.identified)
    m = data.m
    rows = np.repeat(np.arange(m), 3)
    kept = np.ones(m, dtype=bool)
    kept[[2, 7]] = False
    w = np.full(3 * m, 1.0 / 0.015)
    res = least_squares_on(lambda x: model.residuals_and_jacobian(x, data), x0, free, w, rows, kept)
    assert res.outliers == (2, 7) and res.ndata == 3 * (m - 2)
    r = res.residual
    assert res.chi2 == pytest.approx(float(r[kept[rows]] @ r[kept[rows]]), rel=1e-12)
    assert np.any(r[~kept[rows]] != 0)  # the left-out rows are there, as predictions


def test_evolve_normalises_what_changes_and_shares_the_rest():
    """``evolve`` (every protocol result is one: the solver's result re-labelled, then mapped to the full
    parameters) copies and freezes the fields it is given, as the constructor does, and shares the read-only
    arrays it is not given instead of copying them again."""
    J = np.arange(12.0).reshape(6, 2)
    res = FitResult(method="lm", x=[1.0, 2.0], varied=[0, 1], cost=1.0, chi2=2.0, ndata=6, covariance=None,
                    status=1, nit=1, nfev=2, residual=np.ones(6), jacobian=J)  # fmt: skip
    x = np.array([3.0, 4.0])
    new = res.evolve(x=x, history=[1, 0.5], extra={"a": 1})
    assert new.jacobian is res.jacobian and new.residual is res.residual  # shared, not copied
    assert new.x is not x and not new.x.flags.writeable  # the given array copied and frozen
    x[0] = 9.0
    assert new.x[0] == 3.0 and new.history == (1.0, 0.5) and new.extra["a"] == 1
    assert res.x.tolist() == [1.0, 2.0] and res.history == ()  # the original unchanged
    with pytest.raises(ValueError, match="unknown status"):
        res.evolve(status=42)
    with pytest.raises(TypeError, match="unknown field"):
        res.evolve(speed=1.0)
