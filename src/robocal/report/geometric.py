"""The HTML report of a geometric calibration."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.io import is_reproducible
from robocal.kinematics.transforms import rpy_from_matrix
from robocal.metrics import ErrorStats
from robocal.report import plots
from robocal.report.html import Report

if TYPE_CHECKING:
    from robocal.calibration.result import CalibrationResult
    from robocal.calibration.validation import Validation
    from robocal.data.campaign import Campaign


def _mean_rms_max(s: ErrorStats) -> str:
    return f"{s.mean_mm:.4f} / {s.rms_mm:.4f} / {s.max_mm:.4f}"


def geometric_report(
    result: CalibrationResult,
    campaign: Campaign,
    validation: Validation | None,
    validation_before: Validation | None,
    summary: dict[str, Any],
) -> Report:
    """Error before/after per pose, histograms, parameter table with standard errors, eliminated
    parameters, residuals against each joint angle, and the validation statistics."""
    fit = result.fit
    rep = Report(f"Geometric calibration — {result.model.robot.name}")
    rep.paragraph(
        f"Campaign {campaign.source}: {fit['n_rows']} calibration rows, targets {', '.join(fit['targets'])}; "
        f"model {result.model.robot.convention}; {fit['n_identified']} parameters identified, "
        f"{fit['n_eliminated']} eliminated."
    )
    for text in (summary or {}).get("problems", []):
        rep.note(f"FAILED: {text}. Do not use this calibration.", kind="warn")
    for text in (summary or {}).get("warnings", []):
        rep.note(f"{text}. Check before using this calibration.", kind="warn")
    _fit_section(rep, result)
    _gross_errors_section(rep, fit)
    _noise_section(rep, fit)
    assert result.start is not None  # a fitted calibration (not one read from a file)
    kept = result.start.kept
    before = np.linalg.norm(result.start.residuals_before_mm, axis=1)[kept]
    after = np.linalg.norm(result.residuals_mm, axis=1)[kept]
    cal_all = campaign.calibration() if validation else campaign
    cal = cal_all.subset(kept)
    labels = [f"{p}/{t}" for p, t in zip(cal.pose_id, cal.target, strict=True)]
    b = fit.get("before")
    if b:
        rep.paragraph(
            f"Before calibration: RMS {b['rms_position_mm']:.4f} mm, mean {b['mean_position_mm']:.4f} mm, max "
            f"{b['max_position_mm']:.4f} mm — {b['definition']}."
        )
    rep.figure(
        plots.error_per_pose(before, after, labels),
        "Calibration rows (kept): 3-D error before (nominal kinematics, frames and tools fitted to convergence) "
        "and after calibration",
    )
    rep.figure(plots.error_histogram(before, after), "Calibration rows (kept): error histograms")
    if validation and validation_before:
        _validation_section(rep, campaign, validation, validation_before)
    rep.heading("Residuals against joint angles")
    joints = list(result.model.robot.joint_names)  # the robot's own joint names, as everywhere else
    rep.figure(
        plots.residuals_vs_joints(cal.q, result.residuals_mm[kept], joints),
        "Calibration residuals (x, y, z) against each joint's angle (kept rows)",
    )
    _parameters_section(rep, result)
    _frames_section(rep, result)
    return rep


def _fit_section(rep: Report, result: CalibrationResult) -> None:
    """The fit's statistics, with a warning when chi² is outside its band."""
    fit = result.fit
    rep.heading("Fit")
    kv = {
        "RMS 3-D position error (mm)": f"{fit['rms_position_mm']:.4f}",
        "mean / max (mm)": f"{fit['mean_position_mm']:.4f} / {fit['max_position_mm']:.4f}",
        "noise floor RMS (mm)": "n/a" if fit.get("noise_floor_rms_mm") is None else f"{fit['noise_floor_rms_mm']:.4f}",
        "chi² / dof": f"{fit['chi2']:.1f} / {fit['dof']} (95 % band {fit['chi2_band_95'][0]:.0f}–"
        f"{fit['chi2_band_95'][1]:.0f}; {'inside' if fit['chi2_within_band'] else 'OUTSIDE'})",
        "tracker noise assumed (mm)": f"{result.config.noise_mm}",
        **_iterations_time(fit),
        "solver status": fit["message"],
    }
    if "rms_orientation_deg" in fit:
        kv["RMS orientation error (deg)"] = f"{fit['rms_orientation_deg']:.4f}"
    rep.kv(kv)
    if not fit["chi2_within_band"]:
        rep.note(
            "chi² is outside its 95 % band: either the tracker noise setting is wrong or the model misses an "
            "effect (run `robocal discover`).",
            kind="warn",
        )


def _gross_errors_section(rep: Report, fit: Mapping[str, Any]) -> None:
    """The rows the outlier rule left out of the fit, or the rule when none."""
    rep.heading("Gross errors")
    outliers = fit.get("outliers", [])
    if outliers:
        rep.note(
            f"{len(outliers)} of {fit.get('n_rows_total', fit['n_rows'])} calibration rows were left out of the fit "
            f"by the rule: {fit.get('outlier_rule')}. Check them at the cell (beam break, bumped or re-seated "
            "reflector, a joint angle logged from the previous move).",
            kind="warn",
        )
        rep.table(
            [
                [o["row"], o["pose_id"], o["target"], o.get("station") or "", f"{o['residual_mm']:.4f}", o["reason"]]
                for o in outliers
            ],
            columns=["file row", "pose", "target", "station", "residual (mm)", "why"],
            caption="Flagged rows: the residual is the kept fit's prediction minus the measurement",
        )
    else:
        rep.paragraph(f"None flagged. Rule: {fit.get('outlier_rule', 'off')}.")


