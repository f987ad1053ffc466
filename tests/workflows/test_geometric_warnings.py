"""A campaign that states each point's uncertainty (``u_mm``) far from the noise the fit weights by is told so
(newcomer pass 9: a total station's 0.74 mm U95 beside the configured 0.015 mm, silently: the noise floor, the
gross-error test and the thin campaign's prior were judged against a noise 25 times too small)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

import robocal
from robocal.data.contract import read_campaign
from robocal.workflows.geometric import unused_uncertainty


def test_a_u_mm_column_far_from_the_noise_used_is_said(tmp_path):
    rob = robocal.load_robot("kr16_2")
    robocal.simulate({"name": "geometric", "robot": "kr16_2", "n_poses": 20, "n_validation_poses": 5}, tmp_path)
    camp = read_campaign(tmp_path, rob)
    assert unused_uncertainty(camp, 0.015, "constant", 2.0, "calibration") == []  # no column: nothing to say
    tracker = replace(camp, u_mm=np.full(camp.n_rows, 0.03))  # a tracker's U95 (0.015 mm per coordinate)
    assert unused_uncertainty(tracker, 0.015, "constant", 2.0, "calibration") == []
    station = replace(camp, u_mm=np.full(camp.n_rows, 0.735))
    (w,) = unused_uncertainty(station, 0.015, "constant", 2.0, "calibration")
    assert "24.5 times" in w and "noise_model=u_mm" in w
    (w,) = unused_uncertainty(station, 0.015, "constant", 2.0, "discovery")
    assert "noise_model=u_mm" not in w and "discovery.*" in w
    assert unused_uncertainty(station, 0.015, "u_mm", 2.0, "calibration") == []  # used: nothing to say
    assert unused_uncertainty(station, 0.4, "constant", 2.0, "calibration") == []  # noise_mm set near it


def test_calibrate_says_when_its_residuals_imply_a_noise_far_above_the_one_used():
    """Newcomer pass 9: reduced chi² 47 (a heavy arm's weight deflection) and 7 683 (a column's tilt) with status ok
    and nothing on the console; the console now says the model misfits (status and summary.json as before)."""
    from robocal.commands.calibrate import misfit_hint

    def noise(implied: float) -> dict:
        return {"used_mm": 0.0179, "routes": {"fit": {"sigma_mm": implied}}}

    line = misfit_hint(noise(0.103))
    assert line is not None and "5.75 times" in line and "robocal discover" in line
    assert misfit_hint(noise(0.03)) is None  # within twice the noise: a fit at its floor says nothing
    assert misfit_hint({}) is None


def test_the_u_mm_warning_judges_the_noise_the_fit_weighted_by(tmp_path):
    """Newcomer pass 11: a total station's campaign (0.1 mm per coordinate, u_mm 0.2 at k = 2) was weighted by
    the noise its three reflectors show (~0.1 mm, the larger of it and the configured 0.015) and then warned that
    u_mm was "6.67 times the noise this fit weights by (0.015 mm)": the warning now reads the noise used."""
    from robocal.workflows import discovery, geometric

    targets = {"T1": [150.0, 0.0, 120.0], "T2": [-80.0, 130.0, 110.0], "T3": [-80.0, -130.0, 100.0]}
    sc = {"name": "geometric", "robot": "kr16_2", "n_poses": 40, "n_validation_poses": 5, "noise_mm": 0.1,
          "targets": targets}  # fmt: skip
    robocal.simulate(sc, tmp_path / "data")
    rob = robocal.load_robot("kr16_2")
    camp = read_campaign(tmp_path / "data", rob)
    camp = replace(camp, u_mm=np.full(camp.n_rows, 0.2))
    summ = geometric.run(None, rob, tmp_path / "cal", campaign=camp, report=False)
    assert not any("u_mm" in w for w in summ.get("warnings", [])), summ.get("warnings")
    disc = discovery.run(None, rob, tmp_path / "disc", {"dictionary": False, "layer": False}, campaign=camp,
                         report=False)  # fmt: skip
    assert disc["noise_mm"] > 0.05  # the reflectors' spread, not the configured 0.015
    assert not any("u_mm" in w for w in disc.get("warnings", [])), disc.get("warnings")


def test_gross_errors_in_a_campaign_of_logged_signals_are_said_to_maybe_be_their_effect(tmp_path):
    """Newcomer pass 13: calibrate left out a lifting column's most tilted pose (0.8 mm) as gross errors beside a
    declared tilt signal it does not model (discover, taking the signal, flagged nothing)."""
    from robocal.workflows.geometric import signals_not_modelled

    rob = robocal.load_robot("kr16_2")
    scen = {"name": "geometric", "robot": "kr16_2", "n_poses": 20, "n_validation_poses": 5,
            "effects": {"compliant_stand": {}}}  # fmt: skip
    robocal.simulate(scen, tmp_path)
    camp = read_campaign(tmp_path, rob)
    flagged = [{"row": 3}, {"row": 4}]
    (w,) = signals_not_modelled(camp, rob, flagged)
    assert w.startswith("2 row(s) left out as gross errors") and "incl_x" in w and "robocal discover" in w
    assert signals_not_modelled(camp, rob, []) == []  # nothing left out: nothing to say
    plain = replace(camp, extra={})
    assert signals_not_modelled(plain, rob, flagged) == []  # no logged signal: a gross error is one
