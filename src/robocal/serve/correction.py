"""The ``correct`` op's answers: the bundle's joint-space effects at the targets, the nominal joints of pose
targets, the corrected joints with the safety policy's verdict per target, and the same for a robot on
external axes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.compensation.correct import SolverConfig
from robocal.compensation.effects import LOGGED, Signals, compose, needs
from robocal.kinematics.chain import fk
from robocal.kinematics.ik import CompiledChain, compile_chain, forward, quaternions, solve
from robocal.kinematics.transforms import quat_to_matrix
from robocal.serve.bundle import Bundle
from robocal.serve.parsing import LOGGED_FIELD, CorrectRequest, RequestError, Targets
from robocal.serve.settings import ServiceConfig


def _joint_offsets(bundle: Bundle, tg: Targets, payload_kg: float) -> Any:
    """The bundle's joint-space effects at the targets' signals (None without effects); an effect needing a
    signal the request does not give is a ``bad_request``."""
    effects = bundle.joint_effects()
    if not effects:
        return None
    sig = Signals(np.full(len(tg.kind), payload_kg), tg.tau_Nm, tg.current_A, tg.direction, tg.logged)
    missing = sorted(needs(effects) - sig.given())
    if missing:
        shown = [f"{LOGGED_FIELD}.{k[len(LOGGED):]}" if k.startswith(LOGGED) else ("dir" if k == "direction" else k)
                 for k in missing]  # fmt: skip
        raise RequestError(
            "bad_request",
            f"the bundle's discovered effects {[e['key'] for e in bundle.effects]} need {shown} with every target"
            + (" (the logged signals' values at the moment, as in the campaign's columns)"
               if any(k.startswith(LOGGED) for k in missing) else ""),
        )  # fmt: skip
    return compose(effects, sig)


#: the note of a pose target in mode ``position`` whose stated orientation the nominal robot does not reach there
FREED_NOTE = (
    "quat_wxyz is not reached at this position from q_seed_deg: solved for the position only (mode 'position'), "
    "the orientation left free (the joints nearest the seed)"
)


def _nominal_joints(
    cc_nom: CompiledChain,
    tool_T: np.ndarray,
    tg: Targets,
    solver: SolverConfig,
    position: bool = False,
    to_kinematic: Any = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The joints (m, n) rad the nominal controller uses: a joint target as given, a pose target through the
    nominal inverse kinematics from its seed; whether each was reached; and which targets stated an orientation
    that was given up (see below).

    ``position`` (mode ``position``): a target without ``quat_wxyz``, or whose orientation the nominal robot
    does not reach at its position from the seed, is solved for the position only from its seed (the Newton
    steps are least-norm, so the joints, and the orientation with them, stay nearest the seed); the orientation
    is free in this mode, so it never makes a target unreachable. The last array marks the targets whose stated
    orientation was given up that way. ``to_kinematic``: a coupled robot's controller joints (``q_deg`` as the
    controller reports them, FANUC's J3 relative to J2) to the kinematic ones the chain takes."""
    seed = np.deg2rad(tg.q_deg)
    if to_kinematic is not None:
        seed = to_kinematic(seed)
    q_target = seed.copy()
    m = len(tg.kind)
    ik_ok = np.ones(m, dtype=bool)
    oriented = np.ones(m, dtype=bool) if tg.oriented is None else tg.oriented
    pose = tg.kind == 1
    rows = np.flatnonzero(pose & oriented)
    if len(rows):
        R_p = quat_to_matrix(tg.quat[rows])
        ik = solve(cc_nom, tool_T, seed[rows], tg.xyz_mm[rows], R_p, None, **solver.kwargs())
        q_target[rows] = ik.q
        ik_ok[rows] = ik.converged
    freed = np.zeros(m, dtype=bool)
    if position:
        free = np.flatnonzero(pose & ~(oriented & ik_ok))
        if len(free):
            ik = solve(cc_nom, tool_T, seed[free], tg.xyz_mm[free], None, None, **solver.kwargs())
            q_target[free] = ik.q
            ik_ok[free] = ik.converged
            freed[free] = oriented[free] & ik.converged
    return q_target, ik_ok, freed


