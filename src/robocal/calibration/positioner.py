"""Identification of a positioner's axes together with the arm (issue 34): the part carried by a turntable.

A positioner (``positioner:`` in the robot description, :class:`robocal.robot.Positioner`) carries the part; the
rows of the reflectors on the part (its ``targets``) measure ``tracker_T_base · P(q_pos) · w``
(:mod:`robocal.kinematics.positioner`: each axis line's four errors; ``w`` the
reflector on the part), at the angles of the campaign's ``pos<j>_deg`` columns; the other rows measure the tool
as for any arm. :func:`fit_positioner` starts from the arm's calibration on its own rows (what ``robocal
calibrate`` fits) and refits, jointly, the arm's identified parameters (the tracker frame is shared), the
positioner's errors and the part points, by Gauss-Newton on the positions weighted by the point noise; standard
errors from the covariance at the estimated noise (as the calibration's). The axis lines are reported in the
robot base frame (direction and the point nearest the base origin), with the held-out error of the validation
rows of the part.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robocal.calibration.config import point_sigma
from robocal.calibration.result import CalibrationResult
from robocal.calibration.start import fit_data
from robocal.data.campaign import Campaign
from robocal.errors import ConfigError
from robocal.identification.model import FitData
from robocal.kinematics.positioner import parameter_names, part_frames, part_points
from robocal.metrics import ErrorStats, noise_floor

#: finite-difference step of the numerical Jacobian (mm or rad; the parameters are small errors)
STEP = 1e-6


def part_rows(campaign: Campaign, robot: Any) -> np.ndarray:
    """(m,) bool: the rows that measure a reflector on the positioner's part."""
    pos = robot.positioner
    return np.zeros(campaign.n_rows, dtype=bool) if pos is None else np.isin(campaign.target.astype(str), pos.targets)


def positioner_angles(campaign: Campaign, robot: Any) -> np.ndarray:
    """The positioner's angles (m, k) rad of the campaign's rows (columns ``pos<j>_deg``); a ConfigError naming the
    file and column when one is missing or not a number."""
    pos = robot.positioner
    assert pos is not None
    out = np.zeros((campaign.n_rows, pos.n_axes))
    for j, col in enumerate(pos.columns):
        if col not in campaign.extra:
            raise ConfigError(
                f"{campaign.poses_file}: robot {robot.name!r} has a positioner: column {col!r} (its axis "
                f"{pos.names[j]}, deg) is missing"
            )
        v = np.asarray(campaign.extra[col], dtype=float)
        bad = np.flatnonzero(~np.isfinite(v))
        if len(bad):
            raise ConfigError(f"{campaign.poses_file}, row {int(campaign.row_number[bad[0]])}, column {col!r}: not a "
                              "number")  # fmt: skip
        out[:, j] = np.deg2rad(v)
    return out


@dataclass(frozen=True)
class PositionerFit:
    """The identified positioner (:func:`fit_positioner`).

    names / value / stderr : the positioner's parameters (:func:`robocal.kinematics.positioner.parameter_names`;
    mm, rad) then the part points (``W1_x`` ..., mm on the part); x : the arm's calibration vector refitted with
    them; axes : per axis its identified direction ``w`` and point ``p_mm`` (the point nearest the base origin) in
    the robot base frame, with the tilt's and the shift's standard errors; validation : held-out errors (mm) of
    the part's validation rows; rms_mm : the fit's RMS over the part's rows; sigma_hat : the noise scale.
    """

    names: tuple[str, ...]
    value: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    x: np.ndarray
    axes: tuple[dict[str, Any], ...]
    validation: dict[str, Any] = field(default_factory=dict)
    rms_mm: float = float("nan")
    sigma_hat: float = float("nan")
    #: the axis lines in the tracker frame (direction, origin per axis: (6 k,)) and their covariance
    tracker_lines: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tracker_lines_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def get(self, name: str) -> float:
        return float(self.value[self.names.index(name)])

    def error(self, name: str) -> float:
        return float(self.stderr[self.names.index(name)])

    def record(self) -> dict[str, Any]:
        """JSON: the parameters (mm; rotations in deg), the axes in the base frame, the validation."""
        rot = [not (n.endswith(("_tx", "_ty")) or n[-2:] in ("_x", "_y", "_z")) for n in self.names]
        scale = np.where(rot, np.rad2deg(1.0), 1.0)
        return {
            "parameters": [
                {"name": n, "value": float(v), "stderr": float(e), "unit": "deg" if r else "mm"}
                for n, v, e, r in zip(self.names, self.value * scale, self.stderr * scale, rot, strict=True)
            ],
            "axes": [dict(a) for a in self.axes],
            "validation": dict(self.validation),
            "rms_position_mm": self.rms_mm,
            "x": [float(v) for v in self.x],
        }


