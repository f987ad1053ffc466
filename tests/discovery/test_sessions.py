"""A calibration judged on another session (robocal.discovery.sessions, issue 33 item 2)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from robocal.calibration.fit import calibrate
from robocal.calibration.validation import validate
from robocal.discovery.sessions import predicted_flanges, predicted_points, session_validation
from robocal.errors import DataError
from robocal.kinematics.transforms import homogeneous, rotvec_to_matrix

from .conftest import make_campaign


def _moved(camp, T):  # type: ignore[no-untyped-def]
    """The same session seen by a tracker at another placement (every measured point moved rigidly)."""
    return replace(camp, p_mm=camp.p_mm @ T[:3, :3].T + T[:3, 3])


def test_another_tracker_placement_changes_nothing(tmp_path: Path) -> None:
    camp, robot, _ = make_campaign(tmp_path, "geometric", 11, {}, n_poses=40, n_validation_poses=15)
    cal = calibrate(camp, robot)
    # the model's predictions, registered by calibrate's own tracker frame, are validate's figures
    pred = predicted_points(cal, camp.validation(), ())
    T = cal.tracker_T_base
    direct = np.linalg.norm(pred @ T[:3, :3].T + T[:3, 3] - camp.validation().p_mm, axis=1)
    assert np.mean(direct) == pytest.approx(validate(cal, camp)["mean_position_mm"], rel=1e-9)
    # a session from another placement: its tracker registered on its own calibration rows, same errors whatever
    # the placement (the registration is exact for a rigid move; 1e-9 mm is float noise on metre-sized points)
    here = session_validation(cal, camp, cal)
    moved = _moved(camp, homogeneous(rotvec_to_matrix(np.array([0.3, -1.2, 2.0])), np.array([2500.0, -800.0, 40.0])))
    there = session_validation(cal, moved, cal)
    assert there["final"]["mean_position_mm"] == pytest.approx(here["final"]["mean_position_mm"], abs=1e-9)
    assert here["n_registration_rows"] == int(np.sum(camp.split == "calibration"))
    assert here["n_validation_rows"] == int(np.sum(camp.split == "validation"))
    # the geometric calibration has no effects: nothing to leave out, nothing helped or hurt
    assert here["without"] == {} and here["helped"] == [] and here["hurt"] == []
    # registered on the session's own rows, a model near the truth is near the noise (0.015 mm per coordinate:
    # mean 3-D error ~0.024 mm; 0.05 mm allows the calibration's own error on 15 held-out poses)
    assert here["final"]["mean_position_mm"] < 0.05


def test_a_session_of_unknown_targets_or_too_few_rows_is_refused(tmp_path: Path) -> None:
    camp, robot, _ = make_campaign(tmp_path, "geometric", 12, {}, n_poses=30, n_validation_poses=5)
    cal = calibrate(camp, robot)
    other = replace(camp, target=np.full(camp.n_rows, "SMR9", dtype=object))
    with pytest.raises(DataError, match="SMR9"):
        session_validation(cal, other)
    few = camp.subset(np.flatnonzero(camp.split == "validation")[:2])
    with pytest.raises(DataError, match="registering a tracker needs >= 3"):
        session_validation(cal, replace(few, split=np.full(2, "calibration", dtype=object)))


def test_a_session_of_two_tracker_placements_registers_each_on_its_own_rows(tmp_path: Path) -> None:
    """Another session measured from two tracker placements (a ``station`` column): each placement is registered
    on its own calibration rows, so the figure is the one-placement session's (one frame for both put a newcomer's
    session 3 958 mm off); a placement with fewer than 3 calibration rows is not judged, and said so."""
    camp, robot, _ = make_campaign(tmp_path, "geometric", 11, {}, n_poses=40, n_validation_poses=15)
    cal = calibrate(camp, robot)
    here = session_validation(cal, camp, cal)
    half = np.arange(camp.n_rows) % 2 == 1
    T = homogeneous(rotvec_to_matrix(np.array([0.3, -1.2, 2.0])), np.array([2500.0, -800.0, 40.0]))
    p = np.where(half[:, None], camp.p_mm @ T[:3, :3].T + T[:3, 3], camp.p_mm)
    two = replace(camp, p_mm=p, station=np.where(half, "S2", "S1").astype(object))
    there = session_validation(cal, two, cal)
    # each placement's frame from half the rows: the same model errors, registered a little differently (1e-3 mm)
    assert there["final"]["mean_position_mm"] == pytest.approx(here["final"]["mean_position_mm"], abs=2e-3)
    assert "2 stations registered on its own rows" in there["stations"]
    st = np.where(half, "S2", "S1").astype(object)
    st[np.flatnonzero(camp.split == "calibration")[:2]] = "S3"  # two calibration rows of S3 ...
    st[np.flatnonzero(camp.split == "validation")[:3]] = "S3"  # ... and three to judge: too few to register
    small = session_validation(cal, replace(two, station=st), cal)
    assert small["stations_not_judged"] == {"S3": "fewer than 3 calibration rows to register it"}
    assert small["n_validation_rows"] == int(np.sum(camp.split == "validation")) - 3


def test_discover_validate_on_writes_and_prints_the_session(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    import copy
    import json

    from robocal.cli import main
    from robocal.sim.twin import load_scenario, simulate

    sc = copy.deepcopy(load_scenario("geometric"))
    sc.update(n_poses=40, n_validation_poses=12)
    data = tmp_path / "cell"
    simulate(sc, data, seed=21)
    out = tmp_path / "out"
    rc = main(
        ["discover", str(data), "--robot", sc["robot"], "--out", str(out), "--no-report", "--validate-on", str(data)]
    )
    assert rc == 0
    sessions = json.loads((out / "sessions.json").read_text())
    (v,) = sessions.values()
    disc = json.loads((out / "discovery.json").read_text())["validation"]["final"]
    # the same session judged as "another": its tracker registered on its calibration rows instead of the fit's
    # frame, so the figure is close to the within-session one (15 % allows the 6-parameter re-registration)
    assert v["final"]["mean_position_mm"] == pytest.approx(disc["mean_position_mm"], rel=0.15)
    assert set(v) >= {"geometric", "final", "without", "helped", "hurt", "n_registration_rows"}
    printed = capsys.readouterr().out
    assert "another session" in printed and "sessions.json" in printed
    assert "register its tracker (the tool as calibrated)" in printed and v["registered"] == "tracker"
    # --validate-tool: the tool re-measured there too (a re-seated tool), and said so
    rc = main(["discover", str(data), "--robot", sc["robot"], "--out", str(out), "--no-report", "--validate-on",
               str(data), "--validate-tool"])  # fmt: skip
    assert rc == 0 and "register its tracker and tool" in capsys.readouterr().out
    (v,) = json.loads((out / "sessions.json").read_text()).values()
    assert v["registered"] == "tracker and tool"


def test_a_reseated_tool_is_measured_again_when_asked(tmp_path: Path) -> None:
    camp, robot, _ = make_campaign(tmp_path, "geometric", 13, {}, n_poses=40, n_validation_poses=15)
    cal = calibrate(camp, robot)
    # the next session: the tool re-seated 0.8 mm off. Each measured point moves by the flange's rotation of
    # the tool's shift; the tracker registration alone cannot absorb it, the tool re-measured does
    T, _ = predicted_flanges(cal, camp, ())
    shift = np.array([0.5, -0.4, 0.5])
    moved = replace(camp, p_mm=camp.p_mm + np.einsum("mij,j->mi", T[:, :3, :3], shift) @ cal.tracker_T_base[:3, :3].T)
    same = session_validation(cal, camp)["final"]["mean_position_mm"]
    tracker_only = session_validation(cal, moved)["final"]["mean_position_mm"]
    with_tool = session_validation(cal, moved, tool=True)
    assert with_tool["registered"] == "tracker and tool"
    assert tracker_only > 0.2  # most of the 0.8 mm shift left (a third or more: the tracker frame takes the rest)
    # re-measured, the session is as good as without the shift (the 3 tool parameters cost a little: 10 %)
    assert with_tool["final"]["mean_position_mm"] == pytest.approx(same, rel=0.1)


def test_the_joint_angles_a_calibration_visited_decide_what_is_an_extrapolation() -> None:
    from robocal.discovery.sessions import COVERAGE_TOL_DEG, outside_calibrated

    # joint 1 visited 350..360..10 deg (through zero), joint 2 a prismatic axis visited 0..500 mm
    q_cal = np.column_stack([np.deg2rad(np.r_[350.0:360.0:2.0, 0.0:10.5:2.0]), np.linspace(0.0, 500.0, 11)])
    q = np.array([[np.deg2rad(0.0), 250.0], [np.deg2rad(180.0), 250.0], [np.deg2rad(10.0 + COVERAGE_TOL_DEG - 0.1),
                  510.0], [np.deg2rad(-8.0), -10.0]])  # fmt: skip
    out = outside_calibrated(q_cal, q, np.array([False, True]))
    assert out.tolist() == [[False, False], [True, False], [False, True], [False, True]]


def test_a_session_outside_the_calibrated_joint_angles_is_said(tmp_path: Path) -> None:
    camp, robot, _ = make_campaign(tmp_path, "geometric", 14, {}, n_poses=40, n_validation_poses=20)
    cal = calibrate(camp, robot)
    qc = camp.q[camp.split == "calibration"]
    low = qc[qc[:, 0] < np.median(qc[:, 0])]  # a calibration that saw only the lower half of joint 1's angles
    v = session_validation(cal, camp, calibrated_q=low)
    cov = v["coverage"]
    qv = camp.q[camp.split == "validation"]
    beyond = int(np.sum(np.rad2deg(qv[:, 0]) > np.rad2deg(low[:, 0].max()) + 5.0))
    assert beyond > 0 and cov["outside_per_joint"]["j1"] >= beyond
    assert cov["n_judged"] == v["n_validation_rows"] and cov["n_outside"] >= beyond
    assert cov["outside"] is not None and (cov["inside"] is None) == (cov["n_outside"] == cov["n_judged"])
    # without the calibration's angles, no coverage is reported
    assert "coverage" not in session_validation(cal, camp)


def test_an_effect_of_a_logged_signal_is_applied_with_the_sessions_values_or_said_missing(tmp_path: Path) -> None:
    """A joint offset following a logged column (signal:<col>:jN) is evaluated with the new session's own values of
    that column; a session that did not log it is judged without the effect, which says so (before: the session
    validation raised, and series A's discovery, which names signal:src_row:j1, could not be judged on D)."""
    camp, robot, _ = make_campaign(tmp_path, "geometric", 12, {}, n_poses=30, n_validation_poses=10)
    cal = calibrate(camp, robot)
    rec = {"key": "signal:inc:j2", "signal": "logged", "column": "inc", "centre": 0.0, "joint": 2,
           "coefficients": [np.deg2rad(0.01)]}  # 0.01 deg of joint 2 per unit of the column  # fmt: skip
    with_effect = replace(cal, effects=(rec,))
    logged = replace(camp, extra={**camp.extra, "inc": np.linspace(-1.0, 1.0, camp.n_rows)})
    applied = session_validation(with_effect, logged, cal)
    assert "not_applied" not in applied and set(applied["without"]) == {"signal:inc:j2"}
    # the effect moves joint 2 by up to 0.01 deg (~0.1-0.2 mm at the flange): the session is worse with it
    assert applied["final"]["mean_position_mm"] > applied["without"]["signal:inc:j2"]["mean_position_mm"] + 0.01
    missing = session_validation(with_effect, camp, cal)
    assert missing["not_applied"] == {"signal:inc:j2": "the session has no column 'inc'"}
    assert missing["final"]["mean_position_mm"] == pytest.approx(
        session_validation(cal, camp)["final"]["mean_position_mm"]
    )


def test_an_effect_that_moves_the_other_session_by_round_off_neither_helped_nor_hurt(tmp_path: Path) -> None:
    """A windowed effect off in the other session changes its error by ~1e-14 mm: it was listed as "hurt"."""
    from robocal.discovery.sessions import SAME_ERROR_MM

    camp, robot, _ = make_campaign(tmp_path, "geometric", 13, {}, n_poses=40, n_validation_poses=15)
    cal = calibrate(camp, robot)
    # a joint-1 harmonic of 1e-15 rad: it moves the tool by ~1e-12 mm, round-off
    tiny = {"key": "gear:j1:h1", "signal": "angle", "joint": 1, "harmonic": 1, "coefficients": [1e-15, 1e-15]}
    v = session_validation(replace(cal, effects=(tiny,)), camp)
    d = v["without"]["gear:j1:h1"]["mean_position_mm"] - v["final"]["mean_position_mm"]
    assert d != 0.0 and abs(d) < SAME_ERROR_MM  # it moves the figure, by round-off only
    assert v["helped"] == [] and v["hurt"] == []


def test_the_discovered_geometry_alone_is_judged_against_the_geometric_calibrations(tmp_path: Path) -> None:
    """A newcomer's probe outside the visited angles: discovered 0.264 mm, geometric 0.150, and every effect
    "helped" — the geometry refitted with the effects was the loss, which no effect left out in turn shows. The
    model's own geometry with every effect off is judged beside (here a geometry 0.02 deg off at joint 2)."""
    camp, robot, _ = make_campaign(tmp_path, "geometric", 14, {}, n_poses=40, n_validation_poses=15)
    cal = calibrate(camp, robot)
    k = list(cal.names).index("theta2")
    x = np.array(cal.x, dtype=float)
    x[k] += np.deg2rad(0.02)
    tiny = {"key": "gear:j1:h1", "signal": "angle", "joint": 1, "harmonic": 1, "coefficients": [1e-6, 0.0]}
    off = replace(cal, x=x, effects=(tiny,))
    v = session_validation(off, camp, cal)
    ga = v["geometry_alone"]
    assert ga["mean_position_mm"] == pytest.approx(v["without"]["gear:j1:h1"]["mean_position_mm"])
    assert ga["versus_geometric_mm"] > 0.05  # 0.02 deg at ~1 m: ~0.3 mm, partly taken up by the registration
    assert "geometry_alone" not in session_validation(cal, camp, cal)  # no effects: nothing to set apart
