"""The digital twin: writes measurement campaigns in the data contract, with a truth file.

A scenario (a mapping, e.g. ``conf/scenario/geometric.yaml``) says which robot, how many poses (or which:
``poses_deg`` / ``validation_poses_deg``, a list or a ``plan.csv`` path, see :func:`given_poses`),
the size of the geometric errors, where the tracker stands, which targets sit on the tool, the
tracker noise and which optional effects act. The true robot is the nominal one plus random
joint-level errors; effects add joint-angle offsets (compliance, gear errors, backlash) or make the
kinematic parameters drift (thermal). Every random number comes from ``numpy.random.default_rng(seed)``
through named child streams, and files are written with fixed formatting: the same scenario and seed
write the same bytes.

Effects are registered in :data:`EFFECTS` (name -> class); each implements :class:`Effect`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import yaml

from robocal.data.columns import EXTRA_DECIMALS, POSE_COLUMNS, ColumnGroup, joint_columns, known_columns
from robocal.errors import ConfigError
from robocal.io import atomic_write, write_json, write_text
from robocal.kinematics.chain import Chain, build_chain, propagate
from robocal.kinematics.transforms import homogeneous, matrix_from_rpy, matrix_to_quat, rotvec_to_matrix
from robocal.robot import RobotDescription, load_robot

_CONF_SCENARIO_DIR = Path(__file__).resolve().parents[3] / "conf" / "scenario"


@dataclass
class Rows:
    """The measurement plan and the true state of every row, shared by the effects.

    pose_id : (m,) str; split : (m,) str; target_index : (m,) int; q_cmd : (m, n) rad (as reported);
    t_s : (m,) seconds from the campaign start; payload_kg : (m,);
    dq : (m, n) true joint-angle offsets added by effects (rad); deta : (m, P) kinematic parameter drift;
    columns : extra contract columns written to poses.csv (name -> (m,) array).
    """

    pose_id: np.ndarray
    split: np.ndarray
    target_index: np.ndarray
    q_cmd: np.ndarray
    t_s: np.ndarray
    payload_kg: np.ndarray
    dq: np.ndarray
    deta: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    dp_tracker_mm: np.ndarray | None = None  # (m, 3) tracker-frame displacement of the measured points (drift)
    tracker_scale: np.ndarray | None = None  # (m,) the tracker's length-scale error of each row (scale), 1e-6 = 1 ppm
    base_rotvec: np.ndarray | None = None  # (m, 3) rad: the robot base turned about its origin, base axes (stand)
    # joint (0-based) -> (m, 6): a linear axis's true carriage errors (robocal.kinematics.axes.COMPONENTS)
    axis_error: dict[int, np.ndarray] | None = None
    station: np.ndarray | None = None  # (m,) the tracker station of each row, when an effect sets them (sessions)
    dtool_mm: np.ndarray | None = None  # (m, 3) mm: every target moved on the flange (flange axes; a re-seated tool)
    base_scale: np.ndarray | None = None  # (m,) the robot grown about its base (thermal expansion), 1e-6 = 1 ppm
    # (m, 3) tracker frame: the true point of a row that measures something else than the robot's tool (a
    # reflector on a positioner's part, robocal.sim.positioner), NaN for the tool's rows
    fixed_points: np.ndarray | None = None


@dataclass
class TwinContext:
    robot: RobotDescription
    chain: Chain
    eta_true: np.ndarray
    rng_factory: Callable[[str], np.random.Generator]
    truth: dict[str, Any]
    temperature_log: dict[str, np.ndarray] | None = None  # "t_s" + sensor columns


class Effect(Protocol):
    """An optional physical effect of the twin."""

    name: str

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        """Optionally change the measurement plan (e.g. repeat poses over a warm-up, add payloads)."""

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        """Add true joint offsets ``rows.dq`` / parameter drift ``rows.deta``, reported columns, truth."""


EFFECTS: dict[str, Callable[[Mapping[str, Any]], Effect]] = {}
#: Modules that register more effects (thermal warm-up, compliance under payload, tracker drift); imported
#: on first use so that ``robocal.sim.twin`` itself stays light. A module that does not exist is skipped.
EFFECT_MODULES = (
    "robocal.sim.thermal",
    "robocal.sim.compliance",
    "robocal.sim.drift",
    "robocal.sim.stand",
    "robocal.sim.axes",
    "robocal.sim.session",
    "robocal.sim.positioner",
)


def load_effect_modules() -> dict[str, Callable[[Mapping[str, Any]], Effect]]:
    """Import every module of :data:`EFFECT_MODULES` that exists; returns :data:`EFFECTS`."""
    import importlib
    import importlib.util

    for mod in EFFECT_MODULES:
        if importlib.util.find_spec(mod) is not None:
            importlib.import_module(mod)
    return EFFECTS


def register_effect(
    name: str,
) -> Callable[[Callable[[Mapping[str, Any]], Effect]], Callable[[Mapping[str, Any]], Effect]]:
    def deco(cls: Callable[[Mapping[str, Any]], Effect]) -> Callable[[Mapping[str, Any]], Effect]:
        EFFECTS[name] = cls
        return cls

    return deco


def _joint(cfg: Mapping[str, Any], n: int, key: str = "joint") -> int:
    j = int(cfg.get(key, 0))
    if not 1 <= j <= n:
        raise ConfigError(f"The '{key}' setting of the effect must be a joint number 1..{n}. Got {j} instead.")
    return j - 1


@register_effect("gear")
class GearEffect:
    """Periodic gear (reducer) transmission error: ``dq_j = sum_h A_h sin(h q_j + phi_h)``.

    Config: ``joint`` (1-based), ``harmonics`` list of ``{harmonic, amplitude_deg, phase_deg}``.
    """

    name = "gear"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        return rows

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        self.add_harmonics(rows, ctx, self.cfg.get("harmonics", []))

    def add_harmonics(self, rows: Rows, ctx: TwinContext, harmonics: Sequence[Mapping[str, Any]]) -> None:
        """``dq_j += A_h sin(h q_j + phi_h)`` for each ``{harmonic, amplitude_deg, phase_deg}``; the truth under
        this effect's name."""
        j = _joint(self.cfg, ctx.robot.n_joints)
        truth = []
        for h in harmonics:
            k = int(h["harmonic"])
            amp = np.deg2rad(float(h["amplitude_deg"]))
            ph = np.deg2rad(float(h.get("phase_deg", 0.0)))
            rows.dq[:, j] += amp * np.sin(k * rows.q_cmd[:, j] + ph)
            # the same term as a sin/cos pair: a sin(kq + phi) = a cos(phi) sin(kq) + a sin(phi) cos(kq)
            truth.append(
                {
                    "harmonic": k,
                    "amplitude_deg": float(h["amplitude_deg"]),
                    "phase_deg": float(np.rad2deg(ph)),
                    "sin_deg": float(np.rad2deg(amp * np.cos(ph))),
                    "cos_deg": float(np.rad2deg(amp * np.sin(ph))),
                }
            )
        ctx.truth.setdefault("effects", {})[self.name] = {"joint": j + 1, "harmonics": truth}