def _target_replies(
    c: Any,
    cc_nom: CompiledChain,
    tool_T: np.ndarray,
    q_target: np.ndarray,
    kind: np.ndarray,
    to_reported: Any = None,
    orientation: bool = True,
) -> list[dict[str, Any]]:
    """One reply object per target: status, predicted error, reasons and notes; the corrected joints and the
    command for the nominal controller unless refused; the nominal joints of a pose target. ``to_reported``: a
    coupled robot's joints given back as its controller takes them (the correction too). Without ``orientation``
    (mode position) the orientation errors are null: not matched, not zero."""
    cmd_p, cmd_R, _, _ = forward(cc_nom, c.q, tool_T)  # what the nominal controller must be sent
    # rounded once for the whole batch (the wire's digits)
    eb_r = np.round(c.error_before_norm_mm, 7).tolist()
    ebx_r = np.round(c.error_before_mm, 7).tolist()
    ebd_r = (
        np.round(np.rad2deg(np.linalg.norm(c.error_before_rad, axis=1)), 9).tolist()
        if orientation
        else [None] * len(q_target)
    )
    q_c, q_t = (c.q, q_target) if to_reported is None else (to_reported(c.q), to_reported(q_target))
    qc_l = np.rad2deg(q_c).round(9).tolist()
    dq_l = (c.correction_deg if to_reported is None else np.rad2deg(q_c - q_t)).round(9).tolist()
    cmd_p_l = cmd_p.round(7).tolist()
    cmd_q_l = quaternions(cmd_R).round(12).tolist()
    resid_l = c.residual_norm_mm.tolist()
    resid_deg_l = c.residual_norm_deg.tolist() if orientation else [None] * len(q_target)
    qt_l = np.rad2deg(q_t).round(9).tolist()
    results = []
    for k in range(len(q_target)):
        reasons = c.reasons[k]
        r: dict[str, Any] = {
            "status": c.status[k],
            "predicted_error_mm": eb_r[k],
            "predicted_error_xyz_mm": ebx_r[k],
            "predicted_error_deg": ebd_r[k],
        }
        if reasons:
            r["reasons"] = reasons
        if c.notes[k]:  # where an effect does not apply (robocal.compensation.effects.JointOffsets.notes)
            r["notes"] = c.notes[k]
        if c.status[k] != "refused":
            r["q_deg"] = qc_l[k]
            r["correction_deg"] = dq_l[k]
            r["command"] = {"xyz_mm": cmd_p_l[k], "quat_wxyz": cmd_q_l[k]}
            r["residual_mm"] = resid_l[k]
            r["residual_deg"] = resid_deg_l[k]
        if kind[k] == 1:
            r["q_nominal_deg"] = qt_l[k]
        results.append(r)
    return results