@dataclass
class _Part:
    """The part's rows: angles (m, k), measured points (m, 3), target index into the part targets, sigma (m,)."""

    q: np.ndarray
    p: np.ndarray
    target: np.ndarray
    sigma: np.ndarray


def _part(campaign: Campaign, robot: Any, config: Any) -> _Part:
    pos = robot.positioner
    return _Part(
        q=positioner_angles(campaign, robot),
        p=np.asarray(campaign.p_mm, dtype=float),
        target=np.array([pos.targets.index(t) for t in campaign.target.astype(str)], dtype=int),
        sigma=point_sigma(campaign, config),
    )


def _predict(model: Any, robot: Any, x: np.ndarray, theta: np.ndarray, W: np.ndarray, part: _Part) -> np.ndarray:
    """The part's reflectors (m, 3) in the tracker frame."""
    T = model.base_transform(x)
    pb = part_points(robot.positioner, part.q, theta, W[part.target])
    return pb @ T[:3, :3].T + T[:3, 3]


def _start_points(model: Any, robot: Any, x: np.ndarray, part: _Part, n_targets: int) -> np.ndarray:
    """The part points (K, 3) the nominal positioner puts nearest the measurements: the mean of each target's
    measurements taken back to the part."""
    T = model.base_transform(x)
    P = part_frames(robot.positioner, part.q, np.zeros(len(parameter_names(robot.positioner))))
    pb = (part.p - T[:3, 3]) @ T[:3, :3]
    local = np.einsum("mji,mj->mi", P[:, :3, :3], pb - P[:, :3, 3])
    W = np.zeros((n_targets, 3))
    for k in range(n_targets):
        if not np.any(part.target == k):
            raise ConfigError(f"the positioner's target {robot.positioner.targets[k]!r} has no calibration row")
        W[k] = local[part.target == k].mean(axis=0)
    return W


def fit_positioner(campaign: Campaign, base: CalibrationResult, max_iter: int = 30) -> PositionerFit:
    """Identify the positioner of ``base``'s robot on ``campaign`` (module docstring): ``base`` is the arm's
    calibration on the campaign's other rows (those of the tool). Raises :class:`ConfigError` when the robot has no
    positioner or the campaign no calibration row of the part."""
    robot = base.model.robot
    pos = robot.positioner
    if pos is None:
        raise ConfigError(f"robot {robot.name!r} has no positioner (a 'positioner' block in its description)")
    model = base.model
    on_part = part_rows(campaign, robot)
    split = campaign.split.astype(str)
    cal_rows = split != "validation"
    arm = campaign.subset(~on_part & cal_rows)
    if base.start is not None and len(base.start.kept) == arm.n_rows:
        arm = arm.subset(base.start.kept)
    part_camp = campaign.subset(on_part & cal_rows)
    if part_camp.n_rows == 0:
        raise ConfigError(f"{campaign.poses_file}: no calibration row measures the positioner's part {pos.targets}")
    if part_camp.station is not None and len(set(part_camp.station.astype(str))) > 1:
        raise ConfigError(f"{campaign.poses_file}: the part's rows are measured from one tracker station only")
    data = fit_data(arm, False, model.target_names, model.station_names)
    data = FitData(data.q, data.p_mm, data.target_index, None, data.station_index)
    w_arm = np.repeat(1.0 / point_sigma(arm, base.config), 3)
    part = _part(part_camp, robot, base.config)
    w_part = np.repeat(1.0 / part.sigma, 3)
    names = parameter_names(pos)
    K = len(pos.targets)
    free = np.flatnonzero(base.identified)
    x = base.x.copy()
    theta = np.zeros(len(names))
    W = _start_points(model, robot, x, part, K)
    nf, nt = len(free), len(names)
    n_all = nf + nt + 3 * K
    N = np.eye(n_all)
    for _ in range(max_iter):
        r_a, J_a = model.residuals_and_jacobian(x, data)
        r_a, J_a = r_a[: 3 * data.m], J_a[: 3 * data.m][:, free]
        r_p = (_predict(model, robot, x, theta, W, part) - part.p).ravel()
        J_p = _part_jacobian(model, robot, x, theta, W, part, free)
        A = np.vstack([np.hstack([J_a, np.zeros((len(r_a), nt + 3 * K))]), J_p])
        w = np.concatenate([w_arm, w_part])
        b = np.concatenate([r_a, r_p]) * w
        A = A * w[:, None]
        N = A.T @ A
        step = _solve(N, A.T @ b)
        x[free] -= step[:nf]
        theta -= step[nf : nf + nt]
        W -= step[nf + nt :].reshape(K, 3)
        if np.abs(step).max() < 1e-10:
            break
    r_a, _ = model.residuals_and_jacobian(x, data)
    r_p = _predict(model, robot, x, theta, W, part) - part.p
    rss = float(np.sum((r_a[: 3 * data.m] * w_arm) ** 2) + np.sum((r_p.ravel() * w_part) ** 2))
    dof = max(3 * (data.m + len(part.p)) - n_all, 1)
    sigma_hat = float(np.sqrt(rss / dof))
    cov_all = np.linalg.pinv(N) * max(sigma_hat, 1.0) ** 2
    cov = cov_all[nf:, nf:]
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    lines_cov = _lines_covariance(model, pos, x, theta, free, cov_all[: nf + nt, : nf + nt])
    value = np.concatenate([theta, W.ravel()])
    all_names = (*names, *(f"{t}_{c}" for t in pos.targets for c in "xyz"))
    return PositionerFit(
        names=all_names,
        value=value,
        stderr=se,
        covariance=cov,
        x=x,
        axes=tuple(_axes(pos, theta, se[:nt])),
        validation=_validation(campaign, robot, model, x, theta, W, base, on_part),
        rms_mm=ErrorStats.of(r_p).rms_mm,
        sigma_hat=sigma_hat,
        tracker_lines=_lines(model, pos, x, theta),
        tracker_lines_cov=lines_cov,
    )


