"""validate: the validation warm-up compensated four ways (robocal.workflows.thermal.write_validation).

Reads ``robot``, ``thermal`` and ``data`` (only to find a twin's truth.json beside the raw campaign, for the
oracle row and the closed loop); skips explicitly when the campaign has no temperature log, the thermal fit
skipped or there are no validation rows. Takes the thermal
fit from ``reports/thermal`` and the screening's ``selected`` set from ``thermal.screening_file`` (without it:
the parameters with a drift model), fits the proposed model and compares none / traditional / proposed / all
(table 5, figs. 10 and 12). Writes ``reports/validate/`` (thermal.json, thermal_model.json — the model an online
service loads —, validation.csv, compensation.csv for the controller with a status per target, report.html),
figures and metrics (the validation table, the controller CSV's status counts and the number of validation rows
where the model extrapolates are logged to MLflow as metrics; warnings are printed).
"""

from __future__ import annotations

from typing import Any

from common import Context, Metrics, Skipped, Stage, run

STAGE = Stage(
    name="validate",
    params=("robot", "thermal", "data"),
    out="reports/validate",
    metrics="reports/metrics/validate.json",
    plots="reports/plots/validate",
)
INPUT = "data/interim"
FIT = "reports/thermal"


def compute(ctx: Context) -> Metrics | Skipped:
    prep = ctx.read_json(f"{INPUT}/prepare.json")
    if not prep.get("has_temperatures"):
        return ctx.skip("no temperature log: the campaign has no temperatures, there is no thermal compensation")
    from robocal.data.contract import read_campaign
    from robocal.pipeline import campaign_dir
    from robocal.report import plots
    from robocal.report.html import Report
    from robocal.robot import robot_from_dict
    from robocal.thermal import report as thermal_report
    from robocal.thermal.fit import ThermalConfig, choose_selected, load_fit
    from robocal.workflows.thermal import read_truth, write_validation

    cfg = ThermalConfig.from_mapping(ctx.cfg["thermal"])
    why = ctx.upstream_skipped(FIT)
    if why is not None:
        return ctx.skip(f"thermal_fit skipped ({why}): there is no thermal model to validate")
    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    camp = read_campaign(ctx.path(INPUT), robot)
    if not camp.validation().n_rows:
        return ctx.skip(
            f"campaign {prep.get('source', INPUT)} has no validation rows (column 'split'): no second warm-up to "
            "compensate"
        )
    fit = load_fit(ctx.path(FIT), camp, robot, cfg)
    scr_path = ctx.path(cfg.screening_file)
    selected, source = choose_selected(fit, None)
    if cfg.proposed == "screen" and scr_path.is_file():
        scr = ctx.read_json(scr_path)
        if scr.get("status") != "skipped" and "selected" in scr:
            selected, source = list(scr["selected"]), f"sensitivity screening ({cfg.screening_file})"
    truth = read_truth(campaign_dir(ctx.root, ctx.cfg))
    summary, proposed, ev = write_validation(fit, ctx.out, selected, source, truth)
    rep = Report(f"Thermal compensation: {robot.name}", subtitle=f"campaign {prep.get('source', '')}")
    thermal_report.validation_report(rep, proposed, selected, source, ev, fit).save(ctx.out / "report.html")
    assert ctx.plots is not None
    for k, (fig, _) in enumerate(thermal_report.comparison_figures(ev)):
        plots.save_figure(fig, ctx.plots / f"comparison_{k + 1}.png")
    for name in ("thermal.json", "thermal_model.json", "validation.csv", "compensation.csv", "report.html"):
        ctx.artifact(ctx.out / name)
    ctx.tracker.log_text("\n".join(summary["equations"]), "thermal_model_equations.txt")
    ctx.tracker.set_tags({"robocal.thermal.selected": ",".join(selected) or "(none)"})
    metrics: dict[str, Any] = {
        "n_selected": len(selected),
        "validation": summary["validation"],
        "validation_at_state": summary["validation_at_state"],
    }
    if "closed_loop" in summary:
        metrics["closed_loop"] = summary["closed_loop"]
    if "compensation" in summary:  # the controller CSV: refused / flagged targets (status column)
        metrics["compensation_status"] = summary["compensation"]["status_counts"]
    if "extrapolation" in summary:  # validation rows where the thermal model extrapolates
        metrics["n_rows_out_of_range"] = summary["extrapolation"]["n_rows_out_of_range"]
    for w in summary.get("warnings", []):
        print(f"stage validate: WARNING {w}")
    val = summary["validation"]
    headline = {
        f"comp_{way}_mean_mm": val[way]["mean_position_mm"]
        for way in ("none", "proposed")
        if isinstance(val.get(way), dict) and "mean_position_mm" in val[way]
    }
    return Metrics(headline, metrics)


if __name__ == "__main__":
    run(STAGE, compute)
