"""Figures and the HTML report of the thermal workflow (equivalents of Guo et al. 2026, figs. 7, 8, 10, 12, table 5)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.report import plots
from robocal.report.html import Report

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from robocal.thermal.fit import ThermalFit
    from robocal.thermal.model import ParameterModel, ThermalModel

#: Table 5 of the paper (KR16-2, validation warm-up at 90 min): mean / max position (mm), orientation (deg).
PAPER_TABLE5 = {
    "none": {
        "mean_position_mm": 0.9076,
        "max_position_mm": 1.2652,
        "mean_orientation_deg": 0.3646,
        "max_orientation_deg": 0.5183,
    },
    "traditional": {
        "mean_position_mm": 0.4418,
        "max_position_mm": 0.8957,
        "mean_orientation_deg": 0.2478,
        "max_orientation_deg": 0.3891,
    },
    "proposed": {
        "mean_position_mm": 0.3467,
        "max_position_mm": 0.7849,
        "mean_orientation_deg": 0.1778,
        "max_orientation_deg": 0.2568,
    },
}
COLS = ("mean_position_mm", "max_position_mm", "mean_orientation_deg", "max_orientation_deg")


def temperature_figure(fit: ThermalFit) -> Figure:
    """Fig. 7: every sensor over the calibration warm-up (the log, minutes from the first pose)."""
    cal = fit.cal
    log = cal.temperature_log
    assert log is not None
    t0, t1 = float(cal.timestamp_s.min()), float(cal.timestamp_s.max())
    sel = (log["t_s"] >= t0 - 120) & (log["t_s"] <= t1 + 120)
    t = (log["t_s"][sel].to_numpy() - t0) / 60.0
    return plots.time_series(t, {s: log[s][sel].to_numpy() for s in cal.sensor_names}, "temperature (°C)")


def drift_figure(fit: ThermalFit) -> Figure:
    """Fig. 8: mean |drift| of the targets per robot-base axis at each state of the calibration warm-up."""
    from robocal.thermal.identify import _match

    cal, state = fit.cal, fit.state
    Rb = fit.reference.tracker_T_base[:3, :3]
    ref = cal.subset(state == 0)
    S = int(state.max()) + 1
    out = np.zeros((S, 3))
    for s in range(1, S):
        cur = cal.subset(state == s)
        ia, ib = _match(ref, cur)
        d = (cur.p_mm[ib] - ref.p_mm[ia]) @ Rb  # tracker -> base frame
        out[s] = np.mean(np.abs(d), axis=0)
    return plots.time_series(
        fit.drift.t_min, {f"{a} (base)": out[:, k] for k, a in enumerate("XYZ")}, "mean |drift| (mm)"
    )


DEG_PER_RAD = 180.0 / 3.141592653589793
#: Said beside every equation block: the equations keep the paper's units (eq. 28), the tables use degrees.
EQUATION_UNITS = (
    "In the equations, as in every table of this page, Δ of a length is in mm and Δ of an angle in degrees "
    "(the JSON files keep the paper's rad, eq. 28); temperatures in °C, each sensor by its column name."
)
#: The reference calibration's fit statistics, as labelled in the report (units in the labels).
REFERENCE_LABELS = {
    "n_rows": "rows",
    "n_identified": "parameters identified",
    "n_eliminated": "parameters eliminated",
    "rms_position_mm": "RMS 3-D position error (mm)",
    "mean_position_mm": "mean 3-D position error (mm)",
    "max_position_mm": "max 3-D position error (mm)",
    "rms_orientation_deg": "RMS orientation error (deg)",
    "max_orientation_deg": "max orientation error (deg)",
    "chi2": "chi²",
    "dof": "degrees of freedom",
    "reduced_chi2": "reduced chi² (1 = noise as assumed)",
    "chi2_p_value": "chi² p-value",
    "nit": "iterations",
}


def parameter_figures(fit: ThermalFit, model: ThermalModel) -> list[tuple[Figure, str]]:
    """Fig. 10: identified drift per state (markers) and the model at the state temperatures (lines)."""
    from matplotlib.figure import Figure

    d = fit.drift
    pred = model.deta(d.temperatures[:, [d.sensor_names.index(s) for s in model.sensors]])
    figs = []
    for kind, unit, scale in (("length", "mm", 1.0), ("angle", "deg", DEG_PER_RAD)):
        names = [p.name for p in model.parameters if p.kind == kind and p.name in d.names]
        if not names:
            continue
        fig = Figure(figsize=(7.5, 3.6), layout="constrained")
        ax = fig.add_subplot()
        for n in names:
            j = d.names.index(n)
            line = ax.plot(d.t_min, pred[:, model.param_names.index(n)] * scale, label=f"{n} model")[0]
            ax.errorbar(
                d.t_min,
                d.deta[:, j] * scale,
                yerr=d.stderr[j] * scale,
                fmt="o",
                ms=3,
                color=line.get_color(),
                capsize=2,
            )
        ax.set_xlabel("time (min)")
        ax.set_ylabel(f"drift ({unit})")
        fig.legend(loc="outside upper center", ncols=min(len(names), 4))  # outside the data, every entry inside
        figs.append(
            (
                fig,
                f"{kind} parameter drift per state (markers ± 1 std. error, eq. 19-21) and the fitted model "
                "at the state temperatures (lines)",
            )
        )
    return figs


def comparison_figures(ev: Mapping[str, Any]) -> list[tuple[Figure, str]]:
    """Fig. 12: error per validation state per method, and the table-5 bars."""
    figs = []
    t = ev["t_min"]
    series = {m: [s["mean_position_mm"] for s in ev["per_state"][m]] for m in ev["per_state"]}
    figs.append(
        (
            plots.time_series(t, series, "mean position error (mm)"),
            "validation warm-up: mean position error per state after compensation, by method",
        )
    )
    if ev.get("has_orientation"):
        so = {m: [s["mean_orientation_deg"] for s in ev["per_state"][m]] for m in ev["per_state"]}
        figs.append(
            (
                plots.time_series(t, so, "mean orientation error (deg)"),
                "validation warm-up: mean orientation error per state, by method",
            )
        )
    methods = list(ev["table"])
    figs.append(
        (
            plots.bar_table(
                methods,
                {COL_LABELS[k]: [ev["table"][m][k] for m in methods] for k in ("mean_position_mm", "max_position_mm")},
                "error (mm)",
            ),
            "table 5 equivalent over the whole validation warm-up",
        )
    )
    return figs


def _unit(kind: str) -> tuple[str, float]:
    """The table unit of a parameter of ``kind`` and the factor from its model unit (angles in degrees)."""
    return ("mm", 1.0) if kind == "length" else ("deg", DEG_PER_RAD)


def _scaled(v: Any, f: float) -> float | None:
    return None if v is None else float(v) * f


def _alternative(alts: Any, unit: str, f: float) -> str:
    if not alts:
        return "-"
    a = alts[0]
    return f"{a['model']} (CV {a['cv_rmse'] * f:.3g} {unit})"


def model_cv_row(p: ParameterModel) -> dict[str, Any]:
    """One row of the cross-validation table from a fitted parameter model's statistics (the CV errors in the
    parameter's unit: mm, or degrees for an angle)."""
    st = p.stats
    unit, f = _unit(p.kind)
    return {
        "parameter": p.name,
        "form": p.form,
        "sensors": ", ".join(p.sensors),
        "order": p.order,
        "candidate sensors": ", ".join(st.get("candidate_sensors", [])) or "-",
        "models compared": st.get("n_candidates"),
        "unit": unit,
        "CV rmse": _scaled(st.get("cv_rmse"), f),
        "'no drift' CV rmse": _scaled(st.get("no_drift_cv_rmse"), f),
        "p vs no drift": st.get("p_value_vs_no_drift"),
        "next best": _alternative(st.get("cv_alternatives"), unit, f),
    }


