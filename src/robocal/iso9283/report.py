"""The ISO 9283 certificate (``report.html``): what a plant files for a robot's accuracy before and after calibration.

Robot, serial, test date, cell and cube, the test conditions (cycles, load, speed), the characteristics per pose
before and after side by side, the scatter of each pose's cycles around its barycentre, the rows left out and the
standard's definitions one line each. Built with :class:`robocal.report.html.Report` (one offline file).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.report.html import Report
from robocal.report.plots import AFTER_COLOR, BEFORE_COLOR, styled

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from robocal.iso9283.analysis import IsoResult
    from robocal.iso9283.outcome import IsoRun

DEFINITIONS = (
    ("barycentre", "x̄ = (1/n) Σ x_j (and ȳ, z̄, ā, b̄, c̄): the mean of the n attained poses of a test pose (7.2.1)"),
    ("AP_p", "pose accuracy, position: distance from the commanded position to the barycentre (7.2.1)"),
    ("AP_a, AP_b, AP_c", "pose accuracy, orientation: ā - a_c, b̄ - b_c, c̄ - c_c about the base x, y, z (7.2.1)"),
    ("RP_l", "pose repeatability, position: l̄ + 3 S_l, l_j the distance of cycle j from the barycentre (7.2.2)"),
    ("RP_a, RP_b, RP_c", "pose repeatability, orientation: ±3 S of the angle over the cycles (7.2.2)"),
    ("vAP_p", "multi-directional pose accuracy variation: largest distance between the approach barycentres (7.2.3)"),
    ("AD_p", "distance accuracy: mean attained distance between two poses minus the commanded distance (7.3)"),
    ("RD", "distance repeatability: ±3 S of the attained distance over the cycles (7.3)"),
    ("dAP, dRP", "drift: |AP| and |RP| of the first cycles minus those of the last cycles (7.5)"),
)


def _fmt(v: float | None, nd: int = 4) -> Any:
    return None if v is None else round(float(v), nd)


def characteristics_rows(before: IsoResult, after: IsoResult, after_label: str) -> list[dict[str, Any]]:
    """Position characteristics, one row per pose: before / after (mm)."""
    rows = []
    for pb in before.poses:
        pa = next((p for p in after.poses if p.pose == pb.pose), None)
        rows.append(
            {
                "pose": pb.pose,
                "AP_p before": _fmt(pb.AP_p_mm),
                f"AP_p {after_label}": _fmt(pa.AP_p_mm if pa else None),
                "RP_l before": _fmt(pb.RP_l_mm),
                f"RP_l {after_label}": _fmt(pa.RP_l_mm if pa else None),
                "vAP_p before": _fmt(before.vAP_p_mm.get(pb.pose)),
                f"vAP_p {after_label}": _fmt(after.vAP_p_mm.get(pb.pose)),
            }
        )
    return rows


def orientation_rows(before: IsoResult, after: IsoResult) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Orientation accuracy and repeatability (deg) before / after, one row per pose each; empty without measured
    orientations."""
    acc, rep = [], []
    for pb in before.poses:
        if pb.AP_abc_deg is None or pb.RP_abc_deg is None:
            continue
        pa = next((p for p in after.poses if p.pose == pb.pose), None)
        ra: dict[str, Any] = {"pose": pb.pose}
        rr: dict[str, Any] = {"pose": pb.pose}
        for k, c in enumerate("abc"):
            ra[f"AP_{c} before"] = _fmt(pb.AP_abc_deg[k], 5)
            ra[f"AP_{c} after"] = None if pa is None or pa.AP_abc_deg is None else _fmt(pa.AP_abc_deg[k], 5)
            rr[f"RP_{c} before"] = _fmt(pb.RP_abc_deg[k], 5)
            rr[f"RP_{c} after"] = None if pa is None or pa.RP_abc_deg is None else _fmt(pa.RP_abc_deg[k], 5)
        acc.append(ra)
        rep.append(rr)
    return acc, rep


def drift_rows(before: IsoResult, after: IsoResult, after_label: str) -> list[dict[str, Any]]:
    """Drift (mm) of the poses whose cycles span time; empty when none does."""
    rows = []
    for pb in before.poses:
        if pb.dAP_p_mm is None:
            continue
        pa = next((p for p in after.poses if p.pose == pb.pose), None)
        rows.append(
            {
                "pose": pb.pose,
                "between group centres (min)": _fmt(pb.drift_span_min, 1),
                "dAP_p before": _fmt(pb.dAP_p_mm),
                f"dAP_p {after_label}": _fmt(None if pa is None else pa.dAP_p_mm),
                "dRP_l before": _fmt(pb.dRP_l_mm),
                f"dRP_l {after_label}": _fmt(None if pa is None else pa.dRP_l_mm),
            }
        )
    return rows


