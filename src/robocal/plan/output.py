"""Outputs of a plan: ``plan.csv`` (data-contract joint columns, no measurements), ``plan.json`` (criteria,
refusals, predicted standard errors, the poses-needed curve) and a self-contained ``report.html``.

Every file is written atomically (:mod:`robocal.io`). :func:`run_plan` is the one call behind ``robocal plan``
and the pipeline stage ``plan``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from robocal.data.columns import joint_columns
from robocal.io import write_json, write_text
from robocal.plan.config import PlanConfig
from robocal.plan.planner import PlanResult, plan_poses
from robocal.plan.prediction import predict
from robocal.robot import RobotDescription


def plan_csv(result: PlanResult) -> str:
    """``pose_id, [target,] q1_deg … qN_deg``: one row per pose (and per visible target when the tool has
    several targets); angles with 6 decimals (what the planner evaluated); a prismatic joint (a track, a column)
    as ``q<j>_mm`` in mm."""
    cfg = result.problem.config
    n = result.q.shape[1]
    multi = len(cfg.targets) > 1
    robot = result.problem.robot
    qcols = joint_columns(robot.prismatic) if robot.has_prismatic else [f"q{j + 1}_deg" for j in range(n)]
    header = ["pose_id"] + (["target"] if multi else []) + qcols
    lines = [",".join(header)]
    q = result.q if robot.coupling is None else robot.to_reported(result.q)  # the controller's values (coupling)
    qd = np.where(robot.prismatic, q, np.rad2deg(q)) if robot.has_prismatic else np.rad2deg(q)
    for k, pid in enumerate(result.pose_ids):
        angles = [f"{v:.6f}" for v in qd[k]]
        if multi:
            for t, tgt in enumerate(cfg.targets):
                if result.visible[k, t]:
                    lines.append(",".join([pid, tgt.name, *angles]))
        else:
            lines.append(",".join([pid, *angles]))
    return "\n".join(lines) + "\n"


def write_plan(result: PlanResult, out_dir: str | Path, report: bool | None = None) -> dict[str, Any]:
    """Write ``plan.csv``, ``plan.json`` and (unless ``report`` is false) ``report.html``; returns the JSON.

    All three are the same bytes for the same robot, settings and seed (timings are left out of them).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = result.to_dict()
    write_text(out / "plan.csv", plan_csv(result))
    write_json(out / "plan.json", summary)
    if result.problem.config.report if report is None else report:
        build_report(result).save(out / "report.html")
    return summary


def run_plan(
    robot: RobotDescription | str | Mapping[str, Any],
    config: PlanConfig | Mapping[str, Any] | None,
    out_dir: str | Path,
    report: bool | None = None,
) -> dict[str, Any]:
    """Plan and write the outputs; returns the metrics a stage logs (criteria, predicted errors, timings).

    The pipeline stage ``plan`` is meant to call it as
    ``run_plan(ctx.cfg["robot"], {**ctx.cfg["plan"], **cell_from_scenario(ctx.cfg["scenario"])}, ctx.out)``
    (``robocal.plan.region.cell_from_scenario``: the twin's tracker, targets, noise and joint ranges), and the
    ``simulate`` stage then measures ``reports/plan/plan.csv`` with ``scenario.poses_deg`` set to that path.
    """
    result = plan_poses(robot, config)
    summary = write_plan(result, out_dir, report)
    pred = summary["planned"]
    return {
        "n_poses": summary["n_poses"],
        "criterion": summary["criterion"],
        "candidates_accepted": summary["candidates"]["accepted"],
        "n_identifiable": summary["identifiable"]["n"],
        "D_logdet": pred["D_logdet"],
        "A_trace": pred["A_trace"],
        "region": summary["region"]["optimal_for"],
        "region_tool_point_min_mm": summary["region"]["tool_point_min_mm"],
        "region_tool_point_max_mm": summary["region"]["tool_point_max_mm"],
        "predicted_region_rms_mm": pred.get("region_rms_mm"),
        "random_region_rms_mm": summary["random_baseline"].get("region_rms_mm_mean"),
        "n_needed_for_accuracy": summary["n_needed_for_accuracy"],
        "total_s": result.timings["total_s"],
    }


# ---------------------------------------------------------------------------------------------------- report


def build_report(result: PlanResult) -> Any:
    """The HTML report: settings, refusals, criteria planned vs random, standard errors, poses, error map, curve."""
    import matplotlib

    matplotlib.use("Agg")

    from robocal.report.html import Report

    pr = result.problem
    cfg = pr.config
    rep = Report(
        f"Measurement plan: {pr.robot.name}, {len(result.idx)} poses",
        f"{cfg.criterion}-optimal by exchange over {pr.cand.n} accepted of {pr.cand.n_sampled} candidates, "
        f"seed {cfg.seed}",
    )
    _summary_section(rep, result)
    _region_section(rep, result)
    _candidates_section(rep, result)
    _criteria_section(rep, result)
    _stderr_section(rep, result)
    _poses_figure(rep, result)
    _error_map_section(rep, result)
    _curve_section(rep, result)
    rep.heading("Settings")
    rep.kv(settings_rows(cfg), caption="The plan settings (conf/plan/default.yaml and overrides)")
    return rep


