"""A twin campaign's files, written with fixed formats: ``poses.csv`` (+ ``temperatures.csv``,
``signals.yaml``), ``truth.json`` and ``scenario.yaml``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from robocal.data.columns import EXTRA_DECIMALS, POSE_COLUMNS, ColumnGroup, joint_columns, known_columns
from robocal.io import atomic_write, write_json, write_text
from robocal.robot import RobotDescription
from robocal.sim.effects import Rows
from robocal.sim.scenario import ScenarioConfig, _fmt


def _write_campaign(
    out: Path,
    cfg: ScenarioConfig,
    rows: Rows,
    p_meas: np.ndarray,
    quat: np.ndarray | None,
    station_of: np.ndarray | None,
    temperature_log: dict[str, np.ndarray] | None,
    truth: dict[str, Any],
    robot: RobotDescription | None = None,
) -> None:
    """``poses.csv`` (+ ``temperatures.csv``), ``truth.json`` and ``scenario.yaml``, with fixed formats."""
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "poses.csv", _poses_csv(cfg, rows, p_meas, quat, station_of, robot))
    if temperature_log is not None:
        log = temperature_log
        names = [k for k in log if k != "t_s"]
        tl = [",".join(["timestamp", *names])]
        for k, ts in enumerate(log["t_s"]):
            tl.append(",".join([cfg.iso(ts)] + [f"{log[c][k]:.4f}" for c in names]))
        write_text(out / "temperatures.csv", "\n".join(tl) + "\n")
    else:
        (out / "temperatures.csv").unlink(missing_ok=True)
    if truth.get("signals"):  # the logged signals an effect declares (robocal.logged_signals)
        write_text(out / "signals.yaml", yaml.safe_dump({"signals": truth["signals"]}, sort_keys=True))
    else:
        (out / "signals.yaml").unlink(missing_ok=True)
    write_json(out / "truth.json", truth)
    atomic_write(
        out / "scenario.yaml",
        lambda pth: pth.write_text(yaml.safe_dump({**cfg.mapping, "seed": cfg.seed}, sort_keys=True)),
    )


def _poses_csv(
    cfg: ScenarioConfig,
    rows: Rows,
    p_meas: np.ndarray,
    quat: np.ndarray | None,
    station_of: np.ndarray | None,
    robot: RobotDescription | None = None,
) -> str:
    """The poses file, its columns in the contract's order (:data:`robocal.data.columns.POSE_COLUMNS`) in their
    fixed formats; the effects' reported columns (``rows.columns``) at their group's place, columns the
    contract does not name last. The joints as the controller reports them: a prismatic joint in mm, a coupled
    robot's values before its coupling (:meth:`robocal.robot.RobotDescription.to_reported`)."""
    n = rows.q_cmd.shape[1]
    q_file = np.rad2deg(rows.q_cmd)
    prismatic = None
    if robot is not None and (robot.has_prismatic or robot.coupling is not None):
        q_rep = robot.to_reported(rows.q_cmd)
        prismatic = robot.prismatic
        q_file = np.where(prismatic, q_rep, np.rad2deg(q_rep))
    text: dict[str, list[list[str]] | None] = {
        "pose_id": [list(map(str, rows.pose_id))],
        "timestamp": [[cfg.iso(t) for t in rows.t_s]],
        "target": [[cfg.target_names[i] for i in rows.target_index]],
        "split": [list(map(str, rows.split))],
        "station": None if station_of is None else [list(station_of)],
    }
    numbers: dict[str, np.ndarray | None] = {
        "q": q_file.T,
        "p": p_meas.T,
        "quat": None if quat is None else quat.T,
        "payload": rows.payload_kg[None],
    }
    header: list[str] = []
    cols: list[list[str]] = []
    for group in POSE_COLUMNS:
        names = joint_columns(prismatic) if group.key == "q" and prismatic is not None else group.columns(n)
        if group.key in text:
            given = text[group.key]
        elif group.key in numbers:
            v = numbers[group.key]
            given = None if v is None else [_cells(group, x) for x in v]
        else:  # reported by an effect, column by column
            names = [c for c in names if c in rows.columns]
            given = [_cells(group, rows.columns[c]) for c in names]
        if given:
            header += names
            cols += given
    extra = [c for c in rows.columns if c not in known_columns(n, prismatic)]
    header += extra
    cols += [_fmt(rows.columns[c], EXTRA_DECIMALS) for c in extra]
    lines = [",".join(header)] + [",".join(r) for r in zip(*cols, strict=True)]
    return "\n".join(lines) + "\n"


def _cells(group: ColumnGroup, v: np.ndarray) -> list[str]:
    """One column's cells in the group's format: a sign as an integer, a number with its fixed decimals."""
    if group.kind == "sign":
        return [str(int(x)) for x in v]
    assert group.decimals is not None, group.key
    return _fmt(v, group.decimals)
