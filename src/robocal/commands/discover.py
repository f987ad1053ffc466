"""``robocal discover DATA_DIR --robot NAME_OR_YAML --out DIR [key=value ...]``."""

from __future__ import annotations

import argparse
from typing import Any

from robocal.commands import ROBOT_HELP, parse_overrides


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data_dir", help="campaign directory in the data contract")
    p.add_argument("--robot", required=True, help=ROBOT_HELP)
    p.add_argument("--out", required=True, help="output directory: discovery.json, report.html")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report")
    p.add_argument(
        "--validate-on",
        action="append",
        default=[],
        metavar="DIR",
        help="another session of the same robot (campaign folder; repeatable): the models judged there, its tracker "
        "registered on its own calibration rows, each effect left out in turn (sessions.json)",
    )
    p.add_argument(
        "--validate-tool",
        action="store_true",
        help="with --validate-on: re-measure the tool in the other session too, with its tracker (a tool taken off "
        "and put back, a new reflector nest); default: the tool as calibrated",
    )
    p.add_argument(
        "--engine",
        choices=("local", "ray"),
        default="local",
        help="where the per-candidate work of the cross-validated selection runs: this process, or Ray tasks (same "
        "result)",
    )
    p.add_argument("--workers", type=int, default=None, help="Ray: CPUs of the local instance (default: all)")
    p.add_argument("--ray-address", default=None, help="Ray: the cluster to connect to (default: a local instance)")
    p.add_argument(
        "overrides",
        nargs="*",
        help="discovery settings key=value, e.g. noise_mm=0.02 alpha=0.001 'effects=[gear,backlash]' split.method=none",
    )


def run(args: argparse.Namespace) -> int:
    from robocal.workflows import discovery

    ov = parse_overrides(args.overrides)
    split = ov.pop("split", None)
    from robocal.discovery import engine

    with engine.use(args.engine, args.workers, args.ray_address):
        s = discovery.run(
            args.data_dir,
            args.robot,
            args.out,
            ov,
            split=split,
            report=not args.no_report,
            sessions=args.validate_on,
            session_tool=args.validate_tool,
        )
    g = s.get("geometric_calibration")
    # the floor of the noise the search weights by: the data's own, or a configured value (newcomer pass 17: a
    # dense set's 0.0164 mm held out read as 37 % below "the noise floor" of the configured 0.015 mm)
    measured = not g or "model-free estimate" in str(g.get("noise_used_because") or "")
    print(
        f"discover: {_named(s)}; RMS {s['rms_before_mm']:.4f} -> {s['rms_after_mm']:.4f} mm "
        f"(noise floor {s['noise_floor_mm']:.4f}{'' if measured else ' at the configured noise, not measured'}); "
        f"unexplained: {s['unexplained']}"
    )
    from robocal.identification.noise import noise_hint

    if s["unexplained"] and noise_hint(s):
        print(f"  but {noise_hint(s)}")
    if g:
        print(
            f"geometric model (as robocal calibrate): RMS {g['rms_position_mm']:.4f} mm on {g['n_rows']} rows, "
            f"gross-error rows {g['outlier_rows'] or 'none'}; the search weights by {_noise_words(g, 'noise_mm' in ov)}"
        )
    _left_out_lines(s, g)
    gp = s.get("geometry_prior") or {}
    if gp.get("chosen") == "none":  # the "before" above is then the geometry without calibrate's prior
        cv = gp["cv_mean_position_mm"]
        print(
            f"geometry prior: calibrate's prior toward the nominal geometry (chosen for the geometry alone) let go "
            f"under the effects: cross-validated {cv['none']:.4f} mm without it, {cv['calibration']:.4f} with"
        )
    _logged_line(s.get("logged_signals"))
    if "validation" in s:
        _validation_lines(s)
    cv = s.get("cross_validation")
    if cv and "cv_mean_position_mm" in cv:
        # several placements none of which could be left out and judged: nothing says what a new one would give
        placements = (g or {}).get("n_stations", 1) > 1 and "session_cv" not in cv
        within = (
            (
                "within these placements: no session has the rows to be left out and judged, so nothing says "
                "what a new one would give"
            )
            if placements
            else "within this session"
        )
        print(f"cross-validated estimate on the calibration poses (pose-grouped): mean "
              f"{cv['cv_mean_position_mm']:.4f} mm, RMS {cv['cv_rms_position_mm']:.4f} mm ({within})")  # fmt: skip
    if cv and "session_cv" in cv:
        sc, gc = cv["session_cv"], cv.get("geometric_session_cv") or {}
        print(f"expected in a new session (the sessions are the campaign's {len(sc['sessions'])} tracker stations, "
              "another placement whether or not another day: each left out, its tracker registered on half of its "
              f"poses to judge the other half): mean {sc['mean_position_mm']:.4f} mm"
              + (f" (geometric model {gc['mean_position_mm']:.4f} mm"
                 + (", each model's tool re-measured there: the discovered one holds a re-seated tool"
                    if gc.get("tool_re_measured") else "") + ")" if gc else ""))  # fmt: skip
    from robocal.discovery.sessions import SAME_ERROR_MM

    for where, v in s.get("sessions", {}).items():
        g, f = v["geometric"], v["final"]
        what = "tracker and tool" if v.get("registered") == "tracker and tool" else "tracker (the tool as calibrated)"
        print(
            f"another session {where} ({v['n_registration_rows']} rows register its {what}, "
            f"{v['n_validation_rows']} judge): mean {g['mean_position_mm']:.4f} mm geometric -> "
            f"{f['mean_position_mm']:.4f} mm discovered; effects that helped there: {v['helped'] or 'none'}, "
            f"hurt: {v['hurt'] or 'none'} (each left out in turn there; a judgement only: the model is not changed — "
            "to let another session choose the effects, discover over both sessions as one campaign with a station "
            "column)"
        )
        for k, why in (v.get("not_applied") or {}).items():
            print(f"  {k} not applied there: {why}")
        ga = v.get("geometry_alone")
        if ga and ga["versus_geometric_mm"] > SAME_ERROR_MM:
            print(f"  the discovered geometry with every effect off: mean {ga['mean_position_mm']:.4f} mm there, worse "
                  f"than the geometric calibration's by {ga['versus_geometric_mm']:.4f} mm: the geometry refitted with "
                  "the effects costs there what no single effect left out shows (grow_geometry=frozen keeps the "
                  "geometric one under the selection's effects)")  # fmt: skip
        cov = v.get("coverage")
        if cov and cov["n_outside"]:
            joints = ", ".join(f"{j} {n}" for j, n in cov["outside_per_joint"].items() if n)
            ins, outs = cov["inside"], cov["outside"]
            print(
                f"  {cov['n_outside']} of its {cov['n_judged']} judged rows lie outside the joint angles this "
                f"calibration visited ({joints}): an extrapolation; mean {outs['mean_position_mm']:.4f} mm there"
                + (f", {ins['mean_position_mm']:.4f} mm inside" if ins else "")
                + " — measure that region to calibrate it"
            )
    shown = {"calibration.json": "calibration.json (the discovered model)"}
    print(f"wrote {args.out}/" + ", ".join(shown.get(f, f) for f in s["written"]))
    for name, why in s["not_written"].items():
        print(f"no {name}: {why}")
    for text in s.get("problems", []):
        print(f"robocal discover: FAILED: {text}")
    return 1 if s.get("problems") else 0


