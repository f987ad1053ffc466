"""plan: the calibration poses of the twin's cell, chosen before the tracker is switched on (robocal.plan).

Reads ``robot``, ``plan`` (conf/plan/) and ``scenario`` (the twin's cell: tracker, targets, noise, joint
ranges, the number of calibration poses); writes ``reports/plan/`` (``plan.csv`` in the data contract's joint
columns, ``plan.json``, ``report.html``). With ``plan.measured_by_twin`` (default) the ``simulate`` stage
measures these poses for the default campaign, so ``dvc repro`` calibrates from a planned campaign and
``dvc exp run -S plan.measured_by_twin=false`` from random poses, validated on the same poses.

Skipped when ``data.campaign`` names a campaign of your own: the twin's cell is not yours (plan your cell with
``robocal plan --robot R --n 40 --out DIR tracker.position_mm=[...]``).
"""

from __future__ import annotations

from common import Context, Metrics, Skipped, Stage, run

STAGE = Stage(
    name="plan",
    params=("robot", "plan", "scenario", "data.campaign"),
    out="reports/plan",
    metrics="reports/metrics/plan.json",
)


def compute(ctx: Context) -> Metrics | Skipped:
    campaign = ctx.own_campaign()
    if campaign is not None:
        return ctx.skip(f"data.campaign names {campaign!r}: the plan describes the twin's cell, not yours")
    from robocal.plan.output import run_plan
    from robocal.plan.region import cell_from_scenario
    from robocal.robot import robot_from_dict

    cfg = dict(ctx.get("plan", types=dict))
    cfg.pop("measured_by_twin", None)
    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    metrics = run_plan(robot, {**cfg, **cell_from_scenario(ctx.get("scenario", types=dict))}, ctx.out)
    ctx.artifact(ctx.out / "report.html")
    details = {k: v for k, v in metrics.items() if not k.endswith("_s")}
    return Metrics({"plan_region_rms_mm": metrics["predicted_region_rms_mm"]}, details)


if __name__ == "__main__":
    run(STAGE, compute)
