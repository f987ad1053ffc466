"""The data door: read a measurement campaign in the data contract (``docs/data-contract.md``).

Every dataset, simulated or real, enters here. Units are converted once: inside, lengths are mm and angles
radians. Every rule of the contract is enforced with a :class:`robocal.errors.DataError` that names the file,
the (1-based, header = row 1) row and the column, and what was expected. Nothing in the folder is modified.

Files
-----
``poses.csv`` or ``poses.parquet`` (required) and ``temperatures.csv`` / ``temperatures.parquet`` (optional). A CSV
file may be comma-, semicolon- or tab-separated, with decimal points or (semicolon / tab) decimal commas, as a
spreadsheet saves it (:mod:`robocal.data.dialect`).
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
import yaml

from robocal.config import check_fields, parse, setting
from robocal.data.columns import (
    JOINT_SIGNALS,
    POSE_COLUMNS,
    column_name,
    columns,
    joint_columns,
    known_columns,
    required_columns,
)
from robocal.data.dialect import read_csv
from robocal.errors import DataError
from robocal.io import display_path
from robocal.logged_signals import SignalDeclaration, read_signals_file
from robocal.robot import RobotDescription

#: The one definition of how a campaign is read by default (split, temperature tolerance): also the pipeline's
#: ``data`` group (conf/config.yaml puts ``pkg://robocal`` on Hydra's search path).
DEFAULTS_FILE = Path(__file__).with_name("default.yaml")
_D: dict[str, Any] = yaml.safe_load(DEFAULTS_FILE.read_text(encoding="utf-8"))
#: A pose takes the nearest earlier temperature reading at most this old (s), by default.
TEMPERATURE_TOLERANCE_S = float(_D["temperature_tolerance_s"])

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

    method: str = setting(_D["split"]["method"], choices=("random", "random_pose", "none"))
    validation_fraction: float = setting(_D["split"]["validation_fraction"], ge=0, lt=1)
    seed: int = _D["split"]["seed"]

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
    q : (m, n) rad (mm for a prismatic joint), kinematic (after the robot's coupling);
    p_mm : (m, 3) tracker frame; quat : (m, 4) (w, x, y, z) unit, or None.
    payload_kg : (m,); tau_Nm, current_A : (m, n) or None; direction : (m, n) of ±1 or None.
    split : (m,) "calibration" / "validation"; split_from_file : bool.
    temperatures : (m, s) °C joined to the poses (nearest earlier reading), or None; sensor_names : (s,).
    temperature_log : the whole log (``t_s`` + sensor columns), or None.
    extra : extra columns (kept, not used); row_number : (m,) the row in the file (header = 1).
    station : (m,) str, the tracker placement of each row (one station ``"S1"`` when the file has none);
    u_mm : (m,) the tracker's stated uncertainty of each point (mm), or None.
    signal_declarations : the logged signals declared in ``signals.yaml`` beside the campaign
    (:mod:`robocal.logged_signals`).
    prismatic : (n,) bool, the joints whose value is a length (mm), or None (all revolute);
    coupling : (n, n) the robot's coupling ``q = coupling @ q_reported`` applied at the door, or None
    (:mod:`robocal.robot`); :meth:`to_frame` writes the reported values back.
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
    signal_declarations: tuple[SignalDeclaration, ...] = ()
    prismatic: np.ndarray | None = None
    coupling: np.ndarray | None = None

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
        """The campaign back in contract columns (degrees, ISO timestamps), e.g. for the interim Parquet copy.
        Joint values are written as reported (the coupling undone), a prismatic joint's in mm."""

        def per_column(a: np.ndarray | None) -> list[np.ndarray] | None:
            return None if a is None else [a[:, k] for k in range(a.shape[1])]

        # each contract group's values, one array per column (None: the campaign has no such columns)
        values: dict[str, list[Any] | None] = {
            "pose_id": [self.pose_id],
            "timestamp": [pd.to_datetime(self.t0) + pd.to_timedelta(self.timestamp_s, unit="s")],
            "target": [self.target],
            "q": per_column(self._reported_joints()),
            "p": per_column(self.p_mm),
            "quat": per_column(self.quat),
            "payload": [self.payload_kg],
            "tau": per_column(self.tau_Nm),
            "current": per_column(self.current_A),
            "direction": per_column(self.direction),
            "split": [self.split],
            "station": [self.station] if self.has_stations else None,
            "u_mm": None if self.u_mm is None else [self.u_mm],
        }
        cols: dict[str, Any] = {}
        for group in POSE_COLUMNS:
            v = values[group.key]
            if v is not None:
                names = group.columns(self.n_joints)
                if group.key == "q" and self.prismatic is not None:
                    names = joint_columns(self.prismatic)
                cols.update(zip(names, v, strict=True))
        cols.update(self.extra)
        return pd.DataFrame(cols)

    def _reported_joints(self) -> np.ndarray:
        """The joint values as the file has them: reported (the coupling undone), degrees or mm."""
        q = self.q if self.coupling is None else self.q @ np.linalg.inv(self.coupling).T
        if self.prismatic is None or not self.prismatic.any():
            return degrees_read_back(q)
        return np.where(self.prismatic, q, degrees_read_back(q))


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
            # everything as text first, so that a bad cell is reported rather than silently coerced; the
            # delimiter and the decimal mark as the file has them (a European spreadsheet's ';' and ',')
            df = read_csv(path)
    except DataError:
        raise
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


