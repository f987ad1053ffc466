"""Thermal compensation (Guo et al. 2026, section 3.5, fig. 11): the geometric errors identified at the reference
(cold) state plus the drift the thermal model predicts from the current temperatures give the robot's parameters
now; differential error compensation (:func:`robocal.compensation.compensate`) turns every target into corrected
joints and a corrected Cartesian command for the nominal controller, written as a CSV a cell controller reads.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from robocal.compensation import ActualRobot, Compensation, compensate, desired_poses, write_compensation_csv
from robocal.identification.calibrate import CalibrationResult
from robocal.kinematics.chain import fk
from robocal.thermal.model import ThermalModel


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
    """

    ids: np.ndarray
    q_target: np.ndarray
    q: np.ndarray
    command_T: np.ndarray
    residual_mm: np.ndarray
    residual_rad: np.ndarray
    deta: np.ndarray
    results: dict[str, Compensation]


def compensate_targets(
    result: CalibrationResult,
    model: ThermalModel | None,
    temperatures: np.ndarray | None,
    q_target: np.ndarray,
    targets: Sequence[str] | np.ndarray,
    ids: Sequence[str] | None = None,
    orientation: bool = True,
) -> ThermalCompensation:
    """Corrected joints for targets ``q_target (m, n)`` at one temperature reading ``(s,)`` (model sensor order).

    Without a model (or temperatures) only the geometric errors are compensated.
    """
    q_target = np.asarray(q_target, dtype=float)
    m = q_target.shape[0]
    P = result.model.chain.n_params
    deta = np.zeros(P)
    if model is not None and temperatures is not None:
        deta = model.deta(np.asarray(temperatures, dtype=float)[None, :])[0]
    q = q_target.copy()
    res_mm = np.zeros((m, 3))
    res_rad = np.zeros((m, 3))
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
        out[t] = c
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
    return ThermalCompensation(ident, q_target, q, cmd, res_mm, res_rad, deta, out)


def write_controller_csv(path: str | Path, comp: ThermalCompensation) -> Path:
    """The controller CSV (target id, corrected joints, corrected pose, predicted error) of a compensation."""
    return write_compensation_csv(
        path, comp.ids, comp.q, comp.command_T, comp.residual_mm, np.rad2deg(comp.residual_rad)
    )


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
    "ThermalCompensation",
    "calibrated_robot",
    "compensate_targets",
    "nominal_robot",
    "true_robot",
    "write_controller_csv",
]
