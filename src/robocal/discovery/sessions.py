"""A calibration judged on another session: the same robot measured another day, from another tracker
placement, in another part of its workspace (issue 33 item 2).

A plant calibrates once and runs for months; the tracker that measured the calibration is gone or moved. What
carries over is the robot's model (geometry, tool, joint-level effects), not the tracker's frame: so the other
session's tracker is registered to the model's predictions on that session's own calibration rows (a rigid
fit, six parameters, the model frozen), and the model is judged on the session's validation rows. With every
joint-level effect taken out in turn, the same evaluation says which effects helped there and which hurt.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.compensation.discovered import joint_offsets
from robocal.compensation.signals import coverage_weight
from robocal.data.contract import Campaign
from robocal.discovery.physics import configurations, visited_intervals
from robocal.errors import DataError
from robocal.kinematics.chain import fk
from robocal.kinematics.transforms import kabsch
from robocal.metrics import ErrorStats
from robocal.robot import RobotDescription

#: an effect whose removal moves the other session's mean error by less than this (mm) neither helped nor hurt
SAME_ERROR_MM = 1e-4


#: a thermal model is not offered when less than this share of the temperatures' variance is within the sessions
#: (one temperature a session: the model would be each session's own geometry, as the pipeline's thermal stage
#: refuses two temperature states)
THERMAL_WITHIN_SESSIONS = 0.05


def temperature_share_within_sessions(campaign: Campaign, T: np.ndarray) -> float | None:
    """The share of the temperatures' ``T (m, s)`` variance within the campaign's sessions (tracker stations); None
    with fewer than two."""
    if not campaign.has_stations:
        return None
    st = np.asarray(campaign.station).astype(str)
    names = np.unique(st)
    if len(names) < 2:
        return None
    total = float(np.sum((T - T.mean(axis=0)) ** 2))
    within = sum(float(np.sum((T[st == s] - T[st == s].mean(axis=0)) ** 2)) for s in names)
    return within / total if total > 0 else None


def predicted_flanges(
    cal: CalibrationResult, campaign: Campaign, records: tuple[dict[str, Any], ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The flange poses the model predicts for every row of ``campaign`` in the robot's base frame (m, 4, 4), the
    joint-level effects ``records`` (a subset of ``cal.effects``) added to the joint angles (evaluated exactly,
    not from the service's tables), and each row's tool offset (m, 3) mm from the calibration."""
    model = cal.model
    tools = cal.tools
    unknown = sorted(set(campaign.target.astype(str).tolist()) - set(tools))
    if unknown:
        raise DataError(
            f"campaign {campaign.source}: target(s) {unknown} are not in the calibration (its targets: {sorted(tools)})"
        )
    q = np.asarray(campaign.q, dtype=float)
    if records:
        pay = np.broadcast_to(np.asarray(campaign.payload_kg, dtype=float), (campaign.n_rows,))
        signals = dict(tau_Nm=campaign.tau_Nm, current_A=campaign.current_A, direction=campaign.direction)
        q = q + joint_offsets(list(records), model.robot, q, pay, **signals, logged=campaign.extra)
    return fk(model.chain, q, cal.kinematic_errors), np.stack([tools[str(t)] for t in campaign.target])


def predicted_points(cal: CalibrationResult, campaign: Campaign, records: tuple[dict[str, Any], ...]) -> np.ndarray:
    """The target points the model predicts for every row of ``campaign`` in the robot's base frame (m, 3) mm
    (:func:`predicted_flanges` with each row's tool offset)."""
    T, off = predicted_flanges(cal, campaign, records)
    return np.einsum("mij,mj->mi", T[:, :3, :3], off) + T[:, :3, 3]


#: Alternations of tracker registration (Kabsch) and tool offsets (linear least squares) when a new session
#: re-measures the tool too: the rigid fit's start, as calibrate's registration_iters
TOOL_ITERS = 30


def _register(
    T: np.ndarray, off: np.ndarray, targets: np.ndarray, meas: np.ndarray, reg: np.ndarray, tool: bool
) -> tuple[np.ndarray, np.ndarray]:
    """The tracker frame (4, 4) and, with ``tool``, each target's offset re-measured on the rows ``reg``: the
    transform and offsets (m, 3) that bring the model's predictions onto the measured points."""
    off = off.copy()

    def frame() -> np.ndarray:
        pts = np.einsum("mij,mj->mi", T[:, :3, :3], off) + T[:, :3, 3]
        return kabsch(pts[reg], meas[reg])

    X = frame()
    for _ in range(TOOL_ITERS if tool else 0):
        for t in np.unique(targets[reg]):
            rows = reg & (targets == t)
            A = np.einsum("ij,mjk->mik", X[:3, :3], T[rows, :3, :3]).reshape(-1, 3)
            b = (meas[rows] - X[:3, 3] - T[rows, :3, 3] @ X[:3, :3].T).reshape(-1)
            off[targets == t] = np.linalg.lstsq(A, b, rcond=None)[0]
        X = frame()
    return X, off


