"""simulate: the embedded default campaign, written by the digital twin, so a fresh clone has data.

Reads ``scenario`` (conf/scenario/, the twin's settings) and ``robot`` (the robot being calibrated, which the
twin simulates); writes ``data/raw/default/`` in the data contract (poses.csv [+ temperatures.csv], plus
truth.json and scenario.yaml, which readers of the contract ignore).
"""

from __future__ import annotations

from typing import Any

from common import Context, Stage, run

STAGE = Stage(
    name="simulate",
    params=("scenario", "robot"),
    out="data/raw/default",
    metrics="reports/metrics/simulate.json",
)


def compute(ctx: Context) -> dict[str, Any]:
    from robocal.robot import robot_from_dict
    from robocal.sim.twin import simulate

    scenario = ctx.get("scenario", types=dict)
    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    truth = simulate(scenario, ctx.out, seed=ctx.get("scenario.seed", 0, types=int), robot=robot)
    lines = (ctx.out / "poses.csv").read_text(encoding="utf-8").splitlines()
    header = lines[0].split(",")
    split = [row.rsplit(",", 1)[-1] for row in lines[1:]] if header[-1] == "split" else []
    ctx.artifact(ctx.out / "truth.json")
    ctx.artifact(ctx.out / "scenario.yaml")
    return {
        "scenario": truth["scenario"],
        "robot": truth["robot"],
        "n_rows": len(lines) - 1,
        "n_calibration_rows": split.count("calibration"),
        "n_validation_rows": split.count("validation"),
        "has_temperatures": (ctx.out / "temperatures.csv").is_file(),
        "noise_mm": truth["noise_mm"],
    }


if __name__ == "__main__":
    run(STAGE, compute)
