"""Correct a batch of targets, then decide whether each is safe: the code the service's ``correct`` op and the
program filter both run (one Newton, one joint-offset composer, one safety policy).

For joints ``q_target`` the nominal controller would use, the pose it means is the nominal forward kinematics
with the program's (nominal) tool; the corrected joints put the calibrated robot (its compiled chain, the
true tool, the joint-space effects) there (:func:`robocal.kinematics.ik.solve`); the
:class:`~robocal.compensation.safety.SafetyPolicy` then judges each target against the calibration's own
joint-space correction at that pose.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robocal.compensation.effects import JointOffsets
from robocal.compensation.safety import SafetyPolicy
from robocal.config import setting
from robocal.kinematics.chain import RX, RY, RZ, Chain
from robocal.kinematics.ik import CompiledChain, forward, solve
from robocal.status import TargetStatus


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
    flag."""

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

    @property
    def refused(self) -> np.ndarray:
        return np.array([s == TargetStatus.REFUSED for s in self.status], dtype=bool)


def own_correction(
    q: np.ndarray, zero_off: np.ndarray, offsets: JointOffsets | None, rows: np.ndarray | None = None
) -> np.ndarray:
    """The calibration's own joint-space correction ``-(zero offsets) - (effects at q)`` (k, n) rad."""
    if offsets is None:
        return np.broadcast_to(-zero_off, q.shape)
    return -zero_off - offsets(q, rows)


def beyond_own(
    cc: CompiledChain,
    tool: np.ndarray,
    q_target: np.ndarray,
    q: np.ndarray,
    p_desired: np.ndarray,
    zero_off: np.ndarray,
    offsets: JointOffsets | None,
    rows: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The correction ``q - q_target`` (k, n) rad beyond the calibration's own (largest joint, deg) and the
    position error (mm) of the robot ``cc`` with ``tool`` commanded with only its own correction, against
    ``p_desired`` (k, 3); ``rows`` index the targets' signals in ``offsets``."""
    beyond = q - q_target - own_correction(q, zero_off, offsets, rows)
    q_own = q_target + own_correction(q_target, zero_off, offsets, rows)
    qa = q_own if offsets is None else q_own + offsets(q_own, rows)  # the robot's joints when sent q_own
    d = forward(cc, qa, tool)[0] - p_desired
    return np.rad2deg(np.abs(beyond).max(axis=1)), np.sqrt((d * d).sum(axis=1))


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
) -> Corrected:
    """Correct the targets ``q_target`` (m, n) rad and judge them.

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
    dq_deg = np.rad2deg(q - q_target)
    excess = np.abs(dq_deg).max(axis=1)
    eb_n = np.sqrt((eb_mm * eb_mm).sum(axis=1))
    rest = eb_n.copy()
    need = (excess > sf.max_correction_deg) | (rest > sf.max_error_mm)
    if need.any():
        for (rows, _, tt), p_des in zip(groups, desired, strict=True):
            idx = np.arange(m) if rows is None else rows
            sel = need[idx]
            if sel.any():
                k = idx[sel]
                b_deg, r_mm = beyond_own(cc, tt, q_target[k], q[k], p_des[sel], zero_off, offsets, k)
                excess[k] = np.minimum(excess[k], b_deg)
                rest[k] = np.minimum(rest[k], r_mm)
    res_n = np.sqrt((res_mm * res_mm).sum(axis=1))
    res_deg = np.rad2deg(np.sqrt((res_rad * res_rad).sum(axis=1)))
    status, reasons = sf.judge(
        conv, res_n, res_deg, excess, rest, q_target, q, q_limits, joint_names, request_reasons, unreachable
    )
    notes = offsets.notes(q_target) if offsets is not None else [[] for _ in range(m)]
    return Corrected(
        q_target,
        q,
        dq_deg,
        conv,
        eb_mm,
        eb_rad,
        eb_n,
        res_mm,
        res_rad,
        res_n,
        res_deg,
        excess,
        rest,
        status,
        reasons,
        notes,
    )
