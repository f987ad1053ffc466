"""Discovery workflow: campaign -> discovery -> ``discovery.json``, the discovered model as the product
(``calibration.json``, ``compensation.csv``) and ``report.html`` (residual plots per step)."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.data.campaign import Campaign
from robocal.discovery import progress
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.search import DiscoveryResult, discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors
from robocal.io import as_written, write_json
from robocal.robot import RobotDescription
from robocal.status import TargetStatus
from robocal.workflows import campaign_of, robot_of
from robocal.workflows.discovery_report import write_report
from robocal.workflows.geometric import result_cannot_start as geometric_cannot_start
from robocal.workflows.geometric import result_failed, unused_uncertainty

if TYPE_CHECKING:
    pass


def _tool_T(cal: Any, target: str) -> np.ndarray:
    """The calibrated flange-to-tool transform (4, 4) of ``target``."""
    k = cal.model.target_names.index(target)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cal.model.tool_rotations(cal.x)[k], cal.model.tools(cal.x)[k]
    return T


def _axes_product(
    res: DiscoveryResult,
    cal: Any,
    sub: Campaign,
    signals: Any,
    idx: np.ndarray,
    tgt: list[str],
    ids: list[str],
    out: Path,
    said: Mapping[int, list[str]],
) -> None:
    """``compensation.csv`` of a robot on external axes (a track, a column): each pose corrected by
    :func:`robocal.compensation.axes.compensate_axes` with the discovered axis errors, the external axes kept at
    their commanded value, judged by the service's one safety policy (:func:`robocal.compensation.axes.judge_axes`):
    refused (nominal joints kept) or flagged as the service would."""
    from robocal.compensation.axes import compensate_axes, judge_axes
    from robocal.compensation.controller_csv import write_controller_csv
    from robocal.discovery.axes import discovered_axis_fit
    from robocal.kinematics.chain import fk

    robot = res.robot
    af = discovered_axis_fit(res.final, robot, cal.x)
    m = len(idx)
    qc, cmd, err = np.zeros((m, robot.n_joints)), np.zeros((m, 4, 4)), np.zeros((m, 3))
    status: list[str] = [TargetStatus.OK] * m
    reason, corr = [""] * m, np.zeros(m)
    orient = bool(res.extra.get("uses_orientation", True))
    for t in dict.fromkeys(tgt):
        rows = np.array([k for k, tt in enumerate(tgt) if tt == t])
        r = idx[rows]
        # the model's effects corrected for too, with each target's own signals (a tilt an accelerometer logged)
        # the tool's orientation matched only when the campaign measured it (as for an arm alone, write_product)
        comp = compensate_axes(cal, sub.q[r], t, af, payload_kg=sub.payload_kg[r], effects=list(cal.effects),
                               signals=signals.rows(r), orientation=orient)  # fmt: skip
        cmd[rows] = fk(cal.model.chain, comp.q_target) @ _tool_T(cal, t)
        st, why = judge_axes(comp, comp.q_target, robot)
        for k, row in enumerate(rows):
            ok = st[k] != TargetStatus.REFUSED
            qc[row] = comp.q[k] if ok else comp.q_target[k]
            err[row, 0] = comp.residual_mm[k] if ok else comp.error_before_mm[k]
            corr[row] = float(np.rad2deg(np.abs(comp.q[k] - comp.q_target[k])[~robot.prismatic].max()))
            status[row], reason[row] = st[k], "; ".join(why[k])
    _flag(status, reason, said)
    applied = np.array([s != TargetStatus.REFUSED for s in status], dtype=bool)
    write_controller_csv(
        out / "compensation.csv", ids, qc, cmd, err, None, status, applied, corr, reason, prismatic=robot.prismatic
    )


def _flag(status: Any, reason: Any, said: Mapping[int, list[str]]) -> None:
    """The poses ``said`` names get its reasons after their own, flagged where they were ok (a refused pose
    stays refused)."""
    for k, why in said.items():
        reason[k] = "; ".join([r for r in [reason[k], *why] if r])
        if status[k] == TargetStatus.OK:
            status[k] = TargetStatus.FLAGGED


def _signal_notes(
    effects: Sequence[Mapping[str, Any]],
    logged: Mapping[str, np.ndarray],
    gaps: Mapping[str, tuple[np.ndarray, Mapping[str, Any]]],
) -> dict[int, list[str]]:
    """Per corrected pose (its index), what ``compensation.csv`` says of its logged signals, as the service does
    (:func:`robocal.compensation.effects.signal_reasons`): a reading past the values the effects were fitted on,
    and a reading the campaign left empty (corrected with the value the search filled in, and how it was filled);
    such a pose is flagged, never silently ok."""
    from robocal.compensation.effects import signal_reasons

    out = signal_reasons(effects, logged)
    for c, (miss, how) in sorted(gaps.items()):
        for k in np.flatnonzero(miss).tolist():
            out.setdefault(k, []).append(
                f"signals.{c} empty in the campaign: corrected with {float(logged[c][k]):.6g}, filled by "
                f"{how['way']} (its leave-one-out error {how['loo_rms']:.3g})"
            )
    return out


def write_product(res: DiscoveryResult, summ: dict[str, Any], out: Path) -> str | None:
    """The discovered model as the product: ``calibration.json`` (geometry + joint-level effects, readable by
    ``robocal serve --make-bundle --calibration`` and every reader of a calibration) and ``compensation.csv``
    (the corrected joints and command for the campaign's validation poses, or all its poses without a split).

    Returns None when both were written, else why ``compensation.csv`` was not (a stale one is removed, so
    that the folder never pairs a new model with an old file)."""
    from robocal.calibration.load import load_calibration
    from robocal.compensation import write_compensation_csv
    from robocal.compensation.correct import correct
    from robocal.compensation.effects import Signals
    from robocal.discovery.effects import extended_calibration
    from robocal.discovery.logged import filled_columns
    from robocal.kinematics.chain import fk

    fit_stats = {k: summ[k] for k in ("rms_before_mm", "rms_after_mm", "noise_floor_mm", "chi2", "dof", "outliers")}
    cal_dict = extended_calibration(res.final, res.robot, fit_stats)
    for f in (res.final, res.geometric):  # their (M, k) Jacobians not held through the compensation's tables
        f.release()
    if res.robot.has_prismatic:  # the discovered axis errors, served with the calibration (robocal.serve.bundle)
        from robocal.calibration.axes import calibration_axes
        from robocal.discovery.axes import discovered_axis_fit

        af = discovered_axis_fit(res.final, res.robot, np.asarray(cal_dict["x"], dtype=float))
        if af is not None:
            cal_dict["axes"] = calibration_axes(af)
    write_json(out / "calibration.json", cal_dict)
    cal = load_calibration(json.loads(json.dumps(cal_dict)), res.robot)
    camp = res.campaign
    sel = camp.split == "validation" if np.any(camp.split == "validation") else np.ones(camp.n_rows, dtype=bool)
    in_sub = np.flatnonzero(sel & np.isin(camp.target.astype(str), cal.model.target_names))
    sub = camp.subset(in_sub)
    if sub.n_rows == 0:
        (out / "compensation.csv").unlink(missing_ok=True)
        shown = "validation" if np.any(camp.split == "validation") else "campaign"
        targets = sorted(set(camp.target[sel].astype(str).tolist()))
        return (
            f"the {shown} rows measure target(s) {targets}, which the model does not know (its targets: "
            f"{list(cal.model.target_names)}), so their tool offsets are unknown; to compensate them, calibrate with "
            "rows of these targets"
        )
    first: dict[str, tuple[int, str]] = {}
    for i, (pid, t) in enumerate(zip(sub.pose_id, sub.target, strict=True)):
        first.setdefault(str(pid), (i, str(t)))
    idx = np.array([i for i, _ in first.values()])
    tgt = [t for _, t in first.values()]
    # every row's signals; the logged ones the model's effects follow, from the campaign's own columns
    cols = {str(e["column"]) for e in cal.effects if e.get("signal") in ("logged", "logged_frame")}
    logged, gaps = filled_columns(camp, res.robot, cols)  # an empty reading: the value the search filled in
    at_sub = {c: v[in_sub] for c, v in logged.items()}
    signals = Signals(np.asarray(sub.payload_kg, dtype=float), sub.tau_Nm, sub.current_A, sub.direction,
                      at_sub or None)  # fmt: skip
    said = _signal_notes(cal.effects, {c: v[idx] for c, v in at_sub.items()},
                         {c: (m[in_sub][idx], how) for c, (m, how) in gaps.items()})  # fmt: skip
    if res.robot.has_prismatic:  # a robot on external axes: robocal.compensation.axes (the track not moved)
        _axes_product(res, cal, sub, signals, idx, tgt, [f"{p}/{t}" for p, t in zip(first, tgt, strict=True)], out,
                      said)  # fmt: skip
        return None
    qc = np.zeros((len(idx), sub.n_joints))
    cmd = np.zeros((len(idx), 4, 4))
    res_mm = np.zeros((len(idx), 3))
    status = np.full(len(idx), TargetStatus.OK, dtype=object)
    reason = np.full(len(idx), "", dtype=object)
    corr_max = np.zeros(len(idx))
    for t in dict.fromkeys(tgt):
        rows = np.array([k for k, tt in enumerate(tgt) if tt == t])
        r = idx[rows]
        sig = signals.rows(r)
        # the tool's orientation matched only when the campaign measured it (a point reflector's calibration never
        # identified it: chasing it turned joints by up to 8.6 deg and refused 7 of 20 rows, position-only 0.36)
        comp = correct(cal, sub.q[r], target=t, signals=sig, orientation=bool(res.extra.get("uses_orientation", True)))
        c = comp.command_T
        assert c is not None
        refused = comp.refused
        qc[rows] = np.where(refused[:, None], comp.q_target, comp.q)
        cmd[rows] = np.where(refused[:, None, None], fk(cal.model.chain, comp.q_target) @ _tool_T(cal, t), c)
        res_mm[rows] = np.where(refused[:, None], comp.error_before_mm, comp.residual_mm)
        status[rows], reason[rows] = comp.status, ["; ".join(x) for x in comp.reasons]
        corr_max[rows] = np.rad2deg(np.abs(comp.correction_rad).max(axis=1))
    ids = [f"{p}/{t}" for p, t in zip(first, tgt, strict=True)]
    _flag(status, reason, said)
    # the joints as the controller takes them (a coupled robot's J3 is reported relative to J2: fanuc_j2j3)
    qc = res.robot.to_reported(qc)
    write_compensation_csv(out / "compensation.csv", ids, qc, cmd, res_mm, None, status, reason, corr_max)
    return None


def run(
    data_dir: str | Path | None,
    robot: str | Path | RobotDescription,
    out_dir: str | Path,
    settings: Mapping[str, Any] | None = None,
    *,
    split: Mapping[str, Any] | None = None,
    campaign: Campaign | None = None,
    report: bool = True,
    sessions: Sequence[str | Path] | None = None,
    session_tool: bool | None = None,
) -> dict[str, Any]:
    """Discover the effects in the campaign (``settings``: a :class:`DiscoveryConfig` mapping); write
    ``discovery.json``, the product (:func:`write_product`) and ``report.html`` into ``out_dir``. Returns the
    summary (``discovery.json``) and ``written``: the files written, ``not_written``: {file: why not}.

    ``sessions``: campaign folders of other sessions of the same robot (another day, tracker placement,
    region): the geometric and the discovered model are judged on each (its tracker registered on its own
    calibration rows, :func:`robocal.discovery.sessions.session_validation`), with every effect left out in
    turn; written as ``sessions.json`` and returned under ``sessions``. ``session_tool``: the tool re-measured there
    too (a re-seated tool; ``robocal discover --validate-tool``)."""
    rob = robot_of(robot)
    cfg = DiscoveryConfig.from_mapping(settings)
    camp = campaign_of(data_dir, rob, split, campaign)
    progress.start(f"{camp.n_rows} rows of {camp.source}: the geometric calibration")
    res = discover(camp, rob, cfg)
    progress.note(f"discovery done ({len(res.accepted)} effects): writing {out_dir}")
    summ = summary(res, validation_errors(res))
    # nothing to start from, as robocal calibrate says it (it ran on: an arm on a lifting column given without the
    # column named effects with a held-out error of 35 mm where calibrate said FAILED)
    geo = res.extra.get("geometric_calibration")
    problems = [w for w in [geometric_cannot_start(geo, camp, rob)] if w] or [
        f"the geometric calibration (robocal calibrate) failed: {w}"
        for w in (result_failed(geo, res.campaign) if geo is not None else [])
    ]  # fmt: skip
    why_failed = "; ".join(problems)
    if why_failed:  # the key only then: as robocal calibrate's summary (a clean run's discovery.json unchanged)
        summ["problems"] = problems
    used = float(summ.get("noise_mm") or cfg.noise_mm)  # the noise the search weighted by
    notes = camp.reading_notes() + unused_uncertainty(camp, used, "constant", 2.0, "discovery")
    if notes:
        summ.setdefault("warnings", []).extend(notes)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    # written into a staging folder, then moved into place together: an interrupted run (Ctrl-C) leaves the
    # last complete run's files as they were, never a new model beside an old report
    staging = Path(tempfile.mkdtemp(prefix=".discover-", dir=out))
    try:
        why_not = write_product(res, summ, staging)
        if why_failed:  # a model fitted from nowhere is not sent to a controller
            (staging / "compensation.csv").unlink(missing_ok=True)
            why_not = why_failed
        write_json(staging / "discovery.json", summ)
        if report:
            write_report(res, as_written(summ), staging / "report.html")
        if why_not:
            (out / "compensation.csv").unlink(missing_ok=True)
        for f in sorted(staging.iterdir()):
            os.replace(f, out / f.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    written = ["discovery.json", "calibration.json", *([] if why_not else ["compensation.csv"])]
    not_written = {"compensation.csv": why_not} if why_not else {}
    judged: dict[str, Any] = {}
    if sessions:
        from robocal.calibration.load import load_calibration
        from robocal.discovery.sessions import session_validation
        from robocal.io import display_path

        cal = load_calibration(json.loads((out / "calibration.json").read_text()), rob)
        geo = res.extra.get("geometric_calibration")
        for folder in sessions:
            other = campaign_of(folder, rob, None, None)
            judged[display_path(folder)] = session_validation(
                cal, other, geo, tool=bool(session_tool), calibrated_q=camp.q[res.rows]
            )
        write_json(out / "sessions.json", judged)
        written.append("sessions.json")
    extra = {"sessions": judged} if judged else {}
    return {
        **summ,
        **extra,
        "written": [*written, *(["report.html"] if report else [])],
        "not_written": not_written,
    }


__all__ = ["run", "write_product", "write_report"]
