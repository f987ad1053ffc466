"""A campaign in internal units (:class:`Campaign`), how its rows are split (:class:`SplitConfig`) and the
data defaults (``default.yaml``); :func:`degrees_read_back`, the joint angles a campaign is written with.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from robocal.config import check_fields, parse, setting
from robocal.data.columns import POSE_COLUMNS, joint_columns
from robocal.logged_signals import SignalDeclaration

#: The one definition of how a campaign is read by default (split, temperature tolerance): also the pipeline's
#: ``data`` group (conf/config.yaml puts ``pkg://robocal`` on Hydra's search path).
DEFAULTS_FILE = Path(__file__).with_name("default.yaml")
_D: dict[str, Any] = yaml.safe_load(DEFAULTS_FILE.read_text(encoding="utf-8"))
#: A pose takes the nearest earlier temperature reading at most this old (s), by default.
TEMPERATURE_TOLERANCE_S = float(_D["temperature_tolerance_s"])


#: the station of every row when the file has no ``station`` column
DEFAULT_STATION = "S1"


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
    not_read : the campaign folder's other table files (a ``validation.csv`` beside ``poses.csv``), which the
        contract does not read: said by the commands, never silently a part of the campaign or its split
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
    not_read: tuple[str, ...] = ()  # other table files in the campaign folder (validation.csv): not part of it
    notes: tuple[str, ...] = ()  # what reading the campaign noticed (poses and temperatures in other time zones)

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
    def not_read_note(self) -> str | None:
        """What the commands say when the poses have no split column and the folder holds other tables (a
        ``validation.csv`` beside ``poses.csv``): the split was drawn, those files were not read. None otherwise."""
        if self.split_from_file or not self.not_read:
            return None
        return (
            f"the poses have no split column: the validation rows were drawn from them, and {', '.join(self.not_read)} "
            f"in the campaign folder {'was' if len(self.not_read) == 1 else 'were'} not read (the contract reads poses "
            "and temperatures; give validation rows in the poses file with split = validation)"
        )

    def reading_notes(self) -> list[str]:
        """Every warning reading the campaign gave (:meth:`not_read_note`, ``notes``), for the commands to say."""
        return [n for n in (self.not_read_note(), *self.notes) if n]

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
