"""Geometric calibration workflow: data door -> calibration -> validation -> files and report."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate, fit_with_optimizer
from robocal.calibration.result import CalibrationResult
from robocal.calibration.solve import is_gradient
from robocal.calibration.validation import Validation, validate
from robocal.data.campaign import Campaign
from robocal.identification.acceptance import judge
from robocal.io import atomic_write, write_json
from robocal.metrics import ErrorStats
from robocal.robot import RobotDescription
from robocal.status import CampaignStatus
from robocal.workflows import campaign_of, robot_of


def summarise(result: CalibrationResult, validation: Validation | None) -> dict[str, Any]:
    fit = dict(result.fit)
    summary: dict[str, Any] = {
        "robot": result.model.robot.name,
        "fit": fit,
        "n_identified": int(result.identified.sum()),
        "eliminated": [e.describe() for e in result.eliminated],
        "fixed": list(result.fixed_by_user),
    }
    if validation and validation.n_rows:
        summary["validation"] = validation.record()
    return summary


def result_problems(summary: Mapping[str, Any]) -> list[str]:
    """Why a calibration must not be called ok (:func:`robocal.identification.acceptance.judge` on the summary's
    fit and validation figures). Empty when none."""
    return list(judge(summary["fit"], summary.get("validation"), summary.get("validation_before")).problems)


#: A fit that cannot start: the nominal model's best rigid fit ("before") misses the measurements by more than
#: this share of the measured points' RMS distance from their centroid (the cell's size), and by more than
#: START_MIN_MM. A nominal robot misses by millimetres; by a tenth of the cell, the joint angles, the robot or
#: the targets are wrong, and a calibration (which corrects millimetres) has nothing to start from.
START_SHARE = 0.1
START_MIN_MM = 20.0


def start_limit_mm(campaign: Campaign) -> float:
    """The largest "before" RMS error (mm) a calibration of ``campaign`` may start from (:data:`START_SHARE`)."""
    p = campaign.p_mm
    size = ErrorStats.of(p - p.mean(axis=0)).rms_mm if len(p) else 0.0  # RMS distance to the centroid
    return max(START_MIN_MM, START_SHARE * size)


def cannot_start(campaign: Campaign, robot: RobotDescription, start_rms_mm: float | None) -> str | None:
    """Why the calibration had nothing to start from (:data:`START_SHARE`), or None. When the joint columns read
    as radians let the nominal model fit, the reason says so, naming the columns."""
    limit = start_limit_mm(campaign)
    if start_rms_mm is None or not start_rms_mm > limit:
        return None
    text = (
        f"the fit cannot start: the nominal model misses the measurements by {start_rms_mm:.1f} mm RMS after fitting "
        f"the tracker frame and tools (more than {limit:.1f} mm, a tenth of the cell); a calibration corrects "
        "millimetres"
    )
    cols = [f"q{j + 1}_deg" for j in range(campaign.n_joints)]
    try:  # the joint columns read as radians (values v in q*_deg: the contract made them v*pi/180 rad)
        as_rad = replace(campaign, q=np.degrees(campaign.q))
        cfg = CalibrationConfig.from_mapping({"max_iter": 1, "outliers": "off"})
        rad_start = calibrate(as_rad, robot, cfg).start
        assert rad_start is not None
        rad = rad_start.residuals_before_mm
        rad_rms = ErrorStats.of(rad).rms_mm
    except Exception:
        rad_rms = float("inf")
    if rad_rms < 0.1 * start_rms_mm:
        return (
            f"{text}. Read as radians, {cols[0]}..{cols[-1]} fit the nominal model to {rad_rms:.2f} mm: the joint "
            "angles look like radians; the contract wants degrees (multiply radians by 180/pi)"
        )
    axis = _carrying_column(campaign, limit)
    if axis:
        return f"{text}. {axis}"
    return f"{text}. Check the joint angles' unit (degrees), the robot (--robot) and the targets"


def result_cannot_start(result: CalibrationResult | None, campaign: Campaign, robot: RobotDescription) -> str | None:
    """:func:`cannot_start` of a fitted calibration (its start's "before" residuals), or None without one."""
    start = None if result is None else result.start
    if start is None or not len(start.residuals_before_mm):
        return None
    return cannot_start(campaign, robot, ErrorStats.of(start.residuals_before_mm).rms_mm)


def result_failed(result: CalibrationResult | None, campaign: Campaign) -> list[str]:
    """Why ``robocal calibrate`` would call the fitted calibration ``result`` of ``campaign`` failed (its fit and
    validation judged as :func:`run` judges them), for a command that builds on it (discover: a campaign with one
    joint column in radians gave "FAILED, worse than nominal" in calibrate and an "ok" discovery of 56.9 mm)."""
    if result is None or result.start is None:
        return []
    val = validate(result, campaign) if np.any(campaign.split == "validation") else None
    s = summarise(result, val)
    if val is not None:
        s["validation_before"] = validate(result, campaign, x=result.start.x_init).stats.position()
    column = radians_column(campaign, result.model.robot, float(result.fit["rms_position_mm"]))
    return result_problems(s) + ([column] if column else [])


#: calibration rows a tracker station's frame (six parameters) needs beyond its own fit: with fewer the frame is
#: fitted from them alone and absorbs them (a newcomer's station of 2 rows: residual 0.0001 mm, a blunder unseen)
MIN_STATION_ROWS = 3


#: a calibrated model that still misses its own calibration rows by more than this (mm RMS) is a model or data error
#: a calibration cannot correct (a calibration corrects tenths of a millimetre): the joint columns are looked at
MISFIT_MM = 10.0


def radians_column(campaign: Campaign, robot: RobotDescription, rms_mm: float) -> str | None:
    """When the calibrated model misses by more than :data:`MISFIT_MM`: the one joint column that, read as radians,
    lets the nominal model fit ten times better (a newcomer's q6 in radians beside degrees: "FAILED, worse than
    nominal" at 55 mm, or "ok" at 37 mm, naming no column), else None. A problem: the calibration is failed."""
    if not rms_mm > MISFIT_MM or robot.coupling is not None:
        return None
    cfg = CalibrationConfig.from_mapping({"max_iter": 1, "outliers": "off"})
    best: tuple[float, int] | None = None
    for j in range(campaign.n_joints):
        if robot.prismatic[j]:
            continue
        q = campaign.q.copy()
        q[:, j] = np.degrees(q[:, j])  # the column's values v were read as v degrees: as v radians
        try:
            start = calibrate(replace(campaign, q=q), robot, cfg).start
            rms = ErrorStats.of(start.residuals_before_mm).rms_mm if start is not None else float("inf")
        except Exception:
            continue
        if best is None or rms < best[0]:
            best = (rms, j)
    if best is None or not best[0] < 0.1 * rms_mm:
        return None
    return (
        f"read as radians, q{best[1] + 1}_deg lets the nominal model fit to {best[0]:.2f} mm (the calibrated model "
        f"misses by {rms_mm:.1f} mm): that column looks like radians; the contract wants degrees"
    )


def thin_stations(campaign: Campaign) -> list[str]:
    """A warning per tracker station with fewer than :data:`MIN_STATION_ROWS` calibration rows, or none."""
    if campaign.station is None:
        return []
    st = np.asarray(campaign.station).astype(str)[np.asarray(campaign.split) != "validation"]
    names, counts = np.unique(st, return_counts=True)
    return [
        f"station {n}: {c} calibration row(s): its frame (six parameters) is fitted from them alone and absorbs "
        f"them (a gross error there cannot be seen); measure at least {MIN_STATION_ROWS} poses from every station"
        for n, c in zip(names, counts, strict=True) if c < MIN_STATION_ROWS
    ]  # fmt: skip


#: how far the median noise a campaign's ``u_mm`` column states may lie from the noise the fit weights by (a ratio
#: either way) before the fit says it does not use the column
U_MM_RATIO = 3.0


def unused_uncertainty(
    campaign: Campaign, noise_mm: float, noise_model: str, u_coverage: float, where: str
) -> list[str]:
    """A warning when ``poses.csv`` states each point's uncertainty (``u_mm``) and the fit weights by a noise far
    from it without using the column (a total station's 0.74 mm beside the configured 0.015 mm: the noise floor,
    the gross-error test and the prior's strength all judged against a noise 25 times too small). ``where``: the
    settings' section the user sets (``calibration`` or ``discovery``)."""
    if campaign.u_mm is None or noise_model == "u_mm":
        return []
    u = float(np.median(np.asarray(campaign.u_mm, dtype=float))) / u_coverage
    if 1.0 / U_MM_RATIO <= u / noise_mm <= U_MM_RATIO:
        return []
    fix = "set noise_mm to the instrument's noise"
    if where == "calibration":
        fix += " or noise_model=u_mm (each point weighted by its u_mm)"
    fix += f" ({where}.* in the pipeline)"
    return [
        f"{campaign.poses_file} states each point's uncertainty (u_mm, median {u * u_coverage:.3g} mm: {u:.3g} mm "
        f"per coordinate at the coverage factor {u_coverage:g}, calibration.u_coverage), {u / noise_mm:.3g} times "
        f"the noise this fit weights "
        f"by ({noise_mm:g} mm, noise_model {noise_model}), and does not use it: {fix}"
    ]


def signals_not_modelled(campaign: Campaign, robot: RobotDescription, outliers: list[Any]) -> list[str]:
    """Rows left out as gross errors by the geometric model in a campaign that logs signals it does not take (a
    column's tilt an accelerometer follows): said, since such rows may be the signal's effect, not blunders
    (newcomer pass 13: a declared tilt signal, its largest pose left out at 0.8 mm, discover flagging nothing)."""
    if not outliers or not campaign.extra:
        return []
    from robocal.discovery.logged import screen

    used, _ = screen(campaign, robot)
    if not used:
        return []
    names = ", ".join(
        s.name + (f" ({s.declaration.location})" if s.declaration is not None and s.declaration.location else "")
        for s in used
    )
    return [
        f"{len(outliers)} row(s) left out as gross errors by the geometric model, which does not take the campaign's "
        f"logged signals ({names}): rows that a tilt or a shift those signals follow explains are no blunders; "
        "robocal discover offers the signals as causes and judges the rows against them"
    ]


def _carrying_column(campaign: Campaign, limit_mm: float) -> str | None:
    """A hint when an extra column of lengths (``*_mm`` / ``*_m``) spans more than the start's limit: an axis
    carrying the robot (a track, a lifting column) logged beside the arm's joints, which the robot must hold as
    a joint (the fit cannot start while the base moves by that much)."""
    for name, raw in campaign.extra.items():
        unit = 1000.0 if name.endswith("_m") else 1.0 if name.endswith("_mm") else None
        if unit is None:
            continue
        v = pd.to_numeric(pd.Series(raw), errors="coerce").to_numpy(dtype=float) * unit
        if np.isfinite(v).any() and float(np.nanmax(v) - np.nanmin(v)) > limit_mm:
            span = float(np.nanmax(v) - np.nanmin(v))
            return (
                f"The extra column {name} spans {span:.0f} mm: an axis carrying the robot (a track, a lifting "
                "column) logged beside the arm's joints? Give it to the robot description as its first joint "
                "(type: prismatic, the column q1_mm; docs/own-data.md, external axes)"
            )
    return None


def result_warnings(summary: Mapping[str, Any]) -> list[str]:
    """Why a calibration that is not failed must still not be called ok (the warnings of
    :func:`robocal.identification.acceptance.judge`: a fit that stopped without converging, a largest
    validation error worse than the nominal model's). Empty when none."""
    return list(judge(summary["fit"], summary.get("validation"), summary.get("validation_before")).warnings)


def status_of(summary: Mapping[str, Any]) -> str:
    """``failed`` (:func:`result_problems`), ``warning`` (:func:`result_warnings`) or ``ok``."""
    if summary.get("problems"):
        return CampaignStatus.FAILED
    return CampaignStatus.WARNING if summary.get("warnings") else CampaignStatus.OK


#: the files :func:`run` writes into its output folder, in the order it writes them (``report.html`` last, when asked)
OUTPUTS = ("calibration.json", "residuals.csv", "summary.json")
REPORT = "report.html"


def run(
    data_dir: str | Path | None,
    robot: str | Path | RobotDescription,
    out_dir: str | Path,
    settings: Mapping[str, Any] | None = None,
    *,
    split: Mapping[str, Any] | None = None,
    campaign: Campaign | None = None,
    report: bool = True,
    optimizer: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Calibrate the campaign in ``data_dir`` (``settings``: a :class:`CalibrationConfig` mapping); write
    ``calibration.json``, ``summary.json``, ``residuals.csv`` and (optionally) ``report.html`` into ``out_dir``.
    Returns the summary. A robot on external axes (a prismatic joint) also gets its axes' errors along the travel
    fitted on top (:func:`robocal.calibration.axes.fit_axis_errors`): ``summary.json`` → ``axes``, and
    ``calibration.json`` → ``axes`` (with the calibration vector refitted with them) for the service. A robot with a
    positioner (:mod:`robocal.calibration.positioner`): the arm is fitted on the tool's rows, then the
    positioner's axes with it on the part's rows: ``summary.json`` / ``calibration.json`` → ``positioner``.

    ``optimizer``: an optimizer config (``conf/optimizer/*.yaml``), run by
    :func:`robocal.calibration.fit.fit_with_optimizer` (None: Levenberg-Marquardt with ``settings``'
    stopping rules); for the non-gradient ones (``ipopt``, ``igoa``, ``goa``, ``woa``) the summary gets an
    ``optimizer`` section with the raw and (with ``polish``) the polished result."""
    rob = robot_of(robot)
    cfg = CalibrationConfig.from_mapping(settings)
    camp = campaign_of(data_dir, rob, split, campaign)
    full = camp
    if rob.positioner is not None:  # the rows of the part on a positioner are fitted after the arm's (issue 34)
        from robocal.calibration.positioner import part_rows

        camp = camp.subset(~part_rows(camp, rob))
    outcome = fit_with_optimizer(camp, rob, cfg, optimizer)
    result = outcome.result
    val = validate(result, camp) if np.any(camp.split == "validation") else None
    start = result.start
    assert start is not None  # a fitted calibration
    val_before = validate(result, camp, x=start.x_init) if val else None
    summary = summarise(result, val)
    if not is_gradient(optimizer):  # the raw and (with polish) the polished result of the method
        summary["optimizer"] = outcome.summary()
        if outcome.polished is not None and val:
            raw_val = validate(outcome.raw, camp)
            summary["optimizer"]["raw"]["validation_rms_position_mm"] = raw_val.stats.rms_mm
    if val_before:
        summary["validation_before"] = val_before.stats.position()
    before = start.residuals_before_mm
    summary["start_rms_position_mm"] = ErrorStats.of(before).rms_mm if len(before) else None
    summary["problems"] = result_problems(summary)
    why = cannot_start(camp, rob, summary["start_rms_position_mm"])
    if why:
        summary["problems"].insert(0, why)
    # a model missing its own rows by centimetres with a joint column that reads as radians: a data error, failed
    column = None if why else radians_column(camp, rob, float(result.fit["rms_position_mm"]))
    summary["problems"] += [column] if column else []
    warnings = result_warnings(summary) + camp.reading_notes() + thin_stations(camp)
    # against the noise the fit weighted by (the larger of the configured and the model-free estimate), as the
    # console says it, not the configured one (newcomer pass 11: the two lines named 0.2267 and 0.015 mm)
    used = float((result.fit.get("noise") or {}).get("used_mm") or cfg.noise_mm)
    warnings += unused_uncertainty(camp, used, cfg.noise_model, cfg.u_coverage, "calibration")
    warnings += signals_not_modelled(camp, rob, result.fit.get("outliers") or [])
    if warnings:  # the key only when there are some (a clean run's summary.json is unchanged)
        summary["warnings"] = warnings
    cal_record = _with_cell_axes(rob, camp, full, result, summary)
    summary["status"] = status_of(summary)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "calibration.json", cal_record)
    cal = camp.calibration() if val else camp
    rows = pd.DataFrame(
        {
            "pose_id": cal.pose_id,
            "target": cal.target,
            "split": "calibration",
            "err_before_mm": np.linalg.norm(start.residuals_before_mm, axis=1),
            "err_after_mm": np.linalg.norm(result.residuals_mm, axis=1),
            "rx_mm": result.residuals_mm[:, 0],
            "ry_mm": result.residuals_mm[:, 1],
            "rz_mm": result.residuals_mm[:, 2],
        }
    )
    rows["row"] = cal.row_number
    rows["outlier"] = ~np.asarray(start.kept, dtype=bool)
    if val and val_before:
        v = camp.validation()
        keep, e_after, e_before = val.kept_rows, val.errors_mm, val_before.errors_mm
        assert keep is not None and e_after is not None and e_before is not None
        vr = pd.DataFrame(
            {
                "pose_id": v.pose_id[keep],
                "target": v.target[keep],
                "split": "validation",
                "err_before_mm": np.linalg.norm(e_before[keep], axis=1),
                "err_after_mm": np.linalg.norm(e_after[keep], axis=1),
                "rx_mm": e_after[keep, 0],
                "ry_mm": e_after[keep, 1],
                "rz_mm": e_after[keep, 2],
            }
        )
        rows = pd.concat([rows, vr], ignore_index=True)
    atomic_write(out / "residuals.csv", lambda p: rows.to_csv(p, index=False, float_format="%.6f"))
    write_json(out / "summary.json", summary)
    if report:
        from robocal.report.geometric import geometric_report

        geometric_report(result, camp, val, val_before, summary).save(out / "report.html")
    return summary


def _with_cell_axes(
    rob: RobotDescription, camp: Campaign, full: Campaign, result: CalibrationResult, summary: dict[str, Any]
) -> dict[str, Any]:
    """The calibration's record, with (issue 34) a track's or a column's own errors (``axes``, fitted on the arm's
    rows) and a positioner's axes (``positioner``, fitted with the arm on the part's rows of ``full``), each also
    into ``summary``; only when the fit has no problem."""
    cal_record = result.to_dict()
    if rob.has_prismatic and not summary["problems"]:
        from robocal.calibration.axes import calibration_axes, fit_axis_errors

        axis_fit = fit_axis_errors(camp, result)
        summary["axes"] = axis_fit.record()
        cal_record["axes"] = calibration_axes(axis_fit)  # served with the calibration (robocal.serve.bundle)
        v = axis_fit.validation
        if axis_fit.terms and v.get("n_rows") and isinstance(summary.get("validation"), dict):
            # one answer: the headline validation (console, summary.json, the pipeline's val_mean_mm) is the
            # delivered model's, calibration.json with its axis errors; the arm's calibration alone beside it
            # (newcomer pass 9: 1.1119 mm in summary.json and the metric, 1.0882 for the model written)
            keys = ("mean_position_mm", "rms_position_mm", "max_position_mm")
            summary["validation_without_axes"] = {k: summary["validation"][k] for k in keys}
            summary["validation"].update({k: v[k] for k in keys})
            summary["validation"]["with_axes"] = True
    if rob.positioner is not None and not summary["problems"]:  # the axes carrying the part, with the arm
        from robocal.calibration.positioner import fit_positioner

        record = fit_positioner(full, result).record()
        summary["positioner"] = {k: v for k, v in record.items() if k != "x"}
        cal_record["positioner"] = record
    return cal_record
