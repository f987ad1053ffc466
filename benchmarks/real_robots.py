"""Real robots: validation error before, geometric, parametric extended and final, for every real dataset.

    python benchmarks/real_robots.py                       # every dataset in ../shared/data/
    python benchmarks/real_robots.py --data ../shared/data/ur10-ipa
    python benchmarks/real_robots.py --hold-out-range      # also: hold out the top 25 % of joint 2's range
    python benchmarks/real_robots.py --session ../shared/data/ur10-ipa ../shared/data/ur10-ipa-D [-S key=value]
    python benchmarks/real_robots.py --session ../shared/data/ur10-ipa,../shared/data/ur10-ipa-C \
        ../shared/data/ur10-ipa-D

For each dataset (a folder with poses.csv and robot.yaml, its own description, no link masses unless it has
them): the held-out validation rows' mean / RMS / max position error of the nominal model (best rigid fit: the
true "before"), robocal calibrate's geometric model, the discovered parametric extended model and the final
model (the one the service applies), what each named effect contributes (the pose-grouped cross-validated
error with the effect removed) and the cross-validated estimate beside the held-out figure.

``--hold-out-range [--joint J]``: for joint J (default 2, the shoulder), the calibration keeps the poses in the
lower 75 % of its range and the validation is the rest (angles the calibration never visited): the extended model
must be no worse there than the geometric one (its transmission error is zero outside the visited angles).

``--session CAL VAL [VAL ...]``: the session mode (issue 33). Discover on every row of CAL (its split ignored:
the whole session calibrates), then judge the geometric and the discovered model on each VAL, another session of
the same robot (another day, tracker placement, region): VAL's tracker registered on VAL's own calibration rows
(rigid fit, the model frozen), errors on VAL's validation rows; then each named effect left out in turn, which
says which effects helped there and which hurt. ``-S key=value`` sets a discovery setting (repeatable).
CAL may be several folders joined by commas: one campaign of several sessions (each folder a tracker station),
whose discovery judges its effects by leave-one-session-out error too (robocal.discovery.session_cv).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from robocal.calibration.validation import validate
from robocal.data.contract import read_campaign
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors
from robocal.robot import load_robot

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data"


def _row(label: str, v: dict) -> str:
    out = (
        f"  {label:<26} mean {v['mean_position_mm']:.4f}  RMS {v['rms_position_mm']:.4f}  "
        f"max {v['max_position_mm']:.4f} mm"
    )
    w = v.get("without_gross_errors")
    if w and w.get("n_rows") and w["n_rows"] != v["n_rows"]:
        out += (f"   | without gross errors ({w['n_rows']} rows): mean {w['mean_position_mm']:.4f}  "
                f"RMS {w['rms_position_mm']:.4f}  max {w['max_position_mm']:.4f}")  # fmt: skip
    return out


def bench(path: Path, campaign=None, settings: dict | None = None) -> dict:  # type: ignore[no-untyped-def]
    robot = load_robot(path / "robot.yaml")
    camp = campaign if campaign is not None else read_campaign(path, robot)
    t0 = time.perf_counter()
    res = discover(camp, robot, DiscoveryConfig(**settings) if settings else None)
    dt = time.perf_counter() - t0
    val = validation_errors(res)
    assert val is not None, f"{path} has no validation rows"
    summ = summary(res, val)
    geo = res.extra["geometric_calibration"]
    before = validate(geo, camp, x=geo.start.x_init)
    print(f"{path.name}: {int(np.sum(camp.split == 'calibration'))} calibration / {val['geometric']['n_rows']} "
          f"validation rows; discovery {dt:.0f} s")  # fmt: skip
    print(_row("before (nominal, rigid fit)", before))
    print(_row("geometric (calibrate)", val["geometric"]))
    print(_row("parametric extended", val["discovered"]))
    print(_row(f"final (layer: {val['final']['layer']})", val["final"]))
    ge = val["gross_errors"]["rows"]
    if ge:
        print("  validation gross errors (" + val["gross_errors"]["rule"] + "): "
              + ", ".join(f"{g['pose_id']} ({g['error_mm']:.3f} mm)" for g in ge))  # fmt: skip
    cv = summ.get("cross_validation", {})
    if cv:
        print(f"  cross-validated estimate (calibration poses, pose-grouped): mean {cv['cv_mean_position_mm']:.4f}  "
              f"RMS {cv['cv_rms_position_mm']:.4f} mm")  # fmt: skip
    for n in summ["named"]:
        ho = n.get("held_out") or {}
        extra = f"; held-out mean without it {ho['cv_mean_without_mm']:.4f} mm" if ho else ""
        print(f"  named {n['key']:<18} ({n['side']}) RMS of effect {n['rms_of_effect_mm']:.4f} mm{extra}")
    if cv.get("pruned"):
        print(f"  dropped by the cross-validated backward check: {cv['pruned']}")
    gg = summ.get("grow_geometry")
    if gg:
        cvs = ", ".join(f"{k} {v:.4f}" for k, v in gg["cv_mean_position_mm"].items())
        lp = gg.get("frozen_lower_log10_p")
        print(f"  grow_geometry auto: kept {gg['chosen']} (CV mean {cvs}"
              + ("" if lp is None else f"; frozen lower: log10 p {lp:.2f}") + ")")  # fmt: skip
    return val


def hold_out_range(path: Path, joint: int) -> None:
    robot = load_robot(path / "robot.yaml")
    camp = read_campaign(path, robot)
    j = joint - 1
    lim = np.quantile(camp.q[:, j], 0.75)
    split = np.where(camp.q[:, j] <= lim, "calibration", "validation").astype(object)
    camp2 = _resplit(camp, split)
    print(f"hold-out range: joint {j + 1} above {np.rad2deg(lim):.1f} deg is validation only")
    val = bench(path, camp2)
    worse = val["final"]["mean_position_mm"] - val["geometric"]["mean_position_mm"]
    print(f"  final - geometric on the unvisited range: {worse:+.4f} mm mean")


def _resplit(camp, split):  # type: ignore[no-untyped-def]
    from dataclasses import replace

    return replace(camp, split=np.asarray(split))


def session(cal_path: Path, val_paths: list[Path], settings: dict, keep: Path | None = None, every: int = 1) -> None:
    import json

    from robocal.calibration.load import load_calibration
    from robocal.discovery.effects import extended_calibration
    from robocal.discovery.sessions import session_validation
    from robocal.io import to_json, write_text

    parts = [Path(p) for p in str(cal_path).split(",")]
    robot = load_robot(parts[0] / "robot.yaml")
    saved = keep / "session.json" if keep else None
    camp = _sessions(parts, robot) if len(parts) > 1 else read_campaign(cal_path, robot)
    if every > 1:  # every k-th row of CAL (a long series thinned)
        camp = camp.subset(np.arange(camp.n_rows) % every == 0)
    q_cal = camp.q
    if saved is not None and saved.exists():  # the discovery of an earlier run with the same --keep folder
        kept = json.loads(saved.read_text())
        print(f"{'+'.join(p.name for p in parts)}: the discovery kept in {saved} (settings {kept['settings']})")
    else:
        camp = _resplit(camp, np.full(camp.n_rows, "calibration", dtype=object))
        t0 = time.perf_counter()
        res = discover(camp, robot, DiscoveryConfig(**settings) if settings else None)
        summ = summary(res)
        geo_dict = res.extra["geometric_calibration"].to_dict()
        cvr = summ.get("cross_validation", {})
        kept = {
            "settings": settings,
            "named": [n["key"] for n in summ["named"]],
            "rms_after_mm": summ["rms_after_mm"],
            "cv_mean_position_mm": cvr.get("cv_mean_position_mm"),
            "session_cv": cvr.get("session_cv"),
            "geometric_session_cv": cvr.get("geometric_session_cv"),
            "dropped": cvr.get("dropped_no_gain"),
            "windows": cvr.get("windows"),
            "calibration": extended_calibration(res.final, robot, {}),
            "geometric": geo_dict,
            "n_rows": camp.n_rows,
            "seconds": time.perf_counter() - t0,
        }
        kept = json.loads(to_json(kept))
        if saved is not None:
            write_text(saved, to_json(kept))
    cal = load_calibration(kept["calibration"], robot)
    geo = load_calibration(kept["geometric"], robot)
    print(f"{'+'.join(p.name for p in parts)} (all {kept['n_rows']} rows) -> discovery {kept['seconds']:.0f} s, "
          f"fit RMS {kept['rms_after_mm']:.4f} mm, named {kept['named']}")  # fmt: skip
    if kept["cv_mean_position_mm"] is not None:
        print(f"  cross-validated within the session: mean {kept['cv_mean_position_mm']:.4f} mm")
    if kept.get("session_cv"):
        sc, gc = kept["session_cv"], kept["geometric_session_cv"] or {}
        print(f"  expected in a new session (leave-one-session-out over {sc['sessions']}): mean "
              f"{sc['mean_position_mm']:.4f} mm (geometric {gc.get('mean_position_mm', float('nan')):.4f}); "
              f"per session {sc['per_session']}")  # fmt: skip
        for d in kept.get("dropped") or []:
            if d.get("hurts_in_new_session"):
                print(f"  dropped {d['key']}: it raised the error in a session left out ({d['session_gain']:+.2%})")
        for k, w in (kept.get("windows") or {}).items():
            print(f"  {k}: windowed {w['windowed_mm']:.4f} mm, applied everywhere {w['applied_everywhere_mm']:.4f} mm"
                  f" in a session left out -> {'window opened' if w['opened'] else 'window kept'}")  # fmt: skip
    for vp in val_paths:
        vcamp = read_campaign(vp, load_robot(vp / "robot.yaml"))
        for tool in (False, True):
            _session_lines(vp.name, session_validation(cal, vcamp, geo, tool=tool, calibrated_q=q_cal))


def _sessions(parts: list[Path], robot):  # type: ignore[no-untyped-def]
    """Several series of one robot as one campaign of several sessions: each folder's rows a tracker station of its
    own (the folder's name), the columns all of them have."""
    import tempfile

    import pandas as pd

    frames = []
    for p in parts:
        d = pd.read_csv(p / "poses.csv")
        d["station"] = p.name
        frames.append(d)
    cols = [c for c in frames[0].columns if all(c in f.columns for f in frames)]
    with tempfile.TemporaryDirectory() as tmp:
        pd.concat([f[cols] for f in frames]).to_csv(Path(tmp) / "poses.csv", index=False)
        return read_campaign(Path(tmp), robot)


def _session_lines(name: str, v: dict) -> None:
    print(f"  on {name}: {v['n_registration_rows']} rows register the {v['registered']}, "
          f"{v['n_validation_rows']} judge")  # fmt: skip
    for label, key in (("geometric", "geometric"), ("discovered (final)", "final")):
        s = v[key]
        print(f"    {label:<20} mean {s['mean_position_mm']:.4f}  RMS {s['rms_position_mm']:.4f}  "
              f"max {s['max_position_mm']:.4f} mm")  # fmt: skip
    from robocal.discovery.sessions import SAME_ERROR_MM

    for k, s in v["without"].items():
        d = s["mean_position_mm"] - v["final"]["mean_position_mm"]
        verdict = "neither" if abs(d) < SAME_ERROR_MM else ("helped" if d > 0 else "hurt")
        print(f"    without {k:<24} mean {s['mean_position_mm']:.4f} mm ({verdict} {abs(d):.4f})")
    print(f"    helped: {v['helped']}  hurt: {v['hurt']}")
    ga = v.get("geometry_alone")
    if ga:
        print(f"    every effect off (the discovered geometry): mean {ga['mean_position_mm']:.4f} mm "
              f"({ga['versus_geometric_mm']:+.4f} against the geometric calibration)")  # fmt: skip
    for k, why in (v.get("not_applied") or {}).items():
        print(f"    not applied: {k} ({why})")
    cov = v.get("coverage")
    if cov:
        ins, outs = cov["inside"], cov["outside"]
        print(f"    {cov['n_outside']} of {cov['n_judged']} judged rows outside the calibrated joint angles "
              f"{cov['outside_per_joint']}: mean {outs['mean_position_mm'] if outs else float('nan'):.4f} mm there, "
              f"{ins['mean_position_mm'] if ins else float('nan'):.4f} inside")  # fmt: skip


def _setting(text: str) -> tuple[str, object]:
    import yaml

    key, _, value = text.partition("=")
    return key.strip(), yaml.safe_load(value)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, action="append", help="a dataset folder (default: every one in ../shared)")
    ap.add_argument("--hold-out-range", action="store_true")
    ap.add_argument("--joint", type=int, default=2, help="the joint whose top 25 %% is held out (default 2)")
    ap.add_argument("--session", nargs="+", type=Path, metavar="DIR", help="CAL VAL [VAL ...]: across sessions")
    ap.add_argument("-S", dest="settings", action="append", default=[], help="discovery setting key=value")
    ap.add_argument("--keep", type=Path, help="session mode: keep the discovery here and reuse it on a rerun")
    ap.add_argument("--every", type=int, default=1, help="session mode: calibrate on every k-th row of CAL")
    args = ap.parse_args(argv)
    if args.session:
        if len(args.session) < 2:
            ap.error("--session needs CAL and at least one VAL folder")
        session(args.session[0], args.session[1:], dict(map(_setting, args.settings)), args.keep, args.every)
        return 0
    paths = args.data or sorted(p for p in SHARED.glob("*") if (p / "robot.yaml").exists())
    if not paths:
        print(f"no real datasets under {SHARED}")
        return 0
    for p in paths:
        bench(p, settings=dict(map(_setting, args.settings)))
        if args.hold_out_range:
            hold_out_range(p, args.joint)
    return 0


if __name__ == "__main__":
    sys.exit(main())
