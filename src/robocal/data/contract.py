"""The data door: read a measurement campaign in the data contract (``docs/data-contract.md``).

Every dataset, simulated or real, enters here. Units are converted once: inside, lengths are mm and angles
radians. Every rule of the contract is enforced with a :class:`robocal.errors.DataError` that names the file,
the (1-based, header = row 1) row and the column, and what was expected. Nothing in the folder is modified.

Files
-----
``poses.csv`` or ``poses.parquet`` (required) and ``temperatures.csv`` / ``temperatures.parquet`` (optional).
When both a CSV and a Parquet file exist, the Parquet file is read (it is the exact copy the pipeline's
``prepare`` stage writes) only if ``prefer`` says so; by default having both is an error, since it is
ambiguous which one the user means.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from robocal.config import check_fields, parse, setting
from robocal.errors import DataError
from robocal.io import display_path
from robocal.robot import RobotDescription

SPLIT_VALUES = ("calibration", "validation")
#: A measured point closer than this to the tracker (the frame's origin) looks like metres: no target can sit
#: inside the tracker head, and a robot cell measured in metres has every |p| of a few units.
METRES_SUSPECT_MM = 10.0
#: the station of every row when the file has no ``station`` column
DEFAULT_STATION = "S1"
#: Joint angles that look like radians (:func:`_check_not_radians`): every value of every joint column inside
#: +-2 pi, over at least RADIANS_MIN_CONFIGS distinct joint configurations, on a robot whose every joint may move
#: over at least RADIANS_MIN_SPAN_DEG (7x the +-2 pi band): a campaign in degrees would then use less than a
#: seventh of every joint's range at once, which no calibration or validation campaign does.
RADIANS_BOUND = 2.0 * np.pi
RADIANS_MIN_CONFIGS = 8
RADIANS_MIN_SPAN_DEG = 90.0


@dataclass(frozen=True)
class SplitConfig:
    """How rows are split when the campaign has no ``split`` column.

    method : ``random`` (whole pose ids go to validation, so every target and every repetition of a pose
        stays together; ``random_pose`` is the same) or ``none`` (all rows calibrate).
        validation_fraction : share of pose ids held out. seed : the split's seed.
    """

    method: str = setting("random", choices=("random", "random_pose", "none"))
    validation_fraction: float = setting(0.2, ge=0, lt=1)
    seed: int = 0

    def __post_init__(self) -> None:
        check_fields(self, "split")  # direct construction is checked as a mapping is

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None, section: str = "split") -> SplitConfig:
        return parse(cls, m, section)


@dataclass(frozen=True, eq=False)
class Campaign:
    """One measurement campaign, validated, in internal units. Row arrays all have length ``m``.

    Attributes
    ----------
    source : str — the folder; poses_file : str — the file read.
    pose_id : (m,) str; timestamp_s : (m,) float seconds since the first pose's timestamp;
    t0 : pandas Timestamp of time zero (UTC).
    target : (m,) str; target_names : tuple of the distinct targets in order of appearance;
    target_index : (m,) int into ``target_names``.
    q : (m, n) rad; p_mm : (m, 3) tracker frame; quat : (m, 4) (w, x, y, z) unit, or None.
    payload_kg : (m,); tau_Nm, current_A : (m, n) or None; direction : (m, n) of ±1 or None.
    split : (m,) "calibration" / "validation"; split_from_file : bool.
    temperatures : (m, s) °C joined to the poses (nearest earlier reading), or None; sensor_names : (s,).
    temperature_log : the whole log (``t_s`` + sensor columns), or None.
    extra : extra columns (kept, not used); row_number : (m,) the row in the file (header = 1).
    station : (m,) str, the tracker placement of each row (one station ``"S1"`` when the file has none);
    u_mm : (m,) the tracker's stated uncertainty of each point (mm), or None.
    """

    source: str
    poses_file: str
    pose_id: np.ndarray
    timestamp_s: np.ndarray
    t0: Any
    target: np.ndarray
    target_names: tuple[str, ...]
    target_index: np.ndarray
    q: np.ndarray
    p_mm: np.ndarray
    quat: np.ndarray | None
    payload_kg: np.ndarray
    tau_Nm: np.ndarray | None
    current_A: np.ndarray | None
    direction: np.ndarray | None
    split: np.ndarray
    split_from_file: bool
    temperatures: np.ndarray | None = None
    sensor_names: tuple[str, ...] = ()
    temperature_log: pd.DataFrame | None = None
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)
    row_number: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    station: np.ndarray | None = None
    u_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.station is None:
            object.__setattr__(self, "station", np.full(self.q.shape[0], DEFAULT_STATION, dtype=object).astype(str))

    @property
    def station_names(self) -> tuple[str, ...]:
        """The distinct stations in order of first appearance."""
        assert self.station is not None
        return tuple(dict.fromkeys(self.station.tolist()))

    @property
    def has_stations(self) -> bool:
        return len(self.station_names) > 1

    # ----------------------------------------------------------------------------------------- properties
    @property
    def n_rows(self) -> int:
        return int(self.q.shape[0])

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    @property
    def has_orientation(self) -> bool:
        return self.quat is not None

    @property
    def has_temperatures(self) -> bool:
        return self.temperatures is not None

    @property
    def has_payload(self) -> bool:
        return bool(np.any(self.payload_kg != 0))

    @property
    def has_torques(self) -> bool:
        return self.tau_Nm is not None

    @property
    def has_currents(self) -> bool:
        return self.current_A is not None

    @property
    def has_directions(self) -> bool:
        return self.direction is not None

    # ------------------------------------------------------------------------------------------- subsets
    def subset(self, mask: np.ndarray) -> Campaign:
        """The rows selected by a boolean mask or an index array (target names are kept)."""
        idx = np.asarray(mask)
        if idx.dtype == bool:
            if idx.shape != (self.n_rows,):
                raise ValueError(f"mask has shape {idx.shape}, expected ({self.n_rows},)")
            idx = np.flatnonzero(idx)

        def take(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[idx]

        return replace(
            self,
            pose_id=self.pose_id[idx],
            timestamp_s=self.timestamp_s[idx],
            target=self.target[idx],
            target_index=self.target_index[idx],
            q=self.q[idx],
            p_mm=self.p_mm[idx],
            quat=take(self.quat),
            payload_kg=self.payload_kg[idx],
            tau_Nm=take(self.tau_Nm),
            current_A=take(self.current_A),
            direction=take(self.direction),
            split=self.split[idx],
            temperatures=take(self.temperatures),
            extra={k: v[idx] for k, v in self.extra.items()},
            row_number=self.row_number[idx],
            station=take(self.station),
            u_mm=take(self.u_mm),
        )

    def calibration(self) -> Campaign:
        return self.subset(self.split == "calibration")

    def validation(self) -> Campaign:
        return self.subset(self.split == "validation")

    def to_frame(self) -> pd.DataFrame:
        """The campaign back in contract columns (degrees, ISO timestamps), e.g. for the interim Parquet copy."""
        n = self.n_joints
        cols: dict[str, Any] = {
            "pose_id": self.pose_id,
            "timestamp": pd.to_datetime(self.t0) + pd.to_timedelta(self.timestamp_s, unit="s"),
            "target": self.target,
        }
        for j in range(n):
            cols[f"q{j + 1}_deg"] = np.degrees(self.q[:, j])
        for k, c in enumerate("xyz"):
            cols[f"{c}_mm"] = self.p_mm[:, k]
        if self.quat is not None:
            for k, c in enumerate("wxyz"):
                cols[f"q{c}"] = self.quat[:, k]
        cols["payload_kg"] = self.payload_kg
        for arr, fmt in ((self.tau_Nm, "tau{}_Nm"), (self.current_A, "i{}_A"), (self.direction, "dir{}")):
            if arr is not None:
                for j in range(n):
                    cols[fmt.format(j + 1)] = arr[:, j]
        cols["split"] = self.split
        if self.has_stations:
            cols["station"] = self.station
        if self.u_mm is not None:
            cols["u_mm"] = self.u_mm
        for name, v in self.extra.items():
            cols[name] = v
        return pd.DataFrame(cols)


# ------------------------------------------------------------------------------------------------ reading


def _find(folder: Path, stem: str, required: bool) -> Path | None:
    csv, pq = folder / f"{stem}.csv", folder / f"{stem}.parquet"
    if csv.is_file() and pq.is_file():
        raise DataError(f"both {csv.name} and {pq.name} exist; keep one so it is clear which is the data", file=folder)
    if pq.is_file():
        return pq
    if csv.is_file():
        return csv
    if required:
        raise DataError(f"no {stem}.csv or {stem}.parquet in the campaign folder", file=folder)
    return None


def _read_table(path: Path) -> pd.DataFrame:
    try:
        if path.suffix == ".parquet":
            df = pd.read_parquet(path)
        else:
            # everything as text first, so that a bad cell is reported rather than silently coerced
            df = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
            # pandas renames a repeated header ("x_mm", "x_mm.1"): check the header as written
            header = pd.read_csv(path, header=None, nrows=1, dtype=str, keep_default_na=False, skipinitialspace=True)
            df.columns = header.iloc[0].tolist()
    except Exception as exc:
        raise DataError(f"cannot be read as a table: {exc}", file=path) from None
    df.columns = [str(c).strip() for c in df.columns]
    dup = sorted({c for c in df.columns if list(df.columns).count(c) > 1})
    if dup:
        raise DataError(f"duplicated column name(s) {dup}", file=path, row=1, column=dup[0])
    if len(df) == 0:
        raise DataError("has a header but no rows", file=path)
    return df


def _row(i: int) -> int:
    """File row of data row i (header = row 1)."""
    return int(i) + 2


def _numeric(df: pd.DataFrame, col: str, path: Path, *, required: bool = True) -> np.ndarray:
    s = df[col]
    if s.dtype == object or pd.api.types.is_string_dtype(s):
        txt = s.astype(str).str.strip()
        empty = txt.isin(["", "nan", "NaN", "NA", "None"])
        vals = pd.to_numeric(txt.where(~empty, None), errors="coerce")
        bad = vals.isna() & ~empty
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise DataError(f"expected a number, got {s.iloc[i]!r}", file=path, row=_row(i), column=col)
        arr = vals.to_numpy(dtype=float)
    else:
        try:
            arr = s.to_numpy(dtype=float)
        except (TypeError, ValueError):
            raise DataError(f"expected numbers, column has type {s.dtype}", file=path, column=col) from None
    if required:
        nan = ~np.isfinite(arr)
        if nan.any():
            i = int(np.flatnonzero(nan)[0])
            raise DataError(
                f"missing or non-finite value in a required column ({int(nan.sum())} row(s))",
                file=path,
                row=_row(i),
                column=col,
            )
    return arr


def _timestamps(df: pd.DataFrame, col: str, path: Path) -> pd.Series:
    raw = df[col]
    if pd.api.types.is_datetime64_any_dtype(raw):
        ts = pd.to_datetime(raw, utc=True)
    else:
        txt = raw.astype(str).str.strip()
        ts = pd.to_datetime(txt, utc=True, errors="coerce", format="ISO8601")
    bad = ts.isna().to_numpy()
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise DataError(
            f"expected an ISO 8601 timestamp (e.g. 2026-01-01T08:00:00Z), got {raw.iloc[i]!r}",
            file=path,
            row=_row(i),
            column=col,
        )
    return ts


def _require(df: pd.DataFrame, cols: list[str], path: Path) -> None:
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise DataError(
            f"missing required column(s) {missing}; present: {list(df.columns)}", file=path, row=1, column=missing[0]
        )


def _optional_block(df: pd.DataFrame, fmt: str, n: int, path: Path) -> np.ndarray | None:
    names = [fmt.format(j + 1) for j in range(n)]
    present = [c for c in names if c in df.columns]
    if not present:
        return None
    if len(present) != n:
        missing = [c for c in names if c not in df.columns]
        raise DataError(
            f"has {present} but not {missing}: give all {n} joints or none", file=path, row=1, column=missing[0]
        )
    return np.column_stack([_numeric(df, c, path) for c in names])


def read_campaign(  # noqa: C901, PLR0915
    data_dir: str | Path,
    robot: RobotDescription,
    split: SplitConfig | Mapping[str, Any] | None = None,
    *,
    temperature_tolerance_s: float = 900.0,
    quat_norm_tol: float = 1e-3,
    limit_tol_deg: float = 1e-6,
) -> Campaign:
    """Read and check the campaign in ``data_dir`` for ``robot``.

    Parameters
    ----------
    split : used when ``poses`` has no ``split`` column (default: 20 % of pose ids, seed 0).
    temperature_tolerance_s : a pose takes the nearest earlier temperature reading no older than this.
    quat_norm_tol : allowed | |q| - 1 | of measured quaternions.
    limit_tol_deg : rounding slack on joint limits.
    """
    folder = Path(data_dir)
    if not folder.is_dir():
        raise DataError("the campaign folder does not exist", file=folder)
    split_cfg = split if isinstance(split, SplitConfig) else SplitConfig.from_mapping(split)
    path = _find(folder, "poses", required=True)
    assert path is not None
    df = _read_table(path)
    n = robot.n_joints
    qcols = [f"q{j + 1}_deg" for j in range(n)]
    _require(df, ["pose_id", "timestamp", *qcols, "x_mm", "y_mm", "z_mm"], path)
    extra_q = [c for c in df.columns if re.fullmatch(r"q(\d+)_deg", c) and int(c[1:-4]) > n]
    if extra_q:
        raise DataError(
            f"has joint column(s) {extra_q} but robot {robot.name!r} has {n} joints",
            file=path,
            row=1,
            column=extra_q[0],
        )
    m = len(df)

    # identifiers
    pid = df["pose_id"].astype(str).str.strip().to_numpy()
    empty = (pid == "") | (pid == "nan") | df["pose_id"].isna().to_numpy()
    if empty.any():
        i = int(np.flatnonzero(empty)[0])
        raise DataError("missing pose_id", file=path, row=_row(i), column="pose_id")
    ts = _timestamps(df, "timestamp", path)
    if "target" in df.columns:
        target = df["target"].astype(str).str.strip().to_numpy()
        bad = (target == "") | (target == "nan") | df["target"].isna().to_numpy()
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DataError("missing target name", file=path, row=_row(i), column="target")
    else:
        target = np.full(m, "T1", dtype=object)
    target = target.astype(str)

    # joints (deg -> rad) and limits
    q_deg = np.column_stack([_numeric(df, c, path) for c in qcols])
    lim = np.degrees(robot.q_limits)
    for j, c in enumerate(qcols):
        out = (q_deg[:, j] < lim[j, 0] - limit_tol_deg) | (q_deg[:, j] > lim[j, 1] + limit_tol_deg)
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise DataError(
                f"joint angle {q_deg[i, j]:g} deg outside the limits [{lim[j, 0]:g}, {lim[j, 1]:g}] of "
                f"{robot.name!r} ({int(out.sum())} row(s))",
                file=path,
                row=_row(i),
                column=c,
            )

    _check_not_radians(q_deg, qcols, lim, robot.name, path)

    # positions (mm; reject metres, row by row, so that a file mixing units is caught too)
    pcols = ("x_mm", "y_mm", "z_mm")
    p = np.column_stack([_numeric(df, c, path) for c in pcols])
    dist = np.linalg.norm(p, axis=1)
    near = dist < METRES_SUSPECT_MM
    if near.any():
        i = int(np.flatnonzero(near)[0])
        raise DataError(
            f"target {dist[i]:.4g} from the tracker ({int(near.sum())} of {m} row(s) closer than "
            f"{METRES_SUSPECT_MM:g}); positions look like metres, the contract wants millimetres",
            file=path,
            row=_row(i),
            column=pcols[int(np.argmax(np.abs(p[i])))],
        )

    # orientation
    qcols_o = ["qw", "qx", "qy", "qz"]
    present = [c for c in qcols_o if c in df.columns]
    quat = None
    if present:
        if len(present) != 4:
            missing_o = [c for c in qcols_o if c not in present]
            raise DataError(f"has {present} but not all of {qcols_o}", file=path, row=1, column=missing_o[0])
        quat = np.column_stack([_numeric(df, c, path) for c in qcols_o])
        norm = np.linalg.norm(quat, axis=1)
        bad = np.abs(norm - 1.0) > quat_norm_tol
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DataError(
                f"quaternion norm {norm[i]:.6g} differs from 1 by more than {quat_norm_tol:g}",
                file=path,
                row=_row(i),
                column="qw",
            )
        quat = quat / norm[:, None]

    payload = _numeric(df, "payload_kg", path) if "payload_kg" in df.columns else np.zeros(m)
    if np.any(payload < 0):
        i = int(np.flatnonzero(payload < 0)[0])
        raise DataError(f"negative payload {payload[i]:g} kg", file=path, row=_row(i), column="payload_kg")
    tau = _optional_block(df, "tau{}_Nm", n, path)
    cur = _optional_block(df, "i{}_A", n, path)
    direction = _optional_block(df, "dir{}", n, path)
    if direction is not None:
        bad = ~np.isin(direction, (-1.0, 1.0))
        if bad.any():
            i, j = (int(v[0]) for v in np.nonzero(bad))
            raise DataError(
                f"approach direction must be -1 or +1, got {direction[i, j]:g}",
                file=path,
                row=_row(i),
                column=f"dir{j + 1}",
            )

    # duplicates of (pose_id, target, timestamp)
    key = pd.DataFrame({"p": pid, "t": target, "s": ts.to_numpy()})
    dup = key.duplicated(keep="first").to_numpy()
    if dup.any():
        i = int(np.flatnonzero(dup)[0])
        first = int(np.flatnonzero((key == key.iloc[i]).all(axis=1).to_numpy())[0])
        raise DataError(
            f"duplicated (pose_id, target, timestamp) = ({pid[i]}, {target[i]}, {ts.iloc[i].isoformat()}); "
            f"first seen at row {_row(first)}",
            file=path,
            row=_row(i),
            column="pose_id",
        )

    # split
    if "split" in df.columns:
        sp = df["split"].astype(str).str.strip().str.lower().to_numpy()
        bad = ~np.isin(sp, SPLIT_VALUES)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DataError(
                f"split must be one of {SPLIT_VALUES}, got {df['split'].iloc[i]!r}",
                file=path,
                row=_row(i),
                column="split",
            )
        split_arr = sp.astype(str)
        from_file = True
    else:
        split_arr = _make_split(pid, split_cfg)
        from_file = False

    # tracker stations and the tracker's own point uncertainty
    if "station" in df.columns:
        station = df["station"].astype(str).str.strip().to_numpy()
        bad = (station == "") | (station == "nan") | df["station"].isna().to_numpy()
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DataError("missing station name", file=path, row=_row(i), column="station")
        station = station.astype(str)
    else:
        station = np.full(m, DEFAULT_STATION, dtype=object).astype(str)
    u_mm = None
    if "u_mm" in df.columns:
        u_mm = _numeric(df, "u_mm", path)
        bad = ~(u_mm > 0)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DataError(f"point uncertainty must be > 0 mm, got {u_mm[i]:g}", file=path, row=_row(i), column="u_mm")

    known = {"pose_id", "timestamp", "target", *qcols, "x_mm", "y_mm", "z_mm", "payload_kg", "split", *qcols_o}
    known |= {"station", "u_mm"}
    known |= (
        {f"tau{j + 1}_Nm" for j in range(n)} | {f"i{j + 1}_A" for j in range(n)} | {f"dir{j + 1}" for j in range(n)}
    )
    extra = {c: df[c].to_numpy() for c in df.columns if c not in known}

    t0 = ts.min()
    t_s = (ts - t0).dt.total_seconds().to_numpy(dtype=float)
    names = tuple(dict.fromkeys(target.tolist()))
    tindex = np.array([names.index(t) for t in target], dtype=int) if m else np.zeros(0, dtype=int)

    camp = Campaign(
        source=display_path(folder),
        poses_file=display_path(path),
        pose_id=pid.astype(str),
        timestamp_s=t_s,
        t0=t0,
        target=target,
        target_names=names,
        target_index=tindex,
        q=np.radians(q_deg),
        p_mm=p,
        quat=quat,
        payload_kg=payload,
        tau_Nm=tau,
        current_A=cur,
        direction=direction,
        split=split_arr,
        split_from_file=from_file,
        extra=extra,
        row_number=np.arange(m) + 2,
        station=station,
        u_mm=u_mm,
    )
    _check_same_joints(camp, path, qcols)
    tpath = _find(folder, "temperatures", required=False)
    if tpath is not None:
        camp = _join_temperatures(camp, tpath, ts, robot, temperature_tolerance_s)
    return camp


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
    dq = np.degrees(np.abs(q[1:] - q[:-1]))
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
    camp: Campaign, path: Path, pose_ts: pd.Series, robot: RobotDescription, tol_s: float
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
    return replace(camp, temperatures=vals[k], sensor_names=tuple(sensors), temperature_log=log)
