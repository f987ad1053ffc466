"""The twin writes a fleet: N robots with their own errors, campaigns months apart, some with an event.

Each robot draws its own joint-level errors (its own seed); every campaign of it is a twin campaign
(:func:`robocal.simulate`, the ``geometric`` scenario by default) with its own poses, noise and tracker placement,
measuring that robot's *current* geometry. Between campaigns some robots have an event:

* ``jump``: the zero offset (``theta<j>``) of one joint jumps once, between two consecutive campaigns
  (a motor or encoder change, a crash);
* ``drift``: one link length drifts by the same amount between every pair of consecutive campaigns
  (wear, a slowly sagging/compliant link).

The robot's geometry is handed to the twin by the ``fleet_state`` effect (registered here): it sets the
kinematic parameters of every row to the robot's state at that campaign, whatever the scenario's own
random errors were, and records that state in the campaign's ``truth.json``. ``FLEET_DIR/truth.json`` lists
every robot's seed and its events.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from datetime import date, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from robocal.config import parse, setting
from robocal.errors import ConfigError
from robocal.io import write_json, write_text
from robocal.sim.effects import Rows, TwinContext, register_effect

#: Zero offsets that can jump (identifiable for a 6R arm measured by position: theta1 is absorbed by the tracker
#: frame, theta6 by the tool offset; theta5 is left out because its standard error is ~10x the others' on this plan,
#: so a realistic jump there would not always be significant - a limit of the plan, not of the test).
JUMP_PARAMS = ("theta2", "theta3", "theta4")
#: Link lengths that can drift (identified with small standard errors on the KR16-2 plan).
DRIFT_PARAMS = ("a2", "a3", "d4", "a5")


def _iso_date(value: Any) -> Any:
    """YAML reads an unquoted ``2026-01-05`` as a date: the ISO text."""
    return value.isoformat() if isinstance(value, date) else value


def _valid_date(value: str) -> str | None:
    try:
        date.fromisoformat(value)
    except ValueError:
        return "must be a date YYYY-MM-DD"
    return None


@dataclass(frozen=True)
class TwinErrors:
    """Standard deviations of every robot's own joint-level errors."""

    length_mm: float = setting(0.3, ge=0)
    angle_deg: float = setting(0.02, ge=0)


@dataclass(frozen=True)
class TwinSettings:
    """Settings of :func:`simulate_fleet` (``twin`` in conf/fleet/default.yaml)."""

    robot: str = "kr16_2"
    scenario: str = "geometric"
    serial_prefix: str = "R"
    start: str = setting("2026-01-05", convert=_iso_date, check=_valid_date)
    interval_days: int = 91
    n_poses: int = 80
    n_validation_poses: int = 20
    errors: TwinErrors = field(default_factory=TwinErrors)
    tracker_jitter_mm: float = 150.0  # the tracker stands somewhere else at every campaign
    gross_error_share: float = setting(0.2, ge=0, le=1)  # share of campaigns with one gross error (a beam break)
    jump_share: float = setting(0.1, ge=0, le=1)  # share of robots with a zero-offset jump
    drift_share: float = setting(0.1, ge=0, le=1)  # share of robots with a drifting length
    # |jump| uniform in this range, random sign (re-mastering after a motor change)
    jump_deg: tuple[float, float] = (0.03, 0.1)
    drift_mm_per_campaign: tuple[float, float] = (0.04, 0.08)  # |drift| per campaign interval, random sign

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> TwinSettings:
        return parse(cls, cfg, "fleet.twin")


@register_effect("fleet_state")
class FleetState:
    """Twin effect: the true kinematic errors of every row are ``cfg["eta"]`` ({parameter: mm | rad})."""

    name = "fleet_state"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        return rows

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        eta = dict(self.cfg.get("eta") or {})
        names = list(ctx.chain.param_names)
        unknown = sorted(set(eta) - set(names))
        if unknown:
            raise ConfigError(f"The 'fleet_state.eta' twin setting names unknown parameters {unknown}")
        target = np.array([float(eta.get(n, 0.0)) for n in names])
        rows.deta += target - ctx.eta_true
        ctx.truth["kinematic_errors"] = {n: float(v) for n, v in zip(names, target, strict=True)}
        ctx.truth["fleet_state"] = {"serial": self.cfg.get("serial"), "campaign": self.cfg.get("campaign")}


def _settings(cfg: Mapping[str, Any] | None) -> dict[str, Any]:
    return asdict(TwinSettings.from_mapping(cfg))


