"""The discovery's ``report.html``: the verdict, the validation, the named effects, the proposed equations, every
step of the search with residual plots before and after, and the library (:func:`write_report`; the workflow,
:mod:`robocal.workflows.discovery`, writes it beside ``discovery.json``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.discovery.search import DiscoveryResult
from robocal.identification.noise import noise_hint
from robocal.report.html import words

if TYPE_CHECKING:
    from robocal.report.html import Report


def write_report(res: DiscoveryResult, summ: dict[str, Any], path: Path) -> Path:
    """Self-contained HTML report: the verdict, named effects, every step with residual plots before / after."""
    import matplotlib

    matplotlib.use("Agg")

    from robocal.report.html import Report

    rep = Report(f"Discovery — {res.robot.name}", subtitle=str(res.campaign.source))
    _verdict_section(rep, summ)
    if "validation" in summ:
        _validation_table(rep, summ["validation"])
        for w in summ.get("warnings", []):
            rep.paragraph(f"Warning: {w}.")
    if summ["named"]:
        _named_section(rep, summ)
    if summ.get("proposed"):
        _proposed_section(rep, res, summ["proposed"])
    _steps_section(rep, res, summ)
    _library_section(rep, summ)
    return rep.save(path)


def _verdict_section(rep: Report, summ: dict[str, Any]) -> None:
    """What was named, the errors before / after, and warnings (gross errors, the noise used, unexplained)."""
    rep.heading("Verdict")
    names = [n["key"] if n["effect"] == "signal" else f"{n['effect']}" + (f" joint {n['joint']}" if n["joint"] else "")
             for n in summ["named"]]  # fmt: skip
    rep.kv(
        {
            "named": ", ".join(names) if names else "nothing",
            "RMS before (geometric fit), mm": summ["rms_before_mm"],
            "RMS after, mm": summ["rms_after_mm"],
            "noise floor, mm": summ["noise_floor_mm"],
            "chi² / dof": f"{summ['chi2']:.1f} / {summ['dof']}",
            "chi² p-value": summ["chi2_p_value"],
            "unexplained": summ["unexplained"],
            "candidates tested": summ["selection"]["n_tests"],
            "threshold log10 p (Bonferroni)": summ["selection"]["threshold_log10_p"],
        }
    )
    if summ.get("outliers"):
        rep.note(
            f"{len(summ['outliers'])} calibration row(s) flagged as gross errors against the final model and left "
            "out (no effect was fitted to them): "
            + "; ".join(
                f"row {o['row']} (pose {o['pose_id']}, {o['target']}, {o['residual_mm']:.3f} mm)"
                for o in summ["outliers"]
            ),
            kind="warn",
        )
    for key, why in (
        ("left_out_poorly_predicted", "the final model's leave-one-out prediction of them stands out, their error "
         "does not stand out from the rows' own scatter"),
        ("left_out_systematic", "left out before the final model, whose test puts them in a systematic misfit "
         "(below)"),
        ("left_out_earlier", "left out by the gross-error screen or an earlier round; the final model does not "
         "single them out"),
    ):  # fmt: skip
        rows = summ.get(key) or []
        if rows:
            rep.note(
                f"{len(rows)} calibration row(s) left out of the fit, not gross errors: {why}: "
                + ", ".join(f"row {o['row']} ({o['residual_mm']:.3f} mm)" for o in rows)
            )
    scr = summ.get("gross_error_screen")
    if scr:
        fl = scr["flagged_by_final_model"]
        rep.note(
            f"A large campaign: the first search ran on a pose-grouped sample of {scr['sample_rows']} of the "
            f"{scr['kept_rows']} kept rows, only to find the gross errors; the search on every kept row followed"
            + (f"; rows it fitted that stand out against it (not searched again): {', '.join(map(str, fl))}" if fl
               else "")
            + "."
        )  # fmt: skip
    geo_sys = (summ.get("geometric_calibration") or {}).get("systematic_misfit") or []
    for label, found in (("the final model", summ.get("systematic_misfit") or []), ("the geometric model", geo_sys)):
        if found:
            rep.note(
                f"Systematic misfit against {label} (rows that misfit together under one condition: kept in the fit "
                "and offered to the search, not gross errors): "
                + "; ".join(f"{f['n_rows']} rows with {f['condition']}, {f['size_mm']:.3f} mm" for f in found),
                kind="warn",
            )
    if summ.get("noise"):
        nz = summ["noise"]
        rep.paragraph(f"Noise used for weights and for 'unexplained': {nz['used_mm']:.4f} mm — {nz['used_because']}.")
    if summ["unexplained"]:
        w, hint = summ["unexplained_where"], noise_hint(summ)
        rep.note(
            "The residual is still above the tracker-noise floor and no candidate explains it. Joints with the "
            f"largest share: {', '.join(str(j['joint']) for j in w['joints'][:2])}; worst workspace region: "
            f"{words(w['workspace_regions'][0])}; time span: {words(w['time_span'])}."
            + (f" But {hint}." if hint else ""),
            kind="warn",
        )


def _validation_table(rep: Report, validation: dict[str, Any]) -> None:
    """Errors of the held-out rows: geometric, parametric extended and final model (also without gross errors)."""
    vg, vd = validation["geometric"], validation["discovered"]
    vf = validation["final"]
    rows_v = []
    for key, label in (
        ("mean_position_mm", "mean, mm"),
        ("rms_position_mm", "RMS, mm"),
        ("max_position_mm", "max, mm"),
        ("mean_orientation_deg", "mean orientation, deg"),
    ):
        if key in vg:
            rows_v.append({"error": label, "geometric (calibrate)": vg[key], "parametric extended": vd[key],
                           f"final (residual layer: {vf['layer']})": vf[key]})  # fmt: skip
    ge = validation.get("gross_errors", {}).get("rows", [])
    if ge:
        for key, label in (("mean_position_mm", "mean without gross errors, mm"),
                           ("max_position_mm", "max without gross errors, mm")):  # fmt: skip
            rows_v.append({"error": label, "geometric (calibrate)": vg["without_gross_errors"][key],
                           "parametric extended": vd["without_gross_errors"][key],
                           f"final (residual layer: {vf['layer']})": vf["without_gross_errors"][key]})  # fmt: skip
    served = vf.get("as_served")  # the measurement side's effects correct the readings, not the robot
    rows_v += [{"error": f"{label} as served (without {', '.join(vf['measurement_side_effects'])}), mm",
                "geometric (calibrate)": None, "parametric extended": None,
                f"final (residual layer: {vf['layer']})": served[key]}
               for key, label in (("mean_position_mm", "mean"), ("max_position_mm", "max"))
               if served]  # fmt: skip
    rep.table(rows_v, caption=f"Validation rows (held out, {vg['n_rows']} rows): tool offsets from "
              + "; ".join(f"{t}: {src}" for t, src in vg["tool_source"].items()))  # fmt: skip


def _named_section(rep: Report, summ: dict[str, Any]) -> None:
    """The named effects: estimates, drift per state, causes, and each one's held-out contribution."""
    rep.heading("Named effects")
    rows = []
    drift_rows = []
    for n in summ["named"]:
        for k, e in n["estimates"].items():
            if k == "drift_by_state":  # a list of states: its own table below
                for st in e:
                    drift_rows.append(
                        {"effect": n["key"], "t_min": st["t_min"], "rows": st["n_rows"]}
                        | {f"{a} (mm)": f"{st[a + '_mm']['value']:.4f} ± {st[a + '_mm']['stderr']:.4f}" for a in "xyz"}
                    )
                continue
            val = e["value"]
            if isinstance(val, bool):
                val = "yes" if val else "no"
            rows.append({"effect": n["key"], "estimate": k, "value": val, "stderr": e["stderr"],
                         "unit": e["unit"]})  # fmt: skip
    rows += [{"effect": n["key"], "estimate": "caveat", "value": n["caveat"], "stderr": None, "unit": None}
             for n in summ["named"] if n.get("caveat")]  # fmt: skip
    rep.table(rows, caption="Estimates with standard errors (joint fit of geometry and every named effect)")
    if drift_rows:
        rep.table(
            drift_rows,
            caption="Modelled drift at the tool per measurement state, relative to each pose's first measurement "
            "(tracker frame, ± 1 standard error)",
        )
    rep.table(
        [{"effect": n["key"], "cause": n["cause"], "signal": n["signal"]} for n in summ["named"]],
        caption="Physical causes and signals",
    )
    logged = [n for n in summ["named"] if n.get("statement")]
    if logged:
        rep.table(
            [{"effect": n["key"], "what the logged signal does": n["statement"], "side": n["side"]} for n in logged],
            caption="Effects driven by logged signals (extra columns of the campaign), ± 1 standard error; a "
            "robot-side one is compensated with the signal's value given with each target",
        )
    cv = summ.get("cross_validation") or {}
    held = [n for n in summ["named"] if n.get("held_out")]
    sc = cv.get("session_cv")
    if sc:
        gc = cv.get("geometric_session_cv") or {}
        rep.paragraph(
            f"Expected in a new session: {sc['mean_position_mm']:.4f} mm mean (each of the campaign's "
            f"{len(sc['sessions'])} sessions ({', '.join(sc['sessions'])}) left out in turn, the model refitted on the "
            "others without the sessions' own effects (the tracker's drift and scale, a re-seated tool), the "
            "left-out session's tracker (and a re-seated tool) registered on one half of its poses to judge the "
            "other; the geometric model "
            f"{gc.get('mean_position_mm', float('nan')):.4f} mm"
            + (", its tool re-measured there too" if gc.get("tool_re_measured") else "")
            + f"). Within this session (pose-grouped "
            f"cross-validation): {cv.get('cv_mean_position_mm', float('nan')):.4f} mm. Per session left out: "
            + ", ".join(f"{k} {v:.4f} mm" for k, v in sc["per_session"].items())
            + ". An effect that raises the error in a session left out is dropped (the held-out check)."
        )
    if held and "cv_mean_position_mm" in cv:
        rep.table(
            [
                {
                    "effect": n["key"],
                    "side": n["side"],
                    "held-out mean without it, mm": n["held_out"]["cv_mean_without_mm"],
                    "its contribution, mm": n["held_out"]["cv_mean_without_mm"] - cv["cv_mean_position_mm"],
                    "held-out gain as fitted, %": 100 * n["held_out"].get("held_out_gain", float("nan")),
                    **(
                        {
                            "in a new session: its contribution, mm": n["held_out"]["session_mean_without_mm"]
                            - sc["mean_position_mm"]
                        }
                        if sc and "session_mean_without_mm" in n["held_out"]
                        else {}
                    ),
                }
                for n in held
            ],
            caption=f"Each joint-level effect's own contribution to the held-out error: the pose-grouped "
            f"cross-validated mean error of the final model is {cv['cv_mean_position_mm']:.4f} mm; without the "
            "effect (linearised) it is the value shown. An effect stays only when the held-out RMS error as fitted "
            "(positions and, with a 6-DoF probe, orientations) rises without it by more than "
            f"{100 * summ['config']['min_held_out_gain']:g} % (the held-out check): one that turns the tool may "
            "help the orientations more than the positions. Robot-side effects go to the controller; "
            "measurement-side ones (tracker drift) never do",
        )