@styled
def bars_figure(before: IsoResult, after: IsoResult, after_label: str) -> Figure:
    """AP_p and RP_l per pose, before and after, as grouped bars."""
    import matplotlib.pyplot as plt

    poses = [p.pose for p in before.poses]
    x = np.arange(len(poses))
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    for ax, key, title in ((axes[0], "AP_p_mm", "pose accuracy AP_p"), (axes[1], "RP_l_mm", "pose repeatability RP_l")):
        b = [getattr(p, key) for p in before.poses]
        a = [next((getattr(q, key) for q in after.poses if q.pose == p), np.nan) for p in poses]
        ax.bar(x - 0.2, b, 0.4, color=BEFORE_COLOR, label="before")
        ax.bar(x + 0.2, a, 0.4, color=AFTER_COLOR, label=after_label)
        ax.set_xticks(x, poses)
        ax.set_ylabel("mm")
        ax.set_title(title)
        ax.set_ylim(0, 1.25 * float(np.nanmax([*b, *a, 1e-9])))
        ax.legend(loc="upper center", ncol=2)
    fig.tight_layout()
    return fig


@styled
def scatter_figure(before: IsoResult, after: IsoResult, after_label: str) -> Figure:
    """Each pose's cycles around its barycentre (µm), x-y and x-z of the base frame, with the RP_l circle."""
    import matplotlib.pyplot as plt

    poses = before.poses
    k = max(len(poses), 1)
    fig, axes = plt.subplots(2, k, figsize=(2.3 * k + 0.6, 5.4), squeeze=False)
    lim = 0.0
    for p in poses:
        lim = max(lim, p.RP_l_mm, float(np.abs(p.deviations_mm).max()) if len(p.deviations_mm) else 0.0)
    lim = 1e3 * lim * 1.1
    t = np.linspace(0, 2 * np.pi, 100)
    for c, pb in enumerate(poses):
        pa = next((p for p in after.poses if p.pose == pb.pose), None)
        for r, (i, j, lab) in enumerate(((0, 1, "y"), (0, 2, "z"))):
            ax = axes[r, c]
            for pr, col, name in ((pb, BEFORE_COLOR, "before"), (pa, AFTER_COLOR, after_label)):
                if pr is None:
                    continue
                d = 1e3 * pr.deviations_mm
                if name == "before":  # hollow rings, so that the after dots stay visible where they coincide
                    ax.scatter(d[:, i], d[:, j], s=22, facecolors="none", edgecolors=col, linewidths=0.8, label=name)
                else:
                    ax.scatter(d[:, i], d[:, j], s=6, color=col, label=name, linewidths=0)
                ax.plot(1e3 * pr.RP_l_mm * np.cos(t), 1e3 * pr.RP_l_mm * np.sin(t), color=col, lw=0.9)
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            ax.set_aspect("equal")
            ax.set_xlabel("x (µm)")
            ax.set_ylabel(f"{lab} (µm)")
            if r == 0:
                ax.set_title(f"{pb.pose} ({pb.n_cycles} cycles)")
    # one legend for all panels, above them: inside P1's panel it covered the points and its markers were too small
    # to tell rings from dots
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], ls="none", marker="o", ms=8, mfc="none", mec=BEFORE_COLOR, mew=1.2, label="before: a cycle"),
        Line2D([], [], ls="none", marker="o", ms=5, color=AFTER_COLOR, label=f"{after_label}: a cycle"),
        Line2D([], [], color=BEFORE_COLOR, lw=1.4, label="RP_l before (circle)"),
        Line2D([], [], color=AFTER_COLOR, lw=1.4, label=f"RP_l {after_label} (circle)"),
    ]
    ncol = 4 if k >= 4 else 2  # one row over five panels, two over fewer
    fig.legend(handles=handles, loc="upper center", ncol=ncol, fontsize=9, frameon=False, bbox_to_anchor=(0.5, 1.0))
    fig.tight_layout(rect=(0.0, 0.0, 1.0, LEGEND_TOP[ncol]))
    return fig


#: the share of the scatter figure's height left below its legend (one row of four entries, or two rows of two)
LEGEND_TOP = {4: 0.93, 2: 0.86}


def _cube(run: IsoRun) -> dict[str, Any]:
    """The cube as the commanded targets give it: P1 the centre, the side from P2..P5 and the inset."""
    cmd = {p.pose: p.commanded_mm for p in run.before.poses}
    inset = run.settings.test.inset
    out: dict[str, Any] = {}
    if "P1" in cmd:
        c = cmd["P1"]
        out["cube centre P1 (base, mm)"] = ", ".join(f"{v + 0.0:.1f}" for v in np.round(c, 1))
        others = [cmd[k] for k in ("P2", "P3", "P4", "P5") if k in cmd]
        if others:
            half = np.mean([np.abs(o - c).max() for o in others]) / (1.0 - 2.0 * inset)
            out["cube side (mm, from P2..P5)"] = round(float(2.0 * half), 1)
    return out


