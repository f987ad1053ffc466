"""thermal_fit: temperature-dependent kinematic parameters of the interim campaign (robocal.thermal.fit,
robocal.workflows.thermal.write_fit).

Reads ``robot`` and ``thermal``; skips explicitly when the campaign has no temperature log or its calibration rows
are not a warm-up (fewer than three temperature states: an air-temperature log, say). Otherwise: geometric
calibration at the cold state of the calibration warm-up, per-state drift of every identifiable parameter by SVD
(eq. 19-21), per-parameter regression (eq. 5-8, cross-validated) and the traditional model. Writes
``reports/thermal/`` (reference_calibration.json, states.json — the screening's drift file —,
thermal_model_all.json, thermal_model_traditional.json, regression.json, summary.json, report.html), figures and
metrics (the model and its equations are logged to MLflow as artifacts).
"""

from __future__ import annotations

from common import Context, Metrics, Skipped, Stage, run

STAGE = Stage(
    name="thermal_fit",
    params=("robot", "thermal"),
    out="reports/thermal",
    metrics="reports/metrics/thermal_fit.json",
    plots="reports/plots/thermal_fit",
)
INPUT = "data/interim"


def compute(ctx: Context) -> Metrics | Skipped:
    prep = ctx.read_json(f"{INPUT}/prepare.json")
    if not prep.get("has_temperatures"):
        return ctx.skip("no temperature log: the campaign has no temperatures, there is no thermal model to fit")
    from robocal.data.contract import read_campaign
    from robocal.report.html import Report
    from robocal.robot import robot_from_dict
    from robocal.thermal import report as thermal_report
    from robocal.thermal.fit import ThermalConfig, fit_thermal, warm_up_problem
    from robocal.workflows.thermal import write_fit

    cfg = ThermalConfig.from_mapping(ctx.cfg["thermal"])
    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    camp = read_campaign(ctx.path(INPUT), robot)
    problem = warm_up_problem(camp, "calibration", cfg.state_gap_s)
    if problem is not None:  # e.g. an air-temperature log of an ordinary campaign: nothing to fit, not an error
        return ctx.skip(
            f"campaign {prep.get('source', INPUT)}: the temperature log is not a warm-up: {problem}; "
            "there is no thermal model to fit"
        )
    fit = fit_thermal(camp, robot, cfg)
    summary = write_fit(fit, ctx.out)
    rep = Report(f"Thermal fit: {robot.name}", subtitle=f"campaign {prep.get('source', '')}")
    thermal_report.fit_report(fit, rep).save(ctx.out / "report.html")
    assert ctx.plots is not None
    thermal_report.save_figures(fit, ctx.plots)
    for name in (
        "report.html",
        "thermal_model_all.json",
        "thermal_model_traditional.json",
        "states.json",
        "summary.json",
        "regression.json",
        "reference_calibration.json",
    ):
        ctx.artifact(ctx.out / name)
    ctx.tracker.log_text("\n".join(summary["equations"]), "thermal_model_equations.txt")
    ctx.tracker.set_tags({"robocal.thermal.drifting": ",".join(summary["drifting"]) or "(none)"})
    details = {
        "n_states": summary["n_states"],
        "n_identified": summary["n_identified"],
        "n_drifting": len(summary["drifting"]),
        "sigma_scale": summary["sigma_scale"],
        "reference_rms_mm": summary["reference_fit"]["rms_position_mm"],
        "max_drift_rms_mm": max(summary["drift_rms_mm"]),
        "max_residual_rms_mm": max(summary["residual_rms_mm"]),
    }
    headline = {
        "thermal_drift_rms_mm": details["max_drift_rms_mm"],
        "thermal_resid_rms_mm": details["max_residual_rms_mm"],
    }
    return Metrics(headline, details)


if __name__ == "__main__":
    run(STAGE, compute)
