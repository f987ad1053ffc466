"""The data contract's rules, one group of columns at a time (``docs/data-contract.md``): identity, joints,
positions, orientation, loads, split, tracker stations, units; the temperatures joined to the poses.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from robocal.data.campaign import DEFAULT_STATION, Campaign, SplitConfig
from robocal.data.columns import JOINT_SIGNALS, column_name, columns, joint_columns, required_columns
from robocal.data.table import _first, _names, _numeric, _optional_block, _read_table, _require, _row, _timestamps
from robocal.errors import DataError
from robocal.robot import RobotDescription

SPLIT_VALUES = ("calibration", "validation")
#: A measured point closer than this to the tracker (the frame's origin) looks like metres: no target can sit
#: inside the tracker head, and a robot cell measured in metres has every |p| of a few units.
METRES_SUSPECT_MM = 10.0

#: Joint angles that look like radians (:func:`_check_not_radians`): every value of every joint column inside
#: +-2 pi, over at least RADIANS_MIN_CONFIGS distinct joint configurations, on a robot whose every joint may move
#: over at least RADIANS_MIN_SPAN_DEG (7x the +-2 pi band): a campaign in degrees would then use less than a
#: seventh of every joint's range at once, which no calibration or validation campaign does.
RADIANS_BOUND = 2.0 * np.pi
RADIANS_MIN_CONFIGS = 8
RADIANS_MIN_SPAN_DEG = 90.0


def _check_columns(df: pd.DataFrame, robot: RobotDescription, path: Path) -> None:
    """The required columns are there, and no joint column beyond the robot's joints."""
    n = robot.n_joints
    prismatic = robot.prismatic
    wrong_unit = [c for c in joint_columns(~prismatic) if c in df.columns and c not in joint_columns(prismatic)]
    if wrong_unit:
        j = int(wrong_unit[0][1:].split("_")[0])
        kind = "prismatic (a length, column q{j}_mm)" if prismatic[j - 1] else "revolute (an angle, column q{j}_deg)"
        raise DataError(
            f"has column {wrong_unit[0]!r} but joint {j} of robot {robot.name!r} is {kind.format(j=j)}",
            file=path,
            row=1,
            column=wrong_unit[0],
        )
    _require(df, required_columns(n, prismatic), path)
    extra_q = [c for c in df.columns if re.fullmatch(r"q(\d+)_(deg|mm)", c) and int(c[1:].split("_")[0]) > n]
    if extra_q:
        raise DataError(
            f"has joint column(s) {extra_q} but robot {robot.name!r} has {n} joints",
            file=path,
            row=1,
            column=extra_q[0],
        )


def _read_identity(df: pd.DataFrame, path: Path) -> tuple[np.ndarray, pd.Series, np.ndarray]:
    """Pose ids, timestamps and target names (every row on target ``T1`` without a ``target`` column)."""
    pid = _names(df, column_name("pose_id"), path, "pose_id")
    ts = _timestamps(df, column_name("timestamp"), path)
    col = column_name("target")
    target = _names(df, col, path, "target name") if col in df.columns else np.full(len(df), "T1", dtype=object)
    return pid, ts, target.astype(str)


def _read_joints(df: pd.DataFrame, robot: RobotDescription, path: Path, limit_tol_deg: float) -> np.ndarray:
    """Joint values (m, n) as reported, in degrees (mm for a prismatic joint), inside the robot's limits and not
    radians."""
    qcols = joint_columns(robot.prismatic)
    slide = robot.prismatic
    q_deg = np.column_stack([_numeric(df, c, path) for c in qcols])
    lim = np.where(slide[:, None], robot.q_limits, np.degrees(robot.q_limits))
    for j, c in enumerate(qcols):
        out = (q_deg[:, j] < lim[j, 0] - limit_tol_deg) | (q_deg[:, j] > lim[j, 1] + limit_tol_deg)
        if out.any():
            i = _first(out)
            what, unit = ("joint position", "mm") if slide[j] else ("joint angle", "deg")
            raise DataError(
                f"{what} {q_deg[i, j]:g} {unit} outside the limits [{lim[j, 0]:g}, {lim[j, 1]:g}] of "
                f"{robot.name!r} ({int(out.sum())} row(s))",
                file=path,
                row=_row(i),
                column=c,
            )
    rev = ~slide
    if rev.any():
        _check_not_radians(q_deg[:, rev], [c for c, r in zip(qcols, rev, strict=True) if r], lim[rev], robot.name, path)
    return q_deg


