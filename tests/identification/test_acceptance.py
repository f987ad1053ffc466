"""One acceptance rule (robocal.identification.acceptance) for the geometric workflow and the fleet."""

from __future__ import annotations

import pytest

from robocal.config import SettingError
from robocal.fleet.engine import accept
from robocal.identification.acceptance import FLEET, AcceptanceRules, judge
from robocal.workflows.geometric import result_problems

FIT = {"success": True, "message": "ok", "nit": 3, "rms_position_mm": 0.10, "before": {"rms_position_mm": 0.90}}


def test_the_baseline_is_the_start_on_the_same_kept_rows():
    # worse than its start on the kept rows, better than the all-rows start (which holds the gross errors the fit
    # left out): the workflow compared with the latter and called it ok; both levels now fail it the same way
    fit = {**FIT, "rms_position_mm": 1.0}
    summary = {"fit": fit, "start_rms_position_mm": 5.0}
    (text,) = result_problems(summary)
    assert text == "the fit's RMS error 1.0000 mm is worse than its start (0.9000 mm)"
    assert accept(fit, {}, {}) == (False, text)


def test_levels_differ_only_where_configured():
    stopped = {**FIT, "success": False, "message": "the maximum number of iterations was reached", "nit": 1}
    v = judge(stopped)
    assert v.acceptable and v.warnings[0].startswith("the fit did not converge: the maximum number of iterations")
    fleet = judge(stopped, rules=AcceptanceRules.from_mapping(FLEET))
    assert not fleet.acceptable and fleet.problems == v.warnings  # the same sentence, another level
    suspects = {**FIT, "outlier_suspects": [{"row": 2}]}
    assert judge(suspects).acceptable and not judge(suspects, rules=AcceptanceRules.from_mapping(FLEET)).acceptable


def test_ratio_and_validation_limits():
    rules = AcceptanceRules(max_rms_ratio=0.1, max_validation_mean_mm=0.05)
    v = judge(FIT, {"mean_position_mm": 0.2, "max_position_mm": 0.5}, {"mean_position_mm": 0.1}, rules)
    assert v.problems == (
        "the fit's RMS error 0.1000 mm is worse than 0.1 x its start (0.9000 mm)",
        "on the validation poses the calibrated model (0.2000 mm mean error) is worse than the nominal one (0.1000 mm)",
        "validation mean error 0.2000 mm above the limit 0.05 mm",
    )
    with pytest.raises(SettingError, match="not_converged"):
        AcceptanceRules.from_mapping({"not_converged": "maybe"})


def test_a_model_that_starts_where_it_ends_is_not_worse_than_its_start():
    # a calibration re-read from its own calibrated URDF: validation 0.27666278545 vs start 0.27666278132 mm
    # (round-off) failed as "worse than the nominal one"; worse by 1 ppm or more still fails
    fit = {**FIT, "rms_position_mm": 0.2132, "before": {"rms_position_mm": 0.2132}}
    assert judge(fit, {"mean_position_mm": 0.27666278545}, {"mean_position_mm": 0.27666278132}).acceptable
    assert not judge(fit, {"mean_position_mm": 0.2767}, {"mean_position_mm": 0.2766}).acceptable