def _judge(
    cal: CalibrationResult,
    campaign: Campaign,
    records: tuple[dict[str, Any], ...],
    reg: np.ndarray,
    val: np.ndarray,
    tool: bool,
    rows: bool = False,
) -> Any:
    """The model's errors on the rows ``val`` with the tracker (and with ``tool`` the tools) registered on ``reg``:
    their :class:`ErrorStats`, with ``rows`` also each row's 3-D error (mm)."""
    T, off0 = predicted_flanges(cal, campaign, records)
    meas = np.asarray(campaign.p_mm, dtype=float)
    targets = np.asarray(campaign.target).astype(str)
    st = _stations(campaign)
    e = np.zeros((campaign.n_rows, 3))
    for s in dict.fromkeys(st[val].tolist()):  # each tracker placement of the session registered on its own rows
        on = st == s
        X, off = _register(T, off0, targets, meas, reg & on, tool)
        v = val & on
        pts = np.einsum("mij,mj->mi", T[v, :3, :3], off[v]) + T[v, :3, 3]
        e[v] = pts @ X[:3, :3].T + X[:3, 3] - meas[v]
    e = e[val]
    return (ErrorStats.of(e), np.linalg.norm(e, axis=1)) if rows else ErrorStats.of(e)


def _stations(campaign: Campaign) -> np.ndarray:
    """Each row's tracker station (one label for a campaign without a ``station`` column)."""
    return np.full(campaign.n_rows, "") if campaign.station is None else np.asarray(campaign.station).astype(str)


#: visits of a joint closer than this (deg) make one calibrated interval; a row within COVERAGE_TOL_DEG (deg, or mm
#: for a prismatic joint) of a calibrated interval is inside it: the calibration has seen that joint there
COVERAGE_GAP_DEG = 30.0
COVERAGE_TOL_DEG = 5.0
#: and an interval counts only when it holds this many configurations: one or two poses far from the others are
#: not a calibrated range (a newcomer's probe at q3 = 62 deg, where one of 2 500 calibration rows lay, was "inside")
COVERAGE_MIN_VISITS = 3


def outside_calibrated(q_cal: np.ndarray, q: np.ndarray, prismatic: np.ndarray | None = None) -> np.ndarray:
    """``(m, n)`` bool: where each row of ``q`` (rad; mm for a prismatic joint) lies outside the joint angles the
    calibration rows ``q_cal`` visited (modulo one revolution, visits closer than :data:`COVERAGE_GAP_DEG` joined,
    :data:`COVERAGE_TOL_DEG` of tolerance, an interval of fewer than :data:`COVERAGE_MIN_VISITS` configurations
    not counted)."""
    q_cal, q = np.asarray(q_cal, dtype=float), np.asarray(q, dtype=float)
    out = np.zeros(q.shape, dtype=bool)
    conf = configurations(q_cal)  # the visits an interval counts: one per configuration
    for j in range(q.shape[1]):
        if prismatic is not None and prismatic[j]:
            out[:, j] = (q[:, j] < q_cal[:, j].min() - COVERAGE_TOL_DEG) | (
                q[:, j] > q_cal[:, j].max() + COVERAGE_TOL_DEG
            )
            continue
        iv = visited_intervals(conf[:, j], COVERAGE_GAP_DEG, COVERAGE_MIN_VISITS)
        # the raised cosine over twice the tolerance is at 1/2 exactly at the tolerance's distance
        out[:, j] = coverage_weight(q[:, j], iv, 2.0 * COVERAGE_TOL_DEG) < 0.5
    return out


def _coverage(
    q_cal: np.ndarray, campaign: Campaign, val: np.ndarray, e: np.ndarray, robot: RobotDescription
) -> dict[str, Any]:
    """Where the judged rows lie against the joint angles the calibration visited, and the errors inside and
    outside them."""
    out = outside_calibrated(q_cal, campaign.q[val], robot.prismatic)
    any_out = out.any(axis=1)
    return {
        "n_judged": int(val.sum()),
        "n_outside": int(any_out.sum()),
        "outside_per_joint": {f"j{j + 1}": int(out[:, j].sum()) for j in range(out.shape[1])},
        "inside": ErrorStats.of(e[~any_out]).to_dict() if (~any_out).any() else None,
        "outside": ErrorStats.of(e[any_out]).to_dict() if any_out.any() else None,
        "tolerance_deg": COVERAGE_TOL_DEG,
    }


