"""The fleet report: one self-contained HTML page (robocal.report.html.Report, robocal.report.plots)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np

#: at most this many robots get their own figures (the tables list every robot)
MAX_ROBOT_FIGURES = 60


def _days(dates: Sequence[str]) -> np.ndarray:
    d0 = date.fromisoformat(dates[0][:10])
    return np.array([(date.fromisoformat(d[:10]) - d0).days for d in dates], dtype=float)


def _trend_figure(serial: str, name: str, e: Mapping[str, Any], dates: Sequence[str]) -> Any:
    """One parameter across recalibrations with ±2 standard errors."""
    from matplotlib.figure import Figure

    from robocal.report.plots import AFTER_COLOR

    t = _days(dates)
    v, s = np.asarray(e["value"]), np.asarray(e["stderr"])
    fig = Figure(figsize=(6.0, 2.6), layout="constrained")
    ax = fig.add_subplot()
    ax.errorbar(t, v, yerr=2 * s, fmt="o-", ms=4, capsize=3, color=AFTER_COLOR, label="estimate ± 2 std. errors")
    ax.set_xlabel(f"days since {dates[0]}")
    ax.set_ylabel(f"{name} ({e['unit']})")
    ax.set_title(f"{serial}: {name}")
    ax.grid(True, color="#dddddd", lw=0.6)
    ax.legend(loc="best", frameon=False, fontsize=8)
    return fig


def _z_figure(trends: Mapping[str, Any]) -> Any:
    """Histogram of every step z of the fleet against the standard normal: calibrated standard errors put the
    unflagged bulk on the curve; events sit beyond the Bonferroni threshold."""
    from matplotlib.figure import Figure

    from robocal.report.plots import AFTER_COLOR, BEFORE_COLOR

    z = np.array([v for r in trends["robots"].values() for e in r["parameters"].values() for v in e["step_z"]])
    zc = float(trends["test"]["z_critical"])
    fig = Figure(figsize=(7.0, 3.0), layout="constrained")
    ax = fig.add_subplot()
    inside = z[np.abs(z) <= 6.0]
    ax.hist(inside, bins=60, range=(-6, 6), density=True, color=AFTER_COLOR, alpha=0.7, label="steps, |z| <= 6")
    x = np.linspace(-6, 6, 400)
    ax.plot(x, np.exp(-0.5 * x**2) / np.sqrt(2 * np.pi), color="k", lw=1.0, label="standard normal")
    for sgn in (-1, 1):
        ax.axvline(sgn * zc, color=BEFORE_COLOR, ls="--", lw=1.0, label="flag threshold" if sgn > 0 else None)
    ax.set_xlabel(f"step z = Δ / sqrt(se1² + se2²)   ({int(np.sum(np.abs(z) > 6))} steps beyond |z| = 6 not shown)")
    ax.set_ylabel("density")
    ax.grid(True, color="#dddddd", lw=0.6)
    ax.legend(loc="upper left", frameon=False, fontsize=8)
    return fig


def write_report(path: str | Path, fleet_summary: Mapping[str, Any]) -> Path:
    """Write the fleet page from :func:`robocal.fleet.run.run_fleet`'s summary (``fleet.json``)."""
    from robocal.report.html import Report
    from robocal.report.plots import bar_table, time_series

    robots = fleet_summary["robots"]
    trends = fleet_summary["trends"]
    flags = trends["flags"]
    counts = fleet_summary["counts"]
    rep = Report("Fleet calibration", f"{counts['robots']} robots, {counts['campaigns']} campaigns")
    rep.heading("Fleet")
    rep.kv(
        {
            "robots": counts["robots"],
            "campaigns": counts["campaigns"],
            "accepted": counts["accepted"],
            "rejected": counts["rejected"],
            "errors": counts["errors"],
            "flagged parameters": len(flags),
            "robots with a flag": len({f["serial"] for f in flags}),
        }
    )
    # fleet-wide accuracy per campaign round (1st, 2nd, ... campaign of each robot)
    rounds = max(len(r["campaigns"]) for r in robots)
    labels, med_b, med_a, med_v = [], [], [], []
    for k in range(rounds):
        cs = [r["campaigns"][k] for r in robots if len(r["campaigns"]) > k and r["campaigns"][k]["status"] != "error"]
        if not cs:  # only failed campaigns in this round: nothing to plot
            continue
        labels.append(f"campaign {k + 1}")
        med_b.append(float(np.median([c["fit"]["rms_before_mm"] for c in cs])))
        med_a.append(float(np.median([c["fit"]["rms_after_mm"] for c in cs])))
        vv = [c["validation"]["mean_position_mm"] for c in cs if c["validation"].get("mean_position_mm") is not None]
        med_v.append(float(np.median(vv)) if vv else 0.0)
    series = {"RMS before": med_b, "RMS after": med_a, "validation mean": med_v}
    if labels:
        rep.figure(
            bar_table(labels, series, ylabel="median over robots (mm)"),
            "Accuracy across the fleet: median RMS before / after calibration and mean validation error, per campaign",
        )
    rep.heading("Parameters that moved")
    t = trends["test"]
    rep.paragraph(
        "A flag means a kinematic parameter moved between recalibrations more than its standard errors allow. "
        f"Rule: {t['rule']}. With three or more campaigns a flag is named by the pattern that fits the values "
        "better (weighted least squares, two parameters each): a straight line in time (drift) or two levels with "
        "one change point (jump); when even the better one leaves a lack-of-fit chi² with p < "
        f"{t['pattern_alpha']:g}, it is a change. With two campaigns a flag is a jump. Base (tracker) and tool "
        "parameters are not tested."
    )
    if any(e["step_z"] for r in trends["robots"].values() for e in r["parameters"].values()):
        rep.figure(
            _z_figure(trends),
            "Every step of every tested parameter across the fleet: with honest standard errors the bulk follows "
            "the standard normal; the flags lie beyond the dashed threshold",
        )
    if flags:
        rep.table(
            [
                {
                    "robot": f["serial"],
                    "parameter": f["parameter"],
                    "kind": f["kind"],
                    "largest step": f"{f['largest_step']['delta']:+.4g} {f['unit']}",
                    "between": " .. ".join(f["largest_step"]["between"]),
                    "z": f["largest_step"]["z"],
                    "trend z": f["trend_z"],
                    "what it may mean": f["explanation"],
                }
                for f in flags
            ],
            caption="Flagged parameters",
            float_fmt="{:.2f}",
        )
    else:
        rep.note("No parameter moved more than its uncertainty allows.")
    if "truth" in fleet_summary:
        rep.kv(_truth_rows(fleet_summary["truth"]), caption="Twin fleet: planted events against the flags")
    rep.heading("Robots")
    by_serial = {r["serial"]: r for r in robots}
    shown = sorted({f["serial"] for f in flags})[:MAX_ROBOT_FIGURES]
    if len({f["serial"] for f in flags}) > MAX_ROBOT_FIGURES:
        rep.note(f"Figures for the first {MAX_ROBOT_FIGURES} flagged robots only; the tables list every robot.", "warn")
    for serial in shown:
        r = by_serial[serial]
        rep.heading(f"{serial} ({r['robot']})", level=3)
        cs = [c for c in r["campaigns"] if c["status"] != "error"]
        if len(cs) >= 2:
            rep.figure(
                time_series(
                    _days([c["date"] for c in cs]),
                    {
                        "RMS before": [c["fit"]["rms_before_mm"] for c in cs],
                        "RMS after": [c["fit"]["rms_after_mm"] for c in cs],
                        "validation mean": [c["validation"].get("mean_position_mm") or np.nan for c in cs],
                    },
                    ylabel="error (mm)",
                    xlabel=f"days since {cs[0]['date']}",
                ),
                f"{serial}: accuracy before / after calibration over time",
            )
        tr = trends["robots"][serial]
        for f in flags:
            if f["serial"] == serial:
                rep.figure(_trend_figure(serial, f["parameter"], tr["parameters"][f["parameter"]], tr["dates"]))
                rep.paragraph(f["explanation"])
    rep.heading("Every campaign", level=3)
    rep.table(
        [
            {
                "robot": r["serial"],
                "campaign": c["campaign"],
                "status": c["status"],
                "RMS before (mm)": c.get("fit", {}).get("rms_before_mm"),
                "RMS after (mm)": c.get("fit", {}).get("rms_after_mm"),
                "validation mean (mm)": (c.get("validation") or {}).get("mean_position_mm"),
                "gross errors left out": c.get("fit", {}).get("n_outliers"),
                "note": "–" if c["status"] == "ok" else c.get("reason") or "–",
            }
            for r in robots
            for c in r["campaigns"]
        ],
        caption="Accuracy of every calibration (RMS over the calibration rows; mean over the validation rows)",
    )
    return rep.save(path)


#: the twin fleet's truth check, in words (fleet.json keeps its keys)
TRUTH_LABELS = {
    "n_events": "events planted",
    "n_detected": "events flagged",
    "n_right_kind": "flagged as the right kind",
    "missed": "missed",
    "wrong_kind": "flagged as another kind",
    "n_false_flags": "false flags",
    "false_flags": "false flags (robot, parameter)",
    "n_robots_without_event": "robots without an event",
}


def _truth_rows(truth: Mapping[str, Any]) -> dict[str, Any]:
    """The truth check with readable keys and "none" for an empty list (not a blank cell)."""
    out: dict[str, Any] = {}
    for k, v in truth.items():
        label = TRUTH_LABELS.get(k, k.replace("_", " "))
        if isinstance(v, list | tuple):
            v = "; ".join(_item(x) for x in v) if v else "none"
        out[label] = v
    return out


def _item(x: Any) -> str:
    if isinstance(x, Mapping):
        return ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in x.items())
    if isinstance(x, list | tuple):
        return " ".join(str(v) for v in x)
    return str(x)