def _validation_lines(s: dict[str, Any]) -> None:
    """The console's validation lines of a discovery summary ``s`` (its ``validation``, its warnings)."""
    vg, vd, vf = (s["validation"][k] for k in ("geometric", "discovered", "final"))
    print(
        f"validation ({vd['n_rows']} rows): mean {vg['mean_position_mm']:.4f} mm geometric -> "
        f"{vd['mean_position_mm']:.4f} mm discovered -> {vf['mean_position_mm']:.4f} mm final "
        f"(residual layer: {vf['layer']}{_after_parametric(s)}); max {vg['max_position_mm']:.4f} -> "
        f"{vf['max_position_mm']:.4f} mm"
    )
    for st, fig in (vf.get("per_station") or {}).items():  # several stations: each one's own figure
        new = (vf.get("station_source") or {}).get(st, "calibration") != "calibration"
        where = "a new session: its tracker registered on half of its poses" if new else "within the session"
        print(f"  validation station {st} ({where}): "
              f"mean {vg['per_station'][st]['mean_position_mm']:.4f} mm geometric -> {fig['mean_position_mm']:.4f} mm "
              f"final on {fig['n_rows']} rows")  # fmt: skip
    if vg.get("with_axes"):
        print(
            "  the geometric calibration with the linear axes' errors fitted (robocal calibrate's headline): mean "
            f"{vg['with_axes']['mean_position_mm']:.4f} mm"
        )
    if vf.get("as_served"):
        print(
            f"  the final figure corrects the held-out readings by the measurement side's "
            f"{', '.join(vf['measurement_side_effects'])}, which the service does not apply: as served, mean "
            f"{vf['as_served']['mean_position_mm']:.4f} mm (a robot's own drift named a tracker's would show here)"
        )
    if vf.get("filled_signal_rows"):
        cols = ", ".join(f"{c} {n}" for c, n in vf["filled_signal_rows"].items())
        print(
            f"  held-out rows whose logged reading was empty and filled ({cols}): the model follows the fill "
            "there, its error with it (logged_signals.used[].filled: the way and its error)"
        )
    for w in s.get("warnings", []):
        print(f"WARNING: {w}")
    ge = s["validation"]["gross_errors"]["rows"]
    if ge:
        w = vf["without_gross_errors"]
        print(
            f"  {len(ge)} held-out row(s) are gross errors against the final model ("
            + ", ".join(f"{g['pose_id']} {g['error_mm']:.3f} mm" for g in ge[:5])
            + (", ..." if len(ge) > 5 else "")
            + f"); without them: mean {w['mean_position_mm']:.4f}, max {w['max_position_mm']:.4f} mm"
        )


