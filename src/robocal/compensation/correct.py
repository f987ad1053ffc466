"""Correct a batch of targets, then decide whether each is safe: the one compensation entry point.

:func:`correct` (``robocal.compensate``) takes a calibration or the robot at the moment
(:class:`~robocal.compensation.ActualRobot`: thermal drift in its parameters), the targets, the joint-space effects
(compliance, discovered effects: the protocol of :mod:`robocal.compensation.effects`) and the one
:class:`~robocal.compensation.safety.SafetyPolicy`, and returns one :class:`Corrected`. The service's ``correct``
op and the program filter run the same steps on the compiled chains of a bundle (:func:`correct_targets`: targets
grouped by tool). Both bound the correction by what lies beyond the calibration's own (:func:`beyond_own`, its one
definition, through :func:`bound_measures`).

For joints ``q_target`` the nominal controller would use, the pose it means is the nominal forward kinematics
with the program's (nominal) tool; the corrected joints put the calibrated robot (its compiled chain, the
true tool, the joint-space effects) there (:func:`robocal.kinematics.ik.solve`); the
:class:`~robocal.compensation.safety.SafetyPolicy` then judges each target against the calibration's own
joint-space correction at that pose.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from robocal.compensation.effects import JointOffsets
from robocal.compensation.safety import SafetyPolicy
from robocal.config import setting
from robocal.kinematics.chain import RX, RY, RZ, Chain
from robocal.kinematics.ik import CompiledChain, forward, solve
from robocal.status import TargetStatus

if TYPE_CHECKING:
    from robocal.calibration.result import CalibrationResult
    from robocal.compensation import ActualRobot
    from robocal.compensation.effects import JointEffect, Signals

#: the joint-space effects as the Newton solver and :func:`beyond_own` call them: ``(q (k, n), rows (k,) or None)
#: -> dq (k, n)`` rad (:class:`~robocal.compensation.effects.JointOffsets`)
JointOffset = Callable[[np.ndarray, np.ndarray | None], np.ndarray]


@dataclass(frozen=True)
class SolverConfig:
    """Stopping rules of the Newton iteration (``serve.solver`` in conf/serve/default.yaml)."""

    max_iter: int = 20
    tol_mm: float = setting(1e-4, ge=0)
    tol_deg: float = setting(1e-6, ge=0)
    max_step_deg: float = setting(3.0, ge=0)

    def kwargs(self) -> dict[str, Any]:
        return {
            "max_iter": self.max_iter,
            "tol_mm": self.tol_mm,
            "tol_rad": np.deg2rad(self.tol_deg),
            "max_step_rad": np.deg2rad(self.max_step_deg),
        }


def zero_offsets(chain: Chain, eta: np.ndarray) -> np.ndarray:
    """The joint zero offsets ``(n,)`` rad of the parameters ``eta``: the parameters that add to a revolute
    joint's own rotation (MD-H ``theta{i}``, POE ``theta_{i}``), summed per joint."""
    off = np.zeros(chain.n_joints)
    joint, param = np.asarray(chain.joint), np.asarray(chain.param)
    sel = (joint >= 0) & (param >= 0) & np.isin(np.asarray(chain.kinds), (RX, RY, RZ))
    np.add.at(off, joint[sel], np.asarray(eta, dtype=float)[param[sel]])
    return off


@dataclass
class Corrected:
    """A corrected batch: q_target / q (m, n) rad (``q`` what the correction computed, applied or not);
    correction_deg (m, n) ``q - q_target`` in deg; converged (m,); error_before_* / residual_* (m, 3) mm / rad
    (rotation vectors); error_before_norm_mm / residual_norm_mm / residual_norm_deg (m,) their sizes (mm,
    deg); excess_deg (m,) the largest joint correction, or where it exceeds the bound the smaller of it and
    what is beyond the calibration's own correction; rest_mm (m,) the same for the predicted error and the
    error left after the calibration's own correction; status (m,) and reasons per target
    (:class:`SafetyPolicy`); notes per target: where an effect does not apply (:meth:`JointOffsets.notes`), not a
    flag; iterations: the Newton iterations (0 when not reported); command_T (m, 4, 4) or None: the Cartesian
    command the nominal controller must be sent so that its inverse kinematics yields ``q`` (:func:`correct` with a
    calibration)."""

    q_target: np.ndarray
    q: np.ndarray
    correction_deg: np.ndarray
    converged: np.ndarray
    error_before_mm: np.ndarray
    error_before_rad: np.ndarray
    error_before_norm_mm: np.ndarray
    residual_mm: np.ndarray
    residual_rad: np.ndarray
    residual_norm_mm: np.ndarray
    residual_norm_deg: np.ndarray
    excess_deg: np.ndarray
    rest_mm: np.ndarray
    status: list[str]
    reasons: list[list[str]]
    notes: list[list[str]] = field(default_factory=list)
    iterations: int = 0
    command_T: np.ndarray | None = None

    @property
    def correction_rad(self) -> np.ndarray:
        """Joint corrections ``q - q_target`` (m, n), rad."""
        return self.q - self.q_target

    @property
    def refused(self) -> np.ndarray:
        return np.array([s == TargetStatus.REFUSED for s in self.status], dtype=bool)


