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
from dataclasses import dataclass
from typing import Any

import numpy as np

from robocal.compensation.effects import JointOffsets
from robocal.compensation.safety import SafetyPolicy
from robocal.config import setting
from robocal.kinematics.chain import RX, RY, RZ, Chain
from robocal.kinematics.ik import CompiledChain, forward, solve


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
    converged (m,); error_before_* / residual_* (m, 3) mm / rad (rotation vectors); excess_deg (m,) the
    largest joint correction beyond the calibration's own; rest_mm (m,) the error left after the calibration's
    own correction; status (m,) and reasons per target (:class:`SafetyPolicy`)."""

    q_target: np.ndarray
    q: np.ndarray
    converged: np.ndarray
    error_before_mm: np.ndarray
    error_before_rad: np.ndarray
    residual_mm: np.ndarray
    residual_rad: np.ndarray
    excess_deg: np.ndarray
    rest_mm: np.ndarray
    status: list[str]
    reasons: list[list[str]]

    @property
    def refused(self) -> np.ndarray:
        return np.array([s == "refused" for s in self.status], dtype=bool)


def own_correction(
    q: np.ndarray, zero_off: np.ndarray, offsets: JointOffsets | None, rows: np.ndarray | None = None
) -> np.ndarray:
    """The calibration's own joint-space correction ``-(zero offsets) - (effects at q)`` (k, n) rad."""
    own = np.broadcast_to(-zero_off, q.shape)
    return own if offsets is None else own - offsets(q, rows)


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
) -> Corrected:
    """Correct the targets ``q_target`` (m, n) rad and judge them.

    cc / cc_nom : the calibrated (at the moment's temperatures) and the nominal compiled chains; tool_true /
    tool_nominal : (4, 4) or (m, 4, 4) the tool on the calibrated flange and the tool the nominal controller
    plans with; zero_off : (n,) the calibrated joint zero offsets (:func:`zero_offsets`); offsets : the
    joint-space effects (:func:`robocal.compensation.effects.compose`), or None; orientation : match the tool
    orientation too (else the position only). The rest as :meth:`SafetyPolicy.judge`.
    """
    sv = solver or SolverConfig()
    sf = policy or SafetyPolicy()
    kw = sv.kwargs()
    m = len(q_target)
    tt_all = np.broadcast_to(tool_true, (m, 4, 4)) if np.ndim(tool_true) == 2 else tool_true
    tn_all = np.broadcast_to(tool_nominal, (m, 4, 4)) if np.ndim(tool_nominal) == 2 else tool_nominal
    if np.ndim(tool_true) == 2 and np.ndim(tool_nominal) == 2:
        groups = [np.arange(m)]
    else:  # the solver takes one tool per call: targets grouped by tool, in order of first use
        keys = [tn_all[k].tobytes() + tt_all[k].tobytes() for k in range(m)]
        groups = [np.array([k for k in range(m) if keys[k] == key]) for key in dict.fromkeys(keys)]
    q = np.empty_like(q_target)
    conv = np.empty(m, dtype=bool)
    eb_mm, eb_rad, res_mm, res_rad = (np.empty((m, 3)) for _ in range(4))
    rest = np.empty(m)
    for rows in groups:
        whole = len(groups) == 1
        qt = q_target if whole else q_target[rows]
        tn, tt = tn_all[rows[0]], tt_all[rows[0]]
        p_des, R_des, _, _ = forward(cc_nom, qt, tn)
        jo = None
        if offsets is not None:
            f = offsets

            def jo(qc: np.ndarray, r: np.ndarray, rows: np.ndarray = rows, f: JointOffsets = f) -> np.ndarray:
                return f(qc, rows[r])

        sol = solve(cc, tt, qt, p_des, R_des if orientation else None, jo, **kw)
        # the error left after the calibration's own joint-space correction (commanded q_own, the robot at
        # q_own + offsets + effects)
        q_own = qt + own_correction(qt, zero_off, offsets, rows)
        qa = q_own if offsets is None else q_own + offsets(q_own, rows)
        p_own, _, _, _ = forward(cc, qa, tt)
        if whole:
            q, conv, eb_mm, eb_rad, res_mm, res_rad = (
                sol.q,
                sol.converged,
                sol.error_before_mm,
                sol.error_before_rad,
                sol.residual_mm,
                sol.residual_rad,
            )
            rest = np.linalg.norm(p_own - p_des, axis=1)
        else:
            q[rows], conv[rows] = sol.q, sol.converged
            eb_mm[rows], eb_rad[rows] = sol.error_before_mm, sol.error_before_rad
            res_mm[rows], res_rad[rows] = sol.residual_mm, sol.residual_rad
            rest[rows] = np.linalg.norm(p_own - p_des, axis=1)
    excess = np.rad2deg(np.abs(q - q_target - own_correction(q, zero_off, offsets)).max(axis=1))
    status, reasons = sf.judge(
        conv,
        res_mm,
        res_rad,
        excess,
        rest,
        q_target,
        q,
        q_limits,
        joint_names,
        request_reasons,
        unreachable,
    )
    return Corrected(q_target, q, conv, eb_mm, eb_rad, res_mm, res_rad, excess, rest, status, reasons)
