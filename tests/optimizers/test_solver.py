"""The least-squares core: Gauss-Newton and Levenberg-Marquardt are two methods, and both reach what
scipy.optimize.least_squares reaches on the same calibration problem."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.start import fit_data
from robocal.data import read_campaign
from robocal.optimizers.solver import levenberg_marquardt
from robocal.sim.twin import load_scenario, simulate


@pytest.fixture(scope="module")
def problem(tmp_path_factory, kr16):
    d = tmp_path_factory.mktemp("solver")
    sc = load_scenario("geometric")
    sc.update(n_poses=40, n_validation_poses=0, errors={"length_mm": 1.0, "angle_deg": 0.1})
    simulate(sc, d, seed=2)
    camp = read_campaign(d, kr16)
    res = calibrate(camp, kr16, CalibrationConfig(outliers="off"))
    data = fit_data(camp, False, res.model.target_names)
    free = np.flatnonzero(res.identified)
    x0 = res.start.x_init
    w = 1.0 / 0.015
    return res, data, free, x0, w


def test_gn_and_lm_are_different_methods_with_one_minimum(problem):
    res, data, free, x0, w = problem

    def fun(x):
        return res.model.residuals_and_jacobian(x, data)

    gn = levenberg_marquardt(fun, x0, free, w, method="gn")
    lm = levenberg_marquardt(fun, x0, free, w, method="lm", lam0=1e-2)
    assert gn.success and lm.success
    # a damped first step is shorter than the Gauss-Newton step: the paths differ ...
    assert lm.history[1] > gn.history[1]
    # ... the minimum does not (cost to 1e-9 relative, parameters within 1e-6 of their standard errors)
    assert lm.cost == pytest.approx(gn.cost, rel=1e-9)
    se = res.stderr[free]
    assert np.abs((lm.x - gn.x)[free] / se).max() < 1e-6

    # scipy's least_squares (trust-region reflective, its own Jacobian handling) on the same free parameters
    def resid(z):
        x = x0.copy()
        x[free] = z
        return w * res.model.residuals(x, data)

    def jac(z):
        x = x0.copy()
        x[free] = z
        return w * res.model.residuals_and_jacobian(x, data)[1][:, free]

    ref = least_squares(resid, x0[free], jac=jac, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert 0.5 * float(ref.fun @ ref.fun) == pytest.approx(lm.cost, rel=1e-9)
    assert np.abs((ref.x - lm.x[free]) / se).max() < 1e-6


def test_method_setting(problem, kr16):
    with pytest.raises(Exception, match="method"):
        CalibrationConfig.from_mapping({"method": "newton"})
    with pytest.raises(ValueError, match="method"):
        levenberg_marquardt(lambda x: (x, np.eye(len(x))), np.ones(2), np.arange(2), method="bfgs")