def session_validation(
    cal: CalibrationResult,
    campaign: Campaign,
    geometric: CalibrationResult | None = None,
    tool: bool = False,
    calibrated_q: np.ndarray | None = None,
) -> dict:
    """``cal`` (a calibration, with or without discovered effects) on another session ``campaign``: the tracker
    registered on the session's calibration rows (a rigid fit to the model's predictions; with ``tool`` the
    tool offsets re-measured too, as after a re-seated tool), errors on its validation rows (or, without a
    split, on every row: then the figure is a fit, and said so). The robot's model stays as calibrated.

    Returns ``{"n_registration_rows", "n_validation_rows", "final": stats, "geometric": stats (when given),
    "without": {effect key: stats with that effect left out}, "helped": [...], "hurt": [...]}`` and, with
    ``geometric`` and effects, ``"geometry_alone"``: the model's own geometry with every effect off (and its mean
    against the geometric calibration's, ``versus_geometric_mm``: positive, the geometry refitted with the effects
    is worse there); stats are
    :class:`ErrorStats` dicts in mm. With ``calibrated_q`` (the calibration rows' joints, rad) also
    ``"coverage"``: how many judged rows lie outside the joint angles the calibration visited (per joint) and the
    final model's errors inside and outside them — a new session there is an extrapolation."""
    split = np.asarray(campaign.split).astype(str)
    reg = split == "calibration"
    val = split == "validation"
    note = None
    if not val.any():
        reg = val = np.ones(campaign.n_rows, dtype=bool)
        note = "the session has no validation rows: registered and judged on the same rows (a fit, not held out)"
    if int(reg.sum()) < 3:
        raise DataError(
            f"campaign {campaign.source}: {int(reg.sum())} calibration row(s); registering a tracker needs >= 3"
        )
    # a session of several tracker placements (a station column): each registered on its own calibration rows
    # (one frame for all of them put a two-station session metres off); a station with fewer than 3 is not judged
    st = _stations(campaign)
    small = sorted(s for s in set(st[val].tolist()) if int(np.count_nonzero(reg & (st == s))) < 3)
    if small:
        val = val & ~np.isin(st, small)
        if not val.any():
            raise DataError(f"campaign {campaign.source}: no station has >= 3 calibration rows to register it")
    # an effect of a logged signal the session did not log cannot be applied there: left out, and said so
    logged = [e.get("signal") == "logged" and str(e["column"]) not in campaign.extra for e in cal.effects]
    missing = [e for e, lost in zip(cal.effects, logged, strict=True) if lost]
    records = tuple(e for e, lost in zip(cal.effects, logged, strict=True) if not lost)
    final, err = _judge(cal, campaign, records, reg, val, tool, rows=True)
    out: dict[str, Any] = {
        "registered": "tracker and tool" if tool else "tracker",
        "n_registration_rows": int(reg.sum()),
        "n_validation_rows": int(val.sum()),
        "final": final.to_dict(),
    }
    if note:
        out["note"] = note
    n_st = len(set(st.tolist()))
    if n_st > 1:
        out["stations"] = f"each of the session's {n_st} stations registered on its own rows"
    if small:
        out["stations_not_judged"] = {s: "fewer than 3 calibration rows to register it" for s in small}
    if missing:
        out["not_applied"] = {str(e["key"]): f"the session has no column '{e['column']}'" for e in missing}
    if calibrated_q is not None:
        out["coverage"] = _coverage(calibrated_q, campaign, val, err, cal.model.robot)
    if geometric is not None:
        out["geometric"] = _judge(geometric, campaign, (), reg, val, tool).to_dict()
    without: dict[str, Any] = {}
    for k, rec in enumerate(records):
        rest = records[:k] + records[k + 1 :]
        without[str(rec["key"])] = _judge(cal, campaign, rest, reg, val, tool).to_dict()
    out["without"] = without
    if records and geometric is not None:
        # the discovered geometry with every effect off, beside the geometric calibration's: what the geometry
        # refitted with the effects costs or gains there (a newcomer's probe outside the visited angles: 0.264 mm
        # discovered, 0.150 geometric, and every effect "helped": the geometry refitted jointly was the loss)
        alone = _judge(cal, campaign, (), reg, val, tool).to_dict()
        g = out["geometric"]["mean_position_mm"]
        out["geometry_alone"] = {**alone, "versus_geometric_mm": alone["mean_position_mm"] - g}
    m = final.mean_mm
    # a change below SAME_ERROR_MM (the figures' last printed digit) is neither: round-off is not evidence
    out["helped"] = sorted(k for k, s in without.items() if s["mean_position_mm"] > m + SAME_ERROR_MM)
    out["hurt"] = sorted(k for k, s in without.items() if s["mean_position_mm"] < m - SAME_ERROR_MM)
    return out


__all__ = ["outside_calibrated", "predicted_flanges", "predicted_points", "session_validation"]
