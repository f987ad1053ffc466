"""A second session months later (issue 33 item 5): the twin's ``second_session`` effect (another tracker
placement, the tool re-seated, a warmer cell) and what robocal makes of it — the calibration of the first session
judged in the second, and discovery over both naming the re-seated tool as the session's own."""

from __future__ import annotations

import numpy as np
import pytest

import robocal
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.search import discover
from robocal.discovery.session_cv import session_own
from robocal.discovery.sessions import session_validation
from robocal.discovery.summary import summary
from robocal.errors import ConfigError

from .conftest import make_campaign

#: fewer poses than the scenario's 160 + 60 (fast), still 40 calibration poses per session
SMALL = {"n_poses": 80, "n_validation_poses": 40}
#: no discovery extras the tests do not look at (fast)
QUICK = {"dictionary": False, "layer": False}


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    camp, robot, truth = make_campaign(tmp_path_factory.mktemp("two"), "second_session", 0, **SMALL)
    st = np.asarray(camp.station).astype(str)
    return camp, robot, truth, camp.subset(st == "S1"), camp.subset(st == "S2")


def test_the_twin_measures_a_second_session_months_later_from_another_placement(sessions):
    camp, _robot, truth, s1, s2 = sessions
    assert camp.station_names == ("S1", "S2")
    assert s1.n_rows == s2.n_rows == 60  # half of each split's poses in each session
    assert set(np.asarray(s2.split).astype(str)) == {"calibration", "validation"}
    days = (np.min(s2.timestamp_s) - np.max(s1.timestamp_s)) / 86400.0
    assert 119.9 < days < 120.0  # the second session starts 120 days after the first one did
    air = np.asarray(camp.extra["air_T_C"], dtype=float)
    st = np.asarray(camp.station).astype(str)
    assert abs(air[st == "S2"].mean() - air[st == "S1"].mean() - 4.0) < 0.1  # the cell 4 °C warmer
    e = truth["effects"]["second_session"]
    assert e["tool_shift_mm"] == [0.12, -0.08, 0.18]
    assert set(truth["stations_T_base"]) == {"S1", "S2"}


def test_the_first_sessions_calibration_holds_in_the_second_once_its_tool_is_re_measured(sessions):
    _camp, robot, _truth, s1, s2 = sessions
    geo = robocal.calibrate(s1, robot)
    within = session_validation(geo, s1)["final"]["mean_position_mm"]
    tracker = session_validation(geo, s2)["final"]["mean_position_mm"]
    both = session_validation(geo, s2, tool=True)["final"]["mean_position_mm"]
    # the tool moved 0.23 mm: registering the tracker alone leaves most of it (> 0.15 mm); re-measuring the tool
    # too leaves the noise floor (within S1, ~0.025 mm) plus the 46 ppm expansion the rigid registration cannot
    # take (~0.02 mm over this reach), so below 0.08 mm and far below the tracker-only figure
    assert tracker > 0.15
    assert both < 0.08 and both < tracker / 3
    assert within < 0.035


def test_discovery_over_both_sessions_names_the_re_seated_tool_as_the_sessions_own(sessions):
    camp, robot, truth, _s1, _s2 = sessions
    res = discover(camp, robot, DiscoveryConfig.from_mapping(QUICK))
    s = summary(res)
    keys = [n["key"] for n in s["named"]]
    assert "session:S2:tool" in keys
    n = next(n for n in s["named"] if n["key"] == "session:S2:tool")
    assert n["side"] == "session"
    shift = np.array(truth["effects"]["second_session"]["tool_shift_mm"])
    for k, a in enumerate("xyz"):
        est = n["estimates"][f"tool_t{a}_mm"]
        # within 4 standard errors plus 0.01 mm: the tool itself grows 46 ppm in S2 (0.006 mm over its 140 mm)
        assert abs(est["value"] - shift[k]) < 4 * est["stderr"] + 0.01, (a, est, shift[k])
    # never sent to the controller: not among the compensated effects
    assert all(r["key"] != "session:S2:tool" for r in res.extra.get("effect_records", []))
    assert s["cross_validation"]["session_cv"]["sessions"] == ["S1", "S2"]
    # the geometric model's new-session figure is judged like the discovered one's, its tool re-measured there too
    # (newcomer pass 15: it kept the old tool, 0.2659 beside 0.0655, the gap the tool's, not the effects'): within
    # 10 % of the discovered model's (0.0577 both: the sessions' own effects are not carried into a new session, so
    # what is judged there is the geometry with its tool re-measured; the old tool's figure was ~4x)
    sc, gc = s["cross_validation"]["session_cv"], s["cross_validation"]["geometric_session_cv"]
    assert gc["tool_re_measured"] is True
    assert gc["mean_position_mm"] < 1.1 * sc["mean_position_mm"]


def test_two_sessions_with_the_same_tool_name_no_re_seated_tool(tmp_path):
    # the null: the same two sessions, the tool left alone, the same air, the robot not growing; at the 0.001 level over
    # two seeds (a false alarm on either fails the test)
    for seed in (1, 2):
        quiet = {"tool_shift_mm": [0.0, 0.0, 0.0], "air_C": [20.0, 20.0], "expansion_ppm_per_C": 0}
        effects = {"second_session": quiet}
        camp, robot, _ = make_campaign(tmp_path, "second_session", seed, effects, **SMALL)
        res = discover(camp, robot, DiscoveryConfig.from_mapping(QUICK))
        assert not any(a.cand.effect == "session" for a in res.accepted), seed


