"""Thermal compensation (Guo et al. 2026, section 3.5, fig. 11): the geometric errors identified at the reference
(cold) state plus the drift the thermal model predicts from the current temperatures give the robot's parameters
now; the one compensation entry point (:func:`robocal.compensation.correct.correct`) turns every target into corrected
joints and a corrected Cartesian command for the nominal controller, written as a CSV a cell controller reads.

No correction is applied silently. Every target gets a status of the one safety policy
(:class:`robocal.compensation.safety.SafetyPolicy`, ``thermal.compensation`` in conf/thermal/default.yaml, the
same defaults as the service and the program filter): ``refused`` (did not converge, correction beyond the
calibration's own joint offsets above the bound, outside the joint range, or a temperature reading outside the
model's fitted range with ``on_temperature_range: refuse``), ``flagged`` (a problem the policy lets through,
e.g. an extrapolation with ``on_temperature_range: flag``) or ``ok``, with the reasons.

Refused rows keep the nominal (requested) joints and command; flagged rows carry the correction. The CSV is
the one controller CSV (:func:`robocal.compensation.controller_csv.write_controller_csv`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.compensation import ActualRobot, controller_csv, desired_poses
from robocal.compensation.controller_csv import CSV_COLUMNS
from robocal.compensation.correct import Corrected, correct
from robocal.compensation.safety import STATUSES, SafetyPolicy
from robocal.kinematics.chain import fk
from robocal.thermal.model import ThermalModel

#: the thermal controller CSV's limits are the one safety policy (``thermal.compensation``)
CompensationLimits = SafetyPolicy


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
    deta : (P,) drift used; results : the per-target-name :class:`~robocal.compensation.correct.Corrected`.
    status : (m,) one of :data:`STATUSES`; reason : (m,) why not ok; applied : (m,) the correction is in ``q``
    (else ``q = q_target``); q_corrected : (m, n) what the compensation computed (applied or not);
    correction_max_deg : (m,) largest joint correction computed; extrapolation_C : worst sensor's distance
    outside the fitted range (degC, one reading for the batch); residual_* : predicted error of what ``q`` holds;
    orientation : whether the orientation was matched (else only the position); limits : the safety policy
    used; target_refused : (m,) refused for a reason of the target itself (convergence, bound, joint range), not
    only for the batch's temperature reading.
    """

    ids: np.ndarray
    q_target: np.ndarray
    q: np.ndarray
    command_T: np.ndarray
    residual_mm: np.ndarray
    residual_rad: np.ndarray
    deta: np.ndarray
    results: dict[str, Corrected]
    status: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))
    reason: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))
    applied: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    q_corrected: np.ndarray | None = None
    correction_max_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    extrapolation_C: float = 0.0
    orientation: bool = True
    limits: SafetyPolicy = field(default_factory=SafetyPolicy)
    target_refused: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

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
    limits: SafetyPolicy | None = None,
    q_limits: np.ndarray | None = None,
) -> ThermalCompensation:
    """Corrected joints for targets ``q_target (m, n)`` at one temperature reading ``(s,)`` (model sensor order).

    Without a model (or temperatures) only the geometric errors are compensated. Every target gets a status of
    the safety policy ``limits`` (module doc); refused targets keep ``q_target`` in ``q``. ``q_limits`` (n, 2)
    rad: the joint range (None: not checked).
    """
    lim = limits if limits is not None else SafetyPolicy()
    q_target = np.asarray(q_target, dtype=float)
    m, n = q_target.shape
    deta, excess_C, worst = _drift(result, model, temperatures)
    tnames = np.asarray(targets).astype(str)
    ql = np.asarray(q_limits, dtype=float) if q_limits is not None else np.tile([-np.inf, np.inf], (n, 1))
    names = list(result.model.robot.joint_names)
    request = []
    if excess_C > lim.temperature_margin_C:
        request.append(
            f"temperature {worst} outside the fitted range by {excess_C:.2f} degC (> margin "
            f"{lim.temperature_margin_C:g})"
        )
    # the one entry point per target name (its tool): corrected joints and the safety policy's status; nothing is
    # applied silently
    q_corr, res_mm, res_rad = q_target.copy(), np.zeros((m, 3)), np.zeros((m, 3))
    before_mm, before_rad, corr_max = np.zeros((m, 3)), np.zeros((m, 3)), np.zeros(m)
    status = np.full(m, "", dtype=object)
    reasons: list[list[str]] = [[] for _ in range(m)]
    target_refused = np.zeros(m, dtype=bool)
    out: dict[str, Corrected] = {}
    for t in dict.fromkeys(tnames.tolist()):
        sel = tnames == t
        qt = q_target[sel]
        desired = desired_poses(nominal_robot(result, t), qt)
        c = correct(calibrated_robot(result, t, deta), qt, None, lim, desired=desired, orientation=orientation,
                    q_limits=ql, joint_names=names, request_reasons=request)  # fmt: skip
        q_corr[sel], res_mm[sel], res_rad[sel] = c.q, c.residual_mm, c.residual_rad
        before_mm[sel], before_rad[sel] = c.error_before_mm, c.error_before_rad
        corr_max[sel] = np.abs(c.correction_deg).max(axis=1) if n else 0.0
        status[sel] = c.status
        for r, why in zip(np.flatnonzero(sel), c.reasons, strict=True):
            reasons[r] = why
        # refused for a reason of the target itself (not the batch's temperature reading)
        own, _ = lim.judge(c.converged, c.residual_mm, c.residual_rad, c.excess_deg, c.rest_mm, qt, c.q, ql, names)
        target_refused[sel] = [st == "refused" for st in own]
        out[t] = c
    applied = status != "refused"
    for r in np.flatnonzero(~applied):
        reasons[r].append("nominal joints kept")
    q = np.where(applied[:, None], q_corr, q_target)
    res_mm = np.where(applied[:, None], res_mm, before_mm)
    res_rad = np.where(applied[:, None], res_rad, before_rad)
    cmd = _nominal_commands(result, q, tnames, out)
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
        extrapolation_C=excess_C,
        orientation=bool(orientation),
        limits=lim,
        target_refused=target_refused,
    )