def own_correction(
    q: np.ndarray, zero_off: np.ndarray, offsets: JointOffset | None, rows: np.ndarray | None = None
) -> np.ndarray:
    """The calibration's own joint-space correction ``-(zero offsets) - (effects at q)`` (k, n) rad."""
    if offsets is None:
        return np.broadcast_to(-zero_off, q.shape)
    return -zero_off - offsets(q, rows)


def beyond_own(
    position: Callable[[np.ndarray, np.ndarray | None], np.ndarray],
    q_target: np.ndarray,
    q: np.ndarray,
    p_desired: np.ndarray,
    zero_off: np.ndarray,
    offsets: JointOffset | None,
    rows: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The correction beyond the calibration's own (the one definition): the largest joint (deg, (k,)) of the
    correction ``q - q_target`` (k, n) rad beyond the calibration's own joint-space correction
    (:func:`own_correction`), and the position error (mm, (k,)) of the robot commanded with only its own
    correction, against ``p_desired`` (k, 3).

    position : ``(q_real (k, n), rows) -> (k, 3)`` mm, the calibrated robot's tool position at the joints it really
    has (its effects already added); offsets : the joint-space effects ``(q (k, n), rows) -> dq`` or None;
    ``rows`` index the targets in ``offsets`` and ``position`` (all when None)."""
    beyond = q - q_target - own_correction(q, zero_off, offsets, rows)
    q_own = q_target + own_correction(q_target, zero_off, offsets, rows)
    qa = q_own if offsets is None else q_own + offsets(q_own, rows)  # the robot's joints when sent q_own
    d = position(qa, rows) - p_desired
    return np.rad2deg(np.abs(beyond).max(axis=1)), np.sqrt((d * d).sum(axis=1))


def bound_measures(
    policy: SafetyPolicy,
    position: Callable[[np.ndarray, np.ndarray | None], np.ndarray],
    q_target: np.ndarray,
    q: np.ndarray,
    error_before_mm: np.ndarray,
    p_desired: np.ndarray,
    zero_off: np.ndarray,
    offsets: JointOffset | None,
    rows: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """What the bound of ``policy`` sees (``excess_deg``, ``rest_mm``, (k,) each): the largest joint correction
    ``q - q_target`` and the error before ``error_before_mm`` (k, 3); where either exceeds the bound, the smaller of
    it and what is beyond the calibration's own correction (:func:`beyond_own`; ``rows`` as there)."""
    excess = np.abs(np.rad2deg(q - q_target)).max(axis=1)
    rest = np.sqrt((error_before_mm * error_before_mm).sum(axis=1))
    need = (excess > policy.max_correction_deg) | (rest > policy.max_error_mm)
    if need.any():
        k = np.flatnonzero(need)
        at = k if rows is None else np.asarray(rows)[k]
        b_deg, r_mm = beyond_own(position, q_target[k], q[k], p_desired[k], zero_off, offsets, at)
        excess[k] = np.minimum(excess[k], b_deg)
        rest[k] = np.minimum(rest[k], r_mm)
    return excess, rest


def _desired(
    cc_nom: CompiledChain,
    q: np.ndarray,
    tool_nominal: np.ndarray,
    tool_true: np.ndarray,
    frames: tuple[np.ndarray, np.ndarray] | None,
    rows: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """The pose the nominal controller means at ``q``, moved back by the frames of the targets ``rows`` (all when
    None) when logged signals move the base or the tool (:func:`robocal.compensation.discovered.frame_desired`)."""
    p, R, _, _ = forward(cc_nom, q, tool_nominal)
    if frames is None:
        return p, R
    from robocal.compensation.discovered import frame_desired

    sel = slice(None) if rows is None else rows
    return frame_desired((frames[0][sel], frames[1][sel]), tool_true, p, R)


def correct_targets(
    cc: CompiledChain,
    cc_nom: CompiledChain,
    tool_true: np.ndarray,
    tool_nominal: np.ndarray,
    q_target: np.ndarray,
    zero_off: np.ndarray,
    offsets: JointOffsets | None,
    q_limits: np.ndarray,
    joint_names: Sequence[str],
    orientation: bool = True,
    solver: SolverConfig | None = None,
    policy: SafetyPolicy | None = None,
    request_reasons: Sequence[str] = (),
    unreachable: np.ndarray | None = None,
    frames: tuple[np.ndarray, np.ndarray] | None = None,
    to_reported: Any = None,
) -> Corrected:
    """Correct the targets ``q_target`` (m, n) rad and judge them (a coupled robot's joints as the controller
    reports them: ``to_reported``, see :func:`_judged`).

    cc / cc_nom : the calibrated (at the moment's temperatures) and the nominal compiled chains; tool_true /
    tool_nominal : (4, 4) or (m, 4, 4) the tool on the calibrated flange and the tool the nominal controller
    plans with; zero_off : (n,) the calibrated joint zero offsets (:func:`zero_offsets`); offsets : the
    joint-space effects (:func:`robocal.compensation.effects.compose`), or None; orientation : match the tool
    orientation too (else the position only); frames : ``(A, D)`` (m, 4, 4) each, the base and the tool as
    logged signals move them (:func:`robocal.compensation.discovered.frame_transforms`): the pose to reach is
    moved back by them. The rest as :meth:`SafetyPolicy.judge`.
    """
    sv = solver or SolverConfig()
    sf = policy or SafetyPolicy()
    kw = sv.kwargs()
    m = len(q_target)
    groups: list[tuple[np.ndarray | None, np.ndarray, np.ndarray]]
    if np.ndim(tool_true) == 2 and np.ndim(tool_nominal) == 2:
        groups = [(None, tool_nominal, tool_true)]  # one tool: the whole batch in one call
    else:  # the solver takes one tool per call: targets grouped by tool, in order of first use
        tt_all = np.broadcast_to(tool_true, (m, 4, 4)) if np.ndim(tool_true) == 2 else tool_true
        tn_all = np.broadcast_to(tool_nominal, (m, 4, 4)) if np.ndim(tool_nominal) == 2 else tool_nominal
        keys = [tn_all[k].tobytes() + tt_all[k].tobytes() for k in range(m)]
        groups = []
        for key in dict.fromkeys(keys):
            members = np.array([k for k in range(m) if keys[k] == key])
            groups.append((members, tn_all[members[0]], tt_all[members[0]]))
    q: np.ndarray
    conv: np.ndarray
    eb_mm: np.ndarray
    eb_rad: np.ndarray
    res_mm: np.ndarray
    res_rad: np.ndarray
    if groups[0][0] is not None:
        q = np.empty_like(q_target)
        conv = np.empty(m, dtype=bool)
        eb_mm, eb_rad, res_mm, res_rad = (np.empty((m, 3)) for _ in range(4))
    desired = []
    for rows, tn, tt in groups:
        qt = q_target if rows is None else q_target[rows]
        p_des, R_des = _desired(cc_nom, qt, tn, tt, frames, rows)
        desired.append(p_des)
        jo: Any = None
        if offsets is not None:
            f = offsets

            def jo(qc: np.ndarray, r: np.ndarray, rows: np.ndarray | None = rows, f: JointOffsets = f) -> np.ndarray:
                return f(qc, r if rows is None else rows[r])

        sol = solve(cc, tt, qt, p_des, R_des if orientation else None, jo, **kw)
        if rows is None:
            q, conv, eb_mm, eb_rad = sol.q, sol.converged, sol.error_before_mm, sol.error_before_rad
            res_mm, res_rad = sol.residual_mm, sol.residual_rad
        else:
            q[rows], conv[rows] = sol.q, sol.converged
            eb_mm[rows], eb_rad[rows] = sol.error_before_mm, sol.error_before_rad
            res_mm[rows], res_rad[rows] = sol.residual_mm, sol.residual_rad
    # what the bound sees (SafetyPolicy): the whole correction and error, or, where they exceed it, what is
    # left beyond the calibration's own joint-space correction
    excess = np.empty(m)
    rest = np.empty(m)
    for (rows, _, tt), p_des in zip(groups, desired, strict=True):
        idx = np.arange(m) if rows is None else rows

        def position(qa: np.ndarray, _rows: np.ndarray | None, tt: np.ndarray = tt) -> np.ndarray:
            return np.asarray(forward(cc, qa, tt)[0])

        excess[idx], rest[idx] = bound_measures(
            sf, position, q_target[idx], q[idx], eb_mm[idx], p_des, zero_off, offsets, idx
        )
    notes = offsets.notes(q_target) if offsets is not None else [[] for _ in range(m)]
    return _judged(
        sf, q_target, q, conv, eb_mm, eb_rad, res_mm, res_rad, excess, rest, q_limits, joint_names,
        request_reasons, unreachable, notes, to_reported=to_reported,
    )  # fmt: skip


def _judged(
    policy: SafetyPolicy,
    q_target: np.ndarray,
    q: np.ndarray,
    converged: np.ndarray,
    eb_mm: np.ndarray,
    eb_rad: np.ndarray,
    res_mm: np.ndarray,
    res_rad: np.ndarray,
    excess: np.ndarray,
    rest: np.ndarray,
    q_limits: np.ndarray,
    joint_names: Sequence[str],
    request_reasons: Sequence[str],
    unreachable: np.ndarray | None,
    notes: list[list[str]],
    iterations: int = 0,
    command: np.ndarray | None = None,
    to_reported: Any = None,
) -> Corrected:
    """The :class:`Corrected` of a solved batch, judged by ``policy`` (arguments as :meth:`SafetyPolicy.judge`).
    ``to_reported``: a coupled robot's kinematic -> controller joints (:meth:`RobotDescription.to_reported`): its
    limits are the controller's, so the joints are judged (and named in the reasons) as the controller reports them
    (a FANUC J3 judged kinematic refused 24 of 100 targets inside the limits)."""
    res_n = np.sqrt((res_mm * res_mm).sum(axis=1))
    res_deg = np.rad2deg(np.sqrt((res_rad * res_rad).sum(axis=1)))
    qt_j, q_j = (q_target, q) if to_reported is None else (to_reported(q_target), to_reported(q))
    status, reasons = policy.judge(
        converged, res_n, res_deg, excess, rest, qt_j, q_j, q_limits, joint_names, request_reasons, unreachable
    )
    return Corrected(
        q_target,
        q,
        np.rad2deg(q - q_target),
        converged,
        eb_mm,
        eb_rad,
        np.sqrt((eb_mm * eb_mm).sum(axis=1)),
        res_mm,
        res_rad,
        res_n,
        res_deg,
        excess,
        rest,
        status,
        reasons,
        notes,
        iterations,
        command,
    )


def correct(
    robot: CalibrationResult | ActualRobot,
    q_target: np.ndarray,
    effects: Sequence[JointEffect] | JointOffset | None = None,
    policy: SafetyPolicy | None = None,
    *,
    target: str | None = None,
    signals: Signals | None = None,
    desired: tuple[np.ndarray, np.ndarray | None] | None = None,
    orientation: bool = True,
    q_limits: np.ndarray | None = None,
    joint_names: Sequence[str] | None = None,
    request_reasons: Sequence[str] = (),
    **newton: Any,
) -> Corrected:
    """Correct the joint targets ``q_target`` (m, n) rad and judge each: the one compensation entry point.

    robot : a calibration (:class:`~robocal.calibration.result.CalibrationResult`: its geometry, the tool of
    ``target`` (default its first), in the robot base frame) or an
    :class:`~robocal.compensation.ActualRobot` (what the robot is at the moment: thermal drift in its ``eta``, its
    tracker frame and tool). effects : the joint-space effects (:class:`~robocal.compensation.effects.JointEffect`
    list, composed with ``signals`` by :func:`~robocal.compensation.effects.compose`; the compliance model, the
    discovered effects, ...) or a composed hook; None: a calibration's own discovered effects (its ``effects``
    records), an ActualRobot's ``joint_offset``. policy : the one :class:`SafetyPolicy` (default its defaults).
    signals : the targets' :class:`~robocal.compensation.effects.Signals` (default: no payload, nothing else).
    desired : ``(p (m, 3), R (m, 3, 3) or None)`` the pose to reach (R None: the position only); default the
    nominal controller's at ``q_target`` (with a calibration; the base or the tool moved back by logged signals,
    :func:`~robocal.compensation.discovered.frame_transforms`). orientation : match the orientation too (else the
    position only). q_limits (n, 2) rad / joint_names : default the calibration's robot (an ActualRobot: not
    checked, ``q1`` ...). request_reasons : as :meth:`SafetyPolicy.judge`. newton : stopping rules of
    :func:`robocal.compensation.compensate`.
    """
    from robocal.compensation import ActualRobot, compensate, desired_poses
    from robocal.compensation.discovered import DiscoveredEffects, frame_desired, frame_transforms
    from robocal.compensation.effects import JointOffsets, joint_effects
    from robocal.compensation.effects import Signals as Sig
    from robocal.kinematics.chain import fk

    pol = policy if policy is not None else SafetyPolicy()
    q_target = np.asarray(q_target, dtype=float)
    m = len(q_target)
    sig = signals if signals is not None else Sig(np.zeros(m))
    command: np.ndarray | None = None
    if isinstance(robot, ActualRobot):
        actual = robot
        if effects is not None:
            actual = replace(actual, joint_offset=_hook(effects, sig))
        if desired is None:
            raise ValueError(
                "The 'desired' parameter of correct is required with an ActualRobot: the poses to reach, "
                "(p (m, 3) mm, R (m, 3, 3) or None). Got None instead."
            )
        p_d, R_d = desired
    else:
        if not hasattr(robot, "kinematic_errors"):
            raise TypeError(
                "The 'robot' parameter of correct must be a CalibrationResult or an ActualRobot. "
                f"Got {type(robot).__name__} instead."
            )
        model = robot.model
        k = 0 if target is None else model.target_names.index(target)
        tool, tool_R = model.tools(robot.x)[k], model.tool_rotations(robot.x)[k]
        records = list(robot.effects)
        if effects is None:
            effects = joint_effects(None, DiscoveredEffects(tuple(records), model.robot) if records else None)
        actual = ActualRobot(model.chain, robot.kinematic_errors, np.eye(4), tool, tool_R, _hook(effects, sig))
        T_tool = np.eye(4)
        T_tool[:3, :3], T_tool[:3, 3] = tool_R, tool
        if desired is None:
            nominal = ActualRobot(model.chain, np.zeros(model.chain.n_params), np.eye(4), tool, tool_R)
            p_d, R_d = desired_poses(nominal, q_target)
            frames = frame_transforms(records, sig.logged, m, q_target, model.robot)
            if frames is not None:  # the base or the tool moved by the logged signals: reach the pose cancelling it
                p_d, R_d = frame_desired(frames, T_tool, p_d, R_d)
        else:
            p_d, R_d = desired
        q_limits = model.robot.q_limits if q_limits is None else q_limits
        joint_names = model.robot.joint_names if joint_names is None else joint_names
    comp = compensate(actual, q_target, p_d, R_d if orientation else None, **newton)
    hook = actual.joint_offset
    offsets: JointOffset | None = None
    if hook is not None:  # the rows-aware form (a plain callable takes every target's joints at once)
        from robocal.compensation import _rows_of

        offsets = hook if isinstance(hook, JointOffsets) else cast(JointOffset, _rows_of(hook, q_target))
    bare = replace(actual, joint_offset=None)

    def position(qa: np.ndarray, _rows: np.ndarray | None) -> np.ndarray:
        return bare.pose(qa)[0]

    excess, rest = bound_measures(
        pol, position, q_target, comp.q, comp.error_before_mm, np.asarray(p_d, dtype=float),
        zero_offsets(actual.chain, actual.eta), offsets,
    )  # fmt: skip
    n = q_target.shape[1]
    ql = np.asarray(q_limits, dtype=float) if q_limits is not None else np.tile([-np.inf, np.inf], (n, 1))
    names = list(joint_names) if joint_names is not None else [f"q{j + 1}" for j in range(n)]
    if not isinstance(robot, ActualRobot):
        command = fk(robot.model.chain, comp.q) @ T_tool
    notes = hook.notes(q_target) if isinstance(hook, JointOffsets) else [[] for _ in range(m)]
    rob = None if isinstance(robot, ActualRobot) else robot.model.robot
    return _judged(
        pol, q_target, comp.q, comp.converged, comp.error_before_mm, comp.error_before_rad, comp.residual_mm,
        comp.residual_rad, excess, rest, ql, names, request_reasons, None, notes, comp.iterations, command,
        to_reported=None if rob is None or rob.coupling is None else rob.to_reported,
    )  # fmt: skip


def _hook(effects: Sequence[JointEffect] | JointOffset | None, signals: Signals) -> Any:
    """The joint-space effects as the solver's hook: a list composed with the targets' ``signals`` (an effect whose
    signal is not given raises its own error, naming it, when evaluated), a hook as it is; None without."""
    from robocal.compensation.effects import JointOffsets, compose

    if effects is None or callable(effects):
        return effects
    try:
        return compose(list(effects), signals)
    except ValueError:  # a signal not given: the effect's own error names it when evaluated
        return JointOffsets(tuple(effects), signals) if effects else None
