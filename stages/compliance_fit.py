"""compliance_fit: heavy-load joint compliance of the interim campaign (robocal.workflows.compliance.run).

Reads ``robot`` and ``compliance``; ``data/interim`` (the prepare stage's copy of the campaign) and
``data/interim/prepare.json``: without payload rows the stage writes an explicit "skipped" result. Writes
``reports/compliance/`` (compliance.json, compensation.csv, conditions.csv, report.html), metrics (compliance per
joint, errors per load condition before / after compensation) and plots (fig. 8 / table 4 in kind).

    python stages/compliance_fit.py +compliance=default compliance.method=sequential
"""

from __future__ import annotations

from typing import Any

from common import Context, Metrics, Skipped, Stage, run

STAGE = Stage(
    name="compliance_fit",
    params=("robot", "compliance"),
    out="reports/compliance",
    metrics="reports/metrics/compliance_fit.json",
    plots="reports/plots/compliance_fit",
)
#: The stage's input: the prepare stage's interim copy of the campaign.
INPUT = "data/interim"


def metrics_of(summary: dict[str, Any]) -> dict[str, Any]:
    """Compliance per joint, fit RMS and the per-load errors before / after compensation (mm)."""
    out: dict[str, Any] = {
        "kind": summary["kind"],
        "method": summary["method"],
        "fit_rms_mm": summary["fit"]["rms_position_mm"],
        "geometric_rms_mm": summary["geometric_fit"]["rms_position_mm"],
        "c": {k: v["c"] for k, v in summary["compliance"].items() if v["identified"]},
        "c_stderr": {k: v["stderr"] for k, v in summary["compliance"].items() if v["identified"]},
    }
    for c in summary["conditions"]:
        key = f"{c['split']}_{c['payload_kg']:g}kg"
        out[key] = {
            "before_mean_mm": c["after_geometric"]["mean_mm"],
            "before_max_mm": c["after_geometric"]["max_mm"],
            "after_mean_mm": c["after_compliance"]["mean_mm"],
            "after_max_mm": c["after_compliance"]["max_mm"],
        }
    return out


def compute(ctx: Context) -> Metrics | Skipped:
    prep = ctx.read_json(f"{INPUT}/prepare.json")
    if not prep.get("has_payload"):
        return ctx.skip("the campaign has no payload rows (payload_kg is 0 or absent): this stage identifies the "
                        "joints' compliance from payloads; under the arm's own weight it is the discover stage's "
                        "(compliance from the link masses, weight without them)")  # fmt: skip
    from robocal.compliance.fit import ComplianceConfig, missing_loads
    from robocal.compliance.report import condition_figure, load_table_figure
    from robocal.report import plots
    from robocal.robot import robot_from_dict
    from robocal.workflows import campaign_of, compliance

    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    camp = campaign_of(ctx.path(INPUT), robot, None, None)
    why = missing_loads(camp, ComplianceConfig.from_mapping(dict(ctx.cfg["compliance"])), prep.get("source"))
    if why is not None:  # one payload on every row (a heavy robot measured with its working load): no load step
        return ctx.skip(why)
    summary = compliance.run(ctx.path(INPUT), robot, ctx.out, dict(ctx.cfg["compliance"]), campaign=camp)
    assert ctx.plots is not None
    plots.save_figure(condition_figure(summary), ctx.plots / "accuracy_per_condition.png")
    plots.save_figure(load_table_figure(summary), ctx.plots / "load_table.png")
    for name in ("report.html", "compliance.json", "conditions.csv", "compensation.csv"):
        if (ctx.out / name).exists():
            ctx.artifact(ctx.out / name)
    details = metrics_of(summary)
    headline = {"compl_fit_rms_mm": details["fit_rms_mm"]}
    return Metrics(headline, details)


if __name__ == "__main__":
    run(STAGE, compute)
