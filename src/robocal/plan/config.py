"""Settings of measurement planning (``conf/plan/default.yaml``), checked where they enter.

Every error names the setting (``The 'tracker.acceptance_half_angle_deg' plan setting must be ...``).
Units at the door are degrees and millimetres; :class:`PlanConfig` keeps them as given and the planner
converts once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from robocal.errors import ConfigError

CRITERIA = ("D", "A", "I")
VOLUME_KINDS = ("none", "box", "iso9283")


def _err(key: str, expected: str, got: Any) -> ConfigError:
    return ConfigError(f"The '{key}' plan setting must be {expected}. Got {got!r} instead.")


def _known(data: Mapping[str, Any], cls: type, prefix: str) -> dict[str, Any]:
    d = dict(data or {})
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - known)
    if unknown:
        where = f"'{prefix}' " if prefix else ""
        raise ConfigError(f"unknown {where}plan setting(s) {unknown}; known: {sorted(known)}")
    return d


def _float(d: dict[str, Any], key: str, full: str, lo: float | None = None, strict: bool = False) -> None:
    if key not in d:
        return
    try:
        v = float(d[key])
    except (TypeError, ValueError):
        raise _err(full, "a number", d[key]) from None
    if not np.isfinite(v) or (lo is not None and (v <= lo if strict else v < lo)):
        raise _err(full, f"a finite number {'>' if strict else '>='} {lo}", d[key])
    d[key] = v


def _vec3(value: Any, full: str) -> tuple[float, float, float]:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise _err(full, "three numbers [x, y, z]", value) from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise _err(full, "three finite numbers [x, y, z]", value)
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True)
class Target:
    """A reflector (or 6-DoF probe) on the tool: position in the flange frame (mm) and its facing direction."""

    name: str
    position_mm: tuple[float, float, float]
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class TrackerConfig:
    """Where the tracker stands (robot base frame, mm) and what it can see.

    acceptance_half_angle_deg: the reflector's acceptance cone (angle between its normal and the line to the
    tracker); 180 switches the check off. min_range_mm / max_range_mm: the tracker's distance range.
    """

    position_mm: tuple[float, float, float] = (922.26, 2618.05, 328.26)
    acceptance_half_angle_deg: float = 50.0
    min_range_mm: float = 1000.0
    max_range_mm: float = 20000.0
    min_targets_visible: int = 1


@dataclass(frozen=True)
class VolumeConfig:
    """Working volume the targets must lie in (base frame): ``none``, ``box`` (min_mm / max_mm) or
    ``iso9283`` (an axis-aligned cube: center_mm, side_mm, as the ISO 9283 test cube)."""

    kind: str = "none"
    min_mm: tuple[float, float, float] | None = None
    max_mm: tuple[float, float, float] | None = None
    center_mm: tuple[float, float, float] | None = None
    side_mm: float | None = None

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        if self.kind == "box":
            assert self.min_mm is not None and self.max_mm is not None
            return np.asarray(self.min_mm), np.asarray(self.max_mm)
        if self.kind == "iso9283":
            assert self.center_mm is not None and self.side_mm is not None
            c = np.asarray(self.center_mm)
            return c - self.side_mm / 2.0, c + self.side_mm / 2.0
        return None


@dataclass(frozen=True)
class SingularityConfig:
    """Distance to singularities: the smallest singular value of the flange Jacobian ``[J_v / length_mm; J_w]``
    (dimensionless) at least ``min_sigma``, and ``|q_wrist_joint| >= min_wrist_deg`` (0 switches either off)."""

    min_sigma: float = 0.02
    length_mm: float = 1000.0
    wrist_joint: int = 5
    min_wrist_deg: float = 10.0


@dataclass(frozen=True)
class CollisionConfig:
    """Self-collision by link capsules: body ``b`` (0 = base, i = moved by joint i, the tool with the last)
    is a set of segments of radius ``radius_mm[b]``; bodies at least ``skip`` apart must not touch."""

    enabled: bool = False
    radius_mm: tuple[float, ...] = (150.0, 120.0, 100.0, 90.0, 70.0, 60.0, 40.0)
    skip: int = 2
    clearance_mm: float = 0.0


@dataclass(frozen=True)
class RegionConfig:
    """The validation region (I-optimality, the predicted error map): ``n`` configurations sampled inside
    ``ranges_deg`` (default: the candidate ranges) that satisfy the same constraints."""

    n: int = 400
    ranges_deg: tuple[tuple[float, float], ...] | None = None


@dataclass(frozen=True)
class PlanConfig:
    """Settings of :func:`robocal.plan.plan_poses` (see ``conf/plan/default.yaml`` for each key)."""

    n_poses: int = 40
    criterion: str = "D"
    seed: int = 0
    n_candidates: int = 20000
    joint_margin_deg: float = 5.0
    ranges_deg: tuple[tuple[float, float], ...] | None = None
    noise_mm: float = 0.015
    noise_deg: float = 0.01
    orientation: bool = False
    rank_tol: float = 1e-6
    fixed: tuple[str, ...] = ()
    targets: tuple[Target, ...] = (Target("T1", (35.0, -20.0, 120.0)),)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    volume: VolumeConfig = field(default_factory=VolumeConfig)
    singularity: SingularityConfig = field(default_factory=SingularityConfig)
    collision: CollisionConfig = field(default_factory=CollisionConfig)
    region: RegionConfig = field(default_factory=RegionConfig)
    min_orientation_spread_deg: float = 0.0
    accuracy_mm: float = 0.02
    max_exchanges: int = 2000
    active_set: int = 4000
    report: bool = True

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> PlanConfig:
        """Build from a mapping (a Hydra node, YAML, CLI overrides); unknown keys are errors naming them."""
        # the pipeline's switch (the twin measures the plan), not a planning setting
        d = _known({k: v for k, v in dict(cfg or {}).items() if k != "measured_by_twin"}, cls, "")
        if "n_poses" in d:
            try:
                d["n_poses"] = int(d["n_poses"])
            except (TypeError, ValueError):
                raise _err("n_poses", "an integer", d["n_poses"]) from None
            if d["n_poses"] < 1:
                raise _err("n_poses", "a positive integer", d["n_poses"])
        for key, lo in (("n_candidates", 1), ("seed", 0), ("max_exchanges", 0), ("active_set", 1)):
            if key in d:
                try:
                    d[key] = int(d[key])
                except (TypeError, ValueError):
                    raise _err(key, "an integer", d[key]) from None
                if d[key] < lo:
                    raise _err(key, f"an integer >= {lo}", d[key])
        if "criterion" in d:
            c = str(d["criterion"]).upper()
            if c not in CRITERIA:
                raise _err("criterion", f"one of {CRITERIA}", d["criterion"])
            d["criterion"] = c
        for key in ("noise_mm", "noise_deg", "rank_tol", "accuracy_mm"):
            _float(d, key, key, 0.0, strict=True)
        for key in ("joint_margin_deg", "min_orientation_spread_deg"):
            _float(d, key, key, 0.0)
        if "ranges_deg" in d:
            d["ranges_deg"] = _ranges(d["ranges_deg"], "ranges_deg")
        if "fixed" in d:
            d["fixed"] = tuple(str(x) for x in (d["fixed"] or ()))
        for key in ("orientation", "report"):
            if key in d:
                d[key] = bool(d[key])
        if "targets" in d:
            d["targets"] = _targets(d["targets"])
        if "tracker" in d:
            t = _known(d["tracker"], TrackerConfig, "tracker")
            if "position_mm" in t:
                t["position_mm"] = _vec3(t["position_mm"], "tracker.position_mm")
            _float(t, "acceptance_half_angle_deg", "tracker.acceptance_half_angle_deg", 0.0, strict=True)
            if "acceptance_half_angle_deg" in t and t["acceptance_half_angle_deg"] > 180.0:
                raise _err("tracker.acceptance_half_angle_deg", "in (0, 180]", t["acceptance_half_angle_deg"])
            _float(t, "min_range_mm", "tracker.min_range_mm", 0.0)
            _float(t, "max_range_mm", "tracker.max_range_mm", 0.0, strict=True)
            if "min_targets_visible" in t:
                t["min_targets_visible"] = int(t["min_targets_visible"])
                if t["min_targets_visible"] < 1:
                    raise _err("tracker.min_targets_visible", "an integer >= 1", t["min_targets_visible"])
            d["tracker"] = TrackerConfig(**t)
            if d["tracker"].min_range_mm >= d["tracker"].max_range_mm:
                raise _err("tracker.min_range_mm", "below tracker.max_range_mm", d["tracker"].min_range_mm)
        if "volume" in d:
            d["volume"] = _volume(d["volume"])
        if "singularity" in d:
            s = _known(d["singularity"], SingularityConfig, "singularity")
            _float(s, "min_sigma", "singularity.min_sigma", 0.0)
            _float(s, "length_mm", "singularity.length_mm", 0.0, strict=True)
            _float(s, "min_wrist_deg", "singularity.min_wrist_deg", 0.0)
            if "wrist_joint" in s:
                s["wrist_joint"] = int(s["wrist_joint"])
            d["singularity"] = SingularityConfig(**s)
        if "collision" in d:
            c2 = _known(d["collision"], CollisionConfig, "collision")
            if "radius_mm" in c2:
                r = np.asarray(c2["radius_mm"], dtype=float).ravel()
                if r.size == 0 or np.any(~np.isfinite(r)) or np.any(r < 0):
                    raise _err("collision.radius_mm", "a list of radii >= 0, one per body", c2["radius_mm"])
                c2["radius_mm"] = tuple(float(v) for v in r)
            if "enabled" in c2:
                c2["enabled"] = bool(c2["enabled"])
            if "skip" in c2:
                c2["skip"] = int(c2["skip"])
                if c2["skip"] < 1:
                    raise _err("collision.skip", "an integer >= 1", c2["skip"])
            _float(c2, "clearance_mm", "collision.clearance_mm", 0.0)
            d["collision"] = CollisionConfig(**c2)
        if "region" in d:
            g = _known(d["region"], RegionConfig, "region")
            if "n" in g:
                g["n"] = int(g["n"])
                if g["n"] < 1:
                    raise _err("region.n", "a positive integer", g["n"])
            if "ranges_deg" in g:
                g["ranges_deg"] = _ranges(g["ranges_deg"], "region.ranges_deg")
            d["region"] = RegionConfig(**g)
        return cls(**d)


def _ranges(value: Any, key: str) -> tuple[tuple[float, float], ...] | None:
    if value is None:
        return None
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise _err(key, "a list of [min, max] per joint in degrees", value) from None
    if a.ndim != 2 or a.shape[1] != 2 or not np.all(np.isfinite(a)) or np.any(a[:, 0] >= a[:, 1]):
        raise _err(key, "a list of [min, max] per joint in degrees, min < max", value)
    return tuple((float(lo), float(hi)) for lo, hi in a)


def _targets(value: Any) -> tuple[Target, ...]:
    if not isinstance(value, Mapping) or not value:
        raise _err("targets", "a mapping of target names to {position_mm, normal} (or [x, y, z])", value)
    out = []
    for name, spec in value.items():
        key = f"targets.{name}"
        if isinstance(spec, Mapping):
            unknown = sorted(set(spec) - {"position_mm", "normal"})
            if unknown:
                raise ConfigError(f"unknown '{key}' plan setting(s) {unknown}; known: ['normal', 'position_mm']")
            pos = _vec3(spec.get("position_mm"), f"{key}.position_mm")
            nrm = np.asarray(_vec3(spec.get("normal", (0.0, 0.0, 1.0)), f"{key}.normal"))
        else:
            pos = _vec3(spec, key)
            nrm = np.array([0.0, 0.0, 1.0])
        if np.linalg.norm(nrm) < 1e-9:
            raise _err(f"{key}.normal", "a non-zero direction", nrm.tolist())
        nrm = nrm / np.linalg.norm(nrm)
        out.append(Target(str(name), pos, (float(nrm[0]), float(nrm[1]), float(nrm[2]))))
    return tuple(out)


def _volume(value: Any) -> VolumeConfig:
    v = _known(value, VolumeConfig, "volume")
    kind = str(v.get("kind", "none"))
    if kind not in VOLUME_KINDS:
        raise _err("volume.kind", f"one of {VOLUME_KINDS}", kind)
    v["kind"] = kind
    for k in ("min_mm", "max_mm", "center_mm"):
        if v.get(k) is not None:
            v[k] = _vec3(v[k], f"volume.{k}")
    if v.get("side_mm") is not None:
        _float(v, "side_mm", "volume.side_mm", 0.0, strict=True)
    if kind == "box":
        if v.get("min_mm") is None or v.get("max_mm") is None:
            raise _err("volume.min_mm", "given (with volume.max_mm) for a box volume", v.get("min_mm"))
        if np.any(np.asarray(v["min_mm"]) >= np.asarray(v["max_mm"])):
            raise _err("volume.min_mm", "below volume.max_mm on every axis", v["min_mm"])
    if kind == "iso9283" and (v.get("center_mm") is None or v.get("side_mm") is None):
        raise _err("volume.center_mm", "given (with volume.side_mm) for an iso9283 cube", v.get("center_mm"))
    return VolumeConfig(**v)
