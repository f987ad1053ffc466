"""The one geometric fit (issue 22, item 1): start -> solve (any registered optimizer) -> outliers -> statistics.

``robocal.calibrate(campaign, robot, optimizer=...)`` takes every registered optimizer; a fit takes its start
once (no zero-iteration ``calibrate`` round trips for the start, the statistics and the polish); the statistics
of a method's point are those of the start's identifiable set, and its "before" figures are the nominal model's
best rigid fit, as for Levenberg-Marquardt.
"""

from __future__ import annotations

import numpy as np
import pytest

import robocal
from robocal.calibration import start as calibrate_module
from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import fit_with_optimizer
from robocal.calibration.solve import START_DAMPING, gradient_fit
from robocal.calibration.start import calibration_start, least_squares_on
from robocal.data.contract import read_campaign
from robocal.errors import ConfigError
from robocal.sim.twin import load_scenario, simulate

SMALL = {"population": 20, "max_iter": 5}  # a fast run: these tests check the path, not the optimum


@pytest.fixture(scope="module")
def campaign(tmp_path_factory, kr16):
    out = tmp_path_factory.mktemp("twin")
    sc = load_scenario("geometric")
    sc.update(n_poses=40, n_validation_poses=10)
    simulate(sc, out, seed=2)
    return read_campaign(out, kr16)


def test_robocal_calibrate_takes_any_registered_optimizer(campaign, kr16):
    lm = robocal.calibrate(campaign, kr16)
    assert np.array_equal(robocal.calibrate(campaign, kr16, optimizer="lm").x, lm.x)  # the default, unchanged
    gn = robocal.calibrate(campaign, kr16, optimizer={"name": "gn", "max_iter": 30})
    assert gn.fit["rms_position_mm"] == pytest.approx(lm.fit["rms_position_mm"], rel=1e-6)  # the same minimum
    woa = robocal.calibrate(campaign, kr16, optimizer={"name": "woa", **SMALL}, seed=1)
    assert woa.fit["nit"] == SMALL["max_iter"] and woa.solver is not None
    assert woa.fit["rms_position_mm"] >= lm.fit["rms_position_mm"]  # 5 iterations of WOA: not the LM minimum
    polished = robocal.calibrate(campaign, kr16, optimizer={"name": "woa", **SMALL, "polish": True}, seed=1)
    assert polished.fit["rms_position_mm"] == pytest.approx(lm.fit["rms_position_mm"], rel=1e-3)
    with pytest.raises(ConfigError, match=r"'optimizer' parameter must be one of"):
        robocal.calibrate(campaign, kr16, optimizer="pso")


def test_a_fit_takes_its_start_once(campaign, kr16, monkeypatch):
    calls = []
    real = calibrate_module.register_frames

    def counting(*args, **kw):
        calls.append(1)
        return real(*args, **kw)

    monkeypatch.setattr(calibrate_module, "register_frames", counting)
    out = fit_with_optimizer(campaign, kr16, CalibrationConfig(), {"name": "igoa", **SMALL, "polish": True})
    assert len(calls) == 1  # one registration for the search, the raw statistics and the polish
    assert out.polished is not None and out.raw is not out.polished


def test_the_statistics_of_a_method_are_the_starts(campaign, kr16):
    cfg = CalibrationConfig(use_orientation=False)
    start = calibration_start(campaign, kr16, cfg)
    lm = robocal.calibrate(campaign, kr16, cfg)
    out = fit_with_optimizer(campaign, kr16, cfg, {"name": "igoa", "population": 30, "max_iter": 20})
    raw = out.raw
    np.testing.assert_array_equal(np.flatnonzero(raw.identified), start.free)  # the set that was searched
    # "before" is the nominal model's best rigid fit (as for LM), not the method's own point (the old
    # zero-iteration calibrate(x0=...) reported the method's point as "before": 0.385 mm here, = its "after")
    assert raw.fit["before"] == lm.fit["before"]
    np.testing.assert_array_equal(raw.start.x_init, lm.start.x_init)
    # the statistics are at the method's own point (a clean twin campaign: no row left out)
    assert out.optimize is not None and not raw.fit["outliers"]
    np.testing.assert_array_equal(raw.x[start.free], out.optimize.x)
    assert raw.fit["rms_position_mm"] < 0.9 * raw.fit["before"]["rms_position_mm"]  # the method moved (0.38 / 0.82)


def test_the_default_fit_solves_through_the_registered_optimizer(campaign, kr16, monkeypatch):
    """The default fit (Levenberg-Marquardt) is the registered ``lm``'s ``minimize(Problem)``, not a second path
    to the least-squares core: a spy registered as ``lm`` sees every solve, with the calibration's settings; the
    start's rigid fit (frames and tools, undamped) goes through it too."""
    from robocal.optimizers import registry
    from robocal.optimizers.gradient import LevenbergMarquardt

    seen: list[tuple[int, float, int | None]] = []

    class Spy(LevenbergMarquardt):
        def minimize(self, problem):
            seen.append((problem.n, self.lam0, self.max_iter))
            return super().minimize(problem)

    monkeypatch.setitem(registry._REGISTRY, "lm", registry._Entry(Spy, "tests.Spy"))
    res = robocal.calibrate(campaign, kr16, CalibrationConfig(max_iter=40))
    k = int(res.identified.sum())
    n_rigid = int(np.isin(np.array(res.model.kinds), ("base", "tool", "tool_rot")).sum())
    assert seen[0] == (n_rigid, 0.0, 100)  # the rigid fit: frames and tools, undamped (calibration.start.rigid_fit)
    assert seen[1] == (k, START_DAMPING, 40)  # the free parameters; calibrate's damping and budget
    assert res.solver is not None and res.solver.method == "lm" and res.solver.varied.size == k


@pytest.mark.parametrize("method", ["lm", "gn"])
def test_the_protocol_solve_is_the_least_squares_core_to_the_bit(campaign, kr16, method):
    """The solve through the protocol gives the core's fit bit for bit (same steps, point, residuals, Jacobian,
    covariance of the kept rows), also with rows left out (weighted zero in the problem, not data)."""
    cfg = CalibrationConfig(method=method)
    start = calibration_start(campaign, kr16, cfg)
    _, solve = gradient_fit(cfg, None)
    kept = start.kept.copy()
    for rows in (kept, np.where(np.isin(np.arange(start.m), [3, 17]), False, kept)):
        core = least_squares_on(
            start.fun, start.x_init, start.free, start.weights, start.rows, rows,
            max_iter=cfg.max_iter, ftol=cfg.ftol, xtol=cfg.xtol, method=method,
        )  # fmt: skip
        ours = solve(start, start.x_init, rows)
        assert (ours.nit, ours.nfev, ours.status, ours.ndata, ours.outliers) == (
            core.nit, core.nfev, core.status, core.ndata, core.outliers,
        )  # fmt: skip
        for field in ("x", "varied", "residual", "jacobian", "covariance"):
            np.testing.assert_array_equal(getattr(ours, field), getattr(core, field), err_msg=field)
        assert ours.chi2 == core.chi2 and ours.redchi == core.redchi
