"""Validation of thermal compensation on a second warm-up (Guo et al. 2026, section 3.5, table 5, fig. 12).

Every validation row (a pose measured at some moment of the second warm-up, with the temperatures read then) is
predicted by the reference-state geometric calibration plus the drift each method's thermal model gives at those
temperatures. The prediction error is the error left after a compensation with that model (the controller
would be sent the command that makes the *modelled* robot reach the target; what remains is model error plus
measurement noise). Methods: ``none`` (geometric calibration only), ``traditional`` (linear expansion of the
non-zero a and d, the paper's ref. [29]), ``proposed`` (the screened parameters), ``all`` (every identifiable
parameter), and ``oracle`` (the twin's true parameters and drift, when a truth file is given: the noise floor).

With a truth file the compensation is also closed on the twin: corrected joints from
:func:`robocal.thermal.compensate.compensate_targets` at the state's temperature reading are sent to the true
robot, whose pose is compared with the target (no tracker noise: the error the compensation leaves).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.compensation import desired_poses
from robocal.compensation.safety import SafetyPolicy
from robocal.kinematics.transforms import matrix_to_rotvec, quat_to_matrix
from robocal.metrics import ErrorStats, orientation_errors_deg
from robocal.thermal.compensate import compensate_targets, nominal_robot, true_robot
from robocal.thermal.model import ThermalModel

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign

METHODS = ("none", "traditional", "proposed", "all")


def reorder(temperatures: np.ndarray, have: tuple[str, ...], want: tuple[str, ...]) -> np.ndarray:
    """Temperature columns ``have`` -> ``want`` order (every wanted sensor must be present)."""
    missing = [s for s in want if s not in have]
    if missing:
        from robocal.errors import DataError

        raise DataError(f"the campaign lacks the sensor column(s) {missing} the thermal model uses")
    return np.asarray(temperatures)[:, [have.index(s) for s in want]]


def predict(
    result: CalibrationResult, q: np.ndarray, targets: np.ndarray, deta: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted positions ``(m, 3)`` and rotations ``(m, 3, 3)`` with per-row drift ``deta (m, P)``."""
    model = result.model
    P = model.chain.n_params
    ti = np.array([model.target_names.index(str(t)) for t in targets], dtype=int)
    p = np.zeros((len(q), 3))
    R = np.zeros((len(q), 3, 3))
    keys, inv = np.unique(np.round(deta, 14), axis=0, return_inverse=True)
    inv = inv.ravel()
    for g in range(len(keys)):
        sel = inv == g
        x = result.x.copy()
        x[:P] += deta[np.flatnonzero(sel)[0]]
        p[sel], R[sel] = model.predict(x, q[sel], ti[sel])
    return p, R


