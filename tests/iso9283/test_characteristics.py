"""ISO 9283 formulas against values computed by hand (the arithmetic is written out in the comments)."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.iso9283 import characteristics as ch
from robocal.iso9283.analysis import IsoTest, evaluate
from robocal.iso9283.settings import AnalysisConfig

# gross-error rule off: four hand-made cycles are too few for a spread estimate
NO_GROSS = AnalysisConfig(gross_error_k=1e9)


def small_campaign() -> IsoTest:
    """P1 commanded at the origin, 4 cycles from approach 'A' and 2 from 'B'; P2 commanded at (100, 0, 0)."""
    p1a = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 0]]
    p1b = [[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]]
    p2a = [[100.5, 0, 0], [100, 0, 0], [100, 0, 0], [100.3, 0, 0]]
    p = np.array(p1a + p1b + p2a, dtype=float)
    pose = np.array(["P1"] * 6 + ["P2"] * 4)
    approach = np.array(["A"] * 4 + ["B"] * 2 + ["A"] * 4)
    cycle = np.array([1, 2, 3, 4, 1, 2, 1, 2, 3, 4])
    cmd = np.array([[0.0, 0, 0]] * 6 + [[100.0, 0, 0]] * 4)
    # angle a of P1 around a commanded 179.9 deg (crossing the +-180 cut); b, c at the commanded value
    a = [-179.9, 179.8, 179.9, -180.0, 179.9, 179.9] + [10.0] * 4
    rpy = np.column_stack([a, np.zeros(10), np.full(10, 45.0)])
    cmd_rpy = np.column_stack([[179.9] * 6 + [10.0] * 4, np.zeros(10), np.full(10, 45.0)])
    return IsoTest(pose, cycle, approach, p, cmd, np.arange(10.0), np.arange(10) + 2, rpy, cmd_rpy, "hand.csv")


def test_pose_characteristics_match_hand_computation() -> None:
    res = evaluate(small_campaign(), NO_GROSS)
    p1 = res.pose("P1")
    assert p1.n_cycles == 4 and p1.approach == "A"
    # barycentre (0.25, 0.25, 0.25); AP_p = 0.25 * sqrt(3)
    assert p1.AP_p_mm == pytest.approx(0.4330127, abs=1e-7)
    np.testing.assert_allclose(p1.AP_xyz_mm, [0.25, 0.25, 0.25], atol=1e-12)
    # l_j = sqrt(0.6875) = 0.8291562 (three cycles), sqrt(0.1875) = 0.4330127 (the fourth); l_bar = 0.7301203
    # S_l = sqrt((3 * 0.0990359^2 + 0.2971076^2) / 3) = 0.19807175; RP_l = 0.7301203 + 0.5942152 = 1.3243355
    assert p1.l_bar_mm == pytest.approx(0.7301203, abs=1e-7)
    assert p1.S_l_mm == pytest.approx(0.1980717, abs=1e-7)
    assert p1.RP_l_mm == pytest.approx(1.3243355, abs=1e-7)  # 7 digits by hand
    # angle a: differences to 179.9 wrapped: +0.2, -0.1, 0.0, +0.1 -> AP_a = 0.05;
    # S_a = sqrt((0.15^2 + 0.15^2 + 0.05^2 + 0.05^2) / 3) = 0.1290994; RP_a = 3 S_a = 0.3872983
    assert p1.AP_abc_deg is not None and p1.RP_abc_deg is not None
    np.testing.assert_allclose(p1.AP_abc_deg, [0.05, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(p1.RP_abc_deg, [0.3872983, 0.0, 0.0], atol=1e-7)
    # P2: barycentre (100.2, 0, 0) -> AP_p 0.2; l = 0.3, 0.2, 0.2, 0.1 -> l_bar 0.2, S_l = sqrt(0.02 / 3) = 0.08164966,
    # RP_l = 0.2 + 0.2449490 = 0.4449490
    p2 = res.pose("P2")
    assert p2.AP_p_mm == pytest.approx(0.2, abs=1e-9)
    assert p2.RP_l_mm == pytest.approx(0.4449490, abs=1e-7)
    # vAP of P1: barycentres (0.25, 0.25, 0.25) and (0.5, 0.5, 0.5): 0.25 * sqrt(3); P2 has one approach
    assert res.vAP_p_mm == {"P1": pytest.approx(0.4330127, abs=1e-7)}


def test_distance_characteristics_match_hand_computation() -> None:
    res = evaluate(small_campaign(), NO_GROSS)
    # the pair P2-P4 is absent: the first two poses. D_j = 99.5, sqrt(10001) = 100.0049999 (twice), 100.3;
    # D_bar = 99.95249995, D_c = 100 -> AD_p = -0.04750005;
    # RD = 3 sqrt((0.45249995^2 + 2 * 0.05249995^2 + 0.34750005^2) / 3) = 3 * 0.3321771 = 0.9965314
    assert res.distance_pair == ("P1", "P2")
    assert res.AD_p_mm == pytest.approx(-0.04750005, abs=1e-7)
    assert res.RD_l_mm == pytest.approx(0.9965314, abs=1e-6)


def test_drift_between_first_and_last_cycles() -> None:
    # one pose, 30 cycles drifting 0.01 mm per cycle along x, one minute apart, commanded at the origin:
    # first 10 cycles' barycentre x = 0.045, last 10's x = 0.245 -> dAP = 0.2; same spread -> dRP = 0
    n = 30
    p = np.column_stack([0.01 * np.arange(n), np.zeros(n), np.zeros(n)])
    test = IsoTest(
        np.array(["P1"] * n), np.arange(1, n + 1), np.array(["-"] * n), p, np.zeros((n, 3)),
        60.0 * np.arange(n), np.arange(n) + 2,
    )  # fmt: skip
    r = evaluate(test, NO_GROSS).pose("P1")
    assert r.dAP_p_mm == pytest.approx(0.2, abs=1e-12)
    assert r.dRP_l_mm == pytest.approx(0.0, abs=1e-12)
    assert r.drift_span_min == pytest.approx(20.0)  # group centres at cycle 5.5 and 25.5


def test_gross_error_rule_leaves_out_a_bumped_cycle() -> None:
    rng = np.random.default_rng(3)
    n = 30
    p = rng.normal(0.0, 0.02, (n, 3))
    p[7] += [0.0, 0.0, 0.5]  # a reflector bumped by 0.5 mm (25 sigma)
    rows = np.arange(n) + 2
    test = IsoTest(np.array(["P1"] * n), np.arange(1, n + 1), np.array(["-"] * n), p, np.zeros((n, 3)),
                   np.zeros(n), rows)  # fmt: skip
    res = evaluate(test)
    assert [r["row"] for r in res.left_out] == [9]
    assert res.left_out[0]["cycle"] == 8 and "gross error" in res.left_out[0]["reason"]
    assert res.pose("P1").n_cycles == n - 1
    # the kept cycles give the characteristics
    expected = ch.pose_repeatability(np.delete(p, 7, axis=0))[0]
    assert res.pose("P1").RP_l_mm == pytest.approx(expected, rel=1e-12)


def test_wrap_and_input_checks() -> None:
    np.testing.assert_allclose(ch.wrap_deg([180.0, -180.0, 359.8, -0.2]), [180.0, 180.0, -0.2, -0.2], atol=1e-12)
    with pytest.raises(ValueError, match="at least 2 cycles"):
        ch.pose_repeatability(np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        ch.pose_accuracy(np.zeros((3, 2)), np.zeros(3))


def test_gross_error_rule_follows_a_drift() -> None:
    """A warm-up drifts the pose 0.3 mm over the cycles (15 sigma of the scatter): no cycle is a gross error; a
    0.3 mm jump in the middle of it is. (A rule around one median of all cycles misses the jump: the drift widens
    the spread it is judged against.)"""
    rng = np.random.default_rng(5)
    n = 30
    p = rng.normal(0.0, 0.02, (n, 3)) + np.outer(np.linspace(0.0, 0.3, n), [1.0, 0.0, 0.0])
    test = IsoTest(np.array(["P1"] * n), np.arange(1, n + 1), np.array(["-"] * n), p, np.zeros((n, 3)),
                   60.0 * np.arange(n), np.arange(n) + 2)  # fmt: skip
    assert evaluate(test).left_out == []
    p2 = p.copy()
    p2[12] += [0.0, 0.3, 0.0]
    jumped = IsoTest(test.pose, test.cycle, test.approach, p2, test.cmd_mm, test.t_s, test.row)
    assert [r["cycle"] for r in evaluate(jumped).left_out] == [13]