def write_report(run: IsoRun, path: str | Path) -> Path:
    st = run.settings
    info = run.info
    label = "after" if run.after_kind == "measured" else "after (predicted)"
    rep = Report(
        "ISO 9283 performance certificate: pose characteristics",
        f"{info['robot']} · tested {info['date']} · before and after calibration"
        + ("" if run.after_kind == "measured" else " (after: predicted)"),
    )
    rep.heading("Robot and test")
    kv: dict[str, Any] = {
        "robot": info["robot"],
        "serial number": st.certificate.serial or "(not given)",
        "cell": st.certificate.cell or "(not given)",
        "test date": info["date"],
        "standard": "ISO 9283:1998, pose characteristics (clauses 7.2, 7.3, 7.5)",
        "campaign": info["campaign"],
        "calibration": info["calibration"],
        "frame of the figures": run.before.frame.get("figures_frame", "robot base"),
        "tracker registration": run.before.frame.get("registration"),
        "target (reflector)": run.iso.target,
        **_cube(run),
        "cycles (setting / used per pose)": f"{st.test.cycles} / "
        + ", ".join(f"{p.pose}: {p.n_cycles}" for p in run.before.poses),
        "approach for AP / RP / AD": run.before.frame.get("ap_approach"),
        "approach directions (vAP)": ", ".join(run.iso.test.approaches),
        "test load": f"{st.test.load_percent:g} % of rated"
        + ("" if st.test.rated_payload_kg is None else f" ({st.test.rated_payload_kg:g} kg rated)"),
        "test speed": f"{st.test.speed_percent:g} % of rated",
        "rows left out (before)": len(run.before.left_out),
        "after": run.after.frame.get("kind"),
    }
    rep.kv(kv)
    if run.after_kind == "predicted":
        rep.note(
            "The 'after' columns are PREDICTED, not measured: the test was measured once; each attained pose had the "
            "calibrated model's predicted error at its joints removed. Measure the test again with the corrected "
            "program to certify the after values.",
            kind="warn",
        )
    rep.heading("Characteristics per pose")
    rep.table(
        characteristics_rows(run.before, run.after, "after"),
        caption="position (mm): accuracy AP_p, repeatability RP_l, multi-directional variation vAP_p; "
        f"before vs {label}",
    )
    acc, rpt = orientation_rows(run.before, run.after)
    if acc:
        has_after = any(r.get("AP_a after") is not None for r in acc)
        none = "" if has_after else "; no after: the calibration has no orientations"
        rep.table(acc, caption=f"orientation accuracy (deg, about base x, y, z): before vs {label}{none}")
        rep.table(rpt, caption=f"orientation repeatability ± (deg): before vs {label}")
    drift = drift_rows(run.before, run.after, "after")
    if drift:
        g = run.settings.analysis.drift_group_cycles
        rep.table(drift, caption=f"drift (mm): the first {g} cycles vs the last {g}; before vs {label}")
    pair = run.before.distance_pair
    rep.table(
        [
            {
                "pair": "-" if pair is None else f"{pair[0]}-{pair[1]}",
                "AD_p before (mm)": _fmt(run.before.AD_p_mm),
                "AD_p after (mm)": _fmt(run.after.AD_p_mm),
                "RD ± before (mm)": _fmt(run.before.RD_l_mm),
                "RD ± after (mm)": _fmt(run.after.RD_l_mm),
            }
        ],
        caption=f"distance accuracy and repeatability (mm): before vs {label}",
    )
    rep.figure(bars_figure(run.before, run.after, label), "AP_p and RP_l per pose, before and " + label)
    rep.heading("Scatter of the cycles")
    rep.figure(
        scatter_figure(run.before, run.after, label),
        "each pose's cycles around its barycentre (µm; circle: RP_l), base x-y (top) and x-z (bottom)",
    )
    rep.heading("Rows left out")
    rep.paragraph("Rule: " + str(run.before.frame.get("gross_error_rule")) + ".")
    if run.before.left_out:
        rep.table(
            [{k: r[k] for k in ("row", "pose", "cycle", "approach", "distance_mm")} for r in run.before.left_out],
            caption=f"left out of the before test ({info['campaign']})",
        )
    else:
        rep.paragraph("None.")
    rep.heading("Definitions (ISO 9283:1998)")
    rep.table([{"characteristic": k, "definition": v} for k, v in DEFINITIONS])
    return rep.save(path)


__all__ = [
    "DEFINITIONS",
    "bars_figure",
    "characteristics_rows",
    "drift_rows",
    "orientation_rows",
    "scatter_figure",
    "write_report",
]
