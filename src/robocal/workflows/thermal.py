"""Thermal workflow: thermal fit -> screening -> validation -> files and report (``robocal thermal``).

:func:`run` does it all on a campaign; the pipeline runs the same steps one stage each (thermal_fit:
:func:`write_fit`, screen, validate: :func:`write_validation`). The computations are in
:mod:`robocal.thermal.fit`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.errors import DataError
from robocal.io import write_json
from robocal.robot import RobotDescription
from robocal.thermal.fit import (
    ThermalConfig,
    ThermalFit,
    choose_selected,
    fit_selected,
    fit_thermal,
    run_screening,
    validate_thermal,
)
from robocal.thermal.model import ParameterModel, ThermalModel
from robocal.workflows import campaign_of, robot_of

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign
    from robocal.thermal.compensate import ThermalCompensation


def write_fit(fit: ThermalFit, out: str | Path) -> dict[str, Any]:
    """Files of the thermal fit: reference_calibration.json, states.json (the screening's drift file),
    thermal_model_all.json, thermal_model_traditional.json, regression.json, summary.json. Returns the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "reference_calibration.json", fit.reference.to_dict())
    write_json(out / "states.json", fit.drift.to_dict())
    write_json(out / "thermal_model_all.json", fit.model_all.to_dict())
    write_json(out / "thermal_model_traditional.json", fit.model_traditional.to_dict())
    write_json(
        out / "regression.json",
        {
            n: {"chosen": o.chosen.label(), "p_value_vs_no_drift": o.p_value, "candidates": o.table[:10]}
            for n, o in fit.outcomes.items()
        },
    )
    summary = fit_summary(fit)
    write_json(out / "summary.json", summary)
    return summary


def fit_summary(fit: ThermalFit) -> dict[str, Any]:
    d = fit.drift
    return {
        "robot": fit.robot.name,
        "n_states": int(d.deta.shape[0]),
        "state_t_min": d.t_min.tolist(),
        "n_identified": len(d.names),
        "identified": list(d.names),
        "eliminated": [e.describe() for e in d.identifiability.eliminated],
        "sigma_scale": d.sigma_scale,
        "reference_fit": {
            k: fit.reference.fit.get(k) for k in ("rms_position_mm", "max_position_mm", "rms_orientation_deg", "n_rows")
        },
        "drift_rms_mm": d.drift_rms_mm.tolist(),
        "residual_rms_mm": d.residual_rms_mm.tolist(),
        "drifting": list(fit.model_all.names),
        "traditional_parameters": list(fit.traditional_params),
        "equations": fit.model_all.equations(),
        "equations_with_stderr": fit.model_all.equations(stderr=True),
        "equations_absolute": fit.model_all.equations(absolute=True),
        "equations_traditional": fit.model_traditional.equations(),
    }


