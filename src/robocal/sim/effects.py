"""What the twin's effects act on and how they are found: the rows of a campaign being made (:class:`Rows`),
the context (:class:`TwinContext`), the :class:`Effect` protocol and its registry :data:`EFFECTS`
(:func:`register_effect`); the joint-transmission effects (gear, transmission, backlash).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from robocal.errors import ConfigError
from robocal.kinematics.chain import Chain
from robocal.robot import RobotDescription


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
