"""Differential error compensation: joint corrections that make the real robot reach the nominal pose.

The one entry point is :func:`robocal.compensation.correct.correct` (``robocal.compensate``): a calibration or an
:class:`ActualRobot`, the targets, the joint-space effects, the safety policy in; one
:class:`~robocal.compensation.correct.Corrected` out. The one compensation path of robocal: the Newton solver
(:mod:`robocal.kinematics.ik`), the joint-space effects composed once (:mod:`robocal.compensation.effects`), the
one safety policy and its per-target statuses (:mod:`robocal.compensation.safety`), the correction and the one
beyond-own computation (:mod:`robocal.compensation.correct`) and the one controller CSV
(:mod:`robocal.compensation.controller_csv`).
This module keeps the model of the robot at the moment (:class:`ActualRobot`) and the Newton step over it
(:func:`compensate`, unjudged) that :func:`~robocal.compensation.correct.correct` runs.

The controller plans with its nominal kinematics: for a target ``q_target`` it expects the tool frame
at ``desired = tracker_T_base · FK_nominal(q_target) · flange_T_tool``. The real robot (calibrated
kinematic errors, plus thermal drift or joint deflection predicted for the moment) reaches
``FK_actual(q + dq_deflection)`` instead. Compensation solves ``FK_actual(q*) = desired`` by
Newton iterations on the error Jacobian (joint corrections from the pseudo-inverse of the joint
Jacobian), then reports the corrected joints, the corrected Cartesian command (what the nominal
controller must be sent so that its inverse kinematics yields ``q*``) and the predicted residual.

All arrays are batched over targets: ``q`` is ``(m, n)`` rad, positions ``(m, 3)`` mm.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from robocal.kinematics.chain import Chain, ChainState, propagate
from robocal.status import TargetStatus

if TYPE_CHECKING:
    from robocal.kinematics.ik import Solution


@dataclass(frozen=True)
class ActualRobot:
    """What the robot really is at the moment of compensation.

    chain : the compiled nominal chain; eta : (P,) kinematic errors (geometric + thermal, mm / rad);
    tracker_T_base : (4, 4); tool_mm : (3,) tool point in the flange frame; tool_R : (3, 3) tool frame;
    joint_offset : callable ``q_cmd (m, n) -> dq (m, n)`` rad added to the commanded joints (deflection),
    or None.
    """

    chain: Chain
    eta: np.ndarray
    tracker_T_base: np.ndarray
    tool_mm: np.ndarray
    tool_R: np.ndarray
    joint_offset: Callable[[np.ndarray], np.ndarray] | None = None

    def pose(self, q_cmd: np.ndarray, record: bool = False) -> tuple[np.ndarray, np.ndarray, ChainState]:
        q = q_cmd if self.joint_offset is None else q_cmd + self.joint_offset(q_cmd)
        st = propagate(self.chain, q, self.eta, self.tracker_T_base, record=record)
        t = self.tool_mm
        p = st.o + st.x * t[0] + st.y * t[1] + st.z * t[2]
        R = st.R @ self.tool_R
        return p, R, st


def desired_poses(nominal: ActualRobot, q_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tool positions ``(m, 3)`` and rotations ``(m, 3, 3)`` the nominal controller expects at ``q_target``."""
    p, R, _ = nominal.pose(q_target)
    return p, R