def _drift(
    result: CalibrationResult, model: ThermalModel | None, temperatures: np.ndarray | None
) -> tuple[np.ndarray, float, str]:
    """The drift ``deta`` (P,) the model predicts at one reading (zeros without a model or a reading), how far
    (degC) the reading lies outside the model's fitted range and for which sensor (worst)."""
    deta = np.zeros(result.model.chain.n_params)
    excess_C, worst = 0.0, ""
    if model is not None and temperatures is not None:
        T = np.asarray(temperatures, dtype=float)[None, :]
        deta = model.deta(T)[0]
        ex = range_excess(model, T)[0]
        excess_C = float(ex.max()) if ex.size else 0.0
        worst = model.sensors[int(np.argmax(ex))] if ex.size else ""
    return deta, excess_C, worst


def _nominal_commands(
    result: CalibrationResult, q: np.ndarray, tnames: np.ndarray, out: dict[str, Corrected]
) -> np.ndarray:
    """The command (m, 4, 4) the nominal controller must receive so that its inverse kinematics gives ``q``:
    nominal FK at ``q`` times the tool."""
    cmd = np.zeros((q.shape[0], 4, 4))
    for t in out:
        sel = tnames == t
        nom = nominal_robot(result, t)
        T = fk(nom.chain, q[sel])
        tool = np.eye(4)
        tool[:3, :3] = nom.tool_R
        tool[:3, 3] = nom.tool_mm
        cmd[sel] = T @ tool
    return cmd


def write_controller_csv(path: str | Path, comp: ThermalCompensation) -> Path:
    """The controller CSV of a compensation (the one layout, :data:`CSV_COLUMNS`; ``pred_err_deg`` only when
    the orientation was matched). Refused rows carry the nominal joints and command and say why."""
    return controller_csv.write_controller_csv(
        path, comp.ids, comp.q, comp.command_T, comp.residual_mm, comp.residual_rad if comp.orientation else None,
        comp.status, comp.applied, comp.correction_max_deg, comp.reason, comp.extrapolation_C,
    )  # fmt: skip


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
