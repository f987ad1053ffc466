"""Configuration data on a boundary (ABB quadrants, KUKA Turn/wrist signs): a target on a boundary matches both
neighbours."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.cell.programs.common import (
    BOUNDARY_TOL_DEG,
    abb_confdata,
    config_matches,
    kuka_status_turn,
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