@register_effect("transmission")
class TransmissionEffect(GearEffect):
    """Gear transmission error of a real reducer: many harmonics per output revolution (tooth mesh, bearing
    races), ``dq_j = sum_h A_h sin(h q_j + phi_h)`` for every ``h`` in ``cycles``.

    Config: ``joint`` (1-based), ``cycles`` (harmonics per revolution, e.g. ``[17, 18, 19, 20]``),
    ``amplitude_deg`` (one value or one per harmonic); phases from the twin's seeded stream ``transmission``
    unless ``phase_deg`` gives them. Truth: every harmonic's amplitude, phase and sin/cos pair.
    """

    name = "transmission"

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        cycles = [int(c) for c in self.cfg.get("cycles", [])]
        if not cycles or min(cycles) < 1:
            raise ConfigError(f"The 'cycles' setting of the transmission effect must list harmonics >= 1. Got {cycles}")
        amps = np.broadcast_to(np.asarray(self.cfg.get("amplitude_deg", 0.004), dtype=float), (len(cycles),))
        if "phase_deg" in self.cfg:
            phases = np.broadcast_to(np.asarray(self.cfg["phase_deg"], dtype=float), (len(cycles),))
        else:
            phases = ctx.rng_factory("transmission").uniform(0.0, 360.0, len(cycles))
        harmonics = [
            {"harmonic": k, "amplitude_deg": float(a), "phase_deg": float(ph)}
            for k, a, ph in zip(cycles, amps, phases, strict=True)
        ]
        self.add_harmonics(rows, ctx, harmonics)


