"""The ISO 9283 test program: the visits a cell runs, written for the robot's programmer (``iso_program.csv``).

``robocal iso9283 --program DIR --robot R [key=value ...]`` writes, for the cube of ``test.volume`` (the same keys
as ``robocal plan``'s ``volume`` of kind ``iso9283``), one row per visit in the order the test runs them (cycle,
approach, P1..P5): the commanded tool position in the base frame (``cmd_x_mm`` ..), the orientation the nominal
inverse kinematics gives (``cmd_qw`` ..), the joint target ``q1_deg`` .., and the pre-position ``test.approach_mm``
back along the approach direction (``pre_x_mm`` .., ``pre_q1_deg`` ..) from which the pose is approached. The
twin runs exactly these visits (:mod:`robocal.iso9283.twin`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from robocal.compensation import ActualRobot, compensate
from robocal.errors import ConfigError
from robocal.io import write_text
from robocal.iso9283.settings import AXES, IsoSettings
from robocal.kinematics.transforms import matrix_to_quat


def cube_joints(nominal: ActualRobot, robot: Any, pts: np.ndarray, seed_deg: Any) -> np.ndarray:
    """One joint configuration per cube point: the nominal inverse kinematics, P1 from the seed, the others from
    P1's solution (one arm configuration for the whole test)."""
    n = robot.n_joints
    if seed_deg is None:
        lim = np.rad2deg(robot.q_limits)
        seed = np.clip(np.array([0.0, -90.0, 90.0, 0.0, 60.0, 0.0][:n] + [0.0] * max(0, n - 6)), lim[:, 0], lim[:, 1])
    else:
        seed = np.asarray(seed_deg, dtype=float)
        if seed.shape != (n,):
            raise ConfigError(f"iso9283.twin.seed_q_deg: must be {n} joint angles (deg); got {list(seed)}")
    q0 = robot.to_kinematic(np.deg2rad(seed)[None, :])  # the seed as the controller states it (a coupled J3)
    c1 = compensate(nominal, q0, pts[:1], max_iter=80, tol_mm=1e-6, stall=False)
    c = compensate(nominal, np.tile(c1.q, (5, 1)), pts, max_iter=80, tol_mm=1e-6, stall=False)
    if not (c1.converged.all() and c.converged.all()):
        raise ConfigError(
            f"iso9283.test.volume: the cube (centre {list(pts[0])}) is out of reach of {robot.name} from "
            f"seed_q_deg {seed.tolist()}; move the cube or give twin.seed_q_deg"
        )
    # the program's joints are the controller's (a coupled robot's J3 relative to J2), rounded as written; judged
    # by its limits, and returned kinematic (what the chain takes)
    q_rep = np.deg2rad(np.round(np.rad2deg(robot.to_reported(c.q)), 6))
    lim = robot.q_limits
    bad = (q_rep < lim[:, 0]) | (q_rep > lim[:, 1])
    if bad.any():
        k, j = (int(v[0]) for v in np.nonzero(bad))
        raise ConfigError(
            f"iso9283.test.volume: P{k + 1} needs joint {j + 1} at {np.rad2deg(q_rep[k, j]):.1f} deg, outside its "
            "limits; give twin.seed_q_deg (a seed nearer the cube, in the controller's joints)"
        )
    return np.asarray(robot.to_kinematic(q_rep))


def joint_directions(nominal: ActualRobot, q: np.ndarray, dirs: list[np.ndarray]) -> np.ndarray:
    """``(points, approaches, n)`` of -1 / +1: the sign of each joint's velocity ``J⁺ d`` when the tool travels
    along ``d`` into the point (numerical position Jacobian of the nominal robot; a zero counts as +1)."""
    h = 1e-6
    p0, _, _ = nominal.pose(q)
    n = q.shape[1]
    J = np.zeros((len(q), 3, n))
    for j in range(n):
        dq = np.zeros(n)
        dq[j] = h
        J[:, :, j] = (nominal.pose(q + dq)[0] - p0) / h
    Jp = np.linalg.pinv(J)  # (k, n, 3)
    out = np.stack([np.einsum("knc,c->kn", Jp, d) for d in dirs], axis=1)
    return np.where(out < 0, -1, 1)


def write_program(out_dir: str | Path, robot: Any, settings: IsoSettings | None = None) -> Path:
    """``iso_program.csv`` of the test (see the module docstring); the TCP is ``test.tcp_mm`` on the flange."""
    from robocal.kinematics.chain import build_chain
    from robocal.sim.compliance import iso9283_cube_points

    st = settings or IsoSettings()
    chain = build_chain(robot)
    tcp = np.asarray(st.test.tcp_mm, dtype=float)
    nominal = ActualRobot(chain, np.zeros(chain.n_params), np.eye(4), tcp, np.eye(3))
    vol = st.test.volume
    assert vol.center_mm is not None and vol.side_mm is not None
    pts = iso9283_cube_points(np.asarray(vol.center_mm), float(vol.side_mm), st.test.inset)
    q = cube_joints(nominal, robot, pts, st.twin.seed_q_deg)
    p, R, _ = nominal.pose(q)
    quat = matrix_to_quat(R)
    appr = list(st.test.approaches)
    pre_p = np.stack([p - st.test.approach_mm * np.asarray(AXES[a]) for a in appr], axis=1)  # (5, A, 3)
    pre_q = np.zeros((5, len(appr), robot.n_joints))
    for k, lab in enumerate(appr):
        sol = compensate(nominal, q, pre_p[:, k], R, max_iter=80, tol_mm=1e-6, stall=False)
        if not sol.converged.all():
            raise ConfigError(f"iso9283.test.approach_mm: a pre-position of approach {lab!r} is out of reach")
        pre_q[:, k] = sol.q
    n = robot.n_joints
    head = ["visit", "cycle", "approach", "iso_pose", "cmd_x_mm", "cmd_y_mm", "cmd_z_mm"]
    head += ["cmd_qw", "cmd_qx", "cmd_qy", "cmd_qz", *[f"q{j + 1}_deg" for j in range(n)]]
    head += ["pre_x_mm", "pre_y_mm", "pre_z_mm", *[f"pre_q{j + 1}_deg" for j in range(n)]]
    lines = [",".join(head)]
    visit = 0
    for c in range(st.test.cycles):
        for a, lab in enumerate(appr):
            for k in range(5):
                visit += 1
                vals = [str(visit), str(c + 1), lab, f"P{k + 1}"]
                vals += [f"{v:.6f}" for v in p[k]] + [f"{v:.9f}" for v in quat[k]]
                vals += [f"{v:.6f}" for v in np.rad2deg(robot.to_reported(q[k]))]  # the controller's joints
                vals += [f"{v:.6f}" for v in pre_p[k, a]]
                vals += [f"{v:.6f}" for v in np.rad2deg(robot.to_reported(pre_q[k, a]))]
                lines.append(",".join(vals))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return write_text(out / "iso_program.csv", "\n".join(lines) + "\n")


__all__ = ["cube_joints", "joint_directions", "write_program"]