def _proposed_section(rep: Report, res: DiscoveryResult, proposed: list[dict[str, Any]]) -> None:
    """Equations beyond the library: the table, and each one's residual against its term before / after."""
    import matplotlib.pyplot as plt

    from robocal.report import plots

    rep.heading("Proposed equations (beyond the library)")
    rep.paragraph(
        "When no library effect explains what is left, each joint's error is offered a dictionary of terms "
        "(harmonics and products of joint angles, gravity torques, torques, currents, temperatures, time); "
        "orthogonal matching pursuit with stability selection proposes a few terms, which must then pass the "
        "library's gate with a Bonferroni threshold over the dictionary's size."
    )
    rep.table(
        [
            {
                "joint": p["joint"],
                "equation": p["equation"],
                "log10 p / threshold": " / ".join(
                    "–" if v is None else f"{v:.1f}"
                    for v in (p["selection"].get("log10_p"), p["selection"]["threshold_log10_p"])
                ),
                "stability": ", ".join(f"{v:.2f}" for v in p["selection"]["stability"]),
                "online": "yes" if p["compensated_online"] else "no (needs a signal the joints do not give)",
                "reading": p["reading"],
            }
            for p in proposed
        ],
        caption="Coefficients ± 1 standard error from the joint fit with the geometry and the named effects",
    )
    for p, acc in zip(proposed, [a for a in res.accepted if a.cand.effect == "proposed"], strict=True):
        step = next((st for st in res.steps if st.accepted == acc.cand.key), None)
        if step is None or step.residuals_before_mm is None or step.residuals_after_mm is None:
            continue
        j = int(p["joint"]) - 1
        Jj = res.final.Jq[:, :3, j]  # mm/rad: each row's position change per radian of joint j
        nrm = np.maximum(np.sum(Jj**2, axis=1), 1e-12)

        def joint_equiv(r_mm: np.ndarray, Jj: np.ndarray = Jj, nrm: np.ndarray = nrm) -> np.ndarray:
            return np.rad2deg(np.sum(Jj * r_mm, axis=1) / nrm)

        term = acc.cand.S[res.rows][:, 0]
        fig = plots.term_before_after(
            term,
            joint_equiv(step.residuals_before_mm),
            joint_equiv(step.residuals_after_mm),
            xlabel=p["terms"][0]["signal"],
            ylabel=f"residual as a joint-{j + 1} angle (deg)",
        )
        rep.figure(fig, caption=f"Joint {j + 1}: the residual against {p['terms'][0]['signal']}, before and "
                   "after the proposed term")  # fmt: skip
        plt.close(fig)


