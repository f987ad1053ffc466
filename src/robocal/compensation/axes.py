"""Compensation of a robot on external axes (issue 34): a track or a column corrected like the arm, or not moved.

For joint targets ``q_target`` (the arm's joints and the external axes, as the nominal controller would use them)
the pose the program means is the nominal model's: the target (reflector) at
``tracker_T_base · FK_nominal(q_target) · tool``, in the calibration's first tracker frame. The corrected joints
put the *calibrated* robot there: the calibration's kinematics and, when given, the linear axes' own errors along
their travel (:func:`robocal.calibration.axes.fit_axis_errors`), re-evaluated at every Newton step since they
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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robocal.calibration.axes import AxisFit, axis_errors
from robocal.calibration.result import CalibrationResult
from robocal.compensation.correct import zero_offsets
from robocal.compensation.discovered import DiscoveredEffects, frame_desired, frame_transforms
from robocal.compensation.effects import Signals
from robocal.compensation.safety import SafetyPolicy
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
    and after; ``residual_deg`` (m,) its orientation error after (0 without ``orientation``); ``move_external``:
    whether the external axes were free; ``error_before_xyz_mm`` (m, 3) the position error before;
    ``error_before_deg`` (m,) the orientation error before; ``own_error_mm`` (m,) the position error of the robot
    sent only the calibration's own joint correction (the zero offsets of the arm's joints, what
    :func:`robocal.compensation.correct.beyond_own` measures); ``zero_offsets`` (n,) those offsets (rad; 0 on a
    prismatic joint)."""

    q_target: np.ndarray
    q: np.ndarray
    converged: np.ndarray
    error_before_mm: np.ndarray
    residual_mm: np.ndarray
    residual_deg: np.ndarray
    move_external: bool
    error_before_xyz_mm: np.ndarray | None = None
    error_before_deg: np.ndarray | None = None
    own_error_mm: np.ndarray | None = None
    zero_offsets: np.ndarray | None = None


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
    tool: np.ndarray | None = None,
    orientation: bool = True,
    effects: Sequence[Mapping[str, Any]] | None = None,
    signals: Signals | None = None,
) -> AxisCompensation:
    """Correct joint targets ``q_target`` (m, n) for the calibrated robot on its external axes (module docstring);
    ``target`` the reflector whose point is corrected (default: the calibration's first), or ``tool`` (4, 4) a
    flange-to-TCP transform used instead (a program's tool: the nominal pose and the calibrated robot both carry
    it); ``orientation`` False: the position only (the arm's joints then least-norm steps, as the service's mode
    ``position``).

    The Newton steps are batched over the targets (damped normal equations, or the least-norm step when the free
    joints outnumber the equations), each target's step capped at 3 deg on a revolute joint and 50 mm on an
    external axis (near a singular pose a full step overshoots); with more free joints than equations (the
    external axes free, or the position only) the least-norm step, 1 mm of an external axis weighing as much as
    1 mrad of a joint.

    ``effects``: joint-level effect records (a calibration's ``effects``, :mod:`robocal.compensation.discovered`)
    to correct for too — each joint moved by its deflection at the pose, and a base or tool that logged signals
    move (``logged_frame``) moved back — with ``signals`` the targets' own (default: ``payload_kg`` alone)."""
    robot = result.model.robot
    q_target = np.atleast_2d(np.asarray(q_target, dtype=float))
    m, n = q_target.shape
    k = 0 if target is None else result.model.target_names.index(target)
    model = _model(result)
    xfull = result.x if axis_fit is None else axis_fit.x  # the axis fit refitted the calibration's parameters
    x = model._local(xfull, 0)
    T_ref = model.station_T_ref[0]
    if tool is None:
        tool_p, tool_R = result.model.tools(xfull)[k], result.model.tool_rotations(xfull)[k]
    else:
        tool_p, tool_R = np.asarray(tool, dtype=float)[:3, 3], np.asarray(tool, dtype=float)[:3, :3]
    pl = np.broadcast_to(np.asarray(payload_kg, dtype=float), (m,))
    # the pose the program means: the nominal model in the calibration's tracker frame
    T_base = result.model.base_transform(xfull)
    Tn = T_base @ fk(build_chain(robot), q_target)
    p_des = Tn[:, :3, 3] + Tn[:, :3, :3] @ tool_p
    R_des = Tn[:, :3, :3] @ tool_R
    records = [dict(e) for e in effects or ()]
    sig = signals if signals is not None else Signals(np.array(pl))
    joint = [e for e in records if e["signal"] != "logged_frame"]
    deflect = DiscoveredEffects(tuple(joint), robot) if joint else None
    frames = frame_transforms(records, sig.logged, m, q_target, robot) if records else None
    if frames is not None:  # the base or the tool moved by logged signals: reach the pose cancelling it
        Tt = np.eye(4)
        Tt[:3, :3], Tt[:3, 3] = tool_R, tool_p
        Tb = np.linalg.inv(T_base)  # the desired pose in the robot's base frame, where the frames act
        pb, Rb = frame_desired(frames, Tt, (Tb[:3, :3] @ p_des.T).T + Tb[:3, 3], Tb[:3, :3] @ R_des)
        p_des, R_des = (T_base[:3, :3] @ pb.T).T + T_base[:3, 3], T_base[:3, :3] @ Rb

    def pose(q: np.ndarray, rows: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        k_ = len(rows)
        E = axis_errors(robot, q, pl[rows], axis_fit.terms, axis_fit.coef) if axis_fit is not None else None
        if deflect is not None:  # the joints where the effects put them (the Jacobian there: a small effect)
            q = q + deflect.offsets(q, sig.rows(rows))
        qa = np.concatenate([q, np.zeros((k_, model.chain.n_joints - n)) if E is None else E], axis=1)
        st = propagate(model.full_chain, qa, x[: model.n_chain], T_ref, record=jac)
        p = st.o + st.x * tool_p[0] + st.y * tool_p[1] + st.z * tool_p[2]
        R = st.R @ tool_R
        rot = ROT_WEIGHT_MM * matrix_to_rotvec(R @ np.swapaxes(R_des[rows], -1, -2))
        r = np.concatenate([p - p_des[rows], rot], axis=1)
        if not jac:
            return r, None
        _, _, J_q, W_q = point_jacobians(model.full_chain, st, p)
        J = np.concatenate([J_q[:, :, :n], ROT_WEIGHT_MM * W_q[:, :, :n]], axis=1)  # (k, 6, n)
        return r, J

    everyone = np.arange(m)
    r0, _ = pose(q_target, everyone, False)
    free = np.array([True if move_external else not robot.prismatic[j] for j in range(n)])
    q = _newton(pose, q_target, free, robot.prismatic[free], 6 if orientation else 3, max_iter, tol_mm)
    r, _ = pose(q, everyone, False)
    eta = xfull[: result.model.chain.n_params]
    zero_off = np.where(robot.prismatic, 0.0, zero_offsets(result.model.chain, eta))
    r_own, _ = pose(q_target - zero_off, everyone, False)
    rot_after = np.linalg.norm(r[:, 3:], axis=1) / ROT_WEIGHT_MM if orientation else np.zeros(m)
    return AxisCompensation(
        q_target=q_target,
        q=q,
        converged=np.linalg.norm(r[:, : 6 if orientation else 3], axis=1) < max(tol_mm, 1e-3),
        error_before_mm=np.linalg.norm(r0[:, :3], axis=1),
        residual_mm=np.linalg.norm(r[:, :3], axis=1),
        residual_deg=np.rad2deg(rot_after),
        move_external=move_external,
        error_before_xyz_mm=r0[:, :3],
        error_before_deg=np.rad2deg(np.linalg.norm(r0[:, 3:], axis=1) / ROT_WEIGHT_MM),
        own_error_mm=np.linalg.norm(r_own[:, :3], axis=1),
        zero_offsets=zero_off,
    )


def judge_axes(
    c: AxisCompensation,
    q_target: np.ndarray,
    robot: RobotDescription,
    policy: SafetyPolicy | None = None,
    request_reasons: Sequence[str] = (),
    unreachable: np.ndarray | None = None,
) -> tuple[list[str], list[list[str]]]:
    """The one safety policy's status and reasons of every target of a robot on external axes (the service's and
    ``compensation.csv``'s: a correction the service refused was written "ok" in the file, newcomer pass 17):
    the arm's joints as for any robot (the correction beyond the calibration's own zero offsets, the predicted
    error, the residual, the joint limits), an external axis outside its limits (mm) a joint-limit reason too."""
    sf = policy if policy is not None else SafetyPolicy()
    assert c.zero_offsets is not None and c.own_error_mm is not None
    arm = [j for j in range(robot.n_joints) if not robot.prismatic[j]]
    ext = [j for j in range(robot.n_joints) if robot.prismatic[j]]
    dq = c.q[:, arm] - q_target[:, arm]
    excess = np.rad2deg(np.abs(dq).max(axis=1))
    beyond = np.rad2deg(np.abs(dq + c.zero_offsets[arm]).max(axis=1))  # past the calibration's own zero offsets
    excess = np.where(excess > sf.max_correction_deg, np.minimum(excess, beyond), excess)
    rest = np.where(c.error_before_mm > sf.max_error_mm, np.minimum(c.error_before_mm, c.own_error_mm),
                    c.error_before_mm)  # fmt: skip
    status, reasons = sf.judge(
        c.converged, c.residual_mm, c.residual_deg, excess, rest, q_target[:, arm], c.q[:, arm],
        robot.q_limits[arm], [robot.joint_names[j] for j in arm], request_reasons, unreachable,
    )  # fmt: skip
    lim = robot.q_limits[ext]
    for k in range(len(q_target)):
        lo = np.minimum(q_target[k, ext], c.q[k, ext]) < lim[:, 0]
        hi = np.maximum(q_target[k, ext], c.q[k, ext]) > lim[:, 1]
        if (lo | hi).any():
            reasons[k] = [*reasons[k], "outside the external axis limits: " + ", ".join(
                f"{robot.joint_names[j]}={q_target[k, j]:.4f} mm (corrected {c.q[k, j]:.4f})"
                for i, j in enumerate(ext) if lo[i] or hi[i])]  # fmt: skip
            refuse = sf.on_joint_limits == "refuse" or status[k] == "refused"
            status[k] = "refused" if refuse else "flagged"
    return status, reasons


def _newton(
    pose: Any, q_target: np.ndarray, free: np.ndarray, slide: np.ndarray, rows_used: int, max_iter: int, tol_mm: float
) -> np.ndarray:
    """The Newton iterations of :func:`compensate_axes`, batched over the targets still iterating: ``pose(q, rows,
    jac) -> (r (k, 6), J (k, 6, n))``; ``free`` (n,) the joints that move, ``slide`` their kind (prismatic)."""
    q = q_target.copy()
    cap = np.where(slide, MAX_STEP_MM, MAX_STEP_RAD)
    # the least-norm step weighs 1 mm of an external axis as 1 mrad of a joint (ROT_WEIGHT_MM): the track takes
    # its share of an error along its travel instead of almost none
    weight = np.where(slide, 1.0, ROT_WEIGHT_MM)
    active = np.arange(len(q))
    for _ in range(max_iter):
        r, J = pose(q[active], active, True)
        assert J is not None
        r, J = r[:, :rows_used], J[:, :rows_used]
        keep = np.linalg.norm(r, axis=1) >= tol_mm
        if not keep.any():
            break
        active, r, A = active[keep], r[keep], J[keep][:, :, free]
        At = np.swapaxes(A, 1, 2)
        if rows_used >= A.shape[2]:  # (over)determined: damped normal equations
            N = At @ A
            N += 1e-12 * np.einsum("kii->k", N)[:, None, None] * np.eye(A.shape[2])
            dq = -np.linalg.solve(N, (At @ r[:, :, None]))[:, :, 0]
        else:  # more free joints than equations: the least-norm step, a joint's radian weighing ROT_WEIGHT_MM mm
            As = A / weight
            N = As @ np.swapaxes(As, 1, 2)
            N += 1e-12 * np.einsum("kii->k", N)[:, None, None] * np.eye(rows_used)
            dq = -(np.swapaxes(As, 1, 2) @ np.linalg.solve(N, r[:, :, None]))[:, :, 0] / weight
        scale = np.minimum(1.0, np.min(cap / np.maximum(np.abs(dq), 1e-300), axis=1))
        sub = q[active]
        sub[:, free] += dq * scale[:, None]
        q[active] = sub
    return q


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
