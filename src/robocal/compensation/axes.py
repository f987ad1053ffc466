"""Compensation of a robot on external axes (issue 34): a track or a column corrected like the arm, or not moved.

For joint targets ``q_target`` (the arm's joints and the external axes, as the nominal controller would use them)
the pose the program means is the nominal model's: the target (reflector) at
``tracker_T_base · FK_nominal(q_target) · tool``, in the calibration's first tracker frame. The corrected joints
put the *calibrated* robot there: the calibration's kinematics and, when given, the linear axes' own errors along
their travel (:func:`robocal.identification.axes.fit_axis_errors`), re-evaluated at every Newton step since they
depend on the axis position and the pose. Pose = position and orientation (6 equations, rotations weighted as
``ROT_WEIGHT_MM`` mm per rad); the arm's six joints solve them, and with ``move_external`` the external axes
join (least-norm steps); without it (the default: a track is often not to be moved by a correction) they keep
their commanded value exactly.

This is the library's numpy path (:func:`robocal.kinematics.chain.propagate`): the service's compiled chain and
the program filter take revolute joints only, and are not extended here. :func:`krl_e6axis` and
:func:`rapid_jointtarget` write the corrected joints as a KUKA ``E6AXIS`` (``A1``..``A6`` deg, ``E1``.. mm) and an
ABB ``jointtarget`` (``[[j1..j6], [eax_a..eax_f]]``, unused external axes ``9E+09``), reported values (a coupled
robot's coupling undone).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.identification.axes import AxisFit, axis_errors
from robocal.identification.model import with_base
from robocal.kinematics.axes import augment
from robocal.kinematics.chain import build_chain, fk, point_jacobians, propagate
from robocal.kinematics.transforms import matrix_to_rotvec
from robocal.robot import RobotDescription

#: a rotation error of 1 rad weighs as much as this many mm of position error in the Newton steps
ROT_WEIGHT_MM = 1000.0
#: the largest Newton step of a revolute joint (rad, the service's 3 deg) and of an external axis (mm)
MAX_STEP_RAD = float(np.deg2rad(3.0))
MAX_STEP_MM = 50.0


@dataclass(frozen=True)
class AxisCompensation:
    """Corrected joints ``q`` (m, n) (rad, mm for a prismatic joint, kinematic) for ``q_target``; ``converged``
    (m,); ``error_before_mm`` / ``residual_mm`` (m,) the calibrated model's position error at the target before
    and after; ``residual_deg`` (m,) its orientation error after; ``move_external``: whether the external axes
    were free."""

    q_target: np.ndarray
    q: np.ndarray
    converged: np.ndarray
    error_before_mm: np.ndarray
    residual_mm: np.ndarray
    residual_deg: np.ndarray
    move_external: bool


def _model(result: CalibrationResult) -> Any:
    robot = result.model.robot
    axes = [j for j in range(robot.n_joints) if robot.prismatic[j]]
    model = copy.copy(result.model)
    model.chain = augment(result.model.chain, axes)
    model.full_chain = with_base(model.chain)
    return model


def compensate_axes(
    result: CalibrationResult,
    q_target: np.ndarray,
    target: str | None = None,
    axis_fit: AxisFit | None = None,
    move_external: bool = False,
    payload_kg: np.ndarray | float = 0.0,
    max_iter: int = 50,
    tol_mm: float = 1e-5,
) -> AxisCompensation:
    """Correct joint targets ``q_target`` (m, n) for the calibrated robot on its external axes (module docstring);
    ``target`` the reflector whose point is corrected (default: the calibration's first)."""
    robot = result.model.robot
    q_target = np.atleast_2d(np.asarray(q_target, dtype=float))
    m, n = q_target.shape
    k = 0 if target is None else result.model.target_names.index(target)
    model = _model(result)
    xfull = result.x if axis_fit is None else axis_fit.x  # the axis fit refitted the calibration's parameters
    x = model._local(xfull, 0)
    T_ref = model.station_T_ref[0]
    tool = result.model.tools(xfull)[k]
    tool_R = result.model.tool_rotations(xfull)[k]
    pl = np.broadcast_to(np.asarray(payload_kg, dtype=float), (m,))
    # the pose the program means: the nominal model in the calibration's tracker frame
    T_base = result.model.base_transform(xfull)
    Tn = T_base @ fk(build_chain(robot), q_target)
    p_des = Tn[:, :3, 3] + Tn[:, :3, :3] @ tool
    R_des = Tn[:, :3, :3] @ tool_R
    free = np.array([True if move_external else not robot.prismatic[j] for j in range(n)])

    def pose(q: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        E = axis_errors(robot, q, pl, axis_fit.terms, axis_fit.coef) if axis_fit is not None else None
        qa = np.concatenate([q, np.zeros((m, model.chain.n_joints - n)) if E is None else E], axis=1)
        st = propagate(model.full_chain, qa, x[: model.n_chain], T_ref, record=jac)
        p = st.o + st.x * tool[0] + st.y * tool[1] + st.z * tool[2]
        R = st.R @ tool_R
        r = np.concatenate([p - p_des, ROT_WEIGHT_MM * matrix_to_rotvec(R @ np.swapaxes(R_des, -1, -2))], axis=1)
        if not jac:
            return r, p, None
        _, _, J_q, W_q = point_jacobians(model.full_chain, st, p)
        J = np.concatenate([J_q[:, :, :n], ROT_WEIGHT_MM * W_q[:, :, :n]], axis=1)  # (m, 6, n)
        return r, p, J

    q = q_target.copy()
    r0, _, _ = pose(q, False)
    converged = np.zeros(m, dtype=bool)
    for _ in range(max_iter):
        r, _, J = pose(q, True)
        assert J is not None
        converged = np.linalg.norm(r, axis=1) < tol_mm
        if converged.all():
            break
        for i in np.flatnonzero(~converged):
            dq = np.linalg.lstsq(J[i][:, free], -r[i], rcond=None)[0]
            # steps capped as the service caps them (3 deg; 50 mm on an external axis): near a singular pose a
            # full Gauss-Newton step overshoots
            cap = np.where(robot.prismatic[free], MAX_STEP_MM, MAX_STEP_RAD)
            q[i, free] += dq * min(1.0, float(np.min(cap / np.maximum(np.abs(dq), 1e-300))))
    r, _, _ = pose(q, False)
    return AxisCompensation(
        q_target=q_target,
        q=q,
        converged=np.linalg.norm(r, axis=1) < max(tol_mm, 1e-3),
        error_before_mm=np.linalg.norm(r0[:, :3], axis=1),
        residual_mm=np.linalg.norm(r[:, :3], axis=1),
        residual_deg=np.rad2deg(np.linalg.norm(r[:, 3:], axis=1) / ROT_WEIGHT_MM),
        move_external=move_external,
    )


def _reported(robot: RobotDescription, q: np.ndarray) -> tuple[list[int], list[int], np.ndarray]:
    """The arm's joints and the external axes (the prismatic joints), and the reported values (deg / mm)."""
    qr = robot.to_reported(np.atleast_2d(q))
    vals = np.where(robot.prismatic, qr, np.rad2deg(qr))
    ext = [j for j in range(robot.n_joints) if robot.prismatic[j]]
    arm = [j for j in range(robot.n_joints) if not robot.prismatic[j]]
    if len(arm) > 6 or len(ext) > 6:
        raise ValueError(f"{robot.name}: at most six arm joints and six external axes; got {len(arm)} and {len(ext)}")
    return arm, ext, vals


def krl_e6axis(robot: RobotDescription, q: np.ndarray) -> list[str]:
    """KUKA ``E6AXIS`` aggregates of joints ``q`` (m, n): ``{A1 .., A6 .., E1 .., ...}`` (deg, mm)."""
    arm, ext, vals = _reported(robot, q)
    out = []
    for v in vals:
        parts = [f"A{i + 1} {v[j]:.6f}" for i, j in enumerate(arm)]
        parts += [f"E{i + 1} {v[j]:.6f}" for i, j in enumerate(ext)]
        out.append("{" + ", ".join(parts) + "}")
    return out


def rapid_jointtarget(robot: RobotDescription, q: np.ndarray) -> list[str]:
    """ABB ``jointtarget`` values of joints ``q`` (m, n): ``[[j1..j6],[eax_a..eax_f]]``, unused ``9E+09``."""
    arm, ext, vals = _reported(robot, q)
    out = []
    for v in vals:
        rob = ",".join(f"{v[j]:.6f}" for j in arm)
        eax = [f"{v[j]:.6f}" for j in ext] + ["9E+09"] * (6 - len(ext))
        out.append(f"[[{rob}],[{','.join(eax)}]]")
    return out