#: candidates shown per step (the accepted one always; the full scores are in discovery.json), and their columns
STEP_ROWS = 8
SCORE_COLUMNS = ("key", "status", "absorbed_share", "dof", "F", "log10_p", "delta_bic", "excess_share", "cv_gain")


def _steps_section(rep: Report, res: DiscoveryResult, summ: dict[str, Any]) -> None:
    """The search as one story: its phases in order (library F-test search, cross-validated selection, proposed
    equations, residual layer, held-out check), each with its steps and why it stopped; one table of the best
    candidates per step; residual figures only before the search and for the final model (per-step figures made
    the report megabytes; every step's RMS and chi² are in the table)."""
    import matplotlib.pyplot as plt

    from robocal.report import plots

    camp = res.campaign.subset(res.rows)
    rep.heading("Steps")
    phases: dict[str, list[dict[str, Any]]] = {}
    for s in summ["steps"]:
        phases.setdefault(s["phase"] or "search", []).append(s)
    story = []
    for k, (phase, ss) in enumerate(phases.items()):
        took = [s["accepted"] for s in ss if s["accepted"]]
        stop = next((s["label"] for s in ss if not s["accepted"]), None)
        text = f"{k + 1}. {phase}: " + (f"accepted {', '.join(took)}" if took else "accepted nothing")
        if phase.startswith("held-out check"):
            text = f"{k + 1}. {phase}: " + "; ".join(s["label"].removeprefix("held-out check: ") for s in ss)
        elif stop:
            text += "; then " + stop.removeprefix(phase).lstrip(": ")
        story.append(text)
    rep.paragraph("The search runs in phases, each after the previous one stopped: " + " — ".join(story) + ".")
    rep.table(
        [
            {k: s[k] for k in ("step", "phase", "label", "rms_before_mm", "rms_after_mm", "chi2_before", "chi2_after")}
            for s in summ["steps"]
        ],
        caption="Every step, in order: one effect accepted per step (everything refitted jointly), or the phase's stop",
    )
    for k, st in enumerate(res.steps):
        s = summ["steps"][k]
        cands = s["candidates"]
        if not cands:
            continue
        srows = cands[:STEP_ROWS]
        # the accepted candidate is always shown, also when eight others have a smaller p
        srows += [c for c in cands[STEP_ROWS:] if st.accepted is not None and c["key"] == st.accepted]
        rep.heading(f"Step {k + 1} ({s['phase']}): {s['label']}", level=3)
        rep.table(
            [{c: x[c] for c in SCORE_COLUMNS} for x in srows],
            caption=f"Best {STEP_ROWS} of {len(cands)} candidates by log10 p (all in discovery.json). In the library "
            "F-test search cv_gain (relative drop of the held-out error over whole poses) is computed only for a "
            "candidate that passes the F-test, the BIC and the excess share, in order, until one is accepted; a dash "
            "otherwise. The accepted one is always listed",
        )
    first = next((st for st in res.steps if st.residuals_before_mm is not None), None)
    if first is not None and first.residuals_before_mm is not None:
        fig = plots.residuals_vs_joints(camp.q, first.residuals_before_mm, list(res.robot.joint_names))
        rep.figure(fig, caption="Residuals against the joint angles before the search (geometric model)", dpi=80)
        plt.close(fig)
        fig = plots.error_histogram(
            np.linalg.norm(first.residuals_before_mm, axis=1), np.linalg.norm(res.final.residuals_mm, axis=1)
        )
        rep.figure(fig, caption="3-D residuals before the search / with the final model", dpi=80)
        plt.close(fig)
    title = "final model" if first is not None else "geometric fit (nothing named)"
    fig = plots.residuals_vs_joints(camp.q, res.final.residuals_mm, list(res.robot.joint_names))
    rep.figure(fig, caption=f"Residuals of the {title} against the joint angles", dpi=80)
    plt.close(fig)


def _library_section(rep: Report, summ: dict[str, Any]) -> None:
    """The candidates tested, skipped and unidentifiable, and the caution that the noise floor proves no physics."""
    rep.heading("Library")
    rep.table(summ["library"], columns=["key", "cause", "signal"], caption="Candidates tested")
    if summ["skipped"]:
        rep.table(summ["skipped"], caption="Skipped candidates (signal missing or not varying)")
    if summ["unidentifiable"]:
        rep.table(summ["unidentifiable"], caption="Unidentifiable candidates (absorbed by the model)")
    logged = summ.get("logged_signals")
    if logged:
        if logged["used"]:
            rep.table(logged["used"], columns=["column", "declared", "unit", "location", "side"],
                      caption="Logged signals offered as drivers (extra numeric columns of the campaign)")  # fmt: skip
        if logged["not_used"]:
            rep.table(logged["not_used"], columns=["column", "reason"],
                      caption="Extra columns not used as drivers, and why")  # fmt: skip
    rep.paragraph(
        "Reaching the noise floor does not prove the physics: check that the estimates are physically plausible "
        "(e.g. compliance of the right sign and size) before compensating with them."
    )


__all__ = ["write_report"]