def _optional_block(df: pd.DataFrame, key: str, n: int, path: Path) -> np.ndarray | None:
    """The per-joint group ``key`` (:data:`robocal.data.columns.COLUMN`), all ``n`` columns or None."""
    names = columns(key, n)
    present = [c for c in names if c in df.columns]
    if not present:
        return None
    if len(present) != n:
        missing = [c for c in names if c not in df.columns]
        raise DataError(
            f"has {present} but not {missing}: give all {n} joints or none", file=path, row=1, column=missing[0]
        )
    return np.column_stack([_numeric(df, c, path) for c in names])


def _names(df: pd.DataFrame, col: str, path: Path, what: str) -> np.ndarray:
    """A text column with a value in every row (``what`` is the error's word for a missing one)."""
    txt = df[col].astype(str).str.strip().to_numpy()
    empty = (txt == "") | (txt == "nan") | df[col].isna().to_numpy()
    if empty.any():
        i = int(np.flatnonzero(empty)[0])
        raise DataError(f"missing {what}", file=path, row=_row(i), column=col)
    return txt


def _first(bad: np.ndarray) -> int:
    return int(np.flatnonzero(bad)[0])


def read_campaign(
    data_dir: str | Path,
    robot: RobotDescription,
    split: SplitConfig | Mapping[str, Any] | None = None,
    *,
    temperature_tolerance_s: float = TEMPERATURE_TOLERANCE_S,
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
    _check_columns(df, robot, path)
    m = len(df)

    pid, ts, target = _read_identity(df, path)
    q_file = _read_joints(df, robot, path, limit_tol_deg)
    p = _read_positions(df, path)
    quat = _read_orientation(df, path, quat_norm_tol)
    payload, tau, cur, direction = _read_loads(df, n, path)
    _check_unique(pid, target, ts, path)
    split_arr, from_file = _read_split(df, pid, split_cfg, path)
    station, u_mm = _read_tracker(df, path)
    prismatic = robot.prismatic if robot.has_prismatic else None
    extra = {c: df[c].to_numpy() for c in df.columns if c not in known_columns(n, prismatic)}

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
        # units once, here: degrees to radians (a prismatic joint stays in mm), then the reported values to the
        # kinematic ones (the robot's coupling)
        q=robot.to_kinematic(np.where(robot.prismatic, q_file, np.radians(q_file))),
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
        signal_declarations=read_signals_file(folder),
        prismatic=prismatic,
        coupling=robot.coupling,
    )
    _check_same_joints(camp, path, joint_columns(robot.prismatic))
    tpath = _find(folder, "temperatures", required=False)
    if tpath is not None:
        camp = _join_temperatures(camp, tpath, ts, robot, temperature_tolerance_s)
    return camp


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
    quat = np.column_stack([_numeric(df, c, path) for c in qcols_o])
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


def degrees_read_back(q_rad: np.ndarray) -> np.ndarray:
    """Joint angles in degrees that :func:`read_campaign` reads back as exactly ``q_rad`` (``np.radians`` of them).

    ``np.degrees`` alone does not: ``radians(degrees(q))`` differs from ``q`` in the last bit for ~5 % of a real
    campaign's angles, so a copy of a campaign (the pipeline's interim Parquet) was not the campaign, and a
    discrete choice downstream (a gross error, a named effect) could differ between the copy and the user's file.
    ``np.radians`` is monotone, so each angle is stepped by one unit in the last place towards its target until
    it maps onto it; an angle read from a file in degrees always has such a value (the one in the file)."""
    q = np.asarray(q_rad, dtype=float)
    d = np.degrees(q)
    for _ in range(8):  # one or two steps in practice
        r = np.radians(d)
        miss = r != q
        if not miss.any():
            break
        d = np.where(miss, np.nextafter(d, np.where(r < q, np.inf, -np.inf)), d)
    return d


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
