"""simulate: the embedded default campaign, written by the digital twin, so a fresh clone has data.

Reads ``scenario`` (conf/scenario/, the twin's settings), ``robot`` (the robot being calibrated, which the
twin simulates), ``data.campaign`` and ``plan.measured_by_twin`` (the calibration poses are the ``plan``
stage's, ``reports/plan/plan.csv``, unless false); writes ``data/raw/default/`` in the data contract (poses.csv
[+ temperatures.csv], plus truth.json and scenario.yaml, which readers of the contract ignore).

The twin runs only for the default campaign: when ``data.campaign`` names another folder (your own data),
the stage skips with that reason and writes nothing but ``data/raw/default/result.json``. A scenario effect
the robot cannot have (the thermal warm-up on a robot without temperature sensors) is left out with a note
(printed, and in ``scenario.yaml`` under ``left_out``) instead of failing.
"""

from __future__ import annotations

from common import Context, Metrics, Skipped, Stage, run

STAGE = Stage(
    name="simulate",
    params=("scenario", "robot", "data.campaign", "plan.measured_by_twin"),
    out="data/raw/default",
    metrics="reports/metrics/simulate.json",
)


def compute(ctx: Context) -> Metrics | Skipped:
    from robocal.robot import robot_from_dict
    from robocal.sim.twin import simulate

    campaign = ctx.own_campaign()
    if campaign is not None:
        return ctx.skip(f"data.campaign names {campaign!r}, not the default campaign: the twin is not run")
    scenario = dict(ctx.get("scenario", types=dict))
    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    effects = dict(scenario.get("effects") or {})
    left_out = []
    if "thermal" in effects and not robot.sensor_names:
        left_out.append(f"thermal (robot {robot.name!r} has no temperature sensors)")
        del effects["thermal"]
        print(f"stage simulate: note: scenario {scenario.get('name')!r} leaves out its {left_out[-1]}")
    scenario["effects"] = effects
    planned = ctx.get("plan.measured_by_twin", False, types=bool)
    if planned:  # the calibration poses the plan stage chose (validation poses: the same random ones either way)
        from robocal.io import display_path

        scenario["poses_deg"] = display_path(ctx.path("reports/plan/plan.csv"))  # relative: same bytes in any clone
    truth = simulate(scenario, ctx.out, seed=ctx.get("scenario.seed", 0, types=int), robot=robot)
    if left_out:
        with open(ctx.out / "scenario.yaml", "a", encoding="utf-8") as fh:
            fh.write("left_out:\n" + "".join(f"  - {item}\n" for item in left_out))
    lines = (ctx.out / "poses.csv").read_text(encoding="utf-8").splitlines()
    header = lines[0].split(",")
    split = [row.rsplit(",", 1)[-1] for row in lines[1:]] if header[-1] == "split" else []
    ctx.artifact(ctx.out / "truth.json")
    ctx.artifact(ctx.out / "scenario.yaml")
    details = {
        "scenario": truth["scenario"],
        "robot": truth["robot"],
        "n_rows": len(lines) - 1,
        "n_calibration_rows": split.count("calibration"),
        "n_validation_rows": split.count("validation"),
        "has_temperatures": (ctx.out / "temperatures.csv").is_file(),
        "noise_mm": truth["noise_mm"],
        "calibration_poses": "planned (reports/plan/plan.csv)" if planned else "random",
    }
    return Metrics({"sim_rows": details["n_rows"]}, details)


if __name__ == "__main__":
    run(STAGE, compute)
