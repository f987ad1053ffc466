"""geometric_fit: geometric calibration of the interim campaign (robocal.workflows.geometric.run).

Reads ``robot``, ``optimizer`` (any registered optimizer, robocal.calibration.fit.fit_with_optimizer; for
ipopt / igoa / goa / woa the raw and polished results both in summary.json and the metrics)
and ``calibration``; writes ``reports/geometric/``
(calibration.json, summary.json, residuals.csv, report.html), metrics (errors in mm, and degrees when the
campaign has orientations; times) and two plots for ``dvc plots show``.

Sweep inside the stage (nested MLflow runs under one parent)::

    python stages/geometric_fit.py -m optimizer=gn,lm,ipopt
    python stages/geometric_fit.py -m optimizer=igoa,goa,woa optimizer.polish=true
    python stages/geometric_fit.py -m calibration.noise_mm=0.01,0.015,0.02 hydra/launcher=joblib
"""

from __future__ import annotations

from typing import Any

from common import Context, Metrics, Stage, run

STAGE = Stage(
    name="geometric_fit",
    params=("robot", "optimizer", "calibration"),
    out="reports/geometric",
    metrics="reports/metrics/geometric_fit.json",
    plots="reports/plots/geometric_fit",
)
#: The stage's input: the prepare stage's interim copy of the campaign.
INPUT = "data/interim"


def calibration_settings(cfg: dict[str, Any]) -> tuple[dict[str, Any], bool]:
    """The CalibrationConfig mapping from the ``calibration`` section, and ``report``; the optimizer's name
    checked (its stopping rules and ``polish`` are read by robocal.calibration.fit.fit_with_optimizer)."""
    from robocal.errors import ConfigError
    from robocal.optimizers.registry import registered  # the one list of optimizer names

    name = cfg["optimizer"].get("name")
    if name not in registered():
        raise ConfigError(f"The config key 'optimizer.name' must be one of {list(registered())}. Got {name!r} instead.")
    settings = dict(cfg["calibration"])
    report = bool(settings.pop("report", True))
    return settings, report


def metrics_of(summary: dict[str, Any]) -> dict[str, Any]:
    """The numbers worth comparing across runs: fit and validation errors (mm, deg), sizes, times."""
    fit = summary["fit"]
    keep = (
        "rms_position_mm",
        "mean_position_mm",
        "max_position_mm",
        "rms_orientation_deg",
        "mean_orientation_deg",
        "max_orientation_deg",
        "noise_floor_rms_mm",
        "chi2",
        "dof",
        "nit",
        "n_rows",
        "wall_time_s",
    )
    out: dict[str, Any] = {"fit": {k: fit[k] for k in keep if isinstance(fit.get(k), int | float)}}
    out["n_identified"] = summary["n_identified"]
    out["n_eliminated"] = len(summary["eliminated"])
    for part in ("validation", "validation_before"):
        if part in summary:
            out[part] = {k: v for k, v in summary[part].items() if isinstance(v, int | float)}
    if "optimizer" in summary:  # raw and polished results of a non-gradient optimizer, side by side
        opt = summary["optimizer"]
        for part in ("raw", "polished", "times_s"):
            if part in opt:
                out[f"optimizer_{part}"] = {
                    k: v for k, v in opt[part].items() if isinstance(v, int | float) and not isinstance(v, bool)
                }
    return out


def compute(ctx: Context) -> Metrics:
    import pandas as pd

    from robocal.report import plots
    from robocal.robot import robot_from_dict
    from robocal.workflows import geometric

    settings, report = calibration_settings(ctx.cfg)
    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    summary = geometric.run(ctx.path(INPUT), robot, ctx.out, settings, report=report, optimizer=ctx.cfg["optimizer"])

    rows = pd.read_csv(ctx.out / "residuals.csv")
    cal = rows[rows["split"] == "calibration"]
    assert ctx.plots is not None
    plots.save_figure(
        plots.error_histogram(cal["err_before_mm"].to_numpy(), cal["err_after_mm"].to_numpy()),
        ctx.plots / "error_histogram.svg",
    )
    shown = rows[rows["split"] == "validation"] if (rows["split"] == "validation").any() else cal
    plots.save_figure(
        plots.error_per_pose(
            shown["err_before_mm"].to_numpy(),
            shown["err_after_mm"].to_numpy(),
            [f"{p}/{t}" for p, t in zip(shown["pose_id"], shown["target"], strict=True)],
        ),
        ctx.plots / "error_per_pose.png",
    )
    for name in ("report.html", "calibration.json", "summary.json", "residuals.csv"):
        ctx.artifact(ctx.out / name)
    details = metrics_of(summary)
    headline: dict[str, Any] = {"fit_rms_mm": summary["fit"]["rms_position_mm"]}
    if "validation" in summary:
        headline["val_mean_mm"] = summary["validation"]["mean_position_mm"]
        headline["val_nominal_mean_mm"] = summary["validation_before"]["mean_position_mm"]
    problems = list(summary["problems"])
    for text in problems:
        print(f"stage geometric_fit: FAILED: {text}")
    if problems:
        details["reason"] = "; ".join(problems)
        ctx.tracker.set_tags({"robocal.failure": details["reason"]})
    warnings = list(summary.get("warnings", []))
    for text in warnings:
        print(f"stage geometric_fit: WARNING: {text}")
    if warnings:
        details["warning"] = "; ".join(warnings)
        ctx.tracker.set_tags({"robocal.warning": details["warning"]})
    return Metrics(headline, details, status=summary["status"])


if __name__ == "__main__":
    run(STAGE, compute)