def thermal_json(
    fit: ThermalFit,
    proposed: ThermalModel,
    selected: Sequence[str],
    source: str,
    ev: Mapping[str, Any],
    screening_result: Any = None,
) -> dict[str, Any]:
    """The ``thermal.json`` summary of ``robocal thermal``."""
    keep = ("mean_position_mm", "max_position_mm", "mean_orientation_deg", "max_orientation_deg")

    def rows(tab: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
        return {m: {k: v for k, v in s.items() if k in keep} for m, s in tab.items()}

    out: dict[str, Any] = {
        "robot": fit.robot.name,
        "selected": list(selected),
        "selected_from": source,
        "model": {p.name: model_entry(p, proposed) for p in proposed.parameters},
        "equations": proposed.equations(),
        "equations_with_stderr": proposed.equations(stderr=True),
        "equations_absolute": proposed.equations(absolute=True),
        "T_ref_C": dict(zip(proposed.sensors, proposed.T_ref_C.tolist(), strict=True)),
        "validation": rows(ev["table"]),
        "validation_at_state": {"t_min": ev["at_state_min"], **rows(ev["at_state"])},
        "thermal_fit": fit_summary(fit),
    }
    if "closed_loop" in ev:
        out["closed_loop"] = rows(ev["closed_loop"])
        out["closed_loop_refused"] = {
            m: {k: v for k, v in s.items() if k.startswith("n_")} for m, s in ev["closed_loop"].items()
        }
    if "compensation" in ev:
        out["compensation"] = ev["compensation"]
    if "extrapolation" in ev:
        out["extrapolation"] = ev["extrapolation"]
    out["warnings"] = [
        w for w in (ev.get("extrapolation", {}).get("warning"), ev.get("compensation", {}).get("warning")) if w
    ] + fit.campaign.reading_notes()  # (poses and temperatures in other time zones: the model fitted off by hours)
    if screening_result is not None:
        out["screening"] = screening_result.to_dict()
    return out


def model_entry(p: ParameterModel, model: ThermalModel) -> dict[str, Any]:
    """One parameter of ``thermal.json``'s ``model``: form, sensors and order with how cross-validation chose
    them, coefficients with standard errors, and the equation (eq. 28 form)."""
    ref = dict(zip(model.sensors, model.T_ref_C.tolist(), strict=True))
    st = dict(p.stats)
    entry: dict[str, Any] = {
        "form": p.form,
        "unit": "mm" if p.kind == "length" else "rad",
        "sensors": list(p.sensors),
        "order": p.order,
        "terms": [list(e) for e in p.terms],
        "coefficients": [float(c) for c in p.coefficients],
        "stderr": [float(c) for c in p.stderr],
        "coefficient_unit": f"{'mm' if p.kind == 'length' else 'rad'} per degC^order",
        "lambda_per_C": p.lambda_per_C,
        "equation": p.equation(ref),
        "equation_with_stderr": p.equation(ref, stderr=True),
        "equation_absolute": p.equation_absolute(ref),
        "cross_validation": {
            "method": "leave-one-state-out; the smallest model within cv_tolerance of the best CV error, kept only "
            "when it beats 'no drift' (chi-square test)",
            "candidate_sensors": st.get("candidate_sensors"),
            "n_candidates": st.get("n_candidates"),
            "cv_rmse": st.get("cv_rmse"),
            "cv_best_rmse": st.get("cv_best_rmse"),
            "cv_tolerance": st.get("cv_tolerance"),
            "no_drift_cv_rmse": st.get("no_drift_cv_rmse"),
            "p_value_vs_no_drift": st.get("p_value_vs_no_drift"),
            "alternatives": st.get("cv_alternatives"),
        },
        "fit": {k: st.get(k) for k in ("n_states", "rmse", "chi2", "dof", "reduced_chi2", "state_stderr")},
    }
    return entry


def read_truth(data_dir: str | Path) -> dict[str, Any] | None:
    """``truth.json`` beside the data (twin campaigns), else None."""
    p = Path(data_dir) / "truth.json"
    if not p.is_file():
        return None
    data = json.loads(p.read_text(encoding="utf-8"))
    return data if isinstance(data, dict) and "kinematic_errors" in data else None


def write_validation(
    fit: ThermalFit,
    out: str | Path,
    selected: Sequence[str],
    source: str,
    truth: Mapping[str, Any] | None = None,
    screening_result: Any = None,
) -> tuple[dict[str, Any], ThermalModel, dict[str, Any]]:
    """Fit the proposed model, validate, write ``thermal.json``, ``thermal_model.json`` (the proposed model),
    ``validation.csv`` (per-row errors by method) and ``compensation.csv`` (the controller CSV of the validation
    poses at the state nearest ``validation_at_min``). Returns ``(thermal.json dict, proposed model, evaluation)``."""
    import pandas as pd

    from robocal.io import atomic_write
    from robocal.thermal.compensate import (
        compensate_targets,
        extrapolation_summary,
        range_excess,
        write_controller_csv,
    )
    from robocal.thermal.validate import reorder

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    proposed, _, _ = fit_selected(fit, selected)
    ev = validate_thermal(fit, proposed, truth)
    val = fit.campaign.validation()
    vstate = ev["state"]
    assert val.temperatures is not None
    T_val = reorder(val.temperatures, val.sensor_names, proposed.sensors)
    limits = fit.cfg.limits
    ev["extrapolation"] = extrapolation_summary(proposed, T_val, vstate, ev["t_min"], limits.temperature_margin_C)
    k = int(np.argmin(np.abs(np.asarray(ev["t_min"]) - fit.cfg.validation_at_min)))
    sel = vstate == k
    comp = compensate_targets(
        fit.reference,
        proposed,
        T_val[sel].mean(axis=0),
        val.q[sel],
        val.target[sel],
        ids=[f"{p}/{t}" for p, t in zip(val.pose_id[sel], val.target[sel], strict=True)],
        orientation=bool(ev["has_orientation"]),
        limits=limits,
        q_limits=np.asarray(fit.robot.q_limits, dtype=float),
    )
    ev["compensation"] = compensation_summary(comp, float(ev["t_min"][k]))
    summary = thermal_json(fit, proposed, selected, source, ev, screening_result)
    write_json(out / "thermal_model.json", proposed.to_dict())
    write_json(out / "thermal.json", summary)
    frame = pd.DataFrame(
        {"pose_id": val.pose_id, "target": val.target, "state": vstate, "t_min": np.asarray(ev["t_min"])[vstate]}
    )
    for m, e in ev["errors"].items():
        frame[f"{m}_position_mm"] = e
        if ev["errors_deg"][m] is not None:
            frame[f"{m}_orientation_deg"] = ev["errors_deg"][m]
    frame["proposed_extrapolation_C"] = range_excess(proposed, T_val).max(axis=1) if len(T_val) else 0.0
    atomic_write(out / "validation.csv", lambda p: frame.to_csv(p, index=False, float_format="%.6f"))
    write_controller_csv(out / "compensation.csv", comp)
    return summary, proposed, ev


#: A joint correction above this (deg) is flagged in the report: a thermal drift of a fraction of a millimetre needs
#: a joint move this large only near a singularity (wrist q5 ~ 0, stretched or folded arm), where the correction is
#: unreliable. Flagged, not refused: the refusal bound is ``thermal.compensation.max_correction_deg``.
LARGE_CORRECTION_DEG = 0.5


def compensation_summary(comp: ThermalCompensation, t_min: float) -> dict[str, Any]:
    """The ``compensation`` entry of ``thermal.json``: what ``compensation.csv`` holds and how many targets were
    refused or flagged, with the reasons."""
    from robocal.thermal.compensate import CSV_COLUMNS

    counts = comp.counts()
    flagged = [
        {"target_id": str(i), "status": str(s), "reason": str(r)}
        for i, s, r in zip(comp.ids, comp.status, comp.reason, strict=True)
        if s != "ok"
    ]
    warning = ""
    if flagged:
        warning = (
            f"{len(flagged)} of {len(comp.ids)} targets of compensation.csv are not ok ("
            + ", ".join(f"{k}: {v}" for k, v in counts.items() if v and k != "ok")
            + "); see the status and reason columns"
        )
    large = [
        {"target_id": str(i), "correction_max_deg": float(c), "status": str(st)}
        for i, c, st in zip(comp.ids, comp.correction_max_deg, comp.status, strict=True)
        if c > LARGE_CORRECTION_DEG
    ]
    return {
        "file": "compensation.csv",
        "t_min": t_min,
        "large_correction_deg": LARGE_CORRECTION_DEG,
        "large_corrections": sorted(large, key=lambda r: -r["correction_max_deg"]),
        "n_targets": len(comp.ids),
        "n_applied": int(np.sum(comp.applied)),
        "status_counts": counts,
        "extrapolation_C": comp.extrapolation_C,
        "max_correction_deg": float(np.max(comp.correction_max_deg)) if len(comp.ids) else 0.0,
        "limits": comp.limits.to_dict(),
        "flagged": flagged,
        "warning": warning,
        "columns": dict(CSV_COLUMNS),
    }


def run(
    data_dir: str | Path | None,
    robot: str | Path | RobotDescription,
    out_dir: str | Path,
    settings: Mapping[str, Any] | None = None,
    *,
    split: Mapping[str, Any] | None = None,
    campaign: Campaign | None = None,
    report: bool = True,
    screen: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Thermal fit -> screening -> validation on the campaign in ``data_dir`` (``settings``: a
    :class:`ThermalConfig` mapping; ``screen``: the screening settings, ``conf/screen``). Writes
    :func:`write_fit`'s files, ``screening.json``, :func:`write_validation`'s files and ``report.html`` into
    ``out_dir``; a ``truth.json`` beside the data adds the oracle. Returns the ``thermal.json`` content."""
    rob = robot_of(robot)
    cfg = ThermalConfig.from_mapping(settings)
    camp = campaign_of(data_dir, rob, split, campaign)
    where = data_dir if data_dir is not None else camp.source
    if not camp.has_temperatures:
        raise DataError("no temperature log: the campaign has no temperatures.csv", file=where)
    out = Path(out_dir)
    fit = fit_thermal(camp, rob, cfg)
    write_fit(fit, out)
    scr = run_screening(fit, screen) if cfg.proposed == "screen" else None
    if scr is not None:
        write_json(out / "screening.json", scr.to_dict())
    selected, source = choose_selected(fit, scr)
    truth = read_truth(data_dir) if data_dir is not None else None
    summary, proposed, ev = write_validation(fit, out, selected, source, truth, scr)
    if report:
        from robocal.report.html import Report
        from robocal.thermal.report import fit_report, validation_report

        rep = Report(f"Thermal compensation: {rob.name}", subtitle=f"campaign {where}")
        fit_report(fit, rep, truth)
        if scr is not None:
            from robocal.thermal import screening

            screening.add_to_report(scr, rep)
        validation_report(rep, proposed, selected, source, ev, fit)
        rep.save(out / "report.html")
    return summary


__all__ = [
    "LARGE_CORRECTION_DEG",
    "compensation_summary",
    "fit_summary",
    "model_entry",
    "read_truth",
    "run",
    "thermal_json",
    "write_fit",
    "write_validation",
]