def _noise_section(rep: Report, fit: Mapping[str, Any]) -> None:
    """The measurement noise the data imply, by route (nothing when the fit has no noise estimate)."""
    noise = fit.get("noise")
    if not noise:
        return
    rep.heading("Measurement noise", level=3)
    rows_n = [["configured", f"{noise['configured_mm']:.4f}", "", "", "the calibration setting noise_mm"]]
    for name, r in noise["routes"].items():
        rows_n.append(
            [
                name.replace("_", " "),
                f"{r['sigma_mm']:.4f}",
                f"{r['ci95_mm'][0]:.4f} – {r['ci95_mm'][1]:.4f}",
                str(r["dof"]),
                r["source"],
            ]
        )
    rep.table(
        rows_n,
        columns=["route", "σ per coordinate (mm)", "95 % interval (mm)", "dof", "from"],
        caption=f"Noise the data imply; used to judge residuals: {noise['used_mm']:.4f} mm, {noise['used_because']}",
    )


def _validation_section(rep: Report, campaign: Campaign, validation: Validation, validation_before: Validation) -> None:
    """Validation statistics before / after and the error per validation row."""
    rep.heading("Validation")
    rep.kv(
        {
            "rows": str(validation.n_rows),
            "mean / RMS / max after (mm)": _mean_rms_max(validation.stats),
            "mean / RMS / max before (mm)": _mean_rms_max(validation_before.stats),
            **{f"tool of {k}": v for k, v in validation.tool_source.items()},
        }
    )
    keep = validation.kept_rows
    assert keep is not None and validation.errors_mm is not None and validation_before.errors_mm is not None
    vb = np.linalg.norm(validation_before.errors_mm[keep], axis=1)
    va = np.linalg.norm(validation.errors_mm[keep], axis=1)
    val = campaign.validation()
    vl = [f"{p}/{t}" for p, t in zip(val.pose_id[keep], val.target[keep], strict=True)]
    rep.figure(plots.error_per_pose(vb, va, vl), "Validation rows: 3-D error before and after")


def _parameters_section(rep: Report, result: CalibrationResult) -> None:
    """The parameter table, the identified joint-level errors as a figure, the eliminated parameters."""
    rep.heading("Parameters")
    table = result.parameter_table()
    rep.table(
        [[r["name"], r["kind"], r["unit"], r["value"], r["stderr"], r["status"]] for r in table],
        columns=["parameter", "kind", "unit", "value", "std. error", "status"],
        caption="Kinematic errors are deviations from the nominal model; base_* are corrections of the base "
        "frame's closed-form registration (zero: the registration itself, see 'Frames and tools' for the frame); "
        "tool_* are the targets' positions in the flange frame.",
    )
    kin = [r for r in table if r["kind"] == "kinematic" and r["status"] == "identified"]
    if kin:
        rep.figure(
            plots.parameter_errors(
                [r["name"] + (" [deg×100]" if r["unit"] == "deg" else " [mm]") for r in kin],
                np.array([r["value"] * (100 if r["unit"] == "deg" else 1) for r in kin]),
                np.array([r["stderr"] * (100 if r["unit"] == "deg" else 1) for r in kin]),
            ),
            "Identified joint-level errors with ±1 standard error (angles ×100 to share the axis)",
        )
    rep.heading("Eliminated parameters")
    if result.eliminated:
        rep.table(
            [[e.name, e.combination() or "–", e.reason] for e in result.eliminated],
            columns=["parameter", "absorbed by", "reason"],
        )
    else:
        rep.paragraph("None: every candidate parameter is identifiable from these poses.")


def _frames_section(rep: Report, result: CalibrationResult) -> None:
    """The base frame in the tracker frame (per station) and the tools in the flange frame."""
    T = result.tracker_T_base
    rep.heading("Frames and tools")
    rpy = np.rad2deg(rpy_from_matrix(T[:3, :3]))
    stations = {
        f"station {s}: base origin in its tracker frame (mm)": _xyz(result.model.base_transform(result.x, k)[:3, 3])
        for k, s in enumerate(result.model.station_names)
        if k > 0
    }
    first = f" (station {result.model.station_names[0]})" if stations else ""
    rep.kv(
        {
            f"base origin in the tracker frame{first} (mm)": _xyz(T[:3, 3]),
            "base orientation in the tracker frame (deg)": "roll {:.4f}, pitch {:.4f}, yaw {:.4f}".format(*rpy),
            **stations,
            **{f"tool {k} in the flange frame (mm)": _xyz(v) for k, v in result.tools.items()},
        }
    )


def _iterations_time(fit: Mapping[str, Any]) -> dict[str, str]:
    """The iterations and the measured time of the fit. Pipeline reports (reproducible mode: same config, same
    bytes) show the iterations only (the time is in the MLflow run and on the console)."""
    if is_reproducible():
        return {"iterations": str(fit["nit"])}
    t = float(fit["wall_time_s"])
    return {"iterations / time": f"{fit['nit']} / {t:.3f} s" if t >= 0.1 else f"{fit['nit']} / {t * 1e3:.1f} ms"}


def _xyz(v: Any) -> str:
    """``x 2500.0170, y 1199.9799, z −350.4942`` (mm), not a numpy repr."""
    x, y, z = (float(c) for c in np.asarray(v, dtype=float).reshape(3))
    return f"x {x:.4f}, y {y:.4f}, z {z:.4f}".replace("-", "−")
