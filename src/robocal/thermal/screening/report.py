"""The screening figures (fig. 9, table 4 equivalents), files and HTML section."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.thermal.screening.result import ScreeningResult

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from robocal.report.html import Report


# ------------------------------------------------------------------------------------------------ figures

_LENGTH_COLOR = "#4c72b0"
_ANGLE_COLOR = "#dd8452"
_SELECTED_COLOR = "#c44e52"
_OTHER_COLOR = "#8c8c8c"


def _style() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    from robocal.report import plots

    return matplotlib.rc_context(plots.STYLE)


def screening_figures(result: ScreeningResult) -> list[tuple[Figure, str]]:
    """Equivalents of Guo et al. fig. 9 and table 4, as ``(Figure, caption)``.

    1. sensitivity: mean (bar) and max (tick) position error and orientation error per parameter for the
       +/- delta perturbations (fig. 9);
    2. influence: signed ``H`` per parameter, selected ones highlighted, the threshold drawn (table 4);
       without drift, the pure sensitivity score ``E_mean`` instead;
    3. cumulative share of the score, parameters by rank, selected ones highlighted.
    """
    with _style():
        return [_sensitivity_figure(result), _influence_figure(result), _cumulative_share_figure(result)]


def _width(n: int) -> float:
    """Figure width (in) for ``n`` parameters along the x axis."""
    return min(max(6.0, 0.32 * n + 2.0), 14.0)


def _tilt(n: int) -> int:
    """Rotation (deg) of the x tick labels for ``n`` parameters."""
    return 60 if n > 12 else 0


def _sensitivity_figure(result: ScreeningResult) -> tuple[Figure, str]:
    """Mean (bar) and max (tick) position and orientation error per parameter (fig. 9)."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    t = result.table
    names = list(t["parameter"])
    x = np.arange(len(names))
    tilt = _tilt(len(names))
    colors = [_ANGLE_COLOR if k == "angle" else _LENGTH_COLOR for k in t["kind"]]
    step_a = t.loc[t["kind"] == "angle", "step"]
    step_l = t.loc[t["kind"] == "length", "step"]
    steps = ", ".join(
        s
        for s in (
            f"±{step_a.iloc[0]:g}° (angles)" if len(step_a) else "",
            f"±{step_l.iloc[0]:g} mm (lengths)" if len(step_l) else "",
        )
        if s
    )
    n_cfg = result.config.get("n_configs", "?")
    fig = Figure(figsize=(_width(len(names)), 5.6), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    ax1.bar(x, t["mean_position_mm"], color=colors)
    ax1.plot(x, t["max_position_mm"], "_", color="k", ms=9, mew=1.5, label="max")
    ax1.set_ylabel("position error (mm)")
    ax2.bar(x, 1e3 * t["mean_orientation"], color=colors)
    ax2.plot(x, 1e3 * t["max_orientation"], "_", color="k", ms=9, mew=1.5, label="max")
    ax2.set_ylabel("orientation error ‖R_s R_0ᵀ − I‖_F (×10⁻³)")
    handles = [
        Patch(color=_LENGTH_COLOR, label="length (mean)"),
        Patch(color=_ANGLE_COLOR, label="angle (mean)"),
        *ax1.get_legend_handles_labels()[0],
    ]
    ax1.legend(handles=handles, loc="best")
    ax2.set_xticks(x, names, rotation=tilt, ha="right" if tilt else "center")
    ax1.grid(False, axis="x")
    ax2.grid(False, axis="x")
    return fig, f"Sensitivity of the tool pose to each kinematic parameter ({steps}; {n_cfg} random configurations)"


def _influence_figure(result: ScreeningResult) -> tuple[Figure, str]:
    """Signed ``H`` per parameter (``E_mean`` without drift), selected ones highlighted, the threshold drawn."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    t = result.table
    names = list(t["parameter"])
    x = np.arange(len(names))
    tilt = _tilt(len(names))
    by_h = result.score == "|H|"
    val = t["H"] if by_h else t["E_mean"]
    fig = Figure(figsize=(_width(len(names)), 3.8), layout="constrained")
    ax = fig.add_subplot()
    bar_colors = [_SELECTED_COLOR if s else _OTHER_COLOR for s in t["selected"]]
    ax.bar(x, np.nan_to_num(val.to_numpy(dtype=float)), color=bar_colors)
    sel = result.config.get("selection", {})
    if sel.get("rule") == "threshold":
        hm = float(sel.get("h_min", 0.0))
        ax.axhline(hm, color="k", ls="--", lw=0.8, label=f"threshold {hm:g}")
        if by_h:
            ax.axhline(-hm, color="k", ls="--", lw=0.8)
    ax.axhline(0.0, color="k", lw=0.7)
    ax.set_xticks(x, names, rotation=tilt, ha="right" if tilt else "center")
    ax.set_ylabel("H = E_mean · P_o(T)" if by_h else "E_mean (per step)")
    ax.legend(
        handles=[Patch(color=_SELECTED_COLOR, label="selected"), Patch(color=_OTHER_COLOR, label="not selected")]
        + ax.get_legend_handles_labels()[0],
        loc="best",
    )
    ax.grid(False, axis="x")
    cap = (
        "Influence H of each parameter at the temperature state (table 4 equivalent), selected in red"
        if by_h
        else "No drift known: sensitivity E_mean per parameter, selected in red"
    )
    return fig, cap


def _cumulative_share_figure(result: ScreeningResult) -> tuple[Figure, str]:
    """The share of the total score per parameter by rank and its cumulative sum, selected ones highlighted."""
    from matplotlib.figure import Figure

    t = result.table
    tilt = _tilt(len(t))
    sel = result.config.get("selection", {})
    order = t.sort_values("rank")
    fig = Figure(figsize=(_width(len(t)), 3.4), layout="constrained")
    ax = fig.add_subplot()
    cum = np.cumsum(order["share"].to_numpy())
    xs = np.arange(len(order))
    ax.bar(xs, order["share"], color=[_SELECTED_COLOR if s else _OTHER_COLOR for s in order["selected"]])
    ax.plot(xs, cum, "o-", color="k", ms=3, label="cumulative share")
    if sel.get("rule") == "share":
        ax.axhline(float(sel.get("share", 1.0)), color="k", ls="--", lw=0.8, label="share rule")
    ax.set_xticks(xs, list(order["parameter"]), rotation=tilt, ha="right" if tilt else "center")
    ax.set_ylabel(f"share of Σ {result.score}")
    ax.set_ylim(0, 1.05)
    ax.legend(loc="center right")
    ax.grid(False, axis="x")
    return fig, f"Share of the total {result.score} by rank; selected parameters in red"


def write_screening(result: ScreeningResult, directory: str | Path) -> list[Path]:
    """Write ``screening.json`` (:meth:`ScreeningResult.to_dict`) and ``screening.csv`` (the table), atomically."""
    from robocal.io import atomic_write, write_json

    d = Path(directory)
    return [
        write_json(d / "screening.json", result.to_dict()),
        atomic_write(d / "screening.csv", lambda p: result.table.to_csv(p, index=False, float_format="%.9g")),
    ]


FIGURE_FILES = ("screen_sensitivity.png", "screen_influence.png", "screen_cumulative_share.png")


def save_screening_figures(result: ScreeningResult, directory: str | Path) -> list[Path]:
    """Write :func:`screening_figures` to ``directory`` as :data:`FIGURE_FILES` (PNG); returns the paths."""
    from robocal.report.plots import save_figure

    d = Path(directory)
    return [save_figure(fig, d / name) for (fig, _), name in zip(screening_figures(result), FIGURE_FILES, strict=True)]


def add_to_report(result: ScreeningResult, report: Report, level: int = 2) -> Report:
    """Append the screening section (settings, selected set, table, figures) to an HTML :class:`Report`."""
    cfg = result.config
    sel = cfg.get("selection", {})
    rule = sel.get("rule")
    rule_text = {
        "threshold": f"{result.score} ≥ {sel.get('h_min')}",
        "share": f"fewest parameters holding {sel.get('share')} of Σ {result.score}",
        "top_k": f"the {sel.get('top_k')} largest {result.score}",
        "relative": f"{result.score} ≥ {sel.get('relative')} × the largest",
    }.get(str(rule), str(rule))
    report.heading("Sensitivity screening of the kinematic parameters", level)
    report.paragraph(
        "Each parameter is perturbed on its own by ± its step at random joint configurations; position error = "
        "tool-point displacement (eq. 23), orientation error = ‖R_s R_0ᵀ − I‖_F (eq. 24), total = their sum "
        "(eq. 25), E_mean its mean. With the identified drift Δη(T): P_o = Δη(T) / δη (eq. 26) and "
        "H = E_mean · P_o (eq. 27). Guo et al. 2026, section 3.4."
    )
    report.kv(
        {
            "robot": result.robot,
            "configurations": cfg.get("n_configs"),
            "steps": f"±{cfg.get('angle_step_deg')}° / ±{cfg.get('length_step_mm')} mm",
            "tool points (flange frame, mm)": "flange origin"
            if cfg.get("tool_mm") is None
            else "; ".join("x {:.3f}, y {:.3f}, z {:.3f}".format(*t) for t in cfg["tool_mm"]),
            "temperature states in the drift": result.drift_states,
            "state used for P_o(T)": "-" if result.drift_state_used is None else str(result.drift_state_used),
            "score": result.score,
            "selection rule": rule_text,
            "selected": ", ".join(result.selected) or "(none)",
            "seed": result.seed,
        },
        caption="Screening settings and outcome",
    )
    for n in result.notes:
        report.note(n)
    cols = [
        "parameter",
        "unit",
        "step",
        "mean_position_mm",
        "E_mean",
        "drift",
        "drift_z",
        "P_o",
        "H",
        "share",
        "rank",
        "selected",
    ]
    shown = result.table[cols].rename(
        columns={
            "step": "step (unit)",
            "mean_position_mm": "E_pos mean (mm)",
            "drift": "drift (unit)",
        }
    )
    report.table(
        shown,
        caption="Per-parameter sensitivity and influence (table 4 equivalent), step and drift in the row's unit; "
        "orientation errors, maxima and the Jacobian cross-check: screening.csv",
        float_fmt="{:.3g}",
    )
    band, zlim = sel.get("explain_band", 2.0), sel.get("explain_z", 2.0)
    if result.what_if:
        report.paragraph(
            f"Which parameters the selection would add or drop, and why: scores within a factor {band:g} of the "
            f"rule's cut ({result.what_if[0]['cut']:.4g}), selected parameters whose drift is below {zlim:g} "
            "standard errors (not significant: tracker noise can make such a drift), and parameters kept out by "
            "min_z or forced by include / exclude."
        )
        report.table(
            [
                {
                    "parameter": w["parameter"],
                    "selected": w["selected"],
                    result.score: w["score"],
                    "rank": w["rank"],
                    "drift_z": w["drift_z"],
                    "what would change it": w["text"],
                }
                for w in result.what_if
            ],
            caption="Borderline parameters: what would add or drop them",
        )
    else:
        report.paragraph(
            f"No parameter lies within a factor {band:g} of the rule's cut, and every selected drift is significant "
            f"(≥ {zlim:g} std. errors, when known): the selection is not borderline."
        )
    for fig, cap in screening_figures(result):
        report.figure(fig, cap)
    return report
