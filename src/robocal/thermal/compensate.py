"""Thermal compensation (Guo et al. 2026, section 3.5, fig. 11): the geometric errors identified at the reference
(cold) state plus the drift the thermal model predicts from the current temperatures give the robot's parameters
now; differential error compensation (:func:`robocal.compensation.compensate`) turns every target into corrected
joints and a corrected Cartesian command for the nominal controller, written as a CSV a cell controller reads.

No correction is applied silently. Every target gets a status (:data:`STATUSES`, first that applies):

- ``not_converged``: Newton's iteration did not bring the predicted pose to the target (residual above
  ``residual_tol_mm`` / ``residual_tol_deg``), e.g. at a wrist or elbow singularity;
- ``too_large``: a joint correction exceeds ``max_correction_deg`` (near a singularity the correction of a sub-mm
  error becomes degrees: ill-conditioned, so model errors are amplified too) or would leave the joint range;
- ``out_of_range``: the temperature reading lies outside the model's fitted range by more than ``range_margin_C``
  on some sensor (the thermal model extrapolates);
- ``ok``.

Rows that are not ``ok`` keep the nominal (requested) joints and command, unless ``out_of_range: apply`` lets an
extrapolated correction through (still flagged). The CSV columns are described in :data:`CSV_COLUMNS`.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from robocal.compensation import ActualRobot, Compensation, compensate, desired_poses
from robocal.config import parse, setting
from robocal.identification.calibrate import CalibrationResult
from robocal.io import atomic_write
from robocal.kinematics.chain import fk
from robocal.kinematics.transforms import matrix_to_quat
from robocal.thermal.model import ThermalModel

#: Status of a target in the controller CSV, in order of precedence.
STATUSES = ("not_converged", "too_large", "out_of_range", "ok")
EXTRAPOLATION_POLICIES = ("nominal", "apply")

#: Columns of ``compensation.csv`` (:func:`write_controller_csv`) and what they hold.
CSV_COLUMNS = {
    "target_id": "target id (pose id / target name)",
    "status": "ok | not_converged | too_large | out_of_range (see robocal.thermal.compensate)",
    "applied": "1 = the corrected joints below were computed by the compensation; 0 = nominal joints kept",
    "q<j>_deg": "joint command to send, deg: corrected when applied = 1, else the requested (nominal) joints",
    "x_mm, y_mm, z_mm": "Cartesian command for the nominal controller (robot base frame, tool point), mm",
    "qw, qx, qy, qz": "orientation of that command (unit quaternion, tool frame in the robot base frame)",
    "pred_err_mm": "predicted position error (mm) of the robot at the temperature reading when sent this row",
    "pred_err_deg": "predicted orientation error (deg) likewise (when the compensation matched orientation)",
    "correction_max_deg": "largest |corrected - requested| joint angle the compensation computed, deg (also "
    "for rows that were not applied)",
    "extrapolation_C": "how far the temperature reading lies outside the model's fitted range, worst sensor, "
    "degC (0 = inside)",
    "reason": "why the row is not ok (empty when ok)",
}


@dataclass(frozen=True)
class CompensationLimits:
    """When a compensated target is refused or flagged (``thermal.compensation`` in conf/thermal/default.yaml).

    max_correction_deg : largest joint correction applied (deg). residual_tol_mm / residual_tol_deg : predicted
    residual after Newton's iteration above which the target is ``not_converged``. range_margin_C : a sensor
    reading outside the fitted range by more than this (degC) is an extrapolation (``out_of_range``).
    out_of_range : ``nominal`` (keep the nominal joints) or ``apply`` (apply the extrapolated correction, flagged).
    joint_limits : also refuse corrections that leave the robot's joint range.
    """

    max_correction_deg: float = setting(5.0, ge=0)
    residual_tol_mm: float = setting(1e-3, ge=0)
    residual_tol_deg: float = setting(1e-4, ge=0)
    range_margin_C: float = setting(1.0, ge=0)
    out_of_range: str = setting("nominal", choices=EXTRAPOLATION_POLICIES)
    joint_limits: bool = True

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> CompensationLimits:
        return parse(cls, cfg, "thermal.compensation")

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def range_excess(model: ThermalModel, temperatures: np.ndarray) -> np.ndarray:
    """(m, s) degC by which each reading lies outside the model's fitted range (0 inside), model sensor order.

    Only sensors some parameter model uses count (the others are 0): an unused sensor cannot extrapolate."""
    T = np.atleast_2d(np.asarray(temperatures, dtype=float))
    lo, hi = model.fitted_range_C[:, 0], model.fitted_range_C[:, 1]
    used = np.array([any(s in p.sensors for p in model.parameters) for s in model.sensors], dtype=bool)
    return np.where(used[None, :], np.maximum(np.maximum(lo - T, T - hi), 0.0), 0.0)


def extrapolation_summary(
    model: ThermalModel,
    temperatures: np.ndarray,
    state: np.ndarray,
    t_min: Sequence[float],
    margin_C: float,
) -> dict[str, Any]:
    """Where readings ``(m, s)`` (model sensor order) of a warm-up with states ``state (m,)`` starting at
    ``t_min`` minutes lie outside the model's fitted range by more than ``margin_C``: counts per row and state,
    the worst excess per sensor, and a warning text (empty when none)."""
    ex = range_excess(model, temperatures)
    out_rows = (ex > margin_C).any(axis=1) if ex.size else np.zeros(len(state), dtype=bool)
    states = sorted({int(v) for v in np.asarray(state)[out_rows]})
    worst = {s: float(ex[:, j].max()) for j, s in enumerate(model.sensors) if ex.size and ex[:, j].max() > margin_C}
    out: dict[str, Any] = {
        "margin_C": float(margin_C),
        "fitted_range_C": {
            s: [float(a), float(b)] for s, (a, b) in zip(model.sensors, model.fitted_range_C, strict=True)
        },
        "n_rows": len(state),
        "n_rows_out_of_range": int(out_rows.sum()),
        "n_states_out_of_range": len(states),
        "states_out_of_range_t_min": [float(t_min[k]) for k in states],
        "sensors_out_of_range": worst,
        "max_excess_C": float(ex.max()) if ex.size else 0.0,
        "warning": "",
    }
    if out_rows.any():
        out["warning"] = (
            f"the thermal model extrapolates: {int(out_rows.sum())} of {len(state)} rows ({len(states)} state(s), "
            f"t = {', '.join(f'{t:.0f}' for t in out['states_out_of_range_t_min'])} min) have readings outside the "
            f"fitted range by more than {margin_C:g} degC ("
            + ", ".join(f"{s} by {v:.2f} degC" for s, v in worst.items())
            + "); their compensation is flagged out_of_range"
        )
    return out


def calibrated_robot(result: CalibrationResult, target: str, deta: np.ndarray | None = None) -> ActualRobot:
    """The calibrated robot (reference-state geometry + ``deta`` (P,) drift) carrying ``target``."""
    k = result.model.target_names.index(target)
    eta = result.kinematic_errors + (0.0 if deta is None else np.asarray(deta, dtype=float))
    return ActualRobot(
        chain=result.model.chain,
        eta=eta,
        tracker_T_base=result.tracker_T_base,
        tool_mm=result.model.tools(result.x)[k],
        tool_R=result.model.tool_rotations(result.x)[k],
    )


def nominal_robot(result: CalibrationResult, target: str) -> ActualRobot:
    """What the controller believes: nominal kinematics, in the calibrated tracker and tool frames."""
    act = calibrated_robot(result, target)
    return ActualRobot(act.chain, np.zeros_like(act.eta), act.tracker_T_base, act.tool_mm, act.tool_R)


@dataclass
class ThermalCompensation:
    """Compensated commands of a batch of targets measured at one temperature reading.

    ids : (m,) target ids; q_target / q : (m, n) requested and corrected joints (rad);
    command_T : (m, 4, 4) corrected Cartesian command (robot base frame, tool frame) for the nominal controller;
    deta : (P,) drift used; results : the per-target-name :class:`Compensation` objects.
    status : (m,) one of :data:`STATUSES`; reason : (m,) why not ok; applied : (m,) the correction is in ``q``
    (else ``q = q_target``); q_corrected : (m, n) what the compensation computed (applied or not);
    correction_max_deg : (m,) largest joint correction computed; extrapolation_C : worst sensor's distance
    outside the fitted range (degC, one reading for the batch); residual_* : predicted error of what ``q`` holds;
    orientation : whether the orientation was matched (else only the position); limits : the limits used.
    """

    ids: np.ndarray
    q_target: np.ndarray
    q: np.ndarray
    command_T: np.ndarray
    residual_mm: np.ndarray
    residual_rad: np.ndarray
    deta: np.ndarray
    results: dict[str, Compensation]
    status: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))
    reason: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))
    applied: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    q_corrected: np.ndarray | None = None
    correction_max_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    extrapolation_C: float = 0.0
    orientation: bool = True
    limits: CompensationLimits = field(default_factory=CompensationLimits)

    def counts(self) -> dict[str, int]:
        """Number of targets per status (every status listed)."""
        return {k: int(np.sum(self.status == k)) for k in STATUSES}


def compensate_targets(
    result: CalibrationResult,
    model: ThermalModel | None,
    temperatures: np.ndarray | None,
    q_target: np.ndarray,
    targets: Sequence[str] | np.ndarray,
    ids: Sequence[str] | None = None,
    orientation: bool = True,
    limits: CompensationLimits | None = None,
    q_limits: np.ndarray | None = None,
) -> ThermalCompensation:
    """Corrected joints for targets ``q_target (m, n)`` at one temperature reading ``(s,)`` (model sensor order).

    Without a model (or temperatures) only the geometric errors are compensated. Every target gets a status
    (module doc); targets that are not ``ok`` keep ``q_target`` in ``q`` (unless ``limits.out_of_range`` is
    ``apply`` and extrapolation is their only problem). ``q_limits`` (n, 2) rad: the joint range checked when
    ``limits.joint_limits``.
    """
    lim = limits if limits is not None else CompensationLimits()
    q_target = np.asarray(q_target, dtype=float)
    m = q_target.shape[0]
    P = result.model.chain.n_params
    deta = np.zeros(P)
    excess, worst = 0.0, ""
    if model is not None and temperatures is not None:
        T = np.asarray(temperatures, dtype=float)[None, :]
        deta = model.deta(T)[0]
        ex = range_excess(model, T)[0]
        excess = float(ex.max()) if ex.size else 0.0
        worst = model.sensors[int(np.argmax(ex))] if ex.size else ""
    q = q_target.copy()
    res_mm = np.zeros((m, 3))
    res_rad = np.zeros((m, 3))
    before_mm = np.zeros((m, 3))
    before_rad = np.zeros((m, 3))
    out: dict[str, Compensation] = {}
    tnames = np.asarray(targets).astype(str)
    for t in dict.fromkeys(tnames.tolist()):
        sel = tnames == t
        act = calibrated_robot(result, t, deta)
        p_d, R_d = desired_poses(nominal_robot(result, t), q_target[sel])
        c = compensate(act, q_target[sel], p_d, R_d if orientation else None)
        q[sel] = c.q
        res_mm[sel] = c.residual_mm
        res_rad[sel] = c.residual_rad
        before_mm[sel] = c.error_before_mm
        before_rad[sel] = c.error_before_rad
        out[t] = c
    # -- status of every target (module doc): nothing is applied silently
    q_corr = q.copy()
    dq_deg = np.rad2deg(np.abs(q_corr - q_target))
    corr_max = dq_deg.max(axis=1) if q.shape[1] else np.zeros(m)
    reasons: list[list[str]] = [[] for _ in range(m)]
    status = np.full(m, "ok", dtype=object)
    res_n = np.linalg.norm(res_mm, axis=1)
    res_d = np.rad2deg(np.linalg.norm(res_rad, axis=1))
    bad_conv = (res_n > lim.residual_tol_mm) | (res_d > lim.residual_tol_deg) | ~np.isfinite(corr_max)
    big = corr_max > lim.max_correction_deg
    outside: np.ndarray = np.zeros(m, dtype=bool)
    if lim.joint_limits and q_limits is not None:
        ql = np.asarray(q_limits, dtype=float)
        outside = np.asarray(((q_corr < ql[:, 0]) | (q_corr > ql[:, 1])).any(axis=1), dtype=bool)
    extrap = excess > lim.range_margin_C
    for i in range(m):
        if bad_conv[i]:
            reasons[i].append(
                f"compensation did not converge (predicted residual {res_n[i]:.3g} mm / {res_d[i]:.3g} deg; "
                "near a singularity?)"
            )
        if big[i]:
            j = int(np.argmax(dq_deg[i]))
            reasons[i].append(
                f"joint correction {dq_deg[i, j]:.3g} deg on q{j + 1} exceeds max_correction_deg "
                f"{lim.max_correction_deg:g}"
            )
        if outside[i]:
            reasons[i].append("corrected joints leave the joint range")
        if extrap:
            reasons[i].append(
                f"temperature {worst} outside the fitted range by {excess:.2f} degC (> margin {lim.range_margin_C:g})"
            )
    status[bad_conv] = "not_converged"
    status[~bad_conv & (big | outside)] = "too_large"
    status[(status == "ok") & extrap] = "out_of_range"
    applied = (status == "ok") | ((status == "out_of_range") & (lim.out_of_range == "apply"))
    for r in np.flatnonzero(~applied):
        reasons[r].append("nominal joints kept")
    for r in np.flatnonzero(applied & (status == "out_of_range")):
        reasons[r].append("extrapolated correction applied (thermal.compensation.out_of_range: apply)")
    q = np.where(applied[:, None], q_corr, q_target)
    res_mm = np.where(applied[:, None], res_mm, before_mm)
    res_rad = np.where(applied[:, None], res_rad, before_rad)
    # the command the nominal controller must receive so that its inverse kinematics gives q: nominal FK at q
    cmd = np.zeros((m, 4, 4))
    for t in out:
        sel = tnames == t
        nom = nominal_robot(result, t)
        T = fk(nom.chain, q[sel])
        tool = np.eye(4)
        tool[:3, :3] = nom.tool_R
        tool[:3, 3] = nom.tool_mm
        cmd[sel] = T @ tool
    ident = np.asarray(ids if ids is not None else [f"t{k:04d}" for k in range(m)]).astype(str)
    return ThermalCompensation(
        ident,
        q_target,
        q,
        cmd,
        res_mm,
        res_rad,
        deta,
        out,
        status=status,
        reason=np.array(["; ".join(r) for r in reasons], dtype=object),
        applied=applied,
        q_corrected=q_corr,
        correction_max_deg=corr_max,
        extrapolation_C=excess,
        orientation=bool(orientation),
        limits=lim,
    )


def write_controller_csv(path: str | Path, comp: ThermalCompensation) -> Path:
    """The controller CSV of a compensation, one row per target, columns :data:`CSV_COLUMNS` (``q1_deg`` ..
    ``qN_deg``; ``pred_err_deg`` only when the orientation was matched). Rows that are not ``ok`` carry the
    nominal joints and command unless ``applied`` is 1, and say why in ``reason``."""
    q = np.rad2deg(np.asarray(comp.q, dtype=float))
    quat = matrix_to_quat(comp.command_T[:, :3, :3])
    n = q.shape[1]
    head = ["target_id", "status", "applied", *[f"q{j + 1}_deg" for j in range(n)]]
    head += ["x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz", "pred_err_mm"]
    if comp.orientation:
        head.append("pred_err_deg")
    head += ["correction_max_deg", "extrapolation_C", "reason"]
    err = np.linalg.norm(np.atleast_2d(comp.residual_mm), axis=1)
    erd = np.rad2deg(np.linalg.norm(np.atleast_2d(comp.residual_rad), axis=1))
    rows = []
    for k, tid in enumerate(comp.ids):
        vals = [str(tid), str(comp.status[k]), str(int(comp.applied[k]))]
        vals += [f"{v:.6f}" for v in q[k]] + [f"{v:.6f}" for v in comp.command_T[k, :3, 3]]
        vals += [f"{v:.9f}" for v in quat[k]] + [f"{err[k]:.6f}"]
        if comp.orientation:
            vals.append(f"{erd[k]:.6f}")
        vals += [f"{comp.correction_max_deg[k]:.6f}", f"{comp.extrapolation_C:.3f}", str(comp.reason[k])]
        rows.append(vals)

    def _write(p: Path) -> None:
        with p.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(head)
            w.writerows(rows)

    return atomic_write(path, _write)


def true_robot(truth: dict[str, Any], chain: Any, target: str, deta: np.ndarray) -> ActualRobot:
    """The twin's true robot (truth.json) with drift ``deta`` (P,) carrying ``target``."""
    eta = np.array([truth["kinematic_errors"][n] for n in chain.param_names]) + deta
    return ActualRobot(
        chain=chain,
        eta=eta,
        tracker_T_base=np.array(truth["tracker_T_base"]),
        tool_mm=np.array(truth["tools_mm"][target]),
        tool_R=np.array(truth["tool_rotations"][target]),
    )


__all__ = [
    "CSV_COLUMNS",
    "STATUSES",
    "CompensationLimits",
    "ThermalCompensation",
    "calibrated_robot",
    "compensate_targets",
    "extrapolation_summary",
    "nominal_robot",
    "range_excess",
    "true_robot",
    "write_controller_csv",
]