def test_a_re_seated_tool_is_offered_only_between_sessions_large_enough_to_hold_it(sessions, tmp_path):
    from robocal.discovery.candidates import build_library

    camp, robot, _truth, s1, _s2 = sessions
    cfg = DiscoveryConfig.from_mapping(QUICK)
    cands, _ = build_library(camp, robot, cfg)
    assert [c.key for c in cands if c.effect == "session"] == ["session:S2:tool"]
    cands, _ = build_library(s1, robot, cfg)  # one session: nothing to re-seat
    assert not [c for c in cands if c.effect == "session"]
    st = np.asarray(camp.station).astype(str)
    few = camp.subset((st == "S1") | (np.cumsum(st == "S2") <= 10))  # S2 with 10 rows: below the 20 it needs
    cands, skipped = build_library(few, robot, cfg)
    assert not [c for c in cands if c.effect == "session"]
    assert any(k.key == "session:tool" and "fewer than two sessions" in k.reason for k in skipped)


def test_the_sessions_own_effects_are_not_carried_into_a_new_session():
    from robocal.discovery.candidates import Candidate

    def cand(effect, **extra):
        return Candidate(f"{effect}:x", effect, None, None, "", "", "frame", np.zeros((1, 1)), extra=extra)

    assert session_own(cand("scale")) and session_own(cand("drift")) and session_own(cand("session"))
    assert session_own(cand("signal", side="measurement"))
    assert not session_own(cand("signal", side="robot")) and not session_own(cand("weight"))


def test_a_bad_second_session_setting_is_named(tmp_path):
    with pytest.raises(ConfigError, match="'share' setting of the second_session"):
        make_campaign(tmp_path, "second_session", 0, {"second_session": {"share": 1.5}}, **SMALL)


def test_a_temperature_that_changes_only_between_sessions_offers_no_thermal_model(sessions):
    """Newcomer pass 13: a cell 5 °C warmer in the second session, one temperature a session, gave a thermal model
    (every parameter following the temperature: each session's own geometry) that took the re-seated tool in and
    was expected to miss by 1.0 mm in a new session where the geometry alone gave 0.23. Such a log offers no
    thermal model, said why; one that also changes within the sessions still does."""
    from dataclasses import replace

    from robocal.discovery.candidates import build_library

    camp, robot, _truth, _s1, _s2 = sessions
    air = np.asarray(camp.extra["air_T_C"], dtype=float)  # 4 °C between the sessions, a slow wander within
    between = replace(camp, temperatures=air[:, None], sensor_names=("T_cell",))
    cands, skipped = build_library(between, robot, DiscoveryConfig())
    assert "thermal" not in {c.key for c in cands}
    (why,) = [s.reason for s in skipped if s.key == "thermal"]
    assert "change between the sessions" in why and "session effects are offered instead" in why
    assert "session:S2:tool" in {c.key for c in cands}
    # warming up within each session as well (a 3 °C ramp over each one's rows): a thermal model is offered
    st = np.asarray(camp.station).astype(str)
    ramp = np.concatenate([np.linspace(0.0, 3.0, int(np.sum(st == s))) for s in ("S1", "S2")])
    within = replace(camp, temperatures=(air + ramp)[:, None], sensor_names=("T_cell",))
    assert "thermal" in {c.key for c in build_library(within, robot, DiscoveryConfig())[0]}


def test_a_model_worse_in_a_new_session_than_the_geometry_is_said():
    from robocal.discovery.validate import worse_than_geometry

    cv = {"session_cv": {"sessions": ["S1", "S2"], "mean_position_mm": 1.0046},
          "geometric_session_cv": {"sessions": ["S1", "S2"], "mean_position_mm": 0.2261}}  # fmt: skip
    (said,) = worse_than_geometry(None, cv)
    assert "new session" in said and "1.0046" in said and "0.2261" in said
    cv["session_cv"]["mean_position_mm"] = 0.0544
    assert worse_than_geometry(None, cv) == []


def test_a_model_worse_than_calibrates_axes_fit_is_said():
    """Newcomer pass 17: a track arm without its inclinometer, discover 0.1679 mm held-out where calibrate (the
    linear axes' errors fitted, which the search starts without) gave 0.1523, written without a word."""
    from robocal.discovery.validate import worse_than_geometry

    val = {"geometric": {"mean_position_mm": 0.3069, "with_axes": {"mean_position_mm": 0.1523}},
           "final": {"mean_position_mm": 0.1679, "n_rows": 90}}  # fmt: skip
    (said,) = worse_than_geometry(val, {})
    assert "linear axes" in said and "0.1679" in said and "0.1523" in said
    val["final"]["mean_position_mm"] = 0.1500
    assert worse_than_geometry(val, {}) == []
    del val["geometric"]["with_axes"]  # no axes: the discovered model beats the geometric one, nothing said
    val["final"]["mean_position_mm"] = 0.1679
    assert worse_than_geometry(val, {}) == []


def test_a_signal_declared_in_an_angles_near_miss_is_said():
    """Newcomer pass 18: ``unit: mard`` was accepted without a word, its effects printed "per mard" with no gain."""
    from robocal.discovery.validate import unknown_units

    rec = {"used": [{"column": "incl_x", "declared": True, "unit": "mard"},
                    {"column": "incl_y", "declared": True, "unit": "mrad"},
                    {"column": "acc_x", "declared": True, "unit": "m/s^2"},
                    {"column": "air", "declared": True, "unit": "degC"},
                    {"column": "other", "declared": False, "unit": None}]}  # fmt: skip
    (said,) = unknown_units(rec)
    assert "incl_x" in said and "'mard'" in said and "did you mean 'mrad'" in said
    assert unknown_units(None) == []
