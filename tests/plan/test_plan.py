"""Measurement planning: every planned pose satisfies every constraint (checked independently of the
planner's own code where possible), reproducibility, criteria against random designs, Cramér-Rao against a
Monte-Carlo of real calibrations, and errors that name the setting."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from robocal.errors import ConfigError
from robocal.kinematics.chain import build_chain, fk
from robocal.kinematics.transforms import matrix_to_rotvec
from robocal.plan import PlanConfig, build_problem, plan_poses, predict, random_poses
from robocal.plan.constraints import evaluate, segment_distance
from robocal.plan.design import _State, criterion_value, exchange, information, observability
from robocal.plan.output import plan_csv, write_plan
from robocal.plan.planner import rng_stream

TOOL = np.array([35.0, -20.0, 120.0])
TRACKER = np.array([922.26, 2618.05, 328.26])
SETTINGS = {
    "criterion": "D",
    "n_poses": 20,
    "n_candidates": 4000,
    "seed": 3,
    "targets": {"T1": {"position_mm": TOOL.tolist(), "normal": [0, 0, 1]}},
    "tracker": {
        "position_mm": TRACKER.tolist(),
        "acceptance_half_angle_deg": 55.0,
        "min_range_mm": 1200.0,
        "max_range_mm": 4000.0,
    },
    "volume": {"kind": "box", "min_mm": [-2000, -2000, 100], "max_mm": [2000, 2000, 2200]},
    "singularity": {"min_sigma": 0.05, "min_wrist_deg": 15.0},
    "collision": {"enabled": True},
    "joint_margin_deg": 7.0,
    "region": {"n": 150},
}


@pytest.fixture(scope="module")
def planned(kr16):
    return plan_poses(kr16, SETTINGS, curve=False)


def _tool_points(robot, q):
    T = fk(build_chain(robot), q)
    return T, T[:, :3, 3] + T[:, :3, :3] @ TOOL


# ------------------------------------------------------------------------------------- one test per constraint


def test_joint_limits_with_margin(planned, kr16):
    m = np.deg2rad(SETTINGS["joint_margin_deg"])
    assert np.all(planned.q >= kr16.q_limits[:, 0] + m)
    assert np.all(planned.q <= kr16.q_limits[:, 1] - m)


def test_singularity_distance_by_finite_differences(planned, kr16):
    # the flange Jacobian [J_v / 1000 mm; J_w] from central differences of fk (not the planner's analytic one)
    chain = build_chain(kr16)
    h = 1e-6
    for q in planned.q:
        cols = []
        for j in range(kr16.n_joints):
            dq = np.zeros(kr16.n_joints)
            dq[j] = h
            Tp, Tm = fk(chain, (q + dq)[None])[0], fk(chain, (q - dq)[None])[0]
            v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h) / 1000.0
            w = matrix_to_rotvec(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)
            cols.append(np.concatenate([v, w]))
        smin = np.linalg.svd(np.array(cols).T, compute_uv=False)[-1]
        assert smin >= 0.05 - 1e-6  # finite differences are good to ~1e-9 here; 1e-6 is slack
    assert np.all(np.abs(planned.q[:, 4]) >= np.deg2rad(15.0))


def test_working_volume(planned, kr16):
    _, p = _tool_points(kr16, planned.q)
    assert np.all(p >= np.array([-2000, -2000, 100])) and np.all(p <= np.array([2000, 2000, 2200]))


def test_tracker_line_of_sight_and_range(planned, kr16):
    T, p = _tool_points(kr16, planned.q)
    v = TRACKER - p
    d = np.linalg.norm(v, axis=1)
    assert np.all((d >= 1200.0) & (d <= 4000.0))
    cos = np.einsum("mi,mi->m", T[:, :3, 2], v) / d  # reflector normal = flange z
    assert np.all(cos >= np.cos(np.deg2rad(55.0)) - 1e-12)
    assert planned.visible.all()


def test_self_collision_capsules(planned, kr16):
    # the capsule distance is right (against dense sampling of both segments) ...
    rng = np.random.default_rng(0)
    P = rng.normal(0, 100, (60, 4, 3))
    d = segment_distance(P[:, 0], P[:, 1], P[:, 2], P[:, 3])
    t = np.linspace(0, 1, 201)
    A = P[:, None, 0] + t[None, :, None] * (P[:, 1] - P[:, 0])[:, None]
    B = P[:, None, 2] + t[None, :, None] * (P[:, 3] - P[:, 2])[:, None]
    brute = np.linalg.norm(A[:, :, None] - B[:, None, :], axis=-1).min(axis=(1, 2))
    # sampling each segment (~100-500 mm long) at 1/200 of its length misses the minimum by at most half a step
    # on each, < 2.5 mm; the exact distance can never exceed the sampled one
    assert np.all(d <= brute + 1e-9) and np.all(brute - d < 2.5)
    # ... a folded arm (wrist against the column) is refused, the planned poses are not
    cfg = PlanConfig.from_mapping(SETTINGS)
    folded = np.deg2rad([[0.0, -90.0, 150.0, 0.0, 100.0, 0.0]])
    assert evaluate(kr16, build_chain(kr16), folded, cfg)["self_collision"][0]
    assert not evaluate(kr16, build_chain(kr16), planned.q, cfg)["self_collision"].any()


def test_refusals_counted_by_reason(planned):
    c = planned.problem.cand
    assert sum(c.refused.values()) + c.n == c.n_sampled
    assert all(c.failing[r] >= c.refused[r] for r in c.refused)
    assert c.refused["line_of_sight"] > 0 and c.refused["joint_limits"] > 0


def test_orientation_spread_and_6dof_probe(kr16):
    cfg = {**SETTINGS, "orientation": True, "n_poses": 12, "min_orientation_spread_deg": 20.0, "collision": {}}
    res = plan_poses(kr16, cfg, curve=False)
    assert res.problem.F.shape[1] == 6  # 3 position + 3 orientation rows per visible target
    assert res.orientation_spread["satisfied"] and res.orientation_spread["rms_deg"] >= 20.0


def test_two_targets_on_the_tool(kr16):
    tg = {
        "T1": {"position_mm": [0, 0, 120], "normal": [0, 0, 1]},
        "T2": {"position_mm": [80, 0, 60], "normal": [1, 0, 0]},
    }
    res = plan_poses(kr16, {**SETTINGS, "targets": tg, "collision": {}}, curve=False)
    assert res.visible.any(axis=1).all()
    text = plan_csv(res)
    assert text.splitlines()[0] == "pose_id,target,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg"
    assert len(text.splitlines()) - 1 == int(res.visible.sum())


# ------------------------------------------------------------------------------------- design and predictions


def test_reproducible_bytes(tmp_path, kr16):
    small = {**SETTINGS, "n_candidates": 2000, "region": {"n": 60}}
    write_plan(plan_poses(kr16, small), tmp_path / "a", report=True)
    write_plan(plan_poses(kr16, small), tmp_path / "b", report=True)
    for name in ("plan.csv", "plan.json", "report.html"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    other = plan_poses(kr16, {**small, "seed": 4}, curve=False)
    assert plan_csv(other) != (tmp_path / "a" / "plan.csv").read_text()


def test_d_optimal_beats_random_on_det(planned):
    pr = planned.problem
    ld = planned.prediction["D_logdet"]
    rng = np.random.default_rng(0)
    rand = [-criterion_value(information(pr.F, random_poses(pr, 20, rng)), "D") for _ in range(50)]
    assert ld > max(rand)


@pytest.mark.parametrize("crit", ["A", "I"])
def test_a_and_i_optimal_beat_random_on_their_criterion(planned, crit):
    pr = planned.problem
    idx = exchange(pr.F, 20, crit, rng_stream(0, "t"), L=pr.L, init=planned.idx).idx
    v = criterion_value(information(pr.F, idx), crit, pr.L)
    rng = np.random.default_rng(1)
    rand = [criterion_value(information(pr.F, random_poses(pr, 20, rng)), crit, pr.L) for _ in range(50)]
    assert v < min(rand)
    assert v <= criterion_value(information(pr.F, planned.idx), crit, pr.L) + 1e-12  # the exchange never worsens


def test_exchange_gains_equal_recomputed_criteria(planned):
    pr = planned.problem
    idx = planned.idx
    out = np.setdiff1d(np.arange(pr.cand.n), idx)[:4]
    for crit in "DAI":
        st = _State(pr.F, idx, crit, pr.L, ridge=0.0)
        v0 = criterion_value(information(pr.F, idx), crit, pr.L)
        add = [v0 - criterion_value(information(pr.F, [*idx, c]), crit, pr.L) for c in out]
        rem = [v0 - criterion_value(information(pr.F, [i for i in idx if i != c]), crit, pr.L) for c in idx[:3]]
        np.testing.assert_allclose(st.gains(out, +1.0), add, rtol=1e-6)
        np.testing.assert_allclose(st.gains(idx[:3], -1.0), rem, rtol=1e-6)


@pytest.mark.parametrize("criterion", ["D", "A"])
def test_exchange_with_as_many_points_as_candidates(criterion):
    """n = C leaves nothing to exchange (it crashed with "argmax of an empty sequence", issue 30 item 11);
    n = C - 1 leaves one candidate outside, so an excursion can add at most one."""
    F = np.random.default_rng(0).normal(size=(12, 3, 4))
    e = exchange(F, 12, criterion, np.random.default_rng(1))
    np.testing.assert_array_equal(e.idx, np.arange(12))
    assert e.converged and e.n_exchanges == 0
    assert e.value == pytest.approx(criterion_value(information(F, e.idx), criterion), rel=1e-6)  # ridge 1e-10
    e = exchange(F, 11, criterion, np.random.default_rng(1))
    assert len(set(e.idx.tolist())) == 11 and e.converged
    # the best 11 of 12 is the best of the 12 designs that leave one out
    best = min(criterion_value(information(F, np.delete(np.arange(12), k)), criterion) for k in range(12))
    assert e.value == pytest.approx(best, rel=1e-6)


def test_plan_with_as_many_poses_as_accepted_candidates(kr16):
    """n_poses equal to the candidates that satisfy the constraints: every one is planned (issue 30, item 11)."""
    settings = {**SETTINGS, "n_candidates": 150}
    n_accepted = build_problem(kr16, PlanConfig.from_mapping(settings)).cand.n
    assert n_accepted >= 10  # at least the identifiable minimum of the KR 16, so the plan is possible
    plan = plan_poses(kr16, {**settings, "n_poses": n_accepted}, curve=True)
    np.testing.assert_array_equal(plan.idx, np.arange(n_accepted))
    assert plan.curve[-1]["n_poses"] == n_accepted


def test_observability_indices_on_known_singular_values():
    U, _ = np.linalg.qr(np.random.default_rng(0).normal(size=(12, 3)))
    s = np.array([4.0, 2.0, 0.5])
    o = observability(U * s)
    assert o["O1"] == pytest.approx((4 * 2 * 0.5) ** (1 / 3) / np.sqrt(12))
    assert o["O2"] == pytest.approx(0.125) and o["O3"] == pytest.approx(0.5)
    assert o["O4"] == pytest.approx(0.0625) and o["O5"] == pytest.approx(1 / (0.25 + 0.5 + 2.0))


def test_cramer_rao_against_monte_carlo_of_calibrations(tmp_path, kr16):
    """Predicted standard errors vs the spread of 60 real calibrations of twin measurements of the plan."""
    from robocal.calibration.config import CalibrationConfig
    from robocal.calibration.fit import calibrate
    from robocal.data.contract import read_campaign
    from robocal.sim.twin import load_scenario, simulate

    res = plan_poses(kr16, {**SETTINGS, "collision": {}, "n_poses": 25}, curve=False)
    sc = load_scenario("geometric")
    sc.update(noise_mm=0.0, n_validation_poses=0, poses_deg=np.round(np.rad2deg(res.q), 6).tolist())
    simulate(sc, tmp_path, seed=1, robot=kr16)
    camp = read_campaign(tmp_path, kr16, split={"method": "none"})
    rng = np.random.default_rng(5)
    names = [n for n in res.problem.names if not n.startswith("base_")]  # base: relative to a per-fit registration
    X = []
    for _ in range(60):
        c = dataclasses.replace(camp, p_mm=camp.p_mm + rng.normal(0, 0.015, camp.p_mm.shape))
        fit = calibrate(c, kr16, CalibrationConfig(noise_mm=0.015))
        X.append([fit.value(n) for n in names])
    sd = np.std(np.array(X), axis=0, ddof=1)
    pred = res.prediction["stderr"]
    ratio = [
        (np.rad2deg(v) if res.problem.units[res.problem.names.index(n)] == "deg" else v) / pred[n]
        for n, v in zip(names, sd, strict=True)
    ]
    # 60 draws: the sd of a sample sd is ~9 %; 0.65-1.45 is ~4 of those for the worst of ~21 parameters
    assert 0.65 < min(ratio) and max(ratio) < 1.45, ratio
    assert 0.85 < float(np.median(ratio)) < 1.15


def test_prediction_curve_and_error_map(kr16):
    res = plan_poses(kr16, {**SETTINGS, "collision": {}, "accuracy_mm": 0.03}, curve=True)
    ns = [r["n_poses"] for r in res.curve]
    rms = [r["planned_region_rms_mm"] for r in res.curve]
    assert ns == sorted(ns) and ns[0] == res.problem.n_min
    assert rms[-1] < rms[0]
    assert res.n_needed is not None and rms[ns.index(res.n_needed)] <= 0.03
    sig = res.prediction["region_sigma_mm"]
    assert sig.shape == (150,) and np.all(sig > 0)
    assert res.prediction["region_rms_mm"] == pytest.approx(np.sqrt(np.mean(sig**2)))


# ------------------------------------------------------------------------------------- bad input


def test_unknown_robot():
    with pytest.raises(ConfigError, match="unknown robot 'nope'"):
        plan_poses("nope", SETTINGS)


def test_too_few_poses(kr16):
    with pytest.raises(ConfigError, match="'n_poses' plan setting must be at least 10"):
        plan_poses(kr16, {**SETTINGS, "n_poses": 5, "collision": {}})


def test_impossible_constraints_name_the_setting(kr16):
    with pytest.raises(ConfigError, match=r"tracker\.min_range_mm"):
        plan_poses(
            kr16, {**SETTINGS, "tracker": {"position_mm": [0, 0, 0], "min_range_mm": 50000.0, "max_range_mm": 60000.0}}
        )
    with pytest.raises(ConfigError, match=r"tracker\.acceptance_half_angle_deg"):
        plan_poses(kr16, {**SETTINGS, "tracker": {"acceptance_half_angle_deg": 0.001}})


@pytest.mark.parametrize(
    ("settings", "key"),
    [
        ({"criterion": "E"}, "criterion"),
        ({"volume": {"kind": "sphere"}}, "volume.kind"),
        ({"volume": {"kind": "box", "min_mm": [0, 0, 0]}}, "volume.min_mm"),
        ({"noise_mm": -1}, "noise_mm"),
        ({"tracker": {"position_mm": [1, 2]}}, "tracker.position_mm"),
        ({"bogus": 1}, "bogus"),
        ({"ranges_deg": [[0, 1]]}, "ranges_deg"),
        ({"region": {"kind": "box", "min_mm": [0, 0, 0]}}, "region.max_mm"),
        ({"region": {"kind": "joints"}}, "region.ranges_deg"),
        ({"region": {"ranges_deg": [[0, 1]] * 6}}, "region.ranges_deg"),
        ({"region": {"kind": "poses", "poses": [[0, -90, 90, 0, 30]]}}, r"region.poses\[0\]"),
        ({"region": {"kind": "sphere"}}, "region.kind"),
    ],
)
def test_bad_settings_name_the_key(kr16, settings, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        plan_poses(kr16, {**SETTINGS, **settings})


# ------------------------------------------------------------------------------------- outputs, CLI, twin


def test_cli_writes_plan_and_the_twin_measures_it(tmp_path, kr16):
    from robocal.cli import main
    from robocal.data.contract import read_campaign
    from robocal.sim.twin import load_scenario, simulate

    out = tmp_path / "plan"
    rc = main(["plan", "--robot", "kr16_2", "--n", "15", "--out", str(out), "n_candidates=3000", "region.n=100"])
    assert rc == 0
    header = (out / "plan.csv").read_text().splitlines()[0]
    assert header == "pose_id,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg"
    summary = json.loads((out / "plan.json").read_text())
    assert summary["n_poses"] == 15 and "refused" in summary["candidates"] and summary["planned"]["stderr"]
    html = (out / "report.html").read_text()
    assert "Predicted error map" in html and "data:image/png;base64" in html and "http://" not in html
    sc = load_scenario("geometric")
    sc["poses_deg"] = str(out / "plan.csv")
    simulate(sc, tmp_path / "camp", seed=0, robot=kr16)
    camp = read_campaign(tmp_path / "camp", kr16)
    planned = np.loadtxt(out / "plan.csv", delimiter=",", skiprows=1, usecols=range(1, 7))
    cal = camp.calibration()
    np.testing.assert_allclose(np.rad2deg(cal.q), planned, atol=1e-9)


def test_cli_error_names_the_setting(tmp_path, capsys):
    from robocal.cli import main

    rc = main(["plan", "--robot", "kr16_2", "--n", "3", "--out", str(tmp_path), "n_candidates=2000", "region.n=50"])
    assert rc == 2
    assert "'n_poses' plan setting" in capsys.readouterr().err


def test_predict_without_identifiability_is_flagged(planned):
    pr = planned.problem
    p = predict(pr, planned.idx[:3])  # 3 poses: 9 coordinates for 27 parameters
    assert "stderr" not in p and p["observability"]["O3"] == 0.0


def test_build_problem_is_the_same_for_the_same_seed(kr16):
    a = build_problem(kr16, {**SETTINGS, "collision": {}})
    b = build_problem(kr16, {**SETTINGS, "collision": {}})
    assert np.array_equal(a.cand.q, b.cand.q) and np.array_equal(a.F, b.F)


def test_iso9283_cube_volume(kr16):
    cube = {"kind": "iso9283", "center_mm": [600.0, 600.0, 900.0], "side_mm": 1000.0}
    res = plan_poses(kr16, {**SETTINGS, "volume": cube, "collision": {}, "n_candidates": 8000}, curve=False)
    _, p = _tool_points(kr16, res.q)
    assert np.all(np.abs(p - np.array([600.0, 600.0, 900.0])) <= 500.0)
    assert res.problem.cand.refused["volume"] > 0


# ------------------------------------------------------------------------------------- the region (issue 23, item 14)


def test_the_default_plan_is_i_optimal_for_the_robots_working_range(kr16):
    """The default region is the robot's working range (joint limits less the margin), not the poses the tracker
    sees: the robot works where the tracker cannot look. It is said in plan.json and the report."""
    assert PlanConfig().criterion == "I" and PlanConfig().region.kind == "working_range"
    res = plan_poses(kr16, {k: v for k, v in SETTINGS.items() if k != "criterion"} | {"collision": {}}, curve=False)
    pr = res.problem
    margin = np.deg2rad(SETTINGS["joint_margin_deg"])
    lim = kr16.q_limits
    assert np.all(pr.region_q >= lim[:, 0] + margin - 1e-12) and np.all(pr.region_q <= lim[:, 1] - margin + 1e-12)
    # most of the working range is out of the tracker's view: the cell's checks refuse most region configurations
    ev = evaluate(kr16, build_chain(kr16), pr.region_q, pr.config)
    assert np.mean(ev["line_of_sight"] | ev["tracker_range"]) > 0.5
    d = res.to_dict()["region"]
    assert d["kind"] == "working_range" and "working range" in d["optimal_for"] and "7 deg" in d["optimal_for"]
    # the plan spans what the region needs: its I value is no worse than the D plan's of the same candidates
    d_plan = plan_poses(kr16, {**SETTINGS, "collision": {}}, curve=False)
    assert criterion_value(information(pr.F, res.idx), "I", pr.L) <= criterion_value(
        information(pr.F, d_plan.idx), "I", pr.L
    )


def test_a_box_where_the_parts_sit_is_planned_for(kr16):
    box = {"kind": "box", "min_mm": [700, 300, 300], "max_mm": [1300, 900, 900], "n": 120}
    base = {**SETTINGS, "criterion": "I", "collision": {}}
    res = plan_poses(kr16, {**base, "region": box}, curve=False)
    pr = res.problem
    assert pr.region_q.shape == (120, 6) and res.to_dict()["region"]["n"] == 120
    xyz = pr.region_xyz
    assert np.all(xyz >= np.array(box["min_mm"]) - 1e-9) and np.all(xyz <= np.array(box["max_mm"]) + 1e-9)
    assert "box x 700..1300, y 300..900, z 300..900 mm" in res.to_dict()["region"]["optimal_for"]
    # planned for the box, the plan predicts a smaller error there than the plan made for the whole working range
    whole = plan_poses(kr16, base, curve=False)
    I_box = criterion_value(information(pr.F, res.idx), "I", pr.L)
    I_whole_in_box = criterion_value(information(pr.F, whole.idx), "I", pr.L)
    assert I_box < I_whole_in_box
    with pytest.raises(ConfigError, match=r"region\.min_mm / region\.max_mm: .*reaches no point of the box"):
        plan_poses(kr16, {**base, "region": {"kind": "box", "min_mm": [9000, 0, 0], "max_mm": [9100, 100, 100]}})


def test_region_poses_from_a_list_or_a_csv(kr16, tmp_path):
    poses = [[10, -90, 90, 0, 30, 0], [60, -100, 80, 20, 45, -30], [80, -60, 40, -10, 60, 90]]
    base = {**SETTINGS, "criterion": "I", "collision": {}}
    res = plan_poses(kr16, {**base, "region": {"kind": "poses", "poses": poses}}, curve=False)
    np.testing.assert_allclose(res.problem.region_q, np.deg2rad(poses))
    csv = tmp_path / "parts.csv"
    csv.write_text(
        "pose_id,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n"
        + "".join(f"p{k}," + ",".join(str(v) for v in q) + "\n" for k, q in enumerate(poses))
    )
    res2 = plan_poses(kr16, {**base, "region": {"kind": "poses", "poses": str(csv)}}, curve=False)
    np.testing.assert_allclose(res2.problem.region_q, np.deg2rad(poses))
    assert np.array_equal(res.idx, res2.idx)
    assert str(csv) in res2.to_dict()["region"]["optimal_for"]
    bad = tmp_path / "bad.csv"
    bad.write_text("q1_deg,q2_deg\n1,2\n")
    from robocal.errors import DataError

    with pytest.raises(DataError, match=r"bad\.csv: .*missing \['q3_deg'"):
        plan_poses(kr16, {**base, "region": {"kind": "poses", "poses": str(bad)}})
    with pytest.raises(ConfigError, match=r"pose 0: q1 = 500 deg is outside the joint limits"):
        plan_poses(kr16, {**base, "region": {"kind": "poses", "poses": [[500, -90, 90, 0, 30, 0]]}})


def test_the_command_prints_the_region(tmp_path, capsys):
    from robocal.cli import main

    out = tmp_path / "plan"
    args = ["plan", "--robot", "kr16_2", "--n", "15", "--out", str(out), "n_candidates=3000", "region.n=100"]
    assert main([*args, "--no-report"]) == 0
    text = capsys.readouterr().out
    assert "optimal for: the robot's working range (its joint limits less 5 deg); the tool point there spans x" in text
    assert (
        main([*args, "region.kind=joints", "region.ranges_deg=[[0,90],[-120,-40],[0,90],[-90,90],[-90,90],[-90,90]]"])
        == 0
    )
    text = capsys.readouterr().out
    assert "optimal for: joint ranges q1 0..90, q2 -120..-40, q3 0..90" in text
    html = (out / "report.html").read_text()
    assert "Region the plan is made for" in html and "PlanConfig(" not in html
