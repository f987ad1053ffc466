"""A twin scenario: read (:func:`load_scenario`), its poses (sampled or given), its gross errors and
its settings checked (:class:`ScenarioConfig`); :func:`rng_factory`, the named random streams.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from robocal.data.columns import joint_columns
from robocal.errors import ConfigError
from robocal.kinematics.transforms import homogeneous, matrix_from_rpy
from robocal.robot import RobotDescription

_CONF_SCENARIO_DIR = Path(__file__).resolve().parents[3] / "conf" / "scenario"


def load_scenario(name_or_path: str | Path, conf_dir: str | Path | None = None) -> dict[str, Any]:
    """A scenario mapping from ``conf/scenario/<name>.yaml`` or a YAML path."""
    p = Path(name_or_path)
    if p.suffix not in (".yaml", ".yml"):
        base = Path(conf_dir) if conf_dir is not None else _CONF_SCENARIO_DIR
        p = base / f"{name_or_path}.yaml"
        if not p.exists():
            known = sorted(x.stem for x in base.glob("*.yaml")) if base.exists() else []
            raise ConfigError(f"unknown scenario {str(name_or_path)!r}: no {p}; known scenarios: {known}")
    data = yaml.safe_load(p.read_text())
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: a scenario must be a mapping")
    return data


def rng_factory(seed: int) -> Callable[[str], np.random.Generator]:
    """One independent, seeded random stream per name: ``rng_factory(seed)("noise")`` is the same generator for
    the same seed and name, whatever other streams were drawn (the twin's and the ISO test's randomness)."""
    root = np.random.SeedSequence(int(seed))

    def make(stream: str) -> np.random.Generator:
        key = [int(b) for b in stream.encode()]
        return np.random.default_rng(np.random.SeedSequence(entropy=root.entropy, spawn_key=tuple(key)))

    return make


def sample_poses(
    robot: RobotDescription, n: int, rng: np.random.Generator, fraction: float = 0.9, ranges_deg: Any = None
) -> np.ndarray:
    """Uniform random joint configurations ``(n, N)`` rad inside ``fraction`` of the limits (or given ranges)."""
    lim = robot.q_limits.copy()
    if ranges_deg is not None:
        r = np.deg2rad(np.asarray(ranges_deg, dtype=float))
        if r.shape != lim.shape:
            raise ConfigError(f"The 'joint_ranges_deg' setting must have shape {lim.shape}. Got {r.shape} instead.")
        lim = np.clip(r, lim[:, 0:1], lim[:, 1:2])
    mid = lim.mean(1)
    half = (lim[:, 1] - lim[:, 0]) / 2 * fraction
    return rng.uniform(mid - half, mid + half, size=(n, robot.n_joints))


def given_poses(value: Any, robot: RobotDescription, key: str) -> np.ndarray | None:
    """Joint configurations ``(n, N)`` rad from a scenario setting: a list of ``[q1_deg, ..., qN_deg]`` or the
    path of a CSV with ``q1_deg`` ... ``qN_deg`` columns (e.g. ``robocal plan``'s ``plan.csv``; one row per pose
    and target there, so repeated pose ids are read once). ``None`` when the setting is absent."""
    if value is None:
        return None
    n = robot.n_joints
    if isinstance(value, str | Path):
        import pandas as pd

        path = Path(value)
        if not path.exists():
            raise ConfigError(f"The '{key}' scenario setting names {str(path)!r}, which does not exist")
        df = pd.read_csv(path)
        cols = joint_columns(robot.prismatic)  # q<j>_deg, q<j>_mm for a prismatic joint
        missing = [c for c in cols if c not in df.columns]
        if missing:
            raise ConfigError(f"The '{key}' scenario setting's file {path} lacks the column(s) {missing}")
        if "pose_id" in df.columns:
            df = df.drop_duplicates("pose_id")
        arr = df[cols].to_numpy(dtype=float)
    else:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(f"The '{key}' scenario setting must be a list of {n} joint angles per pose") from None
    if arr.ndim != 2 or arr.shape[1] != n or len(arr) == 0 or not np.all(np.isfinite(arr)):
        raise ConfigError(
            f"The '{key}' scenario setting must give {n} finite joint angles (deg) per pose. Got shape {arr.shape}."
        )
    q = np.where(robot.prismatic, arr, np.deg2rad(arr)) if robot.has_prismatic else np.deg2rad(arr)  # mm stay mm
    lim = robot.q_limits
    bad = np.flatnonzero(np.any((q < lim[:, 0] - 1e-9) | (q > lim[:, 1] + 1e-9), axis=1))
    if bad.size:
        raise ConfigError(f"The '{key}' scenario setting has poses outside {robot.name}'s joint limits: {bad.tolist()}")
    return q


def _fmt(v: np.ndarray, nd: int) -> list[str]:
    return [f"{x:.{nd}f}" for x in np.asarray(v, dtype=float)]


@dataclass(frozen=True)
class GrossErrors:
    """``gross_errors: {n, min_mm, max_mm}``: ``n`` calibration rows displaced by ``[min_mm, max_mm]``."""

    n: int = 0
    min_mm: float = 0.5
    max_mm: float = 3.0


def _transform(c: Mapping[str, Any], xyz_mm: Any, rpy_deg: Any) -> np.ndarray:
    """``{xyz_mm, rpy_deg}`` (with defaults) as a 4x4 transform."""
    return homogeneous(
        matrix_from_rpy(np.deg2rad(np.asarray(c.get("rpy_deg", rpy_deg), dtype=float))),
        np.asarray(c.get("xyz_mm", xyz_mm), dtype=float),
    )


@dataclass(frozen=True, eq=False)
class ScenarioConfig:
    """A twin scenario (``conf/scenario/<name>.yaml``, the pipeline's ``scenario`` section), typed.

    The keys are the YAML's (see ``conf/scenario/geometric.yaml``); :meth:`from_mapping` reads them with their
    defaults and keeps the mapping itself (``mapping``, written back as ``scenario.yaml``); keys the twin does
    not use are kept there and ignored. ``errors``, ``tracker``, ``targets``, ``stations`` and ``start`` are held
    in the twin's units: 1-sigma error sizes (mm, rad), the tracker's and the stations' ``tracker_T_base``
    transforms, the reflector offsets (K, 3) mm and the UTC start time. ``effects`` stays a mapping: each effect
    reads its own settings (:data:`EFFECTS`).
    """

    mapping: dict[str, Any]
    name: Any = "custom"
    robot: str = "kr16_2"
    seed: int = 0
    n_poses: int = 80
    n_validation_poses: int = 20
    joint_range_fraction: float = 0.9
    joint_ranges_deg: Any = None
    poses_deg: Any = None
    validation_poses_deg: Any = None
    target_names: tuple[str, ...] = ("T1",)
    tools_mm: np.ndarray = field(default_factory=lambda: np.array([[0.0, 0.0, 120.0]]))
    orientation: bool = False
    noise_mm: float = 0.015
    noise_deg: float = 0.005
    length_error_mm: float = 0.3
    angle_error_rad: float = float(np.deg2rad(0.02))
    tracker_T_base: np.ndarray = field(default_factory=lambda: np.eye(4))
    stations: dict[str, np.ndarray] = field(default_factory=dict)
    gross_errors: GrossErrors = field(default_factory=GrossErrors)
    start: datetime = datetime(2026, 1, 5, 7, tzinfo=UTC)
    interval_s: float = 10.0
    payload_kg: float = 0.0
    effects: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_mapping(cls, scenario: Mapping[str, Any], seed: int | None = None) -> ScenarioConfig:
        """The scenario mapping, read with the twin's defaults; ``seed`` (when given) replaces the scenario's."""
        sc = dict(scenario)
        err = dict(sc.get("errors", {}))
        targets = dict(sc.get("targets", {"T1": [0.0, 0.0, 120.0]}))
        tools = np.array([np.asarray(targets[t], dtype=float) for t in targets])
        if tools.shape != (len(targets), 3):
            raise ConfigError("The 'targets' scenario setting must map target names to [x, y, z] in mm")
        stations = {}
        for nm, c in dict(sc.get("stations") or {}).items():
            c = dict(c or {})
            if "xyz_mm" not in c or "rpy_deg" not in c:
                raise ConfigError(f"The 'stations.{nm}' scenario setting needs xyz_mm and rpy_deg")
            stations[str(nm)] = _transform(c, None, None)
        gross = dict(sc.get("gross_errors") or {})
        start = datetime.fromisoformat(str(sc.get("start", "2026-01-05T07:00:00+00:00")).replace("Z", "+00:00"))
        return cls(
            mapping=sc,
            name=sc.get("name", "custom"),
            robot=sc.get("robot", "kr16_2"),
            seed=int(sc.get("seed", 0) if seed is None else seed),
            n_poses=int(sc.get("n_poses", 80)),
            n_validation_poses=int(sc.get("n_validation_poses", 20)),
            joint_range_fraction=float(sc.get("joint_range_fraction", 0.9)),
            joint_ranges_deg=sc.get("joint_ranges_deg"),
            poses_deg=sc.get("poses_deg"),
            validation_poses_deg=sc.get("validation_poses_deg"),
            target_names=tuple(targets),
            tools_mm=tools,
            orientation=bool(sc.get("orientation", False)),
            noise_mm=float(sc.get("noise_mm", 0.015)),
            noise_deg=float(sc.get("noise_deg", 0.005)),
            length_error_mm=float(err.get("length_mm", 0.3)),
            angle_error_rad=np.deg2rad(float(err.get("angle_deg", 0.02))),
            tracker_T_base=_transform(dict(sc.get("tracker", {})), [2500.0, 1200.0, -350.0], [0.3, -0.5, 135.0]),
            stations=stations,
            gross_errors=GrossErrors(
                int(gross.get("n", 0)), float(gross.get("min_mm", 0.5)), float(gross.get("max_mm", 3.0))
            ),
            start=start if start.tzinfo is not None else start.replace(tzinfo=UTC),
            interval_s=float(sc.get("interval_s", 10.0)),
            payload_kg=float(sc.get("payload_kg", 0.0)),
            effects=dict(sc.get("effects") or {}),
        )

    def iso(self, t_s: float) -> str:
        """The ISO 8601 UTC timestamp (ms) ``t_s`` seconds after :attr:`start`."""
        return (self.start + timedelta(seconds=float(t_s))).astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
