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

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from robocal.data.campaign import (
    DEFAULT_STATION,
    DEFAULTS_FILE,
    TEMPERATURE_TOLERANCE_S,
    Campaign,
    SplitConfig,
    degrees_read_back,
)
from robocal.data.checks import (
    METRES_SUSPECT_MM,
    RADIANS_BOUND,
    RADIANS_MIN_CONFIGS,
    RADIANS_MIN_SPAN_DEG,
    SPLIT_VALUES,
    UNIT_NORM_TOL,
    _check_columns,
    _check_same_joints,
    _check_unique,
    _join_temperatures,
    _read_identity,
    _read_joints,
    _read_loads,
    _read_orientation,
    _read_positions,
    _read_split,
    _read_tracker,
    unit_quaternions,
)
from robocal.data.columns import column_name, joint_columns, known_columns
from robocal.data.table import _find, _read_table
from robocal.errors import DataError
from robocal.io import display_path
from robocal.logged_signals import read_signals_file
from robocal.robot import RobotDescription

#: suffixes of the table files a campaign folder may hold besides poses and temperatures (not read: said)
_TABLES = (".csv", ".parquet", ".tsv", ".txt", ".xlsx", ".xls")


def _tables_not_read(folder: Path) -> tuple[str, ...]:
    """The folder's table files other than ``poses`` and ``temperatures`` (a ``validation.csv`` a user expects to be
    the validation rows was ignored without a word, and the campaign split its own)."""
    return tuple(
        sorted(
            f.name
            for f in folder.iterdir()
            if f.is_file() and f.suffix.lower() in _TABLES and f.stem not in ("poses", "temperatures")
        )
    )


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
        not_read=_tables_not_read(folder),
    )
    _check_same_joints(camp, path, joint_columns(robot.prismatic))
    tpath = _find(folder, "temperatures", required=False)
    if tpath is not None:
        camp = _join_temperatures(camp, tpath, ts, robot, temperature_tolerance_s, df[column_name("timestamp")])
    return camp


# what moved out (issue 32) and is importable from here as before: the campaign value (robocal.data.campaign), the
# contract's rules (robocal.data.checks); the table reading is robocal.data.table
__all__ = [
    "DEFAULTS_FILE",
    "DEFAULT_STATION",
    "METRES_SUSPECT_MM",
    "RADIANS_BOUND",
    "RADIANS_MIN_CONFIGS",
    "RADIANS_MIN_SPAN_DEG",
    "SPLIT_VALUES",
    "TEMPERATURE_TOLERANCE_S",
    "UNIT_NORM_TOL",
    "Campaign",
    "SplitConfig",
    "degrees_read_back",
    "read_campaign",
    "unit_quaternions",
]
