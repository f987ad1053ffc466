"""Discovery on real data: the ABB IRB 120 of Wu et al. (../shared/data/abb-irb120; skipped without it).

The geometric model validates at 0.317 mm mean on target T4 (issue 12: the extended model must reach
<= 0.25 mm, validated exactly as ``calibrate`` validates: T4's tool from its zero-joint row, the same rows).
With the repository's robot description (link masses: an engineering estimate), discovery names the deflection of
joints 2 and 3 under the arm's weight (the weight model: the torque of those masses and the combinations that
correct them): the joints that carry the arm's weight.
"""

from __future__ import annotations

import functools

import pytest

from robocal.calibration.fit import calibrate
from robocal.calibration.validation import validate
from robocal.data import read_campaign
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors
from robocal.robot import load_robot


@functools.lru_cache(maxsize=1)
def _run(folder: str):
    robot = load_robot("abb_irb120")
    camp = read_campaign(folder, robot)
    res = discover(camp, robot)
    return camp, robot, summary(res, validation_errors(res))


@pytest.fixture()
def abb_discovery(shared_dir):
    d = shared_dir / "data" / "abb-irb120"
    if not (d / "poses.csv").is_file():
        pytest.skip(f"{d} has no poses.csv")
    return _run(str(d))


def test_discovered_model_validates_better_on_t4(abb_discovery):
    camp, robot, s = abb_discovery
    v = s["validation"]
    # the geometric part is validated exactly as calibrate validates it (same rows, same T4 tool handling)
    geo = calibrate(camp, robot, None)
    ref = validate(geo, camp)
    assert v["geometric"]["n_rows"] == ref["n_rows"] == 10
    assert v["geometric"]["tool_source"]["T4"] == ref["tool_source"]["T4"]
    assert v["discovered"]["mean_position_mm"] <= 0.25, v
    assert v["discovered"]["max_position_mm"] < v["geometric"]["max_position_mm"]


def test_named_effects_are_physical(abb_discovery):
    _, _, s = abb_discovery
    named = {n["key"]: n for n in s["named"]}
    # the weight model of joints 2 and 3 (the torque of the description's masses and the combinations that correct
    # them: held out 0.134 mm, where the compliance from those masses alone, named before it was offered, had 0.164)
    assert {"weight:j2", "weight:j3"} <= set(named)
    for k in ("weight:j2", "weight:j3"):
        e = named[k]["estimates"]
        # a deflection clearly above its standard error, of a physical size
        assert e["rms_deflection_deg"]["value"] > 5 * e["rms_deflection_deg"]["stderr"] > 0
        assert e["physical"]["value"] is True
