"""What one step of a search records, and a candidate's regressor at the current fit: shared by the F-test
search (:mod:`robocal.discovery.search`) and the cross-validated selection (:mod:`robocal.discovery.grow`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robocal.discovery.candidates import Candidate, with_beta
from robocal.discovery.model import Fit, by_row, tracker_columns
from robocal.identification.model import CalibrationModel, FitData


@dataclass(frozen=True)
class Variant:
    """One variant of a candidate: which of its signal columns and which prior (rad per coefficient, one value or
    one per column)."""

    columns: np.ndarray | None  # None: every column (a parameter drift, whose columns depend on the fit)
    prior_rad: float | np.ndarray | None
    label: str


@dataclass
class Score:
    """The test of one candidate at one step."""

    key: str
    label: str
    status: str  # "tested" | "unidentifiable" | "accepted" | "failed cross-validation"
    absorbed_share: float
    dof: int = 0
    F: float = float("nan")
    log10_p: float = float("nan")
    delta_bic: float = float("nan")
    excess_share: float = float("nan")
    passes: bool = False
    cv_gain: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}


@dataclass
class Step:
    accepted: str | None
    label: str | None
    rms_before_mm: float
    rms_after_mm: float
    chi2_before: float
    chi2_after: float
    dof_after: int
    scores: list[Score]
    dropped: list[str] = field(default_factory=list)
    residuals_before_mm: np.ndarray | None = None
    residuals_after_mm: np.ndarray | None = None
    phase: str = ""  # which phase of the search (PHASES) took the step


#: The phases of a discovery, in order: each accepts effects one per step until it stops, then the next begins.
PHASES = {
    "library": "library F-test search",
    "selection": "cross-validated selection",
    "equations": "proposed equations",
    "held-out parametric": "held-out check of the parametric model",
    "layer": "residual layer",
    "held-out": "held-out check",
}


def regressor(cand: Candidate, fit: Fit, rows: np.ndarray, data: FitData) -> tuple[np.ndarray, tuple[str, ...]]:
    """Whitened regressor ``(M, q)`` of a candidate at the current fit, and (param shape) the parameters it drifts."""
    m = len(rows)
    w = fit.weights[:, None]
    dd = fit.d
    if cand.shape == "joint":
        assert cand.joint is not None
        Z = fit.Jq[:, :, cand.joint - 1][:, :, None] * cand.S[rows][:, None, :]
        return Z.reshape(dd * m, -1) * w, ()
    if cand.shape == "param":
        model = fit.model
        ident = {model.names[i] for i in fit.free}
        if cand.params == ("*identified*",):
            params = tuple(n for k, n in enumerate(model.base.names) if n in ident and model.base.kinds[k] != "")
        else:
            params = tuple(p for p in cand.params if p in ident)
        idx = [model.base.index(p) for p in params]
        Z = fit.Jx[:, :, idx][:, :, :, None] * cand.S[rows][:, None, None, :]
        return Z.reshape(dd * m, -1) * w, params
    if cand.shape == "tracker":
        return tracker_columns(cand, rows, dd).reshape(dd * m, -1) * w, ()
    if cand.shape == "axis":
        from robocal.discovery.axes import axis_rows

        x = fit.theta[: fit.model.nb]
        d = data.with_q(data.q + fit.model.joint_offsets(fit.theta, rows, 0))
        return axis_rows(cand, fit.model.base, x, d, rows, dd).reshape(dd * m, -1) * w, ()
    if cand.shape == "pair":  # two candidates scored together (accepted as the two)
        Zs = [regressor(c, fit, rows, data) for c in cand.extra["members"]]
        return np.hstack([z for z, _ in Zs]), tuple(p for _, prm in Zs for p in prm)
    if cand.shape == "frame":
        from robocal.discovery.logged import frame_rows

        x = fit.theta[: fit.model.nb]
        return frame_rows(cand, fit.Jx, fit.model.base, x, data.target_index, rows).reshape(dd * m, -1) * w, ()
    # structure: the beta column of the robot with that beta free, at the current parameters
    assert cand.joint is not None
    rob = with_beta(fit.model.robot, cand.joint)
    b = fit.model.base
    mod = CalibrationModel(
        rob,
        b.target_names,
        orientation=b.orientation,
        T_ref=b.T_ref,
        tool_R_ref=b.tool_R_ref,
        stations=b.station_names,
        station_T_ref=b.station_T_ref,
    )
    x = np.array(
        [dict(zip(fit.model.base.names, fit.theta[: fit.model.nb], strict=True)).get(n, 0.0) for n in mod.names]
    )
    dq = fit.model.joint_offsets(fit.theta, rows, 0)
    _, J = mod.residuals_and_jacobian(x, data.with_q(data.q + dq))
    return by_row(J[:, [mod.index(f"beta{cand.joint}")]], m, dd) * w, ()


__all__ = ["PHASES", "Score", "Step", "Variant", "regressor"]