def _summary_section(rep: Any, result: PlanResult) -> None:
    pr = result.problem
    cfg = pr.config
    rep.heading("Summary")
    pred = result.prediction
    base = result.random_baseline
    rep.kv(
        {
            "identifiable parameters": pr.p,
            "poses planned": len(result.idx),
            "fewest poses possible": pr.n_min,
            "predicted RMS position error over the region (mm)": pred.get("region_rms_mm"),
            "same, random poses in the same constraints (mean of 20, mm)": base.get("region_rms_mm_mean"),
            "predicted mean error of a held-out measurement (mm, incl. tracker noise)": pred.get(
                "region_mean_measured_mm"
            ),
            f"poses needed for {cfg.accuracy_mm} mm RMS over the region": result.n_needed,
        }
    )


def _region_section(rep: Any, result: PlanResult) -> None:
    cfg = result.problem.config
    reg = result.to_dict()["region"]
    rep.heading("Region the plan is made for")
    lo, hi = reg["tool_point_min_mm"], reg["tool_point_max_mm"]
    rep.kv(
        {
            "region": reg["optimal_for"],
            "configurations in it": reg["n"],
            "tool point x (mm)": f"{lo[0]:.0f} .. {hi[0]:.0f}",
            "tool point y (mm)": f"{lo[1]:.0f} .. {hi[1]:.0f}",
            "tool point z (mm)": f"{lo[2]:.0f} .. {hi[2]:.0f}",
            "criterion": cfg.criterion,
        }
    )
    if cfg.criterion == "I":
        rep.paragraph(
            "The plan minimises the mean predicted error of the calibrated model over this region (I-optimal). "
            "Choose it with region.kind: joints (ranges_deg), box (min_mm, max_mm: where the parts sit) or poses "
            "(a list or a CSV of joint configurations)."
        )
    else:
        rep.paragraph(
            f"A {cfg.criterion}-optimal plan maximises parameter precision whatever the region; the predicted "
            "errors below are over this region. criterion=I plans for the region itself."
        )


def _candidates_section(rep: Any, result: PlanResult) -> None:
    pr = result.problem
    rep.heading("Candidates and what the cell refused")
    rep.paragraph(
        "Each refused candidate is counted once, under the first check it fails (in this order); 'failing' "
        "counts every check a candidate fails."
    )
    rep.table(
        [{"reason": r, "refused": pr.cand.refused[r], "failing": pr.cand.failing[r]} for r in pr.cand.refused],
        caption=f"{pr.cand.n_sampled} sampled, {pr.cand.n} accepted",
    )


def _criteria_section(rep: Any, result: PlanResult) -> None:
    pred = result.prediction
    base = result.random_baseline
    rep.heading("Criteria: planned vs random")
    obs_p = pred["observability"]
    obs_r = base.get("observability_mean", {})
    rows = [
        {"criterion": "log det M (D, larger is better)", "planned": pred["D_logdet"], "random": base["D_logdet_mean"]},
        {"criterion": "tr M⁻¹ (A, scaled)", "planned": pred["A_trace"], "random": base.get("A_trace_mean")},
        {
            "criterion": "mean predicted variance over the region (I, mm²)",
            "planned": pred["I_mean_var_mm2"],
            "random": base.get("I_mean_var_mm2_mean"),
        },
    ]
    rows += [{"criterion": k, "planned": v, "random": obs_r.get(k)} for k, v in obs_p.items()]
    rep.table(rows, caption="O1-O5: Sun & Hollerbach observability indices of the whitened, column-scaled Jacobian")


def _stderr_section(rep: Any, result: PlanResult) -> None:
    pr = result.problem
    pred = result.prediction
    rep.heading("Predicted standard errors (Cramér-Rao)")
    se_r = result.random_baseline.get("stderr_mean", {})
    rep.table(
        [
            {"parameter": n, "unit": u, "planned": pred["stderr"][n], "random (mean)": se_r.get(n)}
            for n, u in zip(pr.names, pr.units, strict=True)
        ],
        caption="σ²(JᵀWJ)⁻¹ at the nominal robot, before any measurement",
    )
    if pr.eliminated:
        rep.paragraph("Not identifiable (held at nominal): " + "; ".join(e["text"] for e in pr.eliminated))


def _poses_figure(rep: Any, result: PlanResult) -> None:
    rep.heading("Poses")
    rep.figure(poses_figure(result), "The first target at the planned poses (robot base frame)")


#: at most this many tick intervals per axis of the pose views: an equal-aspect panel stretched to hold the tracker
#: (metres from the robot) got nine 4-digit labels on 4 cm ("-1500-1000" ran together)
POSE_VIEW_TICKS = 6


