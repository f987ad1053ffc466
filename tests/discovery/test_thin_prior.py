"""Discovery on a thin campaign whose geometry calibrate identified with a prior toward nominal (issue 33).

The geometry's parameters under that prior were listed twice among the discovered fit's free parameters (kept by
the rank test and again as prior-determined), so ``calibration.json``'s correlation matrix had more rows than
identified parameters and ``robocal discover`` stopped writing it (a newcomer's 15 configurations of UR10 B)."""

from __future__ import annotations

import json

import numpy as np

import robocal
from robocal.cli import main
from robocal.sim.scenario import load_scenario


def test_discover_on_a_thin_campaign_with_the_prior_writes_a_calibration_that_reads_back(tmp_path):
    data, out = tmp_path / "thin", tmp_path / "out"
    robocal.simulate(load_scenario("thin"), data, seed=0)
    rc = main(["discover", str(data), "--robot", "kr16_2", "--out", str(out), "--no-report"])
    assert rc == 0
    cal = json.loads((out / "calibration.json").read_text())
    geo = json.loads((out / "discovery.json").read_text())
    assert geo["n_rows"] > 0
    # the thin campaign's geometry had its prior (else this test tests nothing)
    res = robocal.calibrate(robocal.read_campaign(data, robocal.load_robot("kr16_2")), robocal.load_robot("kr16_2"))
    assert (res.fit["configurations"].get("prior") or {}).get("strength", 0) > 0, res.fit["configurations"]
    k = sum(p["status"] == "identified" for p in cal["parameters"])
    assert np.asarray(cal["correlation"]["matrix"]).shape == (k, k)
    assert len(set(cal["correlation"]["names"])) == k
    loaded = robocal.load_calibration(cal, robocal.load_robot("kr16_2"))
    assert loaded.covariance.shape == (k, k)