def _lines(model: Any, pos: Any, x: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """The axis lines in the tracker frame at positioner angles 0: per axis its direction and its origin (the
    nominal frame's, moved by the errors), ``(6 k,)``."""
    T = model.base_transform(x)
    out = []
    for j in range(pos.n_axes):
        F = _axis_frame(pos, theta, j)
        out += [T[:3, :3] @ F[:3, 2], T[:3, :3] @ F[:3, 3] + T[:3, 3]]
    return np.concatenate(out)


def _axis_frame(pos: Any, theta: np.ndarray, j: int) -> np.ndarray:
    """The frame of axis ``j`` in the robot base frame at positioner angles 0 (errors ``theta``)."""
    sub = type(pos)(pos.names[: j + 1], pos.w[: j + 1], pos.p_mm[: j + 1], pos.q_limits[: j + 1], pos.targets)
    return part_frames(sub, np.zeros((1, j + 1)), theta[: 4 * (j + 1)])[0]


def line_distance(fit: PositionerFit, j: int, w_true: np.ndarray, p_true: np.ndarray) -> tuple[np.ndarray, float]:
    """How far axis ``j`` of ``fit`` is from a line (tracker frame: direction ``w_true``, a point ``p_true``): the
    tilt (2, rad) and the shift (2, mm) across the true line, as ``(d (4,), chi2)`` with ``chi2`` the squared
    Mahalanobis distance under the fit's covariance (4 degrees of freedom)."""
    w_t = np.asarray(w_true, dtype=float) / np.linalg.norm(w_true)
    e1 = np.cross(w_t, [1.0, 0.0, 0.0] if abs(w_t[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(w_t, e1)
    E = np.stack([e1, e2])

    def measure(line: np.ndarray) -> np.ndarray:
        w, o = line[6 * j : 6 * j + 3], line[6 * j + 3 : 6 * j + 6]
        w = w / np.linalg.norm(w)
        # the estimated line's point in the plane through p_true across the true line
        s = ((p_true - o) @ w_t) / (w @ w_t)
        return np.concatenate([E @ w, E @ (o + s * w - p_true)])

    d = measure(fit.tracker_lines)
    H = np.zeros((4, len(fit.tracker_lines)))
    for c in range(len(fit.tracker_lines)):
        dl = np.zeros(len(fit.tracker_lines))
        dl[c] = STEP
        H[:, c] = (measure(fit.tracker_lines + dl) - measure(fit.tracker_lines - dl)) / (2 * STEP)
    C = H @ fit.tracker_lines_cov @ H.T
    return d, float(d @ np.linalg.solve(C, d))


def _part_jacobian(
    model: Any, robot: Any, x: np.ndarray, theta: np.ndarray, W: np.ndarray, part: _Part, free: np.ndarray
) -> np.ndarray:
    """The part's residuals' Jacobian ``(3 m, free + positioner + 3 K)``: the arm's identified parameters (through
    the tracker frame only) and the positioner's errors by central differences, the part points exactly."""
    pos = robot.positioner
    nf, nt, K = len(free), len(theta), len(W)
    J = np.zeros((3 * len(part.p), nf + nt + 3 * K))
    for c in range(nf + nt):
        dx, dt = np.zeros_like(x), np.zeros(nt)
        if c < nf:
            dx[free[c]] = STEP
        else:
            dt[c - nf] = STEP
        d = _predict(model, robot, x + dx, theta + dt, W, part) - _predict(model, robot, x - dx, theta - dt, W, part)
        J[:, c] = d.ravel() / (2 * STEP)
    T = model.base_transform(x)
    RP = np.einsum("ij,mjk->mik", T[:3, :3], part_frames(pos, part.q, theta)[:, :3, :3])  # d p / d w
    for k in range(K):
        rows = np.flatnonzero(part.target == k)
        for c in range(3):
            J[(3 * rows[:, None] + np.arange(3)).ravel(), nf + nt + 3 * k + c] = RP[rows, :, c].ravel()
    return J


def _lines_covariance(
    model: Any, pos: Any, x: np.ndarray, theta: np.ndarray, free: np.ndarray, cov: np.ndarray
) -> np.ndarray:
    """The covariance of the axis lines in the tracker frame (what the part's rows see directly; :func:`_lines`)
    from ``cov`` of the arm's identified parameters and the positioner's errors (the tracker frame is the arm's)."""
    nf, nt = len(free), len(theta)
    G = np.zeros((6 * pos.n_axes, nf + nt))
    for c in range(nf + nt):
        dx, dt = np.zeros_like(x), np.zeros(nt)
        if c < nf:
            dx[free[c]] = STEP
        else:
            dt[c - nf] = STEP
        G[:, c] = (_lines(model, pos, x + dx, theta + dt) - _lines(model, pos, x - dx, theta - dt)) / (2 * STEP)
    return G @ cov @ G.T


def _solve(N: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``N⁻¹ g`` scaled to a unit diagonal (mm and rad mixed)."""
    d = np.sqrt(np.maximum(np.diag(N), 1e-300))
    return np.linalg.lstsq(N / np.outer(d, d), g / d, rcond=1e-12)[0] / d


def _axes(pos: Any, theta: np.ndarray, se: np.ndarray) -> list[dict[str, Any]]:
    """Each axis line identified, in the robot base frame at positioner angles 0: its direction, its point nearest
    the base origin, and the standard errors of its tilt (deg) and shift (mm)."""
    out = []
    k = 0
    for j, name in enumerate(pos.names):
        F = _axis_frame(pos, theta, j)
        w, o = F[:3, 2], F[:3, 3]
        p = o - w * (o @ w)
        out.append({
            "name": name,
            "w": [round(float(v), 9) for v in w],
            "p_mm": [round(float(v), 6) for v in p],
            "tilt_stderr_deg": float(np.rad2deg(np.hypot(se[k + 2], se[k + 3]))),
            "shift_stderr_mm": float(np.hypot(se[k], se[k + 1])),
        })  # fmt: skip
        k += 4
    return out


def _validation(
    campaign: Campaign,
    robot: Any,
    model: Any,
    x: np.ndarray,
    theta: np.ndarray,
    W: np.ndarray,
    base: CalibrationResult,
    on_part: np.ndarray,
) -> dict[str, Any]:
    """Held-out errors (mm) of the part's validation rows, and the noise floor of their mean."""
    val = campaign.subset(on_part & (campaign.split.astype(str) == "validation"))
    if val.n_rows == 0:
        return {"n_rows": 0}
    part = _part(val, robot, base.config)
    e = np.linalg.norm(_predict(model, robot, x, theta, W, part) - part.p, axis=1)
    return {
        "n_rows": int(val.n_rows),
        "mean_position_mm": float(e.mean()),
        "max_position_mm": float(e.max()),
        "noise_floor_mean_mm": float(noise_floor(part.sigma, 3 * val.n_rows, 0, "mean")),
    }
