"""The model as the service corrects the robot with it must stand on its own: the robot-side effects without the
measurement side's (a tracker's scale, which corrects the readings and is never served).

A robot-side effect and a measurement-side one fitted to the same cause can cancel: on the UR10's grid series (12 000
rows) a thermal drift of the robot's geometry and two tracker scales of the air temperature were named together, the
model fitting at 0.08 mm and the robot as served 183 mm off (each large, their difference small). Such a pair is
told by the calibration rows themselves: their residuals with the measurement side's effects taken out (the model as
served) are worse than the geometric model's. The robot-side effect that moves the points most is then dropped
(:func:`robocal.discovery.grow.held_out_check`), until the served model is not worse than the geometry."""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.discovery.session_cv import session_own
from robocal.metrics import ErrorStats


def _contribution_mm(fit: Any, sl: slice) -> np.ndarray | None:
    """An effect's displacement of the fitted points (first order, mm, ``(M,)`` whitened rows unweighted): its
    Jacobian columns times its estimates; None when none of its parameters is free."""
    pos = [i for i, p in enumerate(fit.free) if sl.start <= int(p) < sl.stop]
    if not pos:
        return None
    J = fit.jacobian_columns(np.asarray(pos))[: fit.M]
    return np.asarray(J @ fit.theta[fit.free[pos]]) / fit.weights


def _rms_mm(r: np.ndarray, d: int) -> float:
    return ErrorStats.of(r.reshape(-1, d)[:, :3]).rms_mm


def served_conflict(fit: Any, geometric_rms_mm: float | None) -> tuple[str | None, dict[str, float]]:
    """The robot-side effect to drop when the model as served (the measurement side's effects taken out of the fit's
    residuals) is worse on the calibration rows than the geometric model (``geometric_rms_mm``), with the figures:
    ``(key or None, {"served_rms_mm", "fit_rms_mm", "geometric_rms_mm"})``."""
    model = fit.model
    tracker = [(a, sl) for a, sl in zip(model.accepted, model.slices, strict=True) if a.cand.shape == "tracker"]
    if not tracker or geometric_rms_mm is None:
        return None, {}
    r = (fit.r_w[: fit.M] / fit.weights).copy()
    for _a, sl in tracker:  # r(θ) is linear in a scale's coefficients: taken out exactly
        c = _contribution_mm(fit, sl)
        if c is not None:
            r -= c
    served = _rms_mm(r, fit.d)
    figures = {"served_rms_mm": served, "fit_rms_mm": fit.rms_mm, "geometric_rms_mm": float(geometric_rms_mm)}
    if not served > geometric_rms_mm:
        return None, figures
    size: dict[str, float] = {}
    for a, sl in zip(model.accepted, model.slices, strict=True):
        if a.cand.shape == "tracker" or session_own(a.cand):
            continue
        c = _contribution_mm(fit, sl)
        if c is not None:
            size[a.cand.key] = _rms_mm(c, fit.d)
    return (max(size, key=lambda k: size[k]) if size else None), figures


__all__ = ["served_conflict"]