def _read_positions(df: pd.DataFrame, path: Path) -> np.ndarray:
    """Measured points (m, 3) mm; metres are rejected row by row, so that a file mixing units is caught too."""
    pcols = columns("p")
    p = np.column_stack([_numeric(df, c, path) for c in pcols])
    dist = np.linalg.norm(p, axis=1)
    near = dist < METRES_SUSPECT_MM
    if near.any():
        i = _first(near)
        raise DataError(
            f"target {dist[i]:.4g} from the tracker ({int(near.sum())} of {len(p)} row(s) closer than "
            f"{METRES_SUSPECT_MM:g}); positions look like metres, the contract wants millimetres",
            file=path,
            row=_row(i),
            column=pcols[int(np.argmax(np.abs(p[i])))],
        )
    return p


def _read_orientation(df: pd.DataFrame, path: Path, quat_norm_tol: float) -> np.ndarray | None:
    """Measured unit quaternions (m, 4) (w, x, y, z), normalised, or None without orientation columns."""
    qcols_o = columns("quat")
    present = [c for c in qcols_o if c in df.columns]
    if not present:
        return None
    if len(present) != len(qcols_o):
        missing_o = [c for c in qcols_o if c not in present]
        raise DataError(f"has {present} but not all of {qcols_o}", file=path, row=1, column=missing_o[0])
    quat = np.column_stack([_numeric(df, c, path, required=False) for c in qcols_o])
    empty = ~np.isfinite(quat).all(axis=1)
    if empty.all():  # the columns are there, every row empty: positions only
        return None
    if empty.any():
        i = _first(empty)
        col = qcols_o[int(np.flatnonzero(~np.isfinite(quat[i]))[0])]
        raise DataError(
            f"{int(empty.sum())} row(s) have no orientation while the others do: robocal uses the orientation of every "
            f"row or of none; give {qcols_o} in every row, or leave them empty in every row (positions only; a "
            "point reflector's rows with a 6-DoF probe's are fitted on positions then)",
            file=path,
            row=_row(i),
            column=col,
        )
    norm = np.linalg.norm(quat, axis=1)
    bad = np.abs(norm - 1.0) > quat_norm_tol
    if bad.any():
        i = _first(bad)
        raise DataError(
            f"quaternion norm {norm[i]:.6g} differs from 1 by more than {quat_norm_tol:g}",
            file=path,
            row=_row(i),
            column=qcols_o[0],
        )
    return unit_quaternions(quat, norm)


#: A quaternion whose norm is within this of 1 is a unit quaternion already (a few units in the last place).
UNIT_NORM_TOL = 8 * float(np.finfo(float).eps)


def unit_quaternions(quat: np.ndarray, norm: np.ndarray | None = None) -> np.ndarray:
    """``quat`` (m, 4) normalised, leaving alone the rows that are unit already (norm within
    :data:`UNIT_NORM_TOL` of 1). Dividing by the norm is not idempotent in the last bit (a copy of a campaign
    read back would differ from it); this is: a normalised row is within 1.5 units in the last place of 1."""
    n = np.linalg.norm(quat, axis=1) if norm is None else norm
    return np.where((np.abs(n - 1.0) <= UNIT_NORM_TOL)[:, None], quat, quat / n[:, None])


