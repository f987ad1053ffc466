"""Compensation of a compliance fit (Mao et al. 2021, eq. 27): the joints that put the deflected robot where the
controller expects it."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.compensation import ActualRobot
from robocal.compensation.correct import correct
from robocal.compensation.effects import ComplianceEffect, Signals
from robocal.compliance.fit import ComplianceFit
from robocal.kinematics.chain import fk
from robocal.status import TargetStatus

if TYPE_CHECKING:
    from robocal.calibration.result import CalibrationResult
    from robocal.data.campaign import Campaign


def compensation_rows(
    campaign: Campaign, geo: CalibrationResult, cfit: ComplianceFit, policy: Any = None
) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Eq. 27 for every row of ``campaign``: joints that put the deflected robot where the controller expects.

    The controller expects the calibrated geometric model at the commanded joints; the deflection predicted by
    the compliance model (from the row's currents / torques / payload) is undone by Newton iterations
    (:func:`robocal.compensation.correct.correct`, first order ``q* = q_n - c s``). Returns ids, corrected joints,
    the corrected Cartesian command (base frame), the predicted residual (mm) and the one safety policy's
    verdict (``status``, ``reason``, ``correction_max_deg`` per row; ``policy`` default its defaults): a refused
    row carries the commanded joints and their predicted error instead.
    """
    gm = geo.model
    known = {t: k for k, t in enumerate(gm.target_names)}
    q_c = np.zeros_like(campaign.q)
    cmd = np.zeros((campaign.n_rows, 4, 4))
    res = np.zeros((campaign.n_rows, 3))
    status = np.full(campaign.n_rows, TargetStatus.OK, dtype=object)
    reason = np.full(campaign.n_rows, "", dtype=object)
    corr_max = np.zeros(campaign.n_rows)
    eta = cfit.x[: gm.chain.n_params]
    T = gm.base_transform(cfit.x)
    tools = gm.tools(cfit.x)
    model = cfit.model
    for name, k in known.items():
        sel = np.flatnonzero(campaign.target == name)
        if not len(sel):
            continue
        sub = campaign.subset(np.isin(np.arange(campaign.n_rows), sel))
        # the deflection as a joint-space effect (the protocol of robocal.compensation.effects): the compliance
        # model at the corrected joints with the row's payload, currents or torques
        sig = Signals(np.asarray(sub.payload_kg, dtype=float), sub.tau_Nm, sub.current_A)
        actual = ActualRobot(gm.chain, eta, T, tools[k], np.eye(3))
        desired = ActualRobot(gm.chain, geo.x[: gm.chain.n_params], gm.base_transform(geo.x), tools[k], np.eye(3))
        p_des, _, _ = desired.pose(sub.q)
        comp = correct(actual, sub.q, [ComplianceEffect(model)], policy, signals=sig, desired=(p_des, None),
                       orientation=False, q_limits=gm.robot.q_limits, joint_names=gm.robot.joint_names)  # fmt: skip
        refused = comp.refused
        status[sel], reason[sel] = comp.status, ["; ".join(r) for r in comp.reasons]
        corr_max[sel] = np.rad2deg(np.abs(comp.q - sub.q).max(axis=1))
        q_send = np.where(refused[:, None], sub.q, comp.q)
        q_c[sel] = q_send
        Tf = fk(gm.chain, q_send, eta)
        Tt = np.eye(4)
        Tt[:3, 3] = tools[k]
        cmd[sel] = Tf @ Tt
        res[sel] = np.where(refused[:, None], comp.error_before_mm, comp.residual_mm)
    ids = [f"{p}@{w:g}kg/{t}" for p, w, t in zip(campaign.pose_id, campaign.payload_kg, campaign.target, strict=True)]
    return ids, q_c, cmd, res, {"status": status, "reason": reason, "correction_max_deg": corr_max}


__all__ = ["compensation_rows"]
