"""``grow_geometry: auto`` (issue 33): the selection searched with the geometry refitted jointly and frozen, frozen
kept when its pose-grouped cross-validated error is significantly lower — the same result as that mode run alone,
both figures recorded."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors

from .conftest import make_campaign, named

GEAR = {"gear": {"joint": 4, "harmonics": [{"harmonic": 1, "amplitude_deg": 0.006, "phase_deg": 30.0}]}}
FAST = {"dictionary": False, "layer": False, "grow_max_steps": 3}


@pytest.fixture(scope="module")
def camp(tmp_path_factory):
    c, robot, _ = make_campaign(tmp_path_factory.mktemp("auto"), "geometric", 2, GEAR, n_poses=80,
                                n_validation_poses=20)  # fmt: skip
    return c, robot


def test_auto_keeps_the_mode_with_the_lower_cross_validated_error(camp):
    c, robot = camp
    auto = discover(c, robot, DiscoveryConfig.from_mapping({**FAST, "grow_geometry": "auto"}))
    rec = auto.extra["grow_geometry"]
    cv = rec["cv_mean_position_mm"]
    assert set(cv) == {"joint", "frozen"} and all(np.isfinite(v) for v in cv.values())
    # frozen only when lower by the paired test per pose group at cv_alpha (0.01), as an effect must be
    frozen = cv["frozen"] < cv["joint"] and rec["frozen_lower_log10_p"] < np.log10(0.01)
    assert rec["chosen"] == ("frozen" if frozen else "joint")
    assert auto.config.grow_geometry == "auto"  # the settings as given, not the mode kept
    alone = discover(c, robot, DiscoveryConfig.from_mapping({**FAST, "grow_geometry": rec["chosen"]}))
    assert named(auto) == named(alone)
    np.testing.assert_array_equal(auto.final.theta, alone.final.theta)  # the same search, not another one
    assert summary(auto, validation_errors(auto))["grow_geometry"]["chosen"] == rec["chosen"]


def test_without_auto_nothing_is_recorded(camp):
    c, robot = camp
    res = discover(c, robot, DiscoveryConfig.from_mapping(FAST))
    assert "grow_geometry" not in res.extra
