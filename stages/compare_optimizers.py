"""compare_optimizers: the thermal paper's optimizer comparison (section 3.2, fig. 4) on the interim campaign.

Improved GOA vs GOA vs WOA on the geometric calibration (experiments/optimizer_comparison.py): every
algorithm x population x run, each run a nested MLflow run (time, iterations, error, convergence curve); writes
``reports/compare_optimizers/`` (runs.csv, table.csv, summary.json, report.html with fig.-4-like plots).

    make compare        # = dvc exp run -S compare.run=true (off by default: a plain `dvc repro` skips it)
    python stages/compare_optimizers.py -m compare.populations=[500],[1000],[1500]   # a sweep, one job each
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from common import Context, Metrics, Stage, run

STAGE = Stage(
    name="compare_optimizers",
    params=("robot", "calibration", "compare"),
    out="reports/compare_optimizers",
    metrics="reports/metrics/compare_optimizers.json",
    plots="reports/plots/compare_optimizers",
    inline_tracking=True,  # one nested MLflow run per optimizer run, under this stage's run
)
INPUT = "data/interim"
#: The experiment's code (settings, runs, table, paper deltas, report): experiments/optimizer_comparison.py.
EXPERIMENT_DIR = Path(__file__).resolve().parents[1] / "experiments"
#: The algorithms' coefficients (their Hydra group files, read as files: a dependency of the stage).
COEFFICIENTS = "conf/optimizer/{name}.yaml"


#: why a default `dvc repro` does not run the comparison (its skipped result says so)
OFF = "the optimizer comparison takes minutes and is off by default (compare.run: false); run it with `make compare`"


def compute(ctx: Context) -> Any:
    sys.path.insert(0, str(EXPERIMENT_DIR))  # the experiment's code lives with the experiment
    from optimizer_comparison import (
        CompareSettings,
        compare_optimizers,
        comparison_figures,
        comparison_report,
        write_comparison,
    )

    settings = CompareSettings.from_mapping(ctx.cfg["compare"])
    if not settings.run:  # before the data door and the plots are imported: the default run skips at once
        return ctx.skip(OFF)

    import numpy as np
    import yaml

    from robocal.calibration.config import CalibrationConfig
    from robocal.data.contract import read_campaign
    from robocal.report.plots import save_figure
    from robocal.robot import robot_from_dict
    from robocal.tracking.runs import StageRun

    cal_settings = dict(ctx.cfg["calibration"])
    cal_settings.pop("report", None)
    cfg = CalibrationConfig.from_mapping(cal_settings)
    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    campaign = read_campaign(ctx.path(INPUT), robot)
    coefficients = {}
    for name in settings.algorithms:
        path = ctx.path(COEFFICIENTS.format(name=name))
        with open(path, encoding="utf-8") as fh:
            coefficients[name] = yaml.safe_load(fh) or {}
    tracker = ctx.tracker

    def on_run(row: dict[str, Any], history: list[float]) -> None:
        child = StageRun(
            "compare_optimizers",
            enabled=tracker.enabled,
            uri=tracker.uri,
            experiment=tracker.experiment,
            parent_run_id=tracker.run_id,
            run_name=f"{row['algorithm']} pop {row['population']} run {row['run']}",
            tags={"robocal.algorithm": row["algorithm"]},
            quiet=True,  # one line per run would break the progress bar
        )
        with child:
            child.log_params({k: row[k] for k in ("algorithm", "population", "run", "seed")})
            child.log_metrics({k: float(v) for k, v in row.items() if isinstance(v, int | float) and k != "run"})
            every = settings.log_history_every
            if every > 0:
                for i in range(0, len(history), every):
                    child.log_metrics({"best_fitness_mm": history[i]}, step=i + 1)

    result = compare_optimizers(campaign, robot, cfg, settings, coefficients, on_run=on_run)
    summary = write_comparison(result, settings, ctx.out)
    comparison_report(result, summary, settings).save(ctx.out / "report.html")
    assert ctx.plots is not None
    for name, fig in comparison_figures(result, summary).items():
        save_figure(fig, ctx.plots / f"{name}.svg")
    for name in ("report.html", "runs.csv", "table.csv", "summary.json"):
        ctx.artifact(ctx.out / name)
    table = {
        f"{r['algorithm']}_{r['population']}": {k: v for k, v in r.items() if k not in ("algorithm", "population")}
        for r in summary["table"]
    }
    headline = {
        f"cmp_{alg}_err_mm": float(np.mean([r["error_mm"] for r in summary["table"] if r["algorithm"] == alg]))
        for alg in settings.algorithms
    }
    return Metrics(headline, {"table": table, "deltas": summary["deltas"], "gn_rms_mm": summary["gn_rms_mm"]})


if __name__ == "__main__":
    run(STAGE, compute)