def cv_rows(fit: ThermalFit) -> list[dict[str, Any]]:
    """Cross-validation table of every regressed parameter (chosen model or 'none' = no significant drift)."""
    chain = fit.reference.model.chain
    kind = dict(zip(chain.param_names, chain.param_kind, strict=True))
    rows = []
    for name, o in fit.outcomes.items():
        if o.model is not None:
            rows.append(model_cv_row(o.model))
            continue
        best = next((r for r in o.table if r["model"] != "none"), None)
        null = next((r for r in o.table if r["model"] == "none"), None)
        unit, f = _unit(kind[name])
        rows.append(
            {
                "parameter": name,
                "form": "none (no significant drift)",
                "sensors": "-",
                "order": 0,
                "candidate sensors": "-",
                "models compared": len(o.table),
                "unit": unit,
                "CV rmse": None if null is None else null["cv_rmse"] * f,
                "'no drift' CV rmse": None if null is None else null["cv_rmse"] * f,
                "p vs no drift": o.p_value,
                "next best": _alternative([best] if best else None, unit, f),
            }
        )
    if not rows:  # restored fit (load_fit): only the fitted models carry their statistics
        rows = [model_cv_row(p) for p in fit.model_all.parameters]
    return rows


#: table 5's columns as a reader sees them (the JSON keys stay as they are)
COL_LABELS = {
    "mean_position_mm": "mean position (mm)",
    "max_position_mm": "max position (mm)",
    "mean_orientation_deg": "mean orientation (deg)",
    "max_orientation_deg": "max orientation (deg)",
}