@register_effect("backlash")
class BacklashEffect:
    """Backlash: the joint lags by half the dead band against its approach direction.

    Config: ``joints`` {joint number: band_deg}; approach directions random per pose and joint,
    reported as ``dir1..dirN``. ``dq_j = dir_j * band_j / 2``.
    """

    name = "backlash"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        return rows

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        n = ctx.robot.n_joints
        rng = ctx.rng_factory("backlash")
        # one direction per pose (all targets of a pose share the approach)
        _, inv = np.unique(rows.pose_id, return_inverse=True)
        dirs_pose = rng.choice(np.array([-1, 1]), size=(inv.max() + 1, n))
        dirs = dirs_pose[inv]
        bands = {int(k): float(v) for k, v in dict(self.cfg.get("joints", {})).items()}
        for jn, band in bands.items():
            j = _joint({"joint": jn}, n)
            rows.dq[:, j] += dirs[:, j] * np.deg2rad(band) / 2.0
        for j in range(n):
            rows.columns[f"dir{j + 1}"] = dirs[:, j]
        ctx.truth.setdefault("effects", {})["backlash"] = {"band_deg": bands}


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


def simulate(
    scenario: Mapping[str, Any] | ScenarioConfig,
    out_dir: str | Path,
    seed: int | None = None,
    robot: RobotDescription | None = None,
) -> dict[str, Any]:
    """Write ``poses.csv`` (+ ``temperatures.csv``), ``truth.json`` and ``scenario.yaml`` into ``out_dir``.

    ``scenario`` : a scenario mapping (:func:`load_scenario`) or its :class:`ScenarioConfig`; ``seed`` replaces
    the scenario's; ``robot`` replaces the one it names. Returns the truth mapping.
    """
    if isinstance(scenario, ScenarioConfig):
        cfg = scenario if seed is None else replace(scenario, seed=int(seed))
    else:
        cfg = ScenarioConfig.from_mapping(scenario, seed)
    robot = robot or load_robot(cfg.robot)
    chain = build_chain(robot)
    rng = rng_factory(cfg.seed)
    g = rng("geometry")  # the true geometric errors
    eta = np.array(
        [g.normal(0, cfg.length_error_mm if k == "length" else cfg.angle_error_rad) for k in chain.param_kind]
    )
    tool_R = rotvec_to_matrix(rng("tool_rot").normal(0, 0.3, (len(cfg.target_names), 3)))
    rows = _plan(cfg, robot, chain.n_params, rng("poses"))
    truth = _truth(cfg, robot, chain, eta, tool_R)
    ctx = TwinContext(robot=robot, chain=chain, eta_true=eta, rng_factory=rng, truth=truth)
    rows = _apply_effects(cfg, rows, ctx)

    p, R = _true_points(cfg, chain, rows, eta, tool_R)
    if rows.fixed_points is not None:  # rows measuring a reflector on the part (a positioner), not the tool
        on_part = ~np.isnan(rows.fixed_points[:, 0])
        p[on_part] = rows.fixed_points[on_part]
    station_of = _stations(cfg, truth, rows, p, R)
    if rows.tracker_scale is not None:  # about the tracker head: the point in its station's frame
        p = p * (1.0 + rows.tracker_scale)[:, None]
    if rows.dp_tracker_mm is not None:
        p = p + rows.dp_tracker_mm
    noise = rng("noise")
    p_meas = p + noise.normal(0, cfg.noise_mm, p.shape)
    m = len(rows.pose_id)
    sigma_o = np.deg2rad(cfg.noise_deg)
    quat = matrix_to_quat(rotvec_to_matrix(noise.normal(0, sigma_o, (m, 3))) @ R) if cfg.orientation else None
    _gross_errors(cfg.gross_errors, truth, rows, p_meas, rng("gross"), list(cfg.target_names))
    _write_campaign(Path(out_dir), cfg, rows, p_meas, quat, station_of, ctx.temperature_log, truth, robot)
    return truth


