"""screen: sensitivity screening of the kinematic parameters for thermal compensation (Guo et al. 2026, 3.4).

Reads ``robot`` and ``screen`` (``conf/screen/default.yaml``); skips explicitly when the campaign has no
temperatures or the thermal fit skipped (the screening only serves the thermal compensation). Otherwise screens
every parameter of the robot's chain (robocal.thermal.screening.screen) with the per-state drift of the thermal fit
(``screen.drift_file``, reports/thermal/states.json) or ``screen.drift``, and the tool points of the calibration
(TOOL_SOURCES) when ``screen.tool_mm`` is null. Writes ``reports/screen/`` (screening.json, whose ``selected``
list the thermal validation compensates, and ``what_if``: the borderline parameters and which change of the
rule would add or drop them, and why; screening.csv; report.html), figures to ``reports/plots/screen``, metrics.

    python stages/screen.py +screen=default screen.selection.rule=top_k
"""

from __future__ import annotations

from common import Context, Metrics, Skipped, Stage, run

STAGE = Stage(
    name="screen",
    params=("robot", "screen"),
    out="reports/screen",
    metrics="reports/metrics/screen.json",
    plots="reports/plots/screen",
)
PREPARE = "data/interim/prepare.json"
#: The thermal fit's output folder (its drift per state, or its skipped result).
THERMAL = "reports/thermal"
#: Where the tool points come from when ``screen.tool_mm`` is null, first found: the thermal fit's cold-state
#: calibration, else the geometric calibration (``tools_mm``); else the flange origin.
TOOL_SOURCES = ("reports/thermal/reference_calibration.json", "reports/geometric/calibration.json")


def compute(ctx: Context) -> Metrics | Skipped:
    prep = ctx.read_json(PREPARE)
    if not prep.get("has_temperatures"):
        return ctx.skip(
            "no temperature log: the campaign has no temperatures, the screening serves thermal compensation"
        )
    from robocal.report.html import Report
    from robocal.robot import robot_from_dict
    from robocal.thermal import screening as scr

    robot = robot_from_dict(ctx.cfg["robot"], source="params: robot")
    cfg = dict(ctx.cfg["screen"])
    conf = scr.ScreeningConfig.from_mapping(cfg)  # errors name the key before any file is read
    why = ctx.upstream_skipped(THERMAL)
    if why is not None and conf.drift is None:  # no drift of the thermal fit to screen
        return ctx.skip(f"thermal_fit skipped ({why}): the screening serves thermal compensation")
    if conf.tool_mm is None:
        found = [p for p in TOOL_SOURCES if ctx.path(p).is_file()]
        if found:
            cfg["tool_mm"] = ctx.read_json(found[0])["tools_mm"]
    drift = stderr = None
    if conf.drift is None and conf.drift_file is not None:
        drift = scr.load_drift(ctx.path(conf.drift_file))
        stderr = scr.load_drift_stderr(ctx.path(conf.drift_file))
    seed = 0 if conf.seed is None else conf.seed
    result = scr.screen(robot, cfg, seed=seed, drift=drift, drift_stderr=stderr)

    scr.write_screening(result, ctx.out)
    assert ctx.plots is not None
    scr.save_screening_figures(result, ctx.plots)
    rep = Report(f"Sensitivity screening: {robot.name}", subtitle=f"campaign {prep.get('source', '')}")
    scr.add_to_report(result, rep)
    rep.save(ctx.out / "report.html")
    for name in ("screening.json", "screening.csv", "report.html"):
        ctx.artifact(ctx.out / name)
    ctx.tracker.set_tags({"robocal.screen.selected": ",".join(result.selected) or "(none)"})
    print(f"stage screen: selected {len(result.selected)} of {len(result.table)}: {', '.join(result.selected)}")
    for w in result.what_if:  # borderline parameters: which change of the rule would add or drop them, and why
        print(f"  {w['text']}")
    t = result.table
    details = {
        "n_screened": len(t),
        "n_selected": len(result.selected),
        "selected": ",".join(result.selected),
        "score": result.score,
        "selected_share": float(t.loc[t["selected"], "share"].sum()),
        "max_abs_H": float(t["H"].abs().max()) if t["H"].notna().any() else None,
        "max_E_mean": float(t["E_mean"].max()),
        "n_borderline": len(result.what_if),
    }
    return Metrics({"screened_in": len(result.selected)}, details)


if __name__ == "__main__":
    run(STAGE, compute)
