"""The calibration model's Jacobians taken in row chunks (issue 31: the chain's recorded frames and the point
Jacobians' temporaries bounded, not ~10 arrays of every row): the same numbers to the bit, with one station or
two, positions or poses; and a candidate's signals at the fit rows read without their copy
(:class:`robocal.discovery.gram.RowsOf`)."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.start import fit_data, present_stations, present_targets
from robocal.discovery.gram import RowsOf
from robocal.identification import model as model_mod

from .conftest import make_campaign

TWO_STATIONS = {"S2": {"xyz_mm": [-2500.0, 1800.0, -300.0], "rpy_deg": [0.5, -0.3, 140.0]}}


@pytest.fixture(scope="module", params=[(False, False), (True, True)], ids=["position-1-station", "pose-2-stations"])
def problem(request, tmp_path_factory):
    orientation, two = request.param
    over = {"orientation": orientation, "n_poses": 90}
    if two:
        over["stations"] = TWO_STATIONS
    camp, robot, _ = make_campaign(tmp_path_factory.mktemp("chunks"), "geometric", 4, None, **over)
    geo = calibrate(camp, robot, CalibrationConfig(noise_mm=0.015))
    data = fit_data(camp, use_orientation=orientation, targets=present_targets(camp), stations=present_stations(camp))
    assert geo.model.n_stations == (2 if two else 1)
    return geo.model, geo.x, data


def test_jacobians_in_row_chunks_are_the_whole_ones_to_the_bit(problem, monkeypatch):
    model, x, data = problem
    x = x + 1e-6 * np.random.default_rng(0).normal(size=len(x))
    whole = model.residuals_and_jacobian(x, data), model.joint_jacobians(x, data)
    whole_q = model.joint_jacobian(x, data.q, data.target_index, data.station_index)
    assert data.m > 40  # more rows than the chunk below: several chunks per station
    monkeypatch.setattr(model_mod, "CHUNK_ROWS", 17)
    (r, J), (Jq, Wq) = model.residuals_and_jacobian(x, data), model.joint_jacobians(x, data)
    (r0, J0), (Jq0, Wq0) = whole
    np.testing.assert_array_equal(r, r0)
    np.testing.assert_array_equal(J, J0)
    np.testing.assert_array_equal(Jq, Jq0)
    assert (Wq is None) == (Wq0 is None)
    if Wq is not None:
        np.testing.assert_array_equal(Wq, Wq0)
    np.testing.assert_array_equal(model.joint_jacobian(x, data.q, data.target_index, data.station_index), whole_q)


def test_rows_of_reads_the_rows_of_a_fold_without_copying_the_signals():
    S = np.arange(40.0).reshape(10, 4)
    rows = np.array([1, 3, 4, 8])
    view = RowsOf(S, rows)
    assert view.shape == (4, 4) and view.S is S
    np.testing.assert_array_equal(view[np.array([0, 2])], S[[1, 4]])
    mask = np.zeros(10, dtype=bool)
    mask[rows] = True
    np.testing.assert_array_equal(RowsOf(S, mask)[np.arange(4)], S[rows])  # a row mask reads as its indices