def _lines(equations: list[str], width: int = 100) -> str:
    """Equations for a preformatted block that fits the page: the reference temperatures of a long line on a
    continuation line of their own, and long sums broken before a term."""
    out: list[str] = []
    for eq in equations:
        body, sep, refs = eq.partition("    (")
        parts = [body]
        while len(parts[-1]) > width and " +" in parts[-1][:width]:
            cut = parts[-1].rfind(" +", 0, width)
            if cut <= 0:
                break
            parts[-1:] = [parts[-1][:cut], "    " + parts[-1][cut + 1 :]]
        out += parts
        if sep:
            out.append("    (" + refs)
    return "\n".join(out)


def table_rows(tab: Mapping[str, Mapping[str, float]], paper: bool = True) -> list[dict[str, Any]]:
    rows = []
    for m, s in tab.items():
        row: dict[str, Any] = {"method": m, **{COL_LABELS[k]: s.get(k) for k in COLS}}
        if paper:
            p = PAPER_TABLE5.get(m, {})
            row["paper: mean position (mm)"] = p.get("mean_position_mm")
            row["paper: mean orientation (deg)"] = p.get("mean_orientation_deg")
        rows.append(row)
    return rows


def fit_report(fit: ThermalFit, rep: Report, truth: Mapping[str, Any] | None = None) -> Report:
    """Sections of the thermal fit: temperatures, drift, identification, regression (eq. 28 form)."""
    d = fit.drift
    rep.heading("Warm-up and temperatures")
    rep.paragraph(
        f"{d.deta.shape[0]} temperature states of the calibration warm-up at t = "
        + ", ".join(f"{v:.0f}" for v in d.t_min)
        + " min; the first (cold) is the reference state."
    )
    rep.figure(temperature_figure(fit), "sensor temperatures over the calibration warm-up (fig. 7)")
    rep.figure(drift_figure(fit), "mean |drift| of the measured targets per base axis (fig. 8)")
    rep.heading("Reference (cold-state) geometric calibration")
    ref = fit.reference.fit
    rep.kv(
        {
            label: ref[key]
            for key, label in REFERENCE_LABELS.items()
            if isinstance(ref.get(key), int | float) and not isinstance(ref.get(key), bool)
        }
    )
    rep.heading("Thermal parameter errors per state (eq. 19-21)")
    rep.paragraph(
        f"Identifiable: {', '.join(d.names)}. Eliminated: "
        + ("; ".join(e.describe() for e in d.identifiability.eliminated) or "none")
        + f". Noise scale of the drift fit: {d.sigma_scale:.3f} (1 = the configured tracker noise)."
    )
    rows = []
    for j, n in enumerate(d.names):
        length = fit.reference.model.chain.param_kind[d.param_index[j]] == "length"
        f = 1.0 if length else DEG_PER_RAD  # angles in degrees in every table
        rows.append(
            {
                "parameter": n,
                "unit": "mm" if length else "deg",
                "std. error": float(d.stderr[j]) * f,
                **{f"{t:.0f} min": float(d.deta[s, j]) * f for s, t in enumerate(d.t_min)},
            }
        )
    rep.table(rows, caption="identified drift per state (relative to the cold state)", float_fmt="{:.3g}")
    rep.heading("Regression: thermal model of every identifiable parameter")
    rep.paragraph(
        "Per parameter, the form (linear expansion for lengths, eq. 5-6; polynomials for angles, eq. 7-8), the "
        "sensors and the order are chosen by leave-one-state-out cross-validation (the smallest model within "
        f"{fit.cfg.regression_config.cv_tolerance:.0%} of the best CV error), and kept only when it beats 'no drift' "
        f"(chi-square test at {fit.cfg.regression_config.alpha:g}). Coefficients ± standard error, in temperature "
        "differences from the cold state. " + EQUATION_UNITS
    )
    rep.code(_lines(fit.model_all.equations(stderr=True, deg=True)) or "(no parameter drifts significantly)")
    if fit.model_all.parameters:
        rep.paragraph("The same model as the paper prints eq. 28 (polynomials in absolute temperatures, °C):")
        rep.code(_lines(fit.model_all.equations(absolute=True, deg=True)))
    rows_cv = cv_rows(fit)
    if rows_cv:
        rep.table(rows_cv, caption="cross-validated choice of sensors and order per parameter", float_fmt="{:.3g}")
    if truth is not None and "thermal" in truth.get("effects", {}):
        rep.paragraph("Twin truth (reference T0 for every sensor):")
        from robocal.thermal.model import ThermalModel

        rep.code(_lines(ThermalModel.from_dict(truth["effects"]["thermal"]["model"]).equations(deg=True)))
    rep.heading("Traditional model (non-zero a and d, linear expansion)", level=3)
    rep.code(_lines(fit.model_traditional.equations(deg=True)) or "(none)")
    return rep


