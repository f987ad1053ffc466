"""Differential error compensation: joint corrections that make the real robot reach the nominal pose.

The controller plans with its nominal kinematics: for a target ``q_target`` it expects the tool frame
at ``desired = tracker_T_base · FK_nominal(q_target) · flange_T_tool``. The real robot (calibrated
kinematic errors, plus thermal drift or joint deflection predicted for the moment) reaches
``FK_actual(q + dq_deflection)`` instead. Compensation solves ``FK_actual(q*) = desired`` by
Newton iterations on the error Jacobian (joint corrections from the pseudo-inverse of the joint
Jacobian), then reports the corrected joints, the corrected Cartesian command (what the nominal
controller must be sent so that its inverse kinematics yields ``q*``) and the predicted residual.

All arrays are batched over targets: ``q`` is ``(m, n)`` rad, positions ``(m, 3)`` mm.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from robocal.io import atomic_write
from robocal.kinematics.chain import Chain, ChainState, propagate
from robocal.kinematics.transforms import matrix_to_quat


@dataclass(frozen=True)
class ActualRobot:
    """What the robot really is at the moment of compensation.

    chain : the compiled nominal chain; eta : (P,) kinematic errors (geometric + thermal, mm / rad);
    tracker_T_base : (4, 4); tool_mm : (3,) tool point in the flange frame; tool_R : (3, 3) tool frame;
    joint_offset : callable ``q_cmd (m, n) -> dq (m, n)`` rad added to the commanded joints (deflection),
    or None.
    """

    chain: Chain
    eta: np.ndarray
    tracker_T_base: np.ndarray
    tool_mm: np.ndarray
    tool_R: np.ndarray
    joint_offset: Callable[[np.ndarray], np.ndarray] | None = None

    def pose(self, q_cmd: np.ndarray, record: bool = False) -> tuple[np.ndarray, np.ndarray, ChainState]:
        q = q_cmd if self.joint_offset is None else q_cmd + self.joint_offset(q_cmd)
        st = propagate(self.chain, q, self.eta, self.tracker_T_base, record=record)
        t = self.tool_mm
        p = st.o + st.x * t[0] + st.y * t[1] + st.z * t[2]
        R = st.R @ self.tool_R
        return p, R, st


@dataclass
class Compensation:
    """Result of :func:`compensate`.

    q_target : (m, n) the requested joints; q : (m, n) corrected joint targets, rad;
    converged : (m,) bool; residual_mm : (m, 3) predicted position error after compensation;
    residual_rad : (m, 3) predicted orientation error (rotation vector);
    error_before_mm / error_before_rad : the same without compensation; iterations : int.
    """

    q_target: np.ndarray
    q: np.ndarray
    converged: np.ndarray
    residual_mm: np.ndarray
    residual_rad: np.ndarray
    error_before_mm: np.ndarray
    error_before_rad: np.ndarray
    iterations: int

    @property
    def correction_rad(self) -> np.ndarray:
        """Joint corrections ``q - q_target`` (m, n), rad."""
        return self.q - self.q_target


def desired_poses(nominal: ActualRobot, q_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tool positions ``(m, 3)`` and rotations ``(m, 3, 3)`` the nominal controller expects at ``q_target``."""
    p, R, _ = nominal.pose(q_target)
    return p, R


def compensate(
    actual: ActualRobot,
    q_target: np.ndarray,
    p_desired: np.ndarray,
    R_desired: np.ndarray | None = None,
    max_iter: int = 20,
    tol_mm: float = 1e-7,
    tol_rad: float = 1e-9,
    max_step_rad: float = 0.05,
    stall: bool = True,
) -> Compensation:
    """Joint targets ``q*`` with ``actual.pose(q*) = (p_desired, R_desired)``.

    With ``R_desired`` the full 6-D tool pose is matched (6 equations, a square system for a 6-axis
    arm); without it only the tool position (minimum-norm joint correction). ``max_step_rad`` and ``stall``
    as :func:`robocal.kinematics.ik.solve` (inverse kinematics over a large move: a larger step, no stall rule).

    One Newton for everything: this is the online service's solver (:func:`robocal.kinematics.ik.solve`, the
    chain folded at ``actual.eta`` and the tracker frame; damped normal equations, steps clipped, a target that
    stops converging near a singularity reported unconverged), so the controller CSV, the thermal and compliance
    compensation, program filtering and the service give the same corrections.
    """
    from robocal.kinematics.ik import compile_chain, solve
    from robocal.kinematics.transforms import homogeneous

    q0 = np.asarray(q_target, dtype=float)
    cc = compile_chain(actual.chain, np.asarray(actual.eta, dtype=float), actual.tracker_T_base)
    tool_T = homogeneous(np.asarray(actual.tool_R, dtype=float), np.asarray(actual.tool_mm, dtype=float))
    offset = None
    if actual.joint_offset is not None:
        fn = actual.joint_offset
        q_all = q0.copy()

        # the engine asks for the rows still iterating; the callable takes every row (its signals are per row)
        def offset(qs: np.ndarray, rows: np.ndarray) -> np.ndarray:
            q_all[rows] = qs
            return np.asarray(fn(q_all), dtype=float)[rows]

    sol = solve(cc, tool_T, q0, np.asarray(p_desired, dtype=float), R_desired, offset, max_iter=max_iter,
                tol_mm=tol_mm, tol_rad=tol_rad, max_step_rad=max_step_rad, stall=stall)  # fmt: skip
    return Compensation(
        q_target=q0,
        q=sol.q,
        converged=sol.converged,
        residual_mm=sol.residual_mm,
        residual_rad=sol.residual_rad,
        error_before_mm=sol.error_before_mm,
        error_before_rad=sol.error_before_rad,
        iterations=sol.iterations,
    )


def write_compensation_csv(
    path: str | Path,
    target_ids: list[str] | np.ndarray,
    q_corrected: np.ndarray,
    command_T: np.ndarray,
    predicted_error_mm: np.ndarray,
    predicted_error_deg: np.ndarray | None = None,
) -> Path:
    """A CSV a cell controller can consume: one row per target.

    Columns: ``target_id``, ``q1_deg..qN_deg`` (corrected joints), ``x_mm, y_mm, z_mm, qw, qx, qy, qz``
    (corrected Cartesian command, robot base frame), ``pred_err_mm`` (and ``pred_err_deg``).
    """
    q = np.rad2deg(np.asarray(q_corrected, dtype=float))
    quat = matrix_to_quat(command_T[:, :3, :3])
    head = [
        "target_id",
        *[f"q{j + 1}_deg" for j in range(q.shape[1])],
        "x_mm",
        "y_mm",
        "z_mm",
        "qw",
        "qx",
        "qy",
        "qz",
        "pred_err_mm",
    ]
    if predicted_error_deg is not None:
        head.append("pred_err_deg")
    lines = [",".join(head)]
    err = np.linalg.norm(np.atleast_2d(predicted_error_mm), axis=1)
    erd = None if predicted_error_deg is None else np.linalg.norm(np.atleast_2d(predicted_error_deg), axis=1)
    for k, tid in enumerate(target_ids):
        vals = [str(tid)] + [f"{v:.6f}" for v in q[k]] + [f"{v:.6f}" for v in command_T[k, :3, 3]]
        vals += [f"{v:.9f}" for v in quat[k]] + [f"{err[k]:.6f}"]
        if erd is not None:
            vals.append(f"{erd[k]:.6f}")
        lines.append(",".join(vals))
    return atomic_write(path, lambda p: p.write_text("\n".join(lines) + "\n"))
