"""Configuration data on a boundary (ABB quadrants, KUKA Turn/wrist signs) and KUKA A, B, C near B = 90 deg:
a target on a boundary matches both neighbours, and a written frame keeps the representation nearest to the
program's own."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robocal.cell.programs.common import (
    BOUNDARY_TOL_DEG,
    abb_confdata,
    abc_deg,
    config_matches,
    kuka_status_turn,
    rot_zyx_deg,
    written_config,
)


@pytest.fixture(scope="module")
def irb120():
    import robocal
    from robocal.kinematics.chain import build_chain
    from robocal.serve.engine import compile_chain

    robot = robocal.load_robot("abb_irb120")
    return robot, compile_chain(build_chain(robot))


#: a regular pose of the IRB 120 (no joint near a boundary), deg
Q0 = np.array([20.0, 15.0, 20.0, 30.0, 40.0, 50.0])
#: below the tolerance: a signed zero, the inverse kinematics' rounding, half the tolerance
NEAR = (-0.0, 0.0, -1e-16, 1e-16, -0.5 * BOUNDARY_TOL_DEG, 0.5 * BOUNDARY_TOL_DEG)


def _every_boundary(robot):
    """(joint index, boundary deg) of every quadrant boundary of axes 1, 4, 6 inside the joint limits."""
    lim = np.rad2deg(robot.q_limits)
    for j in (0, 3, 5):
        for k in range(-5, 6):
            if lim[j, 0] < 90.0 * k < lim[j, 1]:
                yield j, 90.0 * k


def test_abb_quadrant_boundaries_match_both_neighbours(irb120):
    robot, cc = irb120
    boundaries = list(_every_boundary(robot))
    assert len(boundaries) == 3 + 3 + 9  # axis 1: -90, 0, 90; axis 4: likewise; axis 6 (+-400): -360 .. 360
    for j, b in boundaries:
        i = (0, 3, 5).index(j)
        for eps in NEAR:
            q = Q0.copy()
            q[j] = b + eps
            qr = np.deg2rad(q)[None]
            cf = abb_confdata(cc, qr)[0]
            k = round(b / 90.0)
            for quad, expect in ((k - 2, False), (k - 1, True), (k, True), (k + 1, False)):
                c = cf.copy()
                c[i] = quad
                assert config_matches("rapid", cc, qr, {"cf": c.tolist()})[0] == expect, (j, b, eps, quad)
            # written back with the quadrant the target stated, on either side
            for quad in (k - 1, k):
                c = cf.copy()
                c[i] = quad
                assert written_config("rapid", cc, qr[0], {"cf": c.tolist()})["cf"][i] == quad
        for eps in (-2 * BOUNDARY_TOL_DEG, 2 * BOUNDARY_TOL_DEG):  # beyond the tolerance: one side only
            q = Q0.copy()
            q[j] = b + eps
            qr = np.deg2rad(q)[None]
            cf = abb_confdata(cc, qr)[0]
            other = cf.copy()
            other[i] = cf[i] + (1 if eps < 0 else -1)
            assert config_matches("rapid", cc, qr, {"cf": cf.tolist()})[0]
            assert not config_matches("rapid", cc, qr, {"cf": other.tolist()})[0]
            assert written_config("rapid", cc, qr[0], {"cf": other.tolist()})["cf"][i] == cf[i]


def test_sign_boundaries_match_both_neighbours(irb120):
    """KUKA Turn bit of every axis at 0, the wrist flag (axis 5 at 0) of KUKA Status and ABB cfx."""
    _, cc = irb120
    for j in range(6):
        for eps in NEAR:
            q = Q0.copy()
            q[j] = eps
            qr = np.deg2rad(q)[None]
            s, t = kuka_status_turn(cc, qr)
            for bit in (0, 1):
                tt = (int(t[0]) & ~(1 << j)) | (bit << j)
                assert config_matches("krl", cc, qr, {"S": int(s[0]), "T": tt})[0], (j, eps, bit)
                assert written_config("krl", cc, qr[0], {"S": int(s[0]), "T": tt})["T"] == tt
                if j == 4:  # the wrist flag: Status bit 2, cfx bit 0
                    ss = (int(s[0]) & ~4) | (bit << 2)
                    assert config_matches("krl", cc, qr, {"S": ss, "T": int(t[0])})[0]
                    cf = abb_confdata(cc, qr)[0]
                    cf[3] = (cf[3] & ~1) | bit
                    assert config_matches("rapid", cc, qr, {"cf": cf.tolist()})[0]
        q = Q0.copy()
        q[j] = -2 * BOUNDARY_TOL_DEG
        qr = np.deg2rad(q)[None]
        s, t = kuka_status_turn(cc, qr)
        assert not config_matches("krl", cc, qr, {"S": int(s[0]), "T": int(t[0]) & ~(1 << j)})[0]


RAPID_PICK = """MODULE Pick
  CONST robtarget pPick := [[350,20,300],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
  CONST robtarget pOver := [[350,0,300],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
  PROC main()
    MoveJ pPick, v1000, fine, tool0;
    MoveL pOver, v200, fine, tool0;
  ENDPROC
ENDMODULE
"""


def test_rapid_target_on_a_quadrant_boundary_is_reachable(tmp_path, irb120):
    """The issue's pPick (axis 4 on its boundary) and the same above y = 0 (axes 1, 4 and 6 on theirs)."""
    from robocal.cell.programs.filter import nominal_ik, read_program

    robot, cc = irb120
    (tmp_path / "Pick.mod").write_text(RAPID_PICK)
    prog = read_program(tmp_path / "Pick.mod")
    q = nominal_ik(prog, cc, robot.q_limits)
    qd = np.rad2deg(q)
    assert abs(qd[0, 3]) < 1e-6 and np.abs(qd[1, [0, 3]]).max() < 1e-6  # on the boundaries
    for k in range(2):
        assert written_config("rapid", cc, q[k], prog.targets[k].config)["cf"] == [0, 0, 0, 0]


def test_abc_nearest_representation():
    # B = 90 exactly: only A - C is defined; the split nearest to the original's
    R = rot_zyx_deg(0.3, 90.0, 0.0)
    a, b, c = abc_deg(R, near=(0.0, 90.0, 0.0))
    assert (a, b, c) == pytest.approx((0.15, 90.0, -0.15), abs=1e-9)
    a, b, c = abc_deg(rot_zyx_deg(20.3, -90.0, 10.0), near=(20.0, -90.0, 10.0))  # B = -90: A + C defined
    assert (a, b, c) == pytest.approx((20.15, -90.0, 10.15), abs=1e-9)
    # tool down tilted by 0.04 deg: the principal branch (B < 90, what was written before) has A = C = -170,
    # the other exact one (B > 90) A = C = 10: that one is written
    R = _tilted(rot_zyx_deg(0.0, 90.0, 0.0), 0.04, 10.0)
    pa, pb, _ = abc_deg(R)
    assert pa == pytest.approx(-170.0, abs=0.1) and pb < 90.0
    a, b, c = abc_deg(R, near=(0.0, 90.0, 0.0))
    assert np.allclose(rot_zyx_deg(a, b, c), R, atol=1e-12)  # exact: the same rotation
    assert a == pytest.approx(10.0, abs=0.1) and c == pytest.approx(10.0, abs=0.1) and b > 90.0
    # away from the pole the principal branch is the near one; across +-180 the value stays in (-180, 180]
    assert abc_deg(rot_zyx_deg(179.99, 10.0, -5.0), near=(179.98, 10.0, -5.0)) == pytest.approx(
        (179.99, 10.0, -5.0), abs=1e-9
    )


def _tilted(R: np.ndarray, angle_deg: float, azimuth_deg: float) -> np.ndarray:
    """``R`` turned by ``angle_deg`` about the horizontal axis at ``azimuth_deg`` (world frame)."""
    from robocal.kinematics.transforms import rotvec_to_matrix

    az = math.radians(azimuth_deg)
    axis = np.array([-math.sin(az), math.cos(az), 0.0])
    return np.asarray(rotvec_to_matrix(axis * math.radians(angle_deg))) @ R


def test_krl_tool_down_target_keeps_its_representation(tmp_path):
    """A KRL B = 90 target filtered and read back: the same corrected joints, A/C of the nearer branch."""
    import robocal
    from robocal.cell.programs.filter import filter_program, nominal_ik, read_program, write_filtered
    from robocal.io import write_json
    from robocal.serve.bundle import load_bundle, write_bundle

    robot = robocal.load_robot("kr16_2")
    sc = robocal.load_scenario("geometric")
    sc.update(n_poses=40, n_validation_poses=0)
    robocal.simulate(sc, tmp_path / "camp", seed=2)
    cal = robocal.calibrate(robocal.read_campaign(tmp_path / "camp", robot), robot)
    write_json(tmp_path / "calibration.json", cal.to_dict())
    bundle = load_bundle(write_bundle(tmp_path / "bundle", "kr16_2", tmp_path / "calibration.json"))
    d = tmp_path / "p"
    d.mkdir()
    (d / "Tdown.src").write_bytes(
        b"DEF Tdown( )\r\nLIN {X 1200,Y 100,Z 900,A 0,B 90,C 0}\r\nLIN {X 1100,Y -200,Z 800,A 30,B 90,C 30}\r\nEND\r\n"
    )
    (d / "Tdown.dat").write_bytes(b"DEFDAT Tdown\r\nENDDAT\r\n")
    res = filter_program(read_program(d / "Tdown.src"), bundle)
    assert res.status == ["ok", "ok"], res.reasons
    write_filtered(res, tmp_path / "out")
    back = read_program(tmp_path / "out" / "Tdown.src")
    import re

    text = (tmp_path / "out" / "Tdown.src").read_text()
    abc = [tuple(float(v) for v in m) for m in re.findall(r"A (\S+),B (\S+),C (\S+)\}", text)]
    for (a, b, c), (a0, c0), t in zip(abc, [(0.0, 0.0), (30.0, 30.0)], back.targets, strict=True):
        assert abs(b - 90.0) < 0.1
        # the nearer of the two exact representations: A and C move by less than 90 deg
        assert abs(a - a0) < 90.0 and abs(c - c0) < 90.0, (a, b, c)
        alt = abc_deg(t.T_base_tcp[:3, :3])  # the principal representation of the same rotation
        far = abs(alt[0] - a0) + abs(alt[2] - c0) if abs(alt[1] - b) > 1e-9 else math.inf
        assert abs(a - a0) + abs(c - c0) <= far
    # read back, the nominal controller lands on the corrected joints (text rounding: 1e-4 mm, 1e-5 deg)
    from robocal.serve.engine import compile_chain

    q_back = nominal_ik(back, compile_chain(bundle.chain), bundle.robot.q_limits)
    assert np.abs(np.rad2deg(q_back) - res.q_corrected_deg).max() < 2e-4