def _read_loads(
    df: pd.DataFrame, n: int, path: Path
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Payload (m,) kg (0 without the column), torques, currents and approach directions (m, n) or None."""
    col = column_name("payload")
    payload = _numeric(df, col, path) if col in df.columns else np.zeros(len(df))
    if np.any(payload < 0):
        i = _first(payload < 0)
        raise DataError(f"negative payload {payload[i]:g} kg", file=path, row=_row(i), column=col)
    tau, cur, direction = (_optional_block(df, key, n, path) for key in JOINT_SIGNALS)
    if direction is not None:
        bad = ~np.isin(direction, (-1.0, 1.0))
        if bad.any():
            i, j = (int(v[0]) for v in np.nonzero(bad))
            raise DataError(
                f"approach direction must be -1 or +1, got {direction[i, j]:g}",
                file=path,
                row=_row(i),
                column=columns("direction", n)[j],
            )
    return payload, tau, cur, direction


def _check_unique(pid: np.ndarray, target: np.ndarray, ts: pd.Series, path: Path) -> None:
    """No (pose_id, target, timestamp) twice."""
    key = pd.DataFrame({"p": pid, "t": target, "s": ts.to_numpy()})
    dup = key.duplicated(keep="first").to_numpy()
    if dup.any():
        i = _first(dup)
        first = _first((key == key.iloc[i]).all(axis=1).to_numpy())
        raise DataError(
            f"duplicated (pose_id, target, timestamp) = ({pid[i]}, {target[i]}, {ts.iloc[i].isoformat()}); "
            f"first seen at row {_row(first)}",
            file=path,
            row=_row(i),
            column=column_name("pose_id"),
        )


def _read_split(df: pd.DataFrame, pid: np.ndarray, cfg: SplitConfig, path: Path) -> tuple[np.ndarray, bool]:
    """Each row's split and whether the file gave it (otherwise drawn by ``cfg`` over the pose ids)."""
    col = column_name("split")
    if col not in df.columns:
        return _make_split(pid, cfg), False
    sp = df[col].astype(str).str.strip().str.lower().to_numpy()
    bad = ~np.isin(sp, SPLIT_VALUES)
    if bad.any():
        i = _first(bad)
        raise DataError(
            f"split must be one of {SPLIT_VALUES}, got {df[col].iloc[i]!r}",
            file=path,
            row=_row(i),
            column=col,
        )
    return sp.astype(str), True


def _read_tracker(df: pd.DataFrame, path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Tracker stations (:data:`DEFAULT_STATION` without the column) and the tracker's own point uncertainty."""
    col = column_name("station")
    if col in df.columns:
        station = _names(df, col, path, "station name").astype(str)
    else:
        station = np.full(len(df), DEFAULT_STATION, dtype=object).astype(str)
    col = column_name("u_mm")
    if col not in df.columns:
        return station, None
    u_mm = _numeric(df, col, path)
    bad = ~(u_mm > 0)
    if bad.any():
        i = _first(bad)
        raise DataError(f"point uncertainty must be > 0 mm, got {u_mm[i]:g}", file=path, row=_row(i), column=col)
    return station, u_mm


def _check_not_radians(q_deg: np.ndarray, qcols: list[str], lim_deg: np.ndarray, robot: str, path: Path) -> None:
    """Joint angles in radians written into the ``q*_deg`` columns: every value of every joint column inside
    +-2 pi while the robot's limits span far more (see :data:`RADIANS_BOUND`). Repeated configurations (a
    drift test at one pose) count once, so a campaign standing still near zero is not taken for radians."""
    if q_deg.size == 0 or np.abs(q_deg).max() > RADIANS_BOUND:
        return
    span = lim_deg[:, 1] - lim_deg[:, 0]
    n_configs = len(np.unique(np.round(q_deg, 6), axis=0))
    if n_configs < RADIANS_MIN_CONFIGS or span.min() < RADIANS_MIN_SPAN_DEG:
        return
    i, j = (int(v) for v in np.unravel_index(np.argmax(np.abs(q_deg)), q_deg.shape))
    raise DataError(
        f"joint angles look like radians: every value of {qcols[0]}..{qcols[-1]} lies within +-{RADIANS_BOUND:.4g} "
        f"(largest |{qcols[j]}| = {abs(q_deg[i, j]):.4g}) over {n_configs} distinct configurations, while every "
        f"joint of {robot!r} may move over at least {span.min():g} deg; the contract wants degrees "
        "(multiply radians by 180/pi)",
        file=path,
        row=_row(i),
        column=qcols[j],
    )


def _check_same_joints(camp: Campaign, path: Path, qcols: list[str]) -> None:
    """The contract: a pose_id measured again has the same joint angles (up to 1e-3 deg of rounding)."""
    order = np.argsort(camp.pose_id, kind="stable")
    pid = camp.pose_id[order]
    q = camp.q[order]
    same = pid[1:] == pid[:-1]
    if not same.any():
        return
    dq = np.abs(q[1:] - q[:-1])
    if camp.prismatic is None:
        dq = np.degrees(dq)
    else:  # a prismatic joint's value is in mm already (1e-3 mm of rounding)
        dq = np.where(camp.prismatic, dq, np.degrees(dq))
    bad = same[:, None] & (dq > 1e-3)
    if bad.any():
        k, j = (int(v[0]) for v in np.nonzero(bad))
        i = int(order[k + 1])
        pk = str(pid[k])  # the id itself, not numpy's repr of it
        raise DataError(
            f"pose_id {pk!r} was measured before (row {int(camp.row_number[order[k]])}) with a different joint "
            f"angle ({np.degrees(q[k, j]):.6g} vs {np.degrees(q[k + 1, j]):.6g} deg); the same id must be the same "
            "configuration",
            file=path,
            row=int(camp.row_number[i]),
            column=qcols[j],
        )


def _make_split(pose_id: np.ndarray, cfg: SplitConfig) -> np.ndarray:
    out = np.full(len(pose_id), "calibration", dtype=object)
    if cfg.method == "none" or cfg.validation_fraction == 0:
        return out.astype(str)
    ids = list(dict.fromkeys(pose_id.tolist()))
    n_val = round(cfg.validation_fraction * len(ids))
    if n_val == 0 or n_val >= len(ids):
        return out.astype(str)
    rng = np.random.default_rng(cfg.seed)
    val = {ids[i] for i in rng.choice(len(ids), size=n_val, replace=False)}
    out[np.isin(pose_id, list(val))] = "validation"
    return out.astype(str)


def _join_temperatures(
    camp: Campaign,
    path: Path,
    pose_ts: pd.Series,
    robot: RobotDescription,
    tol_s: float,
    pose_raw: pd.Series | None = None,
) -> Campaign:
    df = _read_table(path)
    _require(df, ["timestamp"], path)
    sensors = [c for c in df.columns if re.fullmatch(r"T_.+_C", c)]
    if not sensors:
        raise DataError("no sensor column (T_<sensor>_C)", file=path, row=1)
    if robot.sensors:
        unknown = [s for s in sensors if s not in robot.sensor_names]
        if unknown:
            raise DataError(
                f"sensor column(s) {unknown} are not in robot {robot.name!r}'s sensors {list(robot.sensor_names)}",
                file=path,
                row=1,
                column=unknown[0],
            )
    ts = _timestamps(df, "timestamp", path)
    tv = ts.to_numpy()
    nonmono = np.flatnonzero(tv[1:] <= tv[:-1])
    if nonmono.size:
        i = int(nonmono[0]) + 1
        raise DataError(
            f"timestamps must increase strictly; {ts.iloc[i].isoformat()} follows {ts.iloc[i - 1].isoformat()}",
            file=path,
            row=_row(i),
            column="timestamp",
        )
    vals = np.column_stack([_numeric(df, c, path) for c in sensors])
    t0 = camp.t0
    t_log = (ts - t0).dt.total_seconds().to_numpy(dtype=float)
    t_pose = (pose_ts - t0).dt.total_seconds().to_numpy(dtype=float)
    k = np.searchsorted(t_log, t_pose, side="right") - 1
    before = k < 0
    if before.any():
        i = int(np.flatnonzero(before)[0])
        raise DataError(
            f"pose measured at {pose_ts.iloc[i].isoformat()} before the first temperature reading "
            f"({ts.iloc[0].isoformat()})",
            file=camp.poses_file,
            row=_row(i),
            column="timestamp",
        )
    age = t_pose - t_log[k]
    stale = age > tol_s
    if stale.any():
        i = int(np.flatnonzero(stale)[0])
        raise DataError(
            f"the nearest earlier temperature reading is {age[i]:.0f} s old (tolerance {tol_s:g} s, "
            f"data.temperature_tolerance_s)",
            file=camp.poses_file,
            row=_row(i),
            column="timestamp",
        )
    log = pd.DataFrame({"t_s": t_log, **{c: vals[:, j] for j, c in enumerate(sensors)}})
    notes = camp.notes
    zoned = (zone_given(pose_raw) if pose_raw is not None else None, zone_given(df["timestamp"]))
    if None not in zoned and zoned[0] != zoned[1]:
        naive = camp.poses_file if not zoned[0] else str(path)
        notes = (*notes, f"{naive} gives its timestamps without a time zone and the other file with one: they are read "
                 "as UTC (the data contract); written in local time, the poses and the temperatures are off by the UTC "
                 "offset (add Z or the offset to every timestamp)")  # fmt: skip
    return replace(camp, temperatures=vals[k], sensor_names=tuple(sensors), temperature_log=log, notes=notes)


def zone_given(raw: pd.Series) -> bool | None:
    """Whether the timestamps ``raw`` state their time zone (``Z`` or an offset, or a zoned datetime column):
    True in every row, False in none, None when some do."""
    if pd.api.types.is_datetime64_any_dtype(raw):
        return getattr(raw.dt, "tz", None) is not None
    has = raw.astype(str).str.strip().str.contains(r"(?:Z|[+-]\d\d:?\d\d)$", regex=True).to_numpy()
    return bool(has.all()) if has.all() or not has.any() else None
