"""An ISO test campaign: the data contract's ``poses.csv`` plus the ISO columns, registered to the robot base.

ISO columns (beyond the contract; every problem is a :class:`robocal.errors.DataError` naming file, row and
column, as the contract's):

``iso_pose``       str   the test pose (``P1`` .. ``P5`` or any label);
``cycle``          int   the cycle number, 1 .. n;
``cmd_x_mm`` ..    mm    the commanded target position in the robot base frame (``cmd_y_mm``, ``cmd_z_mm``);
``cmd_qw`` ..      unit  the commanded orientation (``cmd_qx``, ``cmd_qy``, ``cmd_qz``), when it was commanded;
``approach``       str   optional: the approach direction's label (vAP).

A pose is commanded at one place: every row of an ``iso_pose`` has the same ``cmd_*`` (1e-4 mm, 1e-6 of the
quaternion). One row per (target, ``iso_pose``, ``approach``, ``cycle``).

Registration: the measured points (tracker frame) are taken to the robot base frame by ``tracker_T_base`` when
one is given (:mod:`robocal.iso9283.base_frame`: the axis circles), else by the calibration's (per station when the
calibration has several); orientations likewise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.data import Campaign
from robocal.errors import DataError
from robocal.iso9283.analysis import IsoTest
from robocal.kinematics.transforms import inv_transform, quat_to_matrix, rpy_from_matrix

ISO_COLUMNS = ("iso_pose", "cycle", "cmd_x_mm", "cmd_y_mm", "cmd_z_mm")
CMD_QUAT = ("cmd_qw", "cmd_qx", "cmd_qy", "cmd_qz")


@dataclass(frozen=True)
class IsoCampaign:
    """The ISO rows of one target: the test (base frame) and what the after-prediction needs.

    rows : (k,) indices into the campaign's rows; target : the target measured; T : (k, 4, 4) the
    ``base_T_tracker`` of each row; R_meas : (k, 3, 3) measured orientation in the base frame or None;
    R_cmd : (k, 3, 3) commanded orientation or None.
    """

    test: IsoTest
    campaign: Campaign
    rows: np.ndarray
    target: str
    base_T_tracker: np.ndarray
    R_meas: np.ndarray | None
    R_cmd: np.ndarray | None


def _text(camp: Campaign, col: str, rows: np.ndarray) -> np.ndarray:
    raw = np.asarray(camp.extra[col])
    out = np.array([str(v).strip() for v in raw], dtype=object)
    bad = np.flatnonzero(np.isin(out, ["", "nan", "None"]))
    bad = bad[np.isin(bad, rows)]
    if bad.size:
        raise DataError(f"missing {col} label", file=camp.poses_file, row=int(camp.row_number[bad[0]]), column=col)
    return out.astype(str)


def _number(camp: Campaign, col: str) -> np.ndarray:
    raw = np.asarray(camp.extra[col])
    out = np.full(len(raw), np.nan)
    for i, v in enumerate(raw):
        try:
            out[i] = float(str(v).strip())
        except ValueError:
            raise DataError(
                f"expected a number, got {v!r}", file=camp.poses_file, row=int(camp.row_number[i]), column=col
            ) from None
        if not np.isfinite(out[i]):
            raise DataError(
                "missing or non-finite value in a required column",
                file=camp.poses_file,
                row=int(camp.row_number[i]),
                column=col,
            )
    return out


def read_iso(
    camp: Campaign, calibration: CalibrationResult, target: str | None = None, tracker_T_base: np.ndarray | None = None
) -> IsoCampaign:
    """The ISO test of ``camp`` (one target) in the base frame registered by ``tracker_T_base`` (4, 4) when given
    (one tracker station), else by ``calibration``."""
    f = camp.poses_file
    missing = [c for c in ISO_COLUMNS if c not in camp.extra]
    if missing:
        raise DataError(
            f"missing ISO 9283 column(s) {missing} (iso_pose, cycle, cmd_x_mm, cmd_y_mm, cmd_z_mm: docs/iso9283.md)",
            file=f,
            row=1,
            column=missing[0],
        )
    present_q = [c for c in CMD_QUAT if c in camp.extra]
    if present_q and len(present_q) != 4:
        miss = [c for c in CMD_QUAT if c not in camp.extra]
        raise DataError(f"has {present_q} but not {miss}: give all four or none", file=f, row=1, column=miss[0])
    tname = target if target is not None else camp.target_names[0]
    if tname not in camp.target_names:
        raise DataError(
            f"no row of target {tname!r}; the campaign has {list(camp.target_names)}", file=f, column="target"
        )
    rows = np.flatnonzero(camp.target == tname)
    rn = camp.row_number

    pose = _text(camp, "iso_pose", rows)[rows]
    approach = _text(camp, "approach", rows)[rows] if "approach" in camp.extra else np.full(len(rows), "-", dtype=str)
    cyc_f = _number(camp, "cycle")[rows]
    bad = np.flatnonzero((cyc_f < 1) | (cyc_f != np.round(cyc_f)))
    if bad.size:
        i = rows[bad[0]]
        raise DataError(
            f"cycle must be a whole number >= 1, got {camp.extra['cycle'][i]!r}", file=f, row=int(rn[i]), column="cycle"
        )
    cycle = cyc_f.astype(int)
    cmd = np.column_stack([_number(camp, c)[rows] for c in ISO_COLUMNS[2:]])
    cq = np.column_stack([_number(camp, c)[rows] for c in CMD_QUAT]) if present_q else None
    if cq is not None:
        norm = np.linalg.norm(cq, axis=1)
        off = np.flatnonzero(np.abs(norm - 1.0) > 1e-3)
        if off.size:
            raise DataError(
                f"commanded quaternion norm {norm[off[0]]:.6g}, expected 1",
                file=f,
                row=int(rn[rows[off[0]]]),
                column="cmd_qw",
            )
        cq = cq / norm[:, None]
        cq = cq * np.where(cq[:, :1] < 0, -1.0, 1.0)  # q and -q are one orientation

    # one commanded pose per label; one row per (label, approach, cycle)
    first: dict[str, int] = {}
    seen: dict[tuple[str, str, int], int] = {}
    for k in range(len(rows)):
        lab = str(pose[k])  # labels as text in messages, not numpy's repr
        j = first.setdefault(lab, k)
        dif = np.abs(cmd[k] - cmd[j])
        if dif.max() > 1e-4:
            c = int(np.argmax(dif))
            raise DataError(
                f"iso_pose {lab!r} was commanded at {cmd[j].round(4).tolist()} mm in row {int(rn[rows[j]])}, here at "
                f"{cmd[k].round(4).tolist()}: one test pose has one commanded target",
                file=f,
                row=int(rn[rows[k]]),
                column=ISO_COLUMNS[2 + c],
            )
        if cq is not None and np.abs(cq[k] - cq[j]).max() > 1e-6:
            c = int(np.argmax(np.abs(cq[k] - cq[j])))
            raise DataError(
                f"iso_pose {lab!r} was commanded with another orientation in row {int(rn[rows[j]])}",
                file=f,
                row=int(rn[rows[k]]),
                column=CMD_QUAT[c],
            )
        key = (lab, approach[k], int(cycle[k]))
        if key in seen:
            raise DataError(
                f"iso_pose {lab!r}, approach {str(approach[k])!r}, cycle {cycle[k]} of target {tname!s} is also in row "
                f"{int(rn[rows[seen[key]]])}: one row per pose, approach and cycle",
                file=f,
                row=int(rn[rows[k]]),
                column="cycle",
            )
        seen[key] = k

    # registration: tracker frame -> base frame, per station
    T_tb = _tracker_T_base(camp, calibration, rows, tracker_T_base)
    B = inv_transform(T_tb)  # (k, 4, 4) base_T_tracker
    p_t = camp.p_mm[rows]
    p_b = np.einsum("kij,kj->ki", B[:, :3, :3], p_t) + B[:, :3, 3]
    R_meas = R_cmd = None
    rpy = cmd_rpy = None
    if cq is not None and camp.quat is not None:
        R_meas = B[:, :3, :3] @ quat_to_matrix(camp.quat[rows])
        R_cmd = quat_to_matrix(cq)
        rpy = np.rad2deg(rpy_from_matrix(R_meas))
        cmd_rpy = np.rad2deg(rpy_from_matrix(R_cmd))
    test = IsoTest(
        pose=pose.astype(str),
        cycle=cycle,
        approach=approach.astype(str),
        p_mm=p_b,
        cmd_mm=cmd,
        t_s=camp.timestamp_s[rows],
        row=rn[rows],
        rpy_deg=rpy,
        cmd_rpy_deg=cmd_rpy,
        file=f,
    )
    return IsoCampaign(test, camp, rows, tname, B, R_meas, R_cmd)


def _tracker_T_base(
    camp: Campaign, cal: CalibrationResult, rows: np.ndarray, given: np.ndarray | None = None
) -> np.ndarray:
    """``tracker_T_base`` of every row: ``given`` when given, else the calibration's, or its station's when it has
    several."""
    if given is not None:
        return np.tile(np.asarray(given, dtype=float), (len(rows), 1, 1))
    assert camp.station is not None
    st = camp.station[rows]
    names = tuple(getattr(cal.model, "station_names", ("S1",)))
    if len(names) <= 1:
        return np.tile(cal.tracker_T_base, (len(rows), 1, 1))
    Ts = _stations_T_base(cal)
    out = np.zeros((len(rows), 4, 4))
    for k, s in enumerate(st):
        if s not in Ts:
            raise DataError(
                f"station {s!r} is not a station of the calibration ({list(Ts)}): its tracker frame is unknown",
                file=camp.poses_file,
                row=int(camp.row_number[rows[k]]),
                column="station",
            )
        out[k] = Ts[s]
    return out


def _stations_T_base(cal: CalibrationResult) -> dict[str, np.ndarray]:
    d: dict[str, Any] = cal.to_dict().get("stations_T_base") or {}
    return {str(k): np.asarray(v, dtype=float) for k, v in d.items()}


def predicted_after(iso: IsoCampaign, cal: CalibrationResult) -> IsoTest:
    """The test as the calibrated model predicts it after compensation (real data measured once): each attained
    pose moved by the model's predicted error at its joints, ``p_after = p_measured - (p_model - p_commanded)``,
    i.e. the commanded pose plus the model's residual (orientation likewise, by rotations, when the calibration
    has orientations; a position-only calibration gives no orientation after)."""
    camp = iso.campaign
    tnames = list(cal.tools)
    if iso.target not in tnames:
        raise DataError(
            f"target {iso.target!r} has no tool in the calibration ({tnames})", file=camp.poses_file, column="target"
        )
    q = camp.q[iso.rows]
    tidx = np.full(len(iso.rows), tnames.index(iso.target))
    p_pred_t, R_pred_t = cal.predict(q, tidx)
    B = iso.base_T_tracker
    p_pred = np.einsum("kij,kj->ki", B[:, :3, :3], p_pred_t) + B[:, :3, 3]
    t = iso.test
    p_after = t.p_mm - (p_pred - t.cmd_mm)
    rpy = None  # a position-only calibration predicts no orientation error: no orientation after
    if iso.R_meas is not None and iso.R_cmd is not None and len(R_pred_t) and cal.model.orientation:
        R_pred = B[:, :3, :3] @ R_pred_t
        # the residual rotation (measured relative to predicted, base frame) applied to the commanded orientation
        R_after = iso.R_meas @ np.swapaxes(R_pred, 1, 2) @ iso.R_cmd
        rpy = np.rad2deg(rpy_from_matrix(R_after))
    return IsoTest(
        pose=t.pose,
        cycle=t.cycle,
        approach=t.approach,
        p_mm=p_after,
        cmd_mm=t.cmd_mm,
        t_s=t.t_s,
        row=t.row,
        rpy_deg=rpy,
        cmd_rpy_deg=None if rpy is None else t.cmd_rpy_deg,
        file=t.file,
    )


__all__ = ["CMD_QUAT", "ISO_COLUMNS", "IsoCampaign", "predicted_after", "read_iso"]