def _left_out_lines(s: dict[str, Any], g: dict[str, Any] | None) -> None:
    """The console lines of the rows left out of the fit (gross errors, poorly predicted, of a systematic misfit),
    the gross-error screen and the systematic misfits."""
    from robocal.identification.robust import outlier_line

    print(outlier_line(s.get("outliers", []), s.get("n_rows_total")))
    for key, why in (
        ("left_out_poorly_predicted", "the final model's leave-one-out prediction stands out, their error does not "
         "stand out from the rows' own scatter"),
        ("left_out_systematic", "left out before the final model, whose test puts them in a systematic misfit (below)"),
        ("left_out_earlier", "left out by the gross-error screen or an earlier round; the final model does not single "
         "them out"),
    ):  # fmt: skip
        rows = s.get(key) or []
        if rows:
            print(f"  {len(rows)} more row(s) left out of the fit, not gross errors ({why}): rows "
                  + ", ".join(str(o["row"]) for o in rows))  # fmt: skip
    scr = s.get("gross_error_screen")
    if scr:
        fl = scr["flagged_by_final_model"]
        print(
            f"  gross-error screen: the first search on a sample of {scr['sample_rows']} of the {scr['kept_rows']} "
            f"kept rows, then {scr['searches'] - 1} on every kept row"
            + (f"; fitted by it and standing out against it: rows {', '.join(map(str, fl))}" if fl else "")
        )
    from robocal.identification.misfit import line

    if s.get("systematic_misfit"):
        print(line(s["systematic_misfit"], "against the discovered model: not gross errors, a model error there"))
    elif g and g.get("systematic_misfit"):
        print(line(g["systematic_misfit"], "against the geometric model, none against the discovered one"))


#: effects the console names by their key: "signal", "axis", "session" or "scale" alone say nothing of which
#: column, which carriage error, which session (the console printed "axis j1, axis j1, axis j1")
KEYED = ("signal", "axis", "session", "scale", "drift", "air", "regap")


def _named(s: dict[str, Any]) -> str:
    """``named [...]`` of the console: a logged signal's effect by its key (which column moves which frame:
    "signal" alone said nothing), the others by effect and joint, and the accepted proposed equations (the console
    said "named [nothing]" while an equation had taken the RMS from 1.03 to 0.44 mm)."""
    named = ", ".join(
        n["key"] if n["effect"] in KEYED else
        n["effect"] + (f" j{n['joint']}" if n["joint"] else "") + (f" h{n['harmonic']}" if n["harmonic"] else "")
        for n in s["named"]
    )  # fmt: skip
    props = [p["equation"] for p in s.get("proposed") or []]
    return f"named [{named or 'nothing'}]" + (f" and {len(props)} proposed equation(s): {'; '.join(props)}"
                                               if props else "")  # fmt: skip


def _after_parametric(s: dict[str, Any]) -> str:
    """What changed the model after the parametric one besides the layer (the final figure differs from the
    discovered one without a layer): the transmission windows the sessions' evidence opened, the effects the final
    held-out check dropped."""
    cv = s.get("cross_validation") or {}
    opened = [k for k, v in (cv.get("windows") or {}).items() if v.get("opened")]
    dropped = [k for st in s.get("steps", []) if st.get("phase") == "held-out" for k in st.get("dropped") or []]
    return (f"; window opened by the sessions' evidence: {', '.join(opened)}" if opened else "") + (
        f"; dropped by the final held-out check: {', '.join(dropped)}" if dropped else "")  # fmt: skip


def _noise_words(g: dict[str, Any], set_here: bool = False) -> str:
    """Which noise the search weights by: the data's own estimate, or the configured value when the campaign
    allows none (it said "the noise the data show" of the configured 0.015 mm on a total station's 0.3 mm; and
    "set noise_mm" to a user who had set it)."""
    if "model-free estimate" in str(g.get("noise_used_because") or ""):
        return f"the noise the data show ({g['noise_used_mm']:.4f} mm)"
    if set_here:
        return f"the noise_mm given ({g['noise_used_mm']:.4f} mm: the campaign allows no model-free estimate)"
    return (
        f"the configured noise ({g['noise_used_mm']:.4f} mm: the campaign allows no model-free estimate, one target "
        "and no repeated poses; for an instrument other than a laser tracker, set noise_mm to its noise)"
    )


def _logged_line(rec: dict[str, Any] | None) -> None:
    """One console line on the campaign's logged signals (its extra columns): offered to the search, not used (and
    why), declared but not in this campaign."""
    if not rec:
        return
    used = [
        u.get("column", "?")
        + (
            f" ({u['filled']['rows']} missing readings filled: {u['filled']['way']})"
            if (u.get("filled") or {}).get("rows")
            else ""
        )
        for u in rec.get("used", [])
    ]
    parts = [f"offered to the search: {', '.join(used)}" if used else "none offered to the search"]
    if rec.get("not_used"):
        names = ", ".join(n["column"] for n in rec["not_used"])
        parts.append(f"not used (why: discovery.json logged_signals): {names}")
    if rec.get("declared_not_in_campaign"):
        parts.append("declared but not in this campaign: " + ", ".join(rec["declared_not_in_campaign"]))
    print("logged signals: " + "; ".join(parts))