def validation_report(
    rep: Report,
    proposed: ThermalModel,
    selected: list[str],
    source: str,
    ev: Mapping[str, Any],
    fit: ThermalFit,
) -> Report:
    rep.heading("Proposed model (the selected parameters, eq. 28 form)")
    rep.paragraph(f"Selected ({source}): {', '.join(selected) or 'none'}. {EQUATION_UNITS}")
    rep.code(_lines(proposed.equations(stderr=True, deg=True)) or "(empty)")
    ref = dict(zip(fit.model_all.sensors, fit.model_all.T_ref_C.tolist(), strict=True))
    ref_p = dict(zip(proposed.sensors, proposed.T_ref_C.tolist(), strict=True))
    by_all = {q.name: q for q in fit.model_all.parameters}
    both = [q for q in proposed.parameters if q.name in by_all]
    if both:
        rep.paragraph(
            "One parameter, two models: the proposed model re-identifies the drift on the selected parameters only "
            "(the others held at their cold values) and refits each regression, so a parameter's model here can "
            "differ from the all-parameter model of the thermal fit (reports/thermal) in its coefficients and even "
            "its sensors. Side by side:"
        )
        rep.table(
            [
                {
                    "parameter": q.name,
                    "proposed (this page, applied)": q.equation(ref_p, deg=True).split(" = ", 1)[-1],
                    "all-parameter model (thermal fit)": by_all[q.name].equation(ref, deg=True).split(" = ", 1)[-1],
                }
                for q in both
            ],
            caption="the applied model of each selected parameter beside the thermal fit's",
        )
    if proposed.parameters:
        rep.paragraph("In absolute temperatures (°C), as the paper prints eq. 28:")
        rep.code(_lines(proposed.equations(absolute=True, deg=True)))
        rep.table(
            [model_cv_row(p) for p in proposed.parameters],
            caption="sensors and order of the proposed model, chosen by leave-one-state-out cross-validation",
            float_fmt="{:.3g}",
        )
    rows: list[dict[str, Any]] = []
    weak: set[str] = set()
    for p in proposed.parameters:
        f = 1.0 if p.kind == "length" else DEG_PER_RAD  # angles in degrees in every table
        for c, e, se in zip(p.coefficients, p.terms, p.stderr, strict=True):
            order = sum(e)
            if float(se) > 0 and abs(float(c)) < float(se):
                weak.add(p.name)
            rows.append(
                {
                    "parameter": p.name,
                    "form": p.form,
                    "term": "·".join(f"Δ{s}^{k}" for s, k in zip(p.sensors, e, strict=True) if k),
                    "coefficient": float(c) * f,
                    "std. error": float(se) * f,
                    "unit": f"{'mm' if p.kind == 'length' else 'deg'}/°C" + (f"^{order}" if order > 1 else ""),
                    "|coef| / std. error": abs(float(c)) / float(se) if se else None,
                }
            )
    rep.table(rows, caption="coefficients with standard errors (angles in degrees)", float_fmt="{:.4g}")
    if weak:
        rep.note(
            f"Coefficients smaller than their standard error: {', '.join(sorted(weak))}. The compensation applies "
            "them as fitted; they are not distinguishable from zero on this warm-up.",
            kind="warn",
        )
    for fig, cap in parameter_figures(fit, proposed):
        rep.figure(fig, cap + " (fig. 10)")
    rep.heading("Validation warm-up: compensation compared (table 5)")
    rep.paragraph(
        "Errors left after compensation = prediction error of each method's parameters on the validation "
        "measurements (so they include the tracker noise; 'oracle' = the twin's true parameters). 'none' "
        "keeps the cold-state geometric calibration. The paper's numbers (its table 5) are beside ours; its "
        "'uncompensated' also holds errors other than the thermal drift."
    )
    rep.table(table_rows(ev["table"]), caption="whole validation warm-up", float_fmt="{:.4f}")
    rep.table(
        table_rows(ev["at_state"]),
        caption=f"validation state at {ev['at_state_min']:.0f} min (the paper's 90 min)",
        float_fmt="{:.4f}",
    )
    if "closed_loop" in ev:
        rep.table(
            table_rows(ev["closed_loop"], paper=False),
            caption="closed loop on the twin: corrected joints sent to the true robot (no tracker noise)",
            float_fmt="{:.4f}",
        )
    for fig, cap in comparison_figures(ev):
        rep.figure(fig, cap + " (fig. 12)")
    compensation_section(rep, ev)
    return rep


