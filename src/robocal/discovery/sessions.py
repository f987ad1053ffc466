"""A calibration judged on another session: the same robot measured another day, from another tracker
placement, in another part of its workspace (issue 33 item 2).

A plant calibrates once and runs for months; the tracker that measured the calibration is gone or moved. What
carries over is the robot's model (geometry, tool, joint-level effects), not the tracker's frame: so the other
session's tracker is registered to the model's predictions on that session's own calibration rows (a rigid
fit, six parameters, the model frozen), and the model is judged on the session's validation rows. With every
joint-level effect taken out in turn, the same evaluation says which effects helped there and which hurt.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.compensation.discovered import joint_offsets
from robocal.data.contract import Campaign
from robocal.errors import DataError
from robocal.identification.calibrate import CalibrationResult
from robocal.kinematics.chain import fk
from robocal.kinematics.transforms import kabsch
from robocal.metrics import ErrorStats


def predicted_points(cal: CalibrationResult, campaign: Campaign, records: tuple[dict[str, Any], ...]) -> np.ndarray:
    """The target points the model predicts for every row of ``campaign`` in the robot's base frame (m, 3) mm:
    the joint-level effects ``records`` (a subset of ``cal.effects``) added to the joint angles (evaluated
    exactly, not from the service's tables), the calibrated geometry, the row's target's tool offset."""
    model = cal.model
    tools = cal.tools
    unknown = sorted(set(campaign.target.astype(str).tolist()) - set(tools))
    if unknown:
        raise DataError(
            f"campaign {campaign.source}: target(s) {unknown} are not in the calibration (its targets: {sorted(tools)})"
        )
    q = np.asarray(campaign.q, dtype=float)
    if records:
        pay = np.broadcast_to(np.asarray(campaign.payload_kg, dtype=float), (campaign.n_rows,))
        q = q + joint_offsets(list(records), model.robot, q, pay)
    T = fk(model.chain, q, cal.kinematic_errors)
    off = np.stack([tools[str(t)] for t in campaign.target])
    return np.einsum("mij,mj->mi", T[:, :3, :3], off) + T[:, :3, 3]


def _judge(pred: np.ndarray, meas: np.ndarray, reg: np.ndarray, val: np.ndarray) -> tuple[ErrorStats, np.ndarray]:
    T = kabsch(pred[reg], meas[reg])
    e = pred[val] @ T[:3, :3].T + T[:3, 3] - meas[val]
    return ErrorStats.of(e), e


def session_validation(cal: CalibrationResult, campaign: Campaign, geometric: CalibrationResult | None = None) -> dict:
    """``cal`` (a calibration, with or without discovered effects) on another session ``campaign``: the tracker
    registered on the session's calibration rows (a rigid fit to the model's predictions), errors on its
    validation rows (or, without a split, on every row: then the figure is a fit, and said so).

    Returns ``{"n_registration_rows", "n_validation_rows", "final": stats, "geometric": stats (when given),
    "without": {effect key: stats with that effect left out}, "helped": [...], "hurt": [...]}``; stats are
    :class:`ErrorStats` dicts in mm."""
    split = np.asarray(campaign.split).astype(str)
    reg = split == "calibration"
    val = split == "validation"
    note = None
    if not val.any():
        reg = val = np.ones(campaign.n_rows, dtype=bool)
        note = "the session has no validation rows: registered and judged on the same rows (a fit, not held out)"
    if int(reg.sum()) < 3:
        raise DataError(
            f"campaign {campaign.source}: {int(reg.sum())} calibration row(s); registering a tracker needs >= 3"
        )
    meas = np.asarray(campaign.p_mm, dtype=float)
    records = tuple(cal.effects)
    final, _ = _judge(predicted_points(cal, campaign, records), meas, reg, val)
    out: dict[str, Any] = {
        "n_registration_rows": int(reg.sum()),
        "n_validation_rows": int(val.sum()),
        "final": final.to_dict(),
    }
    if note:
        out["note"] = note
    if geometric is not None:
        out["geometric"] = _judge(predicted_points(geometric, campaign, ()), meas, reg, val)[0].to_dict()
    without: dict[str, Any] = {}
    for k, rec in enumerate(records):
        rest = records[:k] + records[k + 1 :]
        without[str(rec["key"])] = _judge(predicted_points(cal, campaign, rest), meas, reg, val)[0].to_dict()
    out["without"] = without
    m = final.mean_mm
    out["helped"] = sorted(k for k, s in without.items() if s["mean_position_mm"] > m)
    out["hurt"] = sorted(k for k, s in without.items() if s["mean_position_mm"] < m)
    return out


__all__ = ["predicted_points", "session_validation"]