def compensate(
    actual: ActualRobot,
    q_target: np.ndarray,
    p_desired: np.ndarray,
    R_desired: np.ndarray | None = None,
    max_iter: int = 20,
    tol_mm: float = 1e-7,
    tol_rad: float = 1e-9,
    max_step_rad: float = 0.05,
    stall: bool = True,
) -> Solution:
    """Joint targets ``q*`` with ``actual.pose(q*) = (p_desired, R_desired)``: the Newton step, unjudged (the
    solver's :class:`~robocal.kinematics.ik.Solution`; :func:`robocal.compensation.correct.correct` judges it and
    returns the one :class:`~robocal.compensation.correct.Corrected`).

    With ``R_desired`` the full 6-D tool pose is matched (6 equations, a square system for a 6-axis
    arm); without it only the tool position (minimum-norm joint correction). ``max_step_rad`` and ``stall``
    as :func:`robocal.kinematics.ik.solve` (inverse kinematics over a large move: a larger step, no stall rule).

    One Newton for everything: this is the online service's solver (:func:`robocal.kinematics.ik.solve`, the
    chain folded at ``actual.eta`` and the tracker frame; damped normal equations, steps clipped, a target that
    stops converging near a singularity reported unconverged), so the controller CSV, the thermal and compliance
    compensation, program filtering and the service give the same corrections.
    """
    from robocal.kinematics.ik import compile_chain, solve
    from robocal.kinematics.transforms import homogeneous

    q0 = np.asarray(q_target, dtype=float)
    cc = compile_chain(actual.chain, np.asarray(actual.eta, dtype=float), actual.tracker_T_base)
    tool_T = homogeneous(np.asarray(actual.tool_R, dtype=float), np.asarray(actual.tool_mm, dtype=float))
    offset: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    if actual.joint_offset is not None:
        from robocal.compensation.effects import JointOffsets

        fn = actual.joint_offset
        if isinstance(fn, JointOffsets):  # the composed effects take the rows asked about (their signals' rows)
            offset = fn
        else:
            offset = _rows_of(fn, q0)

    sol = solve(cc, tool_T, q0, np.asarray(p_desired, dtype=float), R_desired, offset, max_iter=max_iter,
                tol_mm=tol_mm, tol_rad=tol_rad, max_step_rad=max_step_rad, stall=stall)  # fmt: skip
    return sol


def _rows_of(fn: Callable[[np.ndarray], np.ndarray], q0: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The solver's hook ``(q (k, n), rows (k,)) -> dq`` over a callable that takes every target's joints at once
    (its signals are per target): the rows asked about are set in a copy of ``q0`` and read back. A row asked
    about more than once in one call (the forward-difference Jacobian asks for each target at ``n + 1``
    configurations) is evaluated in as many passes, one configuration per target each."""
    q_all = np.array(q0, dtype=float)

    def offset(qs: np.ndarray, rows: np.ndarray) -> np.ndarray:
        out = np.empty_like(qs)
        todo = np.arange(len(rows))
        while len(todo):
            _, first = np.unique(rows[todo], return_index=True)
            pick = todo[np.sort(first)]
            q_all[rows[pick]] = qs[pick]
            out[pick] = np.asarray(fn(q_all), dtype=float)[rows[pick]]
            todo = np.setdiff1d(todo, pick, assume_unique=True)
        return out

    return offset


def write_compensation_csv(
    path: str | Path,
    target_ids: Sequence[str] | np.ndarray,
    q_corrected: np.ndarray,
    command_T: np.ndarray,
    predicted_error_mm: np.ndarray,
    predicted_error_deg: np.ndarray | None = None,
    status: Sequence[str] | np.ndarray | None = None,
    reason: Sequence[str] | np.ndarray | None = None,
    correction_max_deg: np.ndarray | None = None,
) -> Path:
    """The one controller CSV (:func:`robocal.compensation.controller_csv.write_controller_csv`, columns
    :data:`~robocal.compensation.controller_csv.CSV_COLUMNS`) of joints ``q_corrected`` (m, n) rad to send,
    their Cartesian command ``command_T`` (m, 4, 4) and the predicted error when sent (``predicted_error_mm``
    (m, 3), ``predicted_error_deg`` (m, 3) rad rotation vectors or None). ``status`` / ``reason`` (default ok,
    empty): a refused row must carry the nominal joints; ``correction_max_deg`` (m,) the largest joint
    correction computed (default 0)."""
    from robocal.compensation.controller_csv import write_controller_csv

    m = len(target_ids)
    st = list(status) if status is not None else [TargetStatus.OK] * m
    applied = np.array([s != TargetStatus.REFUSED for s in st], dtype=bool)
    return write_controller_csv(
        path,
        target_ids,
        q_corrected,
        command_T,
        predicted_error_mm,
        predicted_error_deg,
        st,
        applied,
        np.zeros(m) if correction_max_deg is None else correction_max_deg,
        list(reason) if reason is not None else [""] * m,
    )
