"""One result type (issue 32): a calibration carries its covariance, standard errors, χ², degrees of freedom and the
solve's status as attributes, the same for a fitted calibration and one read back from ``calibration.json``; the fit
record (the file's ``fit``) keeps its keys and their order."""

from __future__ import annotations

import json

import numpy as np
import pytest

import robocal
from robocal.calibration.load import load_calibration
from robocal.data.contract import read_campaign
from robocal.sim.twin import load_scenario, simulate

ATTRIBUTES = ("chi2", "dof", "reduced_chi2", "status", "message", "success", "nit", "nfev")


@pytest.fixture(scope="module")
def fitted(tmp_path_factory, kr16):
    out = tmp_path_factory.mktemp("twin")
    sc = load_scenario("geometric")
    sc.update(n_poses=30, n_validation_poses=0)
    simulate(sc, out, seed=3)
    return robocal.calibrate(read_campaign(out, kr16), kr16)


def test_the_figures_are_attributes(fitted):
    res = fitted
    assert res.solver is not None
    assert (res.status, res.message, res.success, res.nit, res.nfev) == (
        res.solver.status, res.solver.message, res.solver.success, res.solver.nit, res.solver.nfev,
    )  # fmt: skip
    assert res.chi2 == res.fit["chi2"] and res.dof == res.fit["dof"] and res.reduced_chi2 == res.chi2 / res.dof
    k = int(res.identified.sum())
    assert res.covariance.shape == (k, k)
    np.testing.assert_array_equal(res.stderr[res.identified], np.sqrt(np.diag(res.covariance)))
    assert np.isnan(res.stderr[~res.identified]).all()


def test_a_calibration_read_back_has_the_same_attributes(fitted, kr16):
    record = json.loads(json.dumps(fitted.to_dict(), default=float))
    back = load_calibration(record, kr16)
    assert back.solver is None
    for name in ATTRIBUTES:
        assert getattr(back, name) == getattr(fitted, name), name
    np.testing.assert_allclose(back.stderr, fitted.stderr, rtol=1e-12)  # read back from the file's JSON floats


def test_the_record_keeps_its_keys_and_order(fitted):
    keys = list(fitted.fit)
    i = keys.index("n_eliminated")
    assert keys[i + 1 : i + 6] == ["nit", "nfev", "status", "message", "success"]
    assert keys[keys.index("wall_time_s") + 1] == "solver_time_s"
    assert keys[:3] == ["n_rows", "n_residuals", "n_params"]


def test_another_solve_takes_the_records_figures_in_place(fitted):
    assert fitted.solver is not None
    other = fitted.solver.evolve(nit=7, nfev=9, status=2)
    moved = fitted.with_solver(other)
    assert (moved.nit, moved.nfev, moved.status, moved.solver) == (7, 9, 2, other)
    assert list(moved.fit) == list(fitted.fit)  # the same keys in the same places
    assert fitted.nit == fitted.solver.nit  # the original is unchanged