def _plan(cfg: ScenarioConfig, robot: RobotDescription, n_params: int, rng: np.random.Generator) -> Rows:
    """The measurement plan: the calibration and validation poses, each measured on every target in turn."""
    n_cal, n_val = cfg.n_poses, cfg.n_validation_poses
    frac = cfg.joint_range_fraction
    q_cal = given_poses(cfg.poses_deg, robot, "poses_deg")
    q_val = given_poses(cfg.validation_poses_deg, robot, "validation_poses_deg")
    if q_cal is None and q_val is None:
        q_all = sample_poses(robot, n_cal + n_val, rng, frac, cfg.joint_ranges_deg)
    else:
        # a given pose list (e.g. robocal plan's plan.csv) replaces that split's part of the random draw; the
        # draw itself is the random design's, so the other split keeps the same poses (planned vs random
        # calibrations are validated on the same poses)
        drawn = sample_poses(robot, n_cal + n_val, rng, frac, cfg.joint_ranges_deg)
        q_cal = drawn[:n_cal] if q_cal is None else q_cal
        q_val = drawn[n_cal:] if q_val is None else q_val
        n_cal, n_val = len(q_cal), len(q_val)
        q_all = np.concatenate([q_cal, q_val])
    if robot.has_prismatic:  # a prismatic joint reports mm (1e-6 mm)
        q_all = np.where(robot.prismatic, np.round(q_all, 6), np.deg2rad(np.round(np.rad2deg(q_all), 6)))
    else:
        q_all = np.deg2rad(np.round(np.rad2deg(q_all), 6))  # what the controller reports, 1e-6 deg
    if robot.coupling is not None:  # drawn (or given) as the controller reports them, inside its limits
        q_all = robot.to_kinematic(q_all)
    K = len(cfg.target_names)
    pid = np.repeat(np.array([f"p{k:04d}" for k in range(n_cal + n_val)], dtype=object), K)
    m = len(pid)
    return Rows(
        pose_id=pid,
        split=np.repeat(np.array(["calibration"] * n_cal + ["validation"] * n_val, dtype=object), K),
        target_index=np.tile(np.arange(K), n_cal + n_val),
        q_cmd=np.repeat(q_all, K, axis=0),
        t_s=np.arange(m) * cfg.interval_s,
        payload_kg=np.full(m, cfg.payload_kg),
        dq=np.zeros((m, robot.n_joints)),
        deta=np.zeros((m, n_params)),
    )


def _truth(
    cfg: ScenarioConfig, robot: RobotDescription, chain: Chain, eta: np.ndarray, tool_R: np.ndarray
) -> dict[str, Any]:
    """The truth file's start: the true errors, tracker frame and tools (effects add theirs)."""
    names, kinds = chain.param_names, chain.param_kind
    return {
        "scenario": cfg.name,
        "seed": cfg.seed,
        "robot": robot.name,
        "kinematic_errors": {name: float(v) for name, v in zip(names, eta, strict=True)},
        "kinematic_units": {name: ("mm" if k == "length" else "rad") for name, k in zip(names, kinds, strict=True)},
        "tracker_T_base": cfg.tracker_T_base.tolist(),
        "tools_mm": {t: cfg.tools_mm[k].tolist() for k, t in enumerate(cfg.target_names)},
        "tool_rotations": {t: tool_R[k].tolist() for k, t in enumerate(cfg.target_names)},
        "noise_mm": cfg.noise_mm,
    }


def _apply_effects(cfg: ScenarioConfig, rows: Rows, ctx: TwinContext) -> Rows:
    """The scenario's effects (:data:`EFFECTS`): each may change the plan, then each acts on the rows."""
    effects: list[Effect] = []
    if cfg.effects:
        load_effect_modules()
    for name, ecfg in cfg.effects.items():
        if ecfg in (None, False):
            continue
        if name not in EFFECTS:
            raise ConfigError(f"unknown twin effect {name!r}; known effects: {sorted(EFFECTS)}")
        effects.append(EFFECTS[name](ecfg if isinstance(ecfg, Mapping) else {}))
    for eff in effects:
        rows = eff.plan(rows, ctx)
    for eff in effects:
        eff.apply(rows, ctx)
    return rows


