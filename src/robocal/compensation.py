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

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from robocal.io import atomic_write
from robocal.kinematics.chain import Chain, ChainState, point_jacobians, propagate
from robocal.kinematics.transforms import matrix_to_quat, matrix_to_rotvec, so3_left_jacobian_inv


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
    joint_offset: object | None = None

    def pose(self, q_cmd: np.ndarray, record: bool = False) -> tuple[np.ndarray, np.ndarray, ChainState]:
        q = q_cmd if self.joint_offset is None else q_cmd + self.joint_offset(q_cmd)  # type: ignore[operator]
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
) -> Compensation:
    """Joint targets ``q*`` with ``actual.pose(q*) = (p_desired, R_desired)``.

    With ``R_desired`` the full 6-D tool pose is matched (6 equations, a square system for a 6-axis
    arm); without it only the tool position (minimum-norm joint correction).
    """
    q0 = np.asarray(q_target, dtype=float)
    q = q0.copy()
    m = q.shape[0]
    use_rot = R_desired is not None
    p, R, _ = actual.pose(q)
    e_p0 = p - p_desired
    e_r0 = matrix_to_rotvec(R @ np.swapaxes(R_desired, -1, -2)) if R_desired is not None else np.zeros((m, 3))
    converged = np.zeros(m, dtype=bool)
    it = 0
    for it in range(1, max_iter + 1):
        p, R, st = actual.pose(q, record=True)
        e_p = p - p_desired
        if use_rot:
            assert R_desired is not None
            e_r = matrix_to_rotvec(R @ np.swapaxes(R_desired, -1, -2))
        else:
            e_r = np.zeros((m, 3))
        converged = (np.abs(e_p).max(axis=1) < tol_mm) & (np.abs(e_r).max(axis=1) < tol_rad)
        if converged.all():
            it -= 1
            break
        _, _, J_q, W_q = point_jacobians(actual.chain, st, p)
        if use_rot:
            A = np.concatenate([J_q, so3_left_jacobian_inv(e_r) @ W_q], axis=1)  # (m, 6, n)
            b = np.concatenate([e_p, e_r], axis=1)
        else:
            A, b = J_q, e_p
        # minimum-norm least-squares step per target: dq = -A^+ b (scale rotation rows to mm at 1 m)
        w = np.ones(A.shape[1])
        if use_rot:
            w[3:] = 1000.0
        Aw = A * w[None, :, None]
        bw = b * w[None, :]
        dq = -np.einsum("mij,mj->mi", np.linalg.pinv(Aw), bw)
        # joint offset (deflection) depends on q only weakly: treated as fixed within a Newton step
        q = q + np.where(converged[:, None], 0.0, dq)
    p, R, _ = actual.pose(q)
    res_p = p - p_desired
    res_r = matrix_to_rotvec(R @ np.swapaxes(R_desired, -1, -2)) if R_desired is not None else np.zeros((m, 3))
    return Compensation(
        q_target=q0,
        q=q,
        converged=converged,
        residual_mm=res_p,
        residual_rad=res_r,
        error_before_mm=e_p0,
        error_before_rad=e_r0,
        iterations=it,
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