def simulate_fleet(
    out_dir: str | Path, n_robots: int, n_campaigns: int = 3, seed: int = 0, config: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Write a twin fleet into ``out_dir`` (see :mod:`robocal.fleet.layout`); returns the truth (also written to
    ``out_dir/truth.json``). The same arguments write the same bytes."""
    from robocal.kinematics.chain import build_chain
    from robocal.robot import load_robot
    from robocal.sim.scenario import load_scenario
    from robocal.sim.twin import simulate

    if n_robots < 1:
        raise ConfigError(f"The 'n_robots' parameter of simulate_fleet must be >= 1. Got {n_robots} instead.")
    if n_campaigns < 1:
        raise ConfigError(f"The 'n_campaigns' parameter of simulate_fleet must be >= 1. Got {n_campaigns} instead.")
    cfg = _settings(config)
    robot = load_robot(cfg["robot"])
    chain = build_chain(robot)
    names = list(chain.param_names)
    kinds = list(chain.param_kind)
    base = load_scenario(cfg["scenario"])
    root = np.random.SeedSequence(int(seed))
    fleet_rng = np.random.default_rng(root.spawn(1)[0])
    need_events = n_campaigns >= 2
    n_jump = round(cfg["jump_share"] * n_robots) if need_events else 0
    n_drift = round(cfg["drift_share"] * n_robots) if need_events else 0
    if n_jump + n_drift > n_robots:
        raise ConfigError("jump_share + drift_share must not exceed 1")
    order = fleet_rng.permutation(n_robots)
    kind_of = {int(i): "jump" for i in order[:n_jump]} | {int(i): "drift" for i in order[n_jump : n_jump + n_drift]}
    start = date.fromisoformat(str(cfg["start"]))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    width = max(4, len(str(n_robots)))
    truth: dict[str, Any] = {"seed": int(seed), "n_robots": n_robots, "n_campaigns": n_campaigns, "robots": {}}
    children = root.spawn(n_robots + 1)[1:]
    for i in range(n_robots):
        serial = f"{cfg['serial_prefix']}{i + 1:0{width}d}"
        rng = np.random.default_rng(children[i])
        robot_seed = int(rng.integers(2**31 - 1))
        sd_len = float(cfg["errors"]["length_mm"])
        sd_ang = np.deg2rad(float(cfg["errors"]["angle_deg"]))
        eta0 = np.array([rng.normal(0, sd_len if k == "length" else sd_ang) for k in kinds])
        deltas, events = _planted_event(kind_of.get(i), rng, names, n_campaigns, cfg)
        rdir = out / serial
        rdir.mkdir(exist_ok=True)
        write_text(rdir / "robot.yaml", yaml.safe_dump({"serial": serial, "robot": cfg["robot"]}, sort_keys=False))
        campaigns = []
        for k in range(n_campaigns):
            day = start + timedelta(days=int(cfg["interval_days"]) * k)
            sc = _campaign_scenario(base, cfg, serial, k, day, rng, dict(zip(names, eta0 + deltas[k], strict=True)))
            simulate(sc, rdir / day.isoformat(), seed=robot_seed + 1000 * (k + 1), robot=robot)
            campaigns.append(day.isoformat())
        truth["robots"][serial] = {
            "robot": cfg["robot"],
            "seed": robot_seed,
            "campaigns": campaigns,
            "events": [{**e, "between": [campaigns[b] for b in e["between"]]} if "between" in e else e for e in events],
        }
    write_json(out / "truth.json", truth)
    return truth


def _planted_event(
    kind: str | None, rng: np.random.Generator, names: list[str], n_campaigns: int, cfg: Mapping[str, Any]
) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """The change of eta at each campaign relative to the first (n_campaigns, P) and the event planted (a jump
    of a joint offset between two campaigns, a steady drift of a length, or none); ``between`` holds campaign
    numbers."""
    deltas = np.zeros((n_campaigns, len(names)))
    events: list[dict[str, Any]] = []
    if kind == "jump":
        p = str(rng.choice(JUMP_PARAMS))
        after = int(rng.integers(1, n_campaigns))  # the jump happens before campaign number `after` (0-based)
        size_deg = float(rng.uniform(*cfg["jump_deg"]) * rng.choice([-1.0, 1.0]))
        deltas[after:, names.index(p)] += np.deg2rad(size_deg)
        events.append({"kind": "jump", "parameter": p, "size_deg": size_deg, "between": [after - 1, after]})
    elif kind == "drift":
        p = str(rng.choice(DRIFT_PARAMS))
        rate = float(rng.uniform(*cfg["drift_mm_per_campaign"]) * rng.choice([-1.0, 1.0]))
        deltas[:, names.index(p)] += rate * np.arange(n_campaigns)
        events.append({"kind": "drift", "parameter": p, "mm_per_campaign": rate})
    return deltas, events


def _campaign_scenario(
    base: Mapping[str, Any],
    cfg: Mapping[str, Any],
    serial: str,
    k: int,
    day: date,
    rng: np.random.Generator,
    eta: dict[str, float],
) -> dict[str, Any]:
    """The twin scenario of campaign ``k`` of robot ``serial``: its day, a jittered tracker, maybe a gross error,
    and the robot's kinematic errors ``eta`` then (the ``fleet_state`` effect)."""
    sc = dict(base)
    sc.update(
        {
            "name": f"fleet {serial} campaign {k + 1}",
            "robot": cfg["robot"],
            "n_poses": int(cfg["n_poses"]),
            "n_validation_poses": int(cfg["n_validation_poses"]),
            "start": f"{day.isoformat()}T07:00:00Z",
        }
    )
    tr = dict(sc.get("tracker") or {})
    xyz = np.asarray(tr.get("xyz_mm", [2500.0, 1200.0, -350.0]), dtype=float)
    jitter = rng.uniform(-1, 1, 3) * float(cfg["tracker_jitter_mm"])
    sc["tracker"] = {**tr, "xyz_mm": [round(float(v), 3) for v in xyz + jitter]}
    sc["gross_errors"] = {"n": 1} if rng.uniform() < float(cfg["gross_error_share"]) else {"n": 0}
    sc["effects"] = {
        **dict(sc.get("effects") or {}),
        "fleet_state": {"serial": serial, "campaign": k, "eta": {n: float(v) for n, v in eta.items()}},
    }
    return sc