def _true_points(
    cfg: ScenarioConfig, chain: Chain, rows: Rows, eta: np.ndarray, tool_R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """True target points (m, 3) and orientations (m, 3, 3) in the tracker frame, grouped by identical drift."""
    m = len(rows.pose_id)
    q_true = rows.q_cmd + rows.dq
    if rows.axis_error:  # the carriages' errors: pseudo joints of the augmented chain (robocal.kinematics.axes)
        from robocal.kinematics.axes import augment

        joints = sorted(rows.axis_error)
        chain = augment(chain, joints)
        q_true = np.concatenate([q_true, *(rows.axis_error[j] for j in joints)], axis=1)
    p = np.zeros((m, 3))
    R = np.zeros((m, 3, 3))
    keys, inv = np.unique(np.round(rows.deta, 15), axis=0, return_inverse=True)
    inv = inv.ravel()
    for g_i in range(len(keys)):
        sel = inv == g_i
        st = propagate(chain, q_true[sel], eta + rows.deta[np.flatnonzero(sel)[0]], cfg.tracker_T_base)
        t = cfg.tools_mm[rows.target_index[sel]]
        if rows.dtool_mm is not None:
            t = t + rows.dtool_mm[sel]
        p[sel] = st.o + st.x * t[:, 0:1] + st.y * t[:, 1:2] + st.z * t[:, 2:3]
        R[sel] = st.R @ tool_R[rows.target_index[sel]]
    if rows.base_scale is not None:  # the robot grown about its base's origin (thermal expansion): T S T^-1
        T = cfg.tracker_T_base
        t0 = T[:3, 3]
        p = t0 + (p - t0) * (1.0 + rows.base_scale)[:, None]
    if rows.base_rotvec is not None:  # the base turned about its own origin (a compliant stand): T R(w) T^-1
        T = cfg.tracker_T_base
        Rt, t0 = T[:3, :3], T[:3, 3]
        Rw = rotvec_to_matrix(rows.base_rotvec)
        pb = (p - t0) @ Rt  # base frame
        p = np.einsum("ij,mj->mi", Rt, np.einsum("mij,mj->mi", Rw, pb)) + t0
        R = Rt @ Rw @ Rt.T @ R
    return p, R


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


def _stations(
    cfg: ScenarioConfig, truth: dict[str, Any], rows: Rows, p: np.ndarray, R: np.ndarray
) -> np.ndarray | None:
    """``stations: {S2: {xyz_mm, rpy_deg}, ...}``: more tracker placements besides ``tracker`` (station S1).
    Pose number k (in plan order) is measured from station ``k mod S`` — or from the station an effect gave the
    row (``rows.station``, the placements in ``truth["stations_T_base"]``: :mod:`robocal.sim.session`); ``p`` and
    ``R`` are moved into that station's frame in place. Returns the station of every row, or None without extra
    stations."""
    T_base = cfg.tracker_T_base
    if rows.station is not None:  # an effect measured the rows from its own stations (robocal.sim.session)
        if cfg.stations:
            raise ConfigError("The 'stations' scenario setting cannot be combined with an effect that sets stations")
        placed = dict(truth["stations_T_base"])
        names = list(placed)
        Ts = [np.asarray(placed[nm], dtype=float) for nm in names]
        st = np.array([names.index(str(s)) for s in rows.station])
    elif not cfg.stations:
        return None
    else:
        names = ["S1", *cfg.stations]
        Ts = [T_base, *cfg.stations.values()]
        poses = list(dict.fromkeys(map(str, rows.pose_id)))
        k_of = {pid: k for k, pid in enumerate(poses)}
        st = np.array([k_of[str(pid)] % len(names) for pid in rows.pose_id])
    inv_base = np.linalg.inv(T_base)
    for s in range(1, len(names)):
        sel = st == s
        D = Ts[s] @ inv_base
        p[sel] = p[sel] @ D[:3, :3].T + D[:3, 3]
        R[sel] = D[:3, :3] @ R[sel]
    truth["stations_T_base"] = {nm: T.tolist() for nm, T in zip(names, Ts, strict=True)}
    return np.array(names, dtype=object)[st]


def _gross_errors(
    cfg: GrossErrors, truth: dict[str, Any], rows: Rows, p_meas: np.ndarray, rng: np.random.Generator, tnames: list
) -> None:
    """``n`` calibration rows displaced in a random direction by a magnitude uniform in ``[min_mm, max_mm]`` (a
    beam break, a bumped reflector). Listed in the truth."""
    n = cfg.n
    if n <= 0:
        return
    lo, hi = cfg.min_mm, cfg.max_mm
    cal = np.flatnonzero(np.asarray(rows.split) == "calibration")
    if n > len(cal):
        raise ConfigError(f"The 'gross_errors.n' scenario setting asks for {n} rows; the campaign has {len(cal)}")
    pick = np.sort(rng.choice(cal, size=n, replace=False))
    out = []
    for i in pick:
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        mag = rng.uniform(lo, hi)
        p_meas[i] += mag * u
        out.append(
            {
                "row": int(i) + 2,
                "pose_id": str(rows.pose_id[i]),
                "target": tnames[int(rows.target_index[i])],
                "magnitude_mm": float(mag),
            }
        )
    truth["gross_errors"] = out