def poses_figure(result: PlanResult) -> Any:
    """Top and side views of the first target at the planned poses among the accepted candidates."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    pr = result.problem
    xyz_all = pr.cand.targets_mm[:, 0]
    xyz = pr.cand.targets_mm[result.idx, 0]
    trk = np.asarray(pr.config.tracker.position_mm)
    fig = Figure(figsize=(9, 4))
    for k, (a, b, lab) in enumerate(((0, 1, "top view: x, y (mm)"), (0, 2, "side view: x, z (mm)"))):
        ax = fig.add_subplot(1, 2, k + 1)
        ax.scatter(xyz_all[:, a], xyz_all[:, b], s=2, c="#cccccc", label="accepted candidates")
        ax.scatter(xyz[:, a], xyz[:, b], s=18, c="#4c72b0", label="planned poses")
        ax.scatter([trk[a]], [trk[b]], marker="^", s=60, c="#c44e52", label="tracker")
        ax.set_title(lab)
        ax.set_aspect("equal", adjustable="datalim")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_locator(MaxNLocator(nbins=POSE_VIEW_TICKS, steps=[1, 2, 2.5, 5, 10]))
        if k == 0:
            ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def _error_map_section(rep: Any, result: PlanResult) -> None:
    """The predicted error over the region of the plan next to one random draw of as many accepted candidates."""
    from matplotlib.figure import Figure

    pr = result.problem
    cfg = pr.config
    pred = result.prediction
    rng = np.random.default_rng(np.random.SeedSequence(entropy=cfg.seed, spawn_key=(7,)))
    rnd = predict(pr, np.sort(rng.choice(pr.cand.n, size=len(result.idx), replace=False)))
    fig = Figure(figsize=(9, 4))
    sig_p = pred.get("region_sigma_mm")
    sig_r = rnd.get("region_sigma_mm")
    if sig_p is None:
        return
    vmax = float(np.max(sig_p if sig_r is None else np.concatenate([sig_p, sig_r])))
    for k, (sig, lab) in enumerate(((sig_p, "planned"), (sig_r, "random (one draw)"))):
        if sig is None:
            continue
        ax = fig.add_subplot(1, 2, k + 1)
        sc = ax.scatter(pr.region_xyz[:, 0], pr.region_xyz[:, 1], c=sig, s=10, vmin=0, vmax=vmax, cmap="viridis")
        ax.set_title(f"{lab}: RMS {np.sqrt(np.mean(sig**2)):.4f} mm")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_aspect("equal", adjustable="datalim")
        fig.colorbar(sc, ax=ax, label="predicted error (mm)")
    fig.tight_layout()
    rep.heading("Predicted error map over the region")
    rep.figure(fig, "Predicted RMS 3-D error of the calibrated model at each region configuration (top view)")


def _curve_section(rep: Any, result: PlanResult) -> None:
    """The poses-needed curve (planned vs random) as a figure and a table; nothing without a curve."""
    from matplotlib.figure import Figure

    if not result.curve:
        return
    cfg = result.problem.config
    fig = Figure(figsize=(6, 3.6))
    ax = fig.add_subplot(1, 1, 1)
    ns = [r["n_poses"] for r in result.curve]
    ax.plot(ns, [r["planned_region_rms_mm"] for r in result.curve], "o-", label="planned")
    ax.plot(ns, [r["random_region_rms_mm"] for r in result.curve], "s--", label="random (median of 5)")
    ax.axhline(cfg.accuracy_mm, color="#c44e52", lw=1, label=f"stated accuracy {cfg.accuracy_mm} mm")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("number of poses")
    ax.set_ylabel("predicted RMS error over the region (mm)")
    ax.legend()
    fig.tight_layout()
    rep.heading("Poses needed for an accuracy")
    rep.figure(fig, "Predicted RMS model error over the region against the number of poses")
    rep.table(
        [
            {
                "poses": r["n_poses"],
                "planned: RMS over the region (mm)": r["planned_region_rms_mm"],
                "random: RMS over the region (mm)": r["random_region_rms_mm"],
                "random draws singular": r["random_singular"],
            }
            for r in result.curve
        ],
        caption="The curve (random: the median of 5 draws from the accepted candidates)",
    )


def settings_rows(cfg: PlanConfig) -> dict[str, str]:
    """The settings as ``dotted.key: value`` text, one row each (not a dataclass repr)."""
    from dataclasses import asdict

    def text(v: Any) -> str:
        if v is None:
            return "none"
        if isinstance(v, bool):
            return "yes" if v else "no"
        if isinstance(v, float):
            return f"{v:g}"
        if isinstance(v, list | tuple):
            inner = [text(x) for x in v]
            return "[" + ", ".join(inner) + "]"
        return str(v)

    out: dict[str, str] = {}

    def walk(prefix: str, node: Any) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(f"{prefix}.{k}" if prefix else str(k), v)
        else:
            out[prefix] = text(node)

    raw = asdict(cfg)
    raw["targets"] = {
        t.name: f"position {text(list(t.position_mm))} mm, normal {text(list(t.normal))}" for t in cfg.targets
    }
    walk("", raw)
    return out