def compensation_section(rep: Report, ev: Mapping[str, Any]) -> Report:
    """Extrapolation warnings and the controller CSV: status counts, refused / flagged targets, the columns."""
    ext = ev.get("extrapolation")
    comp = ev.get("compensation")
    if ext is None and comp is None:
        return rep
    rep.heading("Controller CSV and extrapolation")
    if ext is not None:
        if ext.get("warning"):
            rep.note(ext["warning"] + ".", kind="warn")  # the note says "Warning:"
        else:
            rep.paragraph(
                f"Every validation reading lies within the model's fitted temperature range (margin "
                f"{ext['margin_C']:g} °C; largest excess {ext['max_excess_C']:.2f} °C): the model does not extrapolate."
            )
        rep.table(
            [
                {"sensor": s, "fitted min (°C)": lo, "fitted max (°C)": hi}
                for s, (lo, hi) in ext.get("fitted_range_C", {}).items()
            ],
            caption="fitted temperature range of the proposed model (outside it by more than the margin: refused or "
            "flagged)",
            float_fmt="{:.2f}",
        )
    if comp is not None:
        if comp.get("warning"):
            rep.note(comp["warning"] + ".", kind="warn")
        lim = comp.get("limits", {})
        rep.kv(
            {
                "validation state (min)": comp["t_min"],
                "targets": comp["n_targets"],
                "corrections applied": comp["n_applied"],
                **{f"status {k}": v for k, v in comp["status_counts"].items()},
                "largest joint correction (deg)": comp["max_correction_deg"],
                "max_correction_deg": lim.get("max_correction_deg"),
                "range margin (°C)": lim.get("temperature_margin_C"),
                "outside the range": lim.get("on_temperature_range"),
            },
            caption="compensation.csv: the validation poses at the reported state, compensated for the controller",
        )
        if comp.get("flagged"):
            rep.table(comp["flagged"], caption="targets not ok (nominal joints kept when refused)")
        large = comp.get("large_corrections") or []
        if large:
            rep.note(
                f"Large corrections: {len(large)} target(s) need a joint correction above "
                f"{comp['large_correction_deg']:g}° (largest {large[0]['correction_max_deg']:.2f}° at "
                f"{large[0]['target_id']}). A sub-millimetre thermal drift needs such a move only near a singularity "
                "(wrist, stretched or folded arm), where the correction is unreliable: check these targets before "
                "sending them to the controller.",
                kind="warn",
            )
            rep.table(large, caption="targets with a large joint correction (deg)", float_fmt="{:.3f}")
        rep.table(
            [{"column": k, "meaning": v} for k, v in comp.get("columns", {}).items()],
            caption="columns of compensation.csv",
        )
    return rep


def save_figures(fit: ThermalFit, out: str | Path) -> list[Path]:
    out = Path(out)
    return [
        plots.save_figure(temperature_figure(fit), out / "temperatures.png"),
        plots.save_figure(drift_figure(fit), out / "drift.png"),
    ]


__all__ = [
    "PAPER_TABLE5",
    "comparison_figures",
    "compensation_section",
    "cv_rows",
    "drift_figure",
    "fit_report",
    "model_cv_row",
    "parameter_figures",
    "save_figures",
    "temperature_figure",
    "validation_report",
]
