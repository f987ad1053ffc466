"""HTML report and figures of the heavy-load calibration (paper fig. 8 / table 3 and table 4 in kind)."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from robocal.calibration.result import CalibrationResult
from robocal.compliance.fit import ComplianceFit, position_errors
from robocal.data.campaign import Campaign
from robocal.report import plots
from robocal.report.html import Report


def condition_figure(summary: dict[str, Any], split: str = "validation") -> Figure:
    """Mean error per load condition: nominal, after geometric calibration, after compliance (fig. 8 in kind)."""
    rows = [c for c in summary["conditions"] if c["split"] == split] or summary["conditions"]
    labels = [f"{c['split'][:3]} {c['payload_kg']:g} kg" for c in rows]
    values: dict[str, list[float]] = {}
    if all("nominal" in c for c in rows):
        values["nominal"] = [c["nominal"]["mean_mm"] for c in rows]
    values["geometric calibration"] = [c["after_geometric"]["mean_mm"] for c in rows]
    values["+ compliance"] = [c["after_compliance"]["mean_mm"] for c in rows]
    return plots.bar_table(labels, values, "mean 3-D position error (mm)")


def load_table_figure(summary: dict[str, Any]) -> Figure:
    """Position accuracy before / after compensation per load (table 4 in kind)."""
    t = summary["load_table"]
    labels = [f"{r['payload_kg']:g} kg ({r['load_ratio_pct']:.0f} %)" for r in t]
    return plots.bar_table(
        labels,
        {
            "before compensation": [r["position_before_mm"] for r in t],
            "after compensation": [r["position_after_mm"] for r in t],
        },
        "mean 3-D position error (mm)",
    )


def compliance_report(
    summary: dict[str, Any], campaign: Campaign, geo: CalibrationResult, cfit: ComplianceFit
) -> Report:
    model = cfit.model
    rep = Report(f"Heavy-load calibration: {summary['robot']}", f"compliance from {model.kind} ({model.unit})")
    rep.heading("Summary")
    fit = summary["fit"]
    rep.kv(
        {
            "campaign": campaign.source,
            "method": summary["method"],
            "deflection signal": model.kind,
            "rows used for c": fit["n_rows"],
            "loads used for c (kg)": ", ".join(f"{v:g}" for v in fit["loads_kg"]),
            "geometric fit RMS, unloaded (mm)": summary["geometric_fit"]["rms_position_mm"],
            "compliance fit RMS (mm)": fit["rms_position_mm"],
        }
    )
    rep.paragraph(
        "Mao et al. (2021): geometric calibration on the unloaded rows (POE model), then the joint compliance c "
        "from the loaded rows with dq = c · s (s: motor current, drive torque or computed gravity torque); "
        "compensation commands q* = q_n - c s (eq. 27 with this sign convention). Method 'joint' refits the "
        "geometry together with c on every calibration row."
    )
    rep.heading("Identified compliance")
    trows = []
    truth = summary.get("truth")
    for j, name in enumerate(model.joint_names):
        row = {
            "joint": name,
            f"c ({model.unit})": float(model.c[j]) if model.identified[j] else None,
            "std. error": float(model.stderr[j]) if model.identified[j] else None,
            "t": fit["t_values"].get(name),
        }
        if truth:
            row["truth"] = truth["c"][j]
            rel = truth["relative_error"][j]
            row["error %"] = None if rel is None else 100.0 * rel
        trows.append(row)
    rep.table(trows, float_fmt="{:.4g}")
    ident = np.flatnonzero(model.identified)
    if len(ident):
        rep.figure(
            plots.parameter_errors(
                [model.joint_names[j] for j in ident],
                model.c[ident],
                model.stderr[ident],
                truth=np.asarray(truth["c"])[ident] if truth else None,
                xlabel=f"c ({model.unit})",
                k=2.0,
            ),
            "identified compliance ± 2 standard errors",
        )
    if summary["selection"]:
        rep.note(
            "joints dropped by the automatic selection: "
            + "; ".join(
                f"joint {s['dropped_joint']} (t = {s['t']:.2f}, compliance {s['c']:.3g})"
                if {"dropped_joint", "t", "c"} <= set(s)
                else ", ".join(f"{k} {v}" for k, v in s.items())
                for s in summary["selection"]
            )
        )
    rep.heading("Accuracy per condition (fig. 8 / table 3 in kind)")
    crow = []
    for c in summary["conditions"]:
        crow.append(
            {
                "split": c["split"],
                "payload kg": c["payload_kg"],
                "rows": c["n_rows"],
                "nominal mean": c.get("nominal", {}).get("mean_mm"),
                "nominal max": c.get("nominal", {}).get("max_mm"),
                "geometric mean": c["after_geometric"]["mean_mm"],
                "geometric max": c["after_geometric"]["max_mm"],
                "compliance mean": c["after_compliance"]["mean_mm"],
                "compliance max": c["after_compliance"]["max_mm"],
            }
        )
    rep.table(crow, float_fmt="{:.3f}")
    rep.figure(condition_figure(summary), "mean position error per load condition (validation rows)")
    rep.heading("Load table (table 4 in kind)")
    columns = {  # the load table's columns in words (compliance.json keeps its keys)
        "payload_kg": "payload (kg)",
        "load_ratio_pct": "load ratio (%)",
        "position_before_mm": "position before (mm)",
        "position_after_mm": "position after (mm)",
        "distance_before_mm": "distance before (mm)",
        "distance_after_mm": "distance after (mm)",
        "n_rows": "rows",
    }
    rep.table([{columns.get(k, k): v for k, v in r.items()} for r in summary["load_table"]], float_fmt="{:.3f}")
    rep.figure(load_table_figure(summary), "compensation fitted at full load, applied at each load")
    val = campaign.validation() if np.any(campaign.split == "validation") else campaign
    e0 = position_errors(geo, geo.x, val)
    e1 = position_errors(geo, cfit.x, val, model)
    labels = [f"{p}@{w:g}" for p, w in zip(val.pose_id, val.payload_kg, strict=True)]
    rep.figure(plots.error_per_pose(e0, e1, labels), "validation rows: geometric only (before) vs with compliance")
    rep.heading("Controller parameters (POE decoupling, eq. 26)")
    cp = summary.get("controller_parameters") or {}
    if cp.get("L_nominal_mm"):
        rows = []
        for k in range(5):
            rows.append(
                {
                    "i": k + 1,
                    "L nominal mm": cp["L_nominal_mm"][k],
                    "L calibrated mm": cp["L_calibrated_mm"][k],
                    "dtheta deg": cp["dtheta_deg"][k],
                }
            )
        rows.append({"i": 6, "L nominal mm": None, "L calibrated mm": None, "dtheta deg": cp["dtheta_deg"][5]})
        rep.table(rows, float_fmt="{:.4f}")
        rep.paragraph(
            f"Held at nominal (redundant with base / tool): {', '.join(cp['fixed'])}. The controller parameters "
            f"reproduce the calibrated kinematics to {cp['rms_mm']:.3f} mm RMS ({cp['max_mm']:.3f} mm max) over "
            f"{cp['n_poses']} poses: what axis tilts and other twist errors a controller cannot take."
        )
    else:
        rep.note(f"no controller parameters: {cp.get('reason', 'robot layout not supported')}")
    rep.heading("Residuals of the compliance fit")
    rows_fit = campaign.subset(cfit.fit_rows)
    r = position_errors(geo, cfit.x, rows_fit, model)
    rep.figure(plots.residuals_vs_joints(rows_fit.q, r, list(model.joint_names)), "fit rows: residual vs joint")
    return rep


__all__ = ["compliance_report", "condition_figure", "load_table_figure"]
