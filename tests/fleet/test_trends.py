"""The trend tests on synthetic recalibrations with known standard errors: the null keeps its false-flag rate,
jumps and drifts are named."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.errors import ConfigError
from robocal.fleet.trends import analyse

DATES = ["2026-01-05", "2026-04-06", "2026-07-06"]


def _robot(values, stderr, name="theta2"):
    """Summaries of one robot whose parameter ``name`` takes ``values`` (deg) with ``stderr``."""
    return [
        {
            "date": d,
            "accepted": True,
            "parameters": [
                {"name": name, "kind": "kinematic", "unit": "deg", "value": v, "stderr": s, "status": "identified"},
                {
                    "name": "base_tx",
                    "kind": "base",
                    "unit": "mm",
                    "value": 100.0 * k,
                    "stderr": 0.01,
                    "status": "identified",
                },
            ],
        }
        for k, (d, v, s) in enumerate(zip(DATES, values, stderr, strict=True))
    ]


def test_null_fleet_keeps_the_family_wise_rate():
    # 20 fleets of 100 robots x 5 parameters with exact normal noise and no event: Bonferroni at alpha = 0.2 allows
    # at most 20 % of fleets with any flag (a little less: the tests are positively correlated); under that rate 9
    # or more flagged fleets out of 20 happen with probability < 1 %, so the bound tested is 9.
    rng = np.random.default_rng(1)
    flagged_fleets = 0
    for _ in range(20):
        fleet = {}
        for r in range(100):
            s = rng.uniform(0.001, 0.01, 3)
            summ = _robot(rng.normal(0.0, s), s)
            for p in range(1, 5):  # more parameters on the same campaigns
                s2 = rng.uniform(0.001, 0.01, 3)
                for k, v in enumerate(rng.normal(0.0, s2)):
                    summ[k]["parameters"].append(
                        {
                            "name": f"a{p}",
                            "kind": "kinematic",
                            "unit": "mm",
                            "value": v,
                            "stderr": s2[k],
                            "status": "identified",
                        }
                    )
            fleet[f"R{r}"] = summ
        res = analyse(fleet, alpha=0.2)
        flagged_fleets += bool(res["flags"])
    assert res["test"]["n_tests"] == 100 * 5 * 3  # two steps and one trend per parameter; base parameters not tested
    assert flagged_fleets < 9


@pytest.mark.parametrize(
    ("values", "kind"),
    [
        ([0.0, 0.0, 0.05], "jump"),  # a zero offset re-mastered before the third campaign
        ([0.0, 0.05, 0.05], "jump"),
        ([0.0, 0.03, 0.06], "drift"),  # the same change every quarter
        ([0.0, 0.06, 0.0], "change"),  # neither one step nor a line: the middle campaign is suspect
    ],
)
def test_patterns_are_named(values, kind):
    res = analyse({"R1": _robot(values, [0.002] * 3)})
    (flag,) = res["flags"]
    assert flag["serial"] == "R1" and flag["parameter"] == "theta2" and flag["kind"] == kind
    assert flag["explanation"]


def test_unmoved_parameters_and_rejected_campaigns_are_quiet():
    summ = _robot([0.0, 0.001, 0.2], [0.002] * 3)
    summ[2]["accepted"] = False  # a rejected calibration is not evidence of a move
    res = analyse({"R1": summ})
    assert res["flags"] == [] and res["robots"]["R1"]["dates"] == DATES[:2]
    with pytest.raises(ConfigError, match="alpha"):
        analyse({"R1": summ}, alpha=0.0)