def _truth_predict(
    truth: Mapping[str, Any], chain: Any, q: np.ndarray, targets: np.ndarray, deta: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    p = np.zeros((len(q), 3))
    R = np.zeros((len(q), 3, 3))
    for i in range(len(q)):
        act = true_robot(dict(truth), chain, str(targets[i]), deta[i])
        pi, Ri, _ = act.pose(q[i : i + 1])
        p[i], R[i] = pi[0], Ri[0]
    return p, R


def _stats(e_pos: np.ndarray, e_deg: np.ndarray | None) -> dict[str, float]:
    """Mean / max / RMS of the position errors and mean / max of the orientation errors (NaN with no rows:
    e.g. every target refused by the compensation)."""
    st = ErrorStats.of(e_pos, e_deg)
    return {**st.position(("mean", "max", "rms")), **st.orientation(("mean", "max"))}


def evaluate(
    result: CalibrationResult,
    val: Campaign,
    state: np.ndarray,
    models: Mapping[str, ThermalModel | None],
    truth: Mapping[str, Any] | None = None,
    at_min: float = 90.0,
    limits: SafetyPolicy | None = None,
) -> dict[str, Any]:
    """Errors of every method on the validation warm-up ``val`` (rows with temperatures), see the module doc.

    state : (m,) state numbers of ``val`` (0 = cold). Returns ``{"table": {method: stats}, "at_state":
    {method: stats at the state nearest ``at_min`` minutes}, "per_state": {...}, "errors": {method: (m,) mm},
    "closed_loop": {...} (with truth), ...}``.
    """
    assert val.temperatures is not None
    chain = result.model.chain
    P = chain.n_params
    use_rot = val.quat is not None and result.model.orientation
    R_meas = quat_to_matrix(val.quat) if use_rot and val.quat is not None else None
    n_states = int(state.max()) + 1
    t_start = float(val.timestamp_s.min())
    t_min = np.array([(float(val.timestamp_s[state == s].min()) - t_start) / 60.0 for s in range(n_states)])
    k_at = int(np.argmin(np.abs(t_min - at_min)))
    drifts: dict[str, np.ndarray] = {}
    for name, model in models.items():
        if model is None:
            drifts[name] = np.zeros((val.n_rows, P))
        else:
            drifts[name] = model.deta(reorder(val.temperatures, val.sensor_names, model.sensors))
    preds = {name: predict(result, val.q, val.target, d) for name, d in drifts.items()}
    if truth is not None and "thermal" in truth.get("effects", {}):
        tm = ThermalModel.from_dict(truth["effects"]["thermal"]["model"])
        d_true = tm.deta(reorder(val.temperatures, val.sensor_names, tm.sensors))
        preds["oracle"] = _truth_predict(truth, chain, val.q, val.target, d_true)
        drifts["oracle"] = d_true
    table, at_state, per_state, errors, errors_deg = {}, {}, {}, {}, {}
    for name, (p, R) in preds.items():
        e = np.linalg.norm(p - val.p_mm, axis=1)
        ed = None
        if R_meas is not None:
            ed = orientation_errors_deg(R, R_meas)
        errors[name] = e
        errors_deg[name] = ed
        table[name] = _stats(e, ed)
        at_state[name] = _stats(e[state == k_at], None if ed is None else ed[state == k_at])
        per_state[name] = [_stats(e[state == s], None if ed is None else ed[state == s]) for s in range(n_states)]
    out: dict[str, Any] = {
        "table": table,
        "at_state": at_state,
        "at_state_min": float(t_min[k_at]),
        "per_state": per_state,
        "t_min": t_min.tolist(),
        "errors": errors,
        "errors_deg": errors_deg,
        "drifts": drifts,
        "n_rows": int(val.n_rows),
        "has_orientation": bool(use_rot),
    }
    if truth is not None and "oracle" in drifts:
        out["closed_loop"] = closed_loop(result, val, state, models, truth, drifts["oracle"], use_rot, limits)
    return out


def closed_loop(
    result: CalibrationResult,
    val: Campaign,
    state: np.ndarray,
    models: Mapping[str, ThermalModel | None],
    truth: Mapping[str, Any],
    d_true: np.ndarray,
    use_rot: bool,
    limits: SafetyPolicy | None = None,
) -> dict[str, dict[str, float]]:
    """Twin only: send each method's corrected joints (at each state's mean temperature reading) to the true
    robot and measure the pose error against the target without tracker noise. Targets the safety policy refuses
    for a reason of their own (not converged, e.g. at a wrist singularity, correction above the bound; see
    :mod:`robocal.thermal.compensate`) are counted in ``n_refused`` and left out; targets refused or flagged only
    because the temperature reading extrapolates are scored with their correction and counted in
    ``n_extrapolated``."""
    assert val.temperatures is not None
    chain = result.model.chain
    out: dict[str, dict[str, float]] = {}
    for name, model in models.items():
        e_all, ed_all = [], []
        counts = {"refused": 0, "extrapolated": 0}
        for s in range(int(state.max()) + 1):
            sel = np.flatnonzero(state == s)
            T = None
            if model is not None:
                T = reorder(val.temperatures[sel], val.sensor_names, model.sensors).mean(axis=0)
            comp = compensate_targets(result, model, T, val.q[sel], val.target[sel], orientation=use_rot, limits=limits)
            for t in dict.fromkeys(val.target[sel].astype(str).tolist()):
                ts = val.target[sel].astype(str) == t
                rows = sel[ts]
                p_d, R_d = desired_poses(nominal_robot(result, t), val.q[rows])
                own = comp.target_refused[ts]
                counts["refused"] += int(np.sum(own))
                counts["extrapolated"] += int(np.sum(~own & (comp.status[ts] != "ok")))
                assert comp.q_corrected is not None
                for i, r in enumerate(rows):
                    if own[i]:  # refused (near a singularity): counted, not scored
                        continue
                    act = true_robot(dict(truth), chain, t, d_true[r])
                    p, R, _ = act.pose(comp.q_corrected[ts][i : i + 1])
                    e_all.append(float(np.linalg.norm(p[0] - p_d[i])))
                    rv = matrix_to_rotvec(R[0] @ R_d[i].T)
                    ed_all.append(float(np.rad2deg(np.linalg.norm(rv))))
        out[name] = {
            **_stats(np.array(e_all), np.array(ed_all) if use_rot else None),
            **{f"n_{k}": v for k, v in counts.items()},
        }
    return out


__all__ = ["METHODS", "closed_loop", "evaluate", "predict", "reorder"]
