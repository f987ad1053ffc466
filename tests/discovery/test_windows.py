"""Where the gear transmission error is applied (issue 33, a newcomer's second session): an angle one pose saw far
from the others is not a calibrated range; which windows the model uses is decided by the cross-validation; and a
frozen geometry stays frozen through every later refit."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.discovery import search as search_mod
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.physics import configurations, visited_intervals
from robocal.discovery.search import discover
from robocal.discovery.sessions import outside_calibrated

from .conftest import make_campaign, named

TRANSMISSION = {"transmission": {"joint": 2, "cycles": [17, 19], "amplitude_deg": 0.006}}
FAST = {"dictionary": False, "layer": False, "grow_max_steps": 4}


def test_an_interval_needs_its_visits():
    d = np.deg2rad
    q = d(np.array([10.0, 11.0, 12.0, 13.0, 50.0, 100.0, 101.0]))  # 50 deg: one visit
    assert visited_intervals(q, 5.0) == [[50.0, 50.0], [100.0, 101.0], [10.0, 13.0]]
    assert visited_intervals(q, 5.0, 2) == [[100.0, 101.0], [10.0, 13.0]]
    assert visited_intervals(q, 5.0, 3) == [[10.0, 13.0]]
    # a joint held at one angle by many configurations: visited there
    assert np.allclose(visited_intervals(d(np.full(8, 30.0)), 5.0, 3), [[30.0, 30.0]])
    # one visit per configuration: a pose measured on three targets is one visit
    Q = np.zeros((5, 2))
    Q[:, 0] = d([10.0, 10.0, 10.0, 11.0, 12.0])
    assert len(configurations(Q)) == 3
    assert visited_intervals(d(np.array([350.0, 355.0, 2.0, 5.0])), 10.0, 4) == [[350.0, 5.0]]  # wrapping: 4 angles
    assert visited_intervals(d(np.array([10.0, 11.0])), 5.0, 3) == []


def test_a_probe_where_one_calibration_pose_lay_is_outside_the_calibrated_angles():
    """One calibration row at q3 = 61.9 deg among hundreds at 0-40 deg made a probe at 62 deg "inside"."""
    rng = np.random.default_rng(1)
    q_cal = np.zeros((400, 6))
    q_cal[:, 2] = np.deg2rad(rng.uniform(0.0, 20.0, 400))
    q_cal[0, 2] = np.deg2rad(61.9)  # beyond the gap that joins visits (30 deg)
    probe = np.zeros((5, 6))
    probe[:, 2] = np.deg2rad([62.0, 61.0, 63.0, 10.0, 19.0])
    out = outside_calibrated(q_cal, probe)
    assert out[:3, 2].all() and not out[3:, 2].any()
    assert not out[:, [0, 1, 3, 4, 5]].any()  # joints held at one angle by every pose: visited there
    q_cal[1:3, 2] = np.deg2rad([61.0, 62.5])  # three poses there: a calibrated range
    assert not outside_calibrated(q_cal, probe)[:3, 2].any()


@pytest.fixture(scope="module")
def camp(tmp_path_factory):
    c, robot, _ = make_campaign(tmp_path_factory.mktemp("win"), "geometric", 3, TRANSMISSION, n_poses=90,
                                n_validation_poses=20)  # fmt: skip
    return c, robot


def test_the_window_is_chosen_by_the_cross_validation_and_kept(camp):
    c, robot = camp
    res = discover(c, robot, DiscoveryConfig.from_mapping({**FAST, "transmission_min_visits": [1, 2]}))
    rec = res.extra.get("transmission_window")
    assert rec is not None, "the premise: a random twin visits some joint angle alone, so the windows differ"
    cv, lp = rec["cv_mean_position_mm"], rec["lower_than_every_visit_log10_p"]
    assert set(cv) == {"1", "2"} and set(lp) == {"2"}
    two = cv["2"] < cv["1"] and lp["2"] < np.log10(0.01)  # cv_alpha: lower by the paired test, as an effect must
    assert rec["chosen_min_visits"] == (2 if two else 1)
    assert res.config.transmission_min_visits == (1, 2)  # the settings as given
    alone = discover(
        c, robot, DiscoveryConfig.from_mapping({**FAST, "transmission_min_visits": [rec["chosen_min_visits"]]})
    )
    assert "transmission_window" not in alone.extra
    assert named(res) == named(alone)
    np.testing.assert_array_equal(res.final.theta, alone.final.theta)  # the same search, not another one
    for a in res.accepted:
        if a.cand.effect == "transmission":
            assert a.cand.extra["min_visits"] == rec["chosen_min_visits"]


def test_a_frozen_geometry_stays_frozen_through_the_later_refits(camp, monkeypatch):
    """grow_geometry=frozen: the refit that holds the geometry (the selection's) is the one every later step
    uses — the equations, the held-out checks' drops, the layer (the final check refitted the geometry jointly: a
    newcomer's frozen model came out equal to the joint refit's to 1e-11, unsaid)."""
    c, robot = camp
    seen = {}
    real_grow, real_finish = search_mod.grow, search_mod.finish

    def spy_grow(state, pool, refit):
        seen["grow"] = refit
        return real_grow(state, pool, refit)

    def spy_finish(state):
        seen["finish"] = state.refit
        return real_finish(state)

    monkeypatch.setattr(search_mod, "grow", spy_grow)
    monkeypatch.setattr(search_mod, "finish", spy_finish)
    frozen = {**FAST, "grow_geometry": "frozen", "transmission_min_visits": [1]}
    discover(c, robot, DiscoveryConfig.from_mapping(frozen))
    assert seen["finish"] is seen["grow"]
    discover(c, robot, DiscoveryConfig.from_mapping({**FAST, "transmission_min_visits": [1]}))  # joint: one refit
    assert seen["finish"] is seen["grow"]
