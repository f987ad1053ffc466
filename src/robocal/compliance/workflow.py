"""Heavy-load workflow: data door -> unloaded geometric calibration -> compliance -> compensation -> files.

``run_compliance(data_dir, robot, out_dir, settings)`` writes into ``out_dir``:

- ``compliance.json``: the compliance model (per joint ``c`` with standard errors, rad/A or rad/(N·m)), the fit,
  accuracy per load condition before / after compensation (mean / max / RMS mm), the load table (paper table 4
  in kind), the controller parameters of the geometric calibration (POE decoupling, eq. 26) when the robot has
  the Mao layout, and the geometric calibration itself (``geometric``, loadable with ``load_calibration``);
- ``compensation.csv``: controller-ready corrected joints for the validation rows (eq. 27), the format of
  :func:`robocal.compensation.write_compensation_csv`;
- ``conditions.csv``: one row per (split, payload) condition; ``report.html``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from robocal.compensation import ActualRobot, compensate, write_compensation_csv
from robocal.compliance.fit import (
    ComplianceConfig,
    ComplianceFit,
    accuracy_by_condition,
    campaign_signal,
    fit_compliance,
    load_table,
)
from robocal.data.contract import Campaign, SplitConfig, read_campaign
from robocal.errors import ConfigError
from robocal.identification.calibrate import CalibrationConfig, CalibrationResult, calibrate
from robocal.io import atomic_write, write_json
from robocal.kinematics.chain import fk
from robocal.robot import RobotDescription, load_robot


def geometric_step(campaign: Campaign, robot: RobotDescription, cfg: ComplianceConfig) -> CalibrationResult:
    """Geometric calibration of the unloaded calibration rows (the paper's first step)."""
    unloaded = (campaign.split == "calibration") & (campaign.payload_kg <= cfg.unloaded_max_kg)
    if not unloaded.any():
        raise ConfigError(
            f"campaign {campaign.source}: no unloaded calibration rows (payload_kg <= {cfg.unloaded_max_kg:g}); "
            "the compliance fit sits on an unloaded geometric calibration"
        )
    return calibrate(
        campaign.subset(unloaded), robot, CalibrationConfig.from_mapping(cfg.geometric, "compliance.geometric")
    )


def compensation_rows(
    campaign: Campaign, geo: CalibrationResult, cfit: ComplianceFit
) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 27 for every row of ``campaign``: joints that put the deflected robot where the controller expects.

    The controller expects the calibrated geometric model at the commanded joints; the deflection predicted by
    the compliance model (from the row's currents / torques / payload) is undone by Newton iterations
    (:func:`robocal.compensation.compensate`, first order ``q* = q_n - c s``). Returns ids, corrected joints,
    the corrected Cartesian command (base frame) and the predicted residual (mm).
    """
    gm = geo.model
    known = {t: k for k, t in enumerate(gm.target_names)}
    q_c = np.zeros_like(campaign.q)
    cmd = np.zeros((campaign.n_rows, 4, 4))
    res = np.zeros((campaign.n_rows, 3))
    eta = cfit.x[: gm.chain.n_params]
    T = gm.base_transform(cfit.x)
    tools = gm.tools(cfit.x)
    model = cfit.model
    for name, k in known.items():
        sel = np.flatnonzero(campaign.target == name)
        if not len(sel):
            continue
        sub = campaign.subset(np.isin(np.arange(campaign.n_rows), sel))
        S = campaign_signal(model, sub)
        dq_fixed = S * model.c

        def offset(q: np.ndarray, dq: np.ndarray = dq_fixed, s: Campaign = sub) -> np.ndarray:
            if model.kind == "gravity":
                return model.joint_offsets(q, s.payload_kg)
            return dq

        actual = ActualRobot(gm.chain, eta, T, tools[k], np.eye(3), joint_offset=offset)
        desired = ActualRobot(gm.chain, geo.x[: gm.chain.n_params], gm.base_transform(geo.x), tools[k], np.eye(3))
        p_des, _, _ = desired.pose(sub.q)
        comp = compensate(actual, sub.q, p_des)
        q_c[sel] = comp.q
        Tf = fk(gm.chain, comp.q, eta)
        Tt = np.eye(4)
        Tt[:3, 3] = tools[k]
        cmd[sel] = Tf @ Tt
        res[sel] = comp.residual_mm
    ids = [f"{p}@{w:g}kg/{t}" for p, w, t in zip(campaign.pose_id, campaign.payload_kg, campaign.target, strict=True)]
    return ids, q_c, cmd, res


def run_compliance(
    data_dir: str | Path,
    robot: str | Path | RobotDescription,
    out_dir: str | Path,
    settings: Mapping[str, Any] | None = None,
    split: Mapping[str, Any] | None = None,
    campaign: Campaign | None = None,
    truth: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The whole heavy-load calibration; returns the ``compliance.json`` content (without the geometric part)."""
    rob = robot if isinstance(robot, RobotDescription) else load_robot(robot)
    cfg = ComplianceConfig.from_mapping(settings)
    camp = campaign if campaign is not None else read_campaign(data_dir, rob, split=SplitConfig.from_mapping(split))
    if not camp.has_payload:
        raise ConfigError(f"campaign {camp.source}: every payload_kg is 0; nothing to identify compliance from")
    geo = geometric_step(camp, rob, cfg)
    cfit = fit_compliance(camp, rob, geo, cfg)
    conditions = accuracy_by_condition(camp, geo, cfit, geo.extra.get("x_init"))
    table = load_table(conditions)
    unloaded_cal = camp.subset((camp.split == "calibration") & (camp.payload_kg <= cfg.unloaded_max_kg))
    decoupled: dict[str, Any] | None
    try:
        from robocal.compliance.decoupling import controller_parameters

        decoupled = controller_parameters(geo, unloaded_cal.q, unloaded_cal.target_index)
    except ConfigError as exc:
        decoupled = {"available": False, "reason": str(exc)}
    model_dict = cfit.model.to_dict()
    summary: dict[str, Any] = {
        "robot": rob.name,
        "kind": cfit.model.kind,
        "unit": cfit.model.unit,
        "method": cfit.method,
        "compliance": {
            j["name"]: {k: j[k] for k in ("c", "stderr", "identified", "stiffness")} for j in model_dict["joints"]
        },
        "fit": cfit.fit,
        "selection": cfit.selection,
        "geometric_fit": {k: geo.fit[k] for k in ("rms_position_mm", "mean_position_mm", "max_position_mm", "n_rows")},
        "conditions": conditions,
        "load_table": table,
        "controller_parameters": decoupled,
        "model": model_dict,
    }
    if truth and "effects" in truth and "compliance" in truth["effects"]:
        tc = truth["effects"]["compliance"]
        key = "c_rad_per_A" if cfit.model.kind == "current" else "c_rad_per_Nm"
        true_c = np.asarray(tc[key], dtype=float)
        summary["truth"] = {
            "c": true_c.tolist(),
            "relative_error": [
                float((cfit.model.c[j] - true_c[j]) / true_c[j]) if cfit.model.identified[j] and true_c[j] else None
                for j in range(rob.n_joints)
            ],
        }
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    flat = []
    for c in conditions:
        row = {"split": c["split"], "payload_kg": c["payload_kg"], "n_rows": c["n_rows"]}
        for stage in ("nominal", "after_geometric", "after_compliance"):
            for k, v in c.get(stage, {}).items():
                row[f"{stage}_{k}"] = v
        flat.append(row)
    frame = pd.DataFrame(flat)
    atomic_write(out / "conditions.csv", lambda p: frame.to_csv(p, index=False, float_format="%.6f"))
    if cfg.compensation:
        val = camp.validation() if np.any(camp.split == "validation") else camp.subset(camp.payload_kg > 0)
        ids, qc, cmd, res = compensation_rows(val, geo, cfit)
        write_compensation_csv(out / "compensation.csv", ids, qc, cmd, res)
        summary["compensation"] = {"rows": len(ids), "max_predicted_residual_mm": float(np.abs(res).max())}
    if cfg.report:
        from robocal.compliance.report import compliance_report

        compliance_report(summary, camp, geo, cfit).save(out / "report.html")
    write_json(out / "compliance.json", {**summary, "geometric": geo.to_dict(), "refitted_x": cfit.x.tolist()})
    return summary


__all__ = ["compensation_rows", "geometric_step", "run_compliance"]
