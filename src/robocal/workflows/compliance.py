"""Heavy-load workflow: data door -> unloaded geometric calibration -> compliance -> compensation -> files.

``run(data_dir, robot, out_dir, settings)`` writes into ``out_dir``:

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

from robocal.compensation import write_compensation_csv
from robocal.compliance.compensate import compensation_rows
from robocal.compliance.fit import ComplianceConfig, accuracy_by_condition, fit_compliance, geometric_step, load_table
from robocal.data.campaign import Campaign
from robocal.errors import ConfigError
from robocal.io import atomic_write, write_json
from robocal.robot import RobotDescription
from robocal.workflows import campaign_of, robot_of


def run(
    data_dir: str | Path | None,
    robot: str | Path | RobotDescription,
    out_dir: str | Path,
    settings: Mapping[str, Any] | None = None,
    *,
    split: Mapping[str, Any] | None = None,
    campaign: Campaign | None = None,
    report: bool = True,
    truth: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The whole heavy-load calibration (``settings``: a :class:`ComplianceConfig` mapping; ``report`` and the
    setting ``report`` both must be true for ``report.html``; ``truth``: a twin's truth, compared in the summary);
    returns the ``compliance.json`` content (without the geometric part)."""
    rob = robot_of(robot)
    cfg = ComplianceConfig.from_mapping(settings)
    camp = campaign_of(data_dir, rob, split, campaign)
    if not camp.has_payload:
        raise ConfigError(f"campaign {camp.source}: every payload_kg is 0; nothing to identify compliance from")
    geo = geometric_step(camp, rob, cfg)
    cfit = fit_compliance(camp, rob, geo, cfg)
    conditions = accuracy_by_condition(camp, geo, cfit, None if geo.start is None else geo.start.x_init)
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
        ids, qc, cmd, res, judged = compensation_rows(val, geo, cfit)
        write_compensation_csv(
            out / "compensation.csv", ids, qc, cmd, res, None, judged["status"], judged["reason"],
            judged["correction_max_deg"],
        )  # fmt: skip
        summary["compensation"] = {"rows": len(ids), "max_predicted_residual_mm": float(np.abs(res).max())}
    if report and cfg.report:
        from robocal.compliance.report import compliance_report

        compliance_report(summary, camp, geo, cfit).save(out / "report.html")
    write_json(out / "compliance.json", {**summary, "geometric": geo.to_dict(), "refitted_x": cfit.x.tolist()})
    return summary


__all__ = ["run"]
