"""discover: name the effects the geometric model is missing (robocal.workflows.discovery.run).

Reads ``robot`` and ``discovery``; the interim campaign (split fixed by ``prepare``); writes
``reports/discovery/`` (discovery.json, report.html), metrics (RMS before / after, the final model's held-out
mean ``disc_val_mean_mm`` (and ``disc_val_served_mean_mm``, the robot as served, when measurement-side effects
corrected the held-out readings), noise floor, what was named, per-step RMS) and a plot of the RMS per step. The MLflow
run logs the steps as a metric series (``step_rms_mm``).

    python stages/discover.py discovery.alpha=0.0001
"""

from __future__ import annotations

from typing import Any

from common import Context, Metrics, Stage, run

STAGE = Stage(
    name="discover",
    params=("robot", "discovery"),
    out="reports/discovery",
    metrics="reports/metrics/discover.json",
    plots="reports/plots/discover",
)
#: The stage's input: the prepare stage's interim copy of the campaign.
INPUT = "data/interim"


def metrics_of(summary: dict[str, Any]) -> dict[str, Any]:
    return {
        "rms_before_mm": summary["rms_before_mm"],
        "rms_after_mm": summary["rms_after_mm"],
        "noise_floor_mm": summary["noise_floor_mm"],
        "n_named": len(summary["named"]),
        "unexplained": int(bool(summary["unexplained"])),
        "chi2": summary["chi2"],
        "dof": summary["dof"],
        "n_skipped": len(summary["skipped"]),
        "named": {
            f"{n['effect']}_j{n['joint']}" + (f"_h{n['harmonic']}" if n["harmonic"] else ""): 1
            for n in summary["named"]
        },
        **({"validation": summary["validation"]} if "validation" in summary else {}),
    }


def headline_of(summary: dict[str, Any], details: dict[str, Any]) -> dict[str, Any]:
    """The stage's headline metrics: RMS after, how many named, the final model's held-out mean and, when
    measurement-side effects corrected the held-out readings, the robot's as the service corrects it (newcomer pass
    15: 0.0251 mm final beside 0.1686 as served, which only one console line said)."""
    headline = {"disc_rms_mm": details["rms_after_mm"], "disc_named": details["n_named"]}
    final = (summary.get("validation") or {}).get("final") or {}
    if "mean_position_mm" in final:  # the held-out figure of the model the service applies (the one to judge by)
        headline["disc_val_mean_mm"] = final["mean_position_mm"]
    if "as_served" in final:
        headline["disc_val_served_mean_mm"] = final["as_served"]["mean_position_mm"]
    return headline


def compute(ctx: Context) -> Metrics:
    from robocal.report import plots
    from robocal.robot import robot_from_dict
    from robocal.workflows import discovery

    settings = dict(ctx.cfg["discovery"])
    report = bool(settings.pop("report", True))
    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    summary = discovery.run(ctx.path(INPUT), robot, ctx.out, settings, split={"method": "none"}, report=report)
    steps = summary["steps"]
    rms = [summary["rms_before_mm"]] + [s["rms_after_mm"] for s in steps if s["accepted"]]
    for k, v in enumerate(rms):
        ctx.tracker.log_metrics({"step_rms_mm": v}, step=k)
    assert ctx.plots is not None
    labels = ["geometric"] + [s["accepted"] for s in steps if s["accepted"]]
    plots.save_figure(
        plots.bar_table(labels, {"RMS (mm)": rms, "noise floor (mm)": [summary["noise_floor_mm"]] * len(rms)}, "mm"),
        ctx.plots / "rms_per_step.png",
    )
    for name in ("discovery.json", "report.html"):
        if (ctx.out / name).exists():
            ctx.artifact(ctx.out / name)
    details = metrics_of(summary)
    headline = headline_of(summary, details)
    problems = list(summary.get("problems", []))
    for text in problems:  # the fit had nothing to start from (as geometric_fit says it)
        print(f"stage discover: FAILED: {text}")
    if problems:
        details["reason"] = "; ".join(problems)
        ctx.tracker.set_tags({"robocal.failure": details["reason"]})
        return Metrics(headline, details, status="failed")
    return Metrics(headline, details)


if __name__ == "__main__":
    run(STAGE, compute)