def _correct_external(
    bundle: Bundle, r: CorrectRequest, cfg: ServiceConfig
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The ``correct`` op for a robot on external axes (issue 34): the replies and the request-level keys.

    The joints the nominal controller uses: a joint target's arm joints and external axes as given; a pose target
    (in the robot base frame, the external axes at their stated ``ext_mm``) through the nominal inverse
    kinematics of the arm with its external axes held there (:func:`robocal.kinematics.axes.arm_chain`, the
    service's compiled solver). The correction: :func:`robocal.compensation.axes.compensate_axes` (the calibrated
    geometry and the axes' own errors along the travel, numpy), the external axes moved only with
    ``move_external``. The one safety policy judges the arm's joints as for any robot (the correction beyond the
    calibration's own zero offsets, the predicted error, the residual, the joint limits); an external axis outside
    its limits (mm) is a joint-limit reason too."""
    from robocal.compensation.axes import compensate_axes, judge_axes
    from robocal.kinematics.axes import arm_chain

    tg = r.targets
    assert tg.ext_mm is not None
    m = len(tg.kind)
    arm, ext = bundle.arm, bundle.external
    robot = bundle.robot
    q_arm = np.deg2rad(tg.q_deg)
    ik_ok = np.ones(m, dtype=bool)
    freed = np.zeros(m, dtype=bool)
    pose = np.flatnonzero(tg.kind == 1)
    if len(pose):  # the nominal inverse kinematics, grouped by the external axes' values
        keys = [tg.ext_mm[k].tobytes() for k in pose]
        for key in dict.fromkeys(keys):
            rows = pose[[i for i, kk in enumerate(keys) if kk == key]]
            cc = compile_chain(arm_chain(bundle.chain, ext, tg.ext_mm[rows[0]]))
            q_r, ok_r, fr_r = _nominal_joints(cc, r.tool_T, tg.subset(rows), cfg.solver, r.mode == "position")
            q_arm[rows], ik_ok[rows], freed[rows] = q_r, ok_r, fr_r
    q_target = np.zeros((m, robot.n_joints))
    q_target[:, arm], q_target[:, ext] = q_arm, tg.ext_mm
    _joint_offsets(bundle, tg, r.payload_kg)  # an effect's signal missing from the request: a bad_request
    signals = Signals(np.full(m, r.payload_kg), tg.tau_Nm, tg.current_A, tg.direction, tg.logged)
    c = compensate_axes(
        bundle.calibration, q_target, r.tool_name, bundle.axis_fit, r.move_external, r.payload_kg,
        max_iter=max(cfg.solver.max_iter, 30), tol_mm=cfg.solver.tol_mm, orientation=r.mode == "pose",
        effects=list(bundle.effects), signals=signals,
    )  # fmt: skip
    status, reasons = judge_axes(c, q_target, robot, cfg.safety, r.reasons, ~ik_ok)
    assert c.error_before_xyz_mm is not None
    dq = c.q[:, arm] - q_target[:, arm]
    # the command for the nominal controller: the nominal pose of the corrected joints (base frame)
    T = fk(bundle.chain, c.q) @ r.tool_T
    quat = quaternions(T[:, :3, :3])
    results = []
    for k in range(m):
        res: dict[str, Any] = {
            "status": status[k],
            "predicted_error_mm": round(float(c.error_before_mm[k]), 7),
            "predicted_error_xyz_mm": np.round(c.error_before_xyz_mm[k], 7).tolist(),
            # null where the orientation is not matched (mode position): 0.0 read as "no orientation error"
            "predicted_error_deg": round(float(c.error_before_deg[k]), 9) if c.error_before_deg is not None else None,
        }
        if reasons[k]:
            res["reasons"] = reasons[k]
        if freed[k]:
            res["notes"] = [FREED_NOTE]
        if status[k] != "refused":
            res["q_deg"] = np.rad2deg(c.q[k, arm]).round(9).tolist()
            res["ext_mm"] = c.q[k, ext].tolist()  # unrounded: a track not moved comes back exactly as sent
            res["correction_deg"] = np.rad2deg(dq[k]).round(9).tolist()
            res["ext_correction_mm"] = (c.q[k, ext] - q_target[k, ext]).tolist()
            res["command"] = {"xyz_mm": T[k, :3, 3].round(7).tolist(), "quat_wxyz": quat[k].round(12).tolist()}
            res["residual_mm"] = float(c.residual_mm[k])
            res["residual_deg"] = float(c.residual_deg[k]) if r.mode == "pose" else None
        if tg.kind[k] == 1:
            res["q_nominal_deg"] = np.rad2deg(q_arm[k]).round(9).tolist()
        results.append(res)
    return results, {"move_external": r.move_external, "external_axes": [robot.joint_names[j] for j in ext]}
