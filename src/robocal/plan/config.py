"""Settings of measurement planning (``conf/plan/default.yaml``), checked where they enter.

Every error names the setting (``plan.tracker.acceptance_half_angle_deg: must be in (0, 180]; got 0``), by the
one settings parser (:mod:`robocal.config`). Units at the door are degrees and millimetres; :class:`PlanConfig`
keeps them as given and the planner converts once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from robocal.config import SettingError, parse, setting

CRITERIA = ("D", "A", "I")
VOLUME_KINDS = ("none", "box", "iso9283")

Vec3 = tuple[float, float, float]


def _ranges(value: tuple[tuple[float, float], ...] | None) -> str | None:
    if value is not None and (not value or any(lo >= hi for lo, hi in value)):
        return "must be a list of [min, max] per joint in degrees, min < max"
    return None


def _direction(value: Vec3) -> str | None:
    return "must be a non-zero direction" if float(np.linalg.norm(value)) < 1e-9 else None


def _upper(value: Any) -> Any:
    return value.upper() if isinstance(value, str) else value


@dataclass(frozen=True)
class Target:
    """A reflector (or 6-DoF probe) on the tool: position in the flange frame (mm) and its facing direction."""

    name: str
    position_mm: Vec3
    normal: Vec3 = setting((0.0, 0.0, 1.0), check=_direction)


@dataclass(frozen=True)
class TrackerConfig:
    """Where the tracker stands (robot base frame, mm) and what it can see.

    acceptance_half_angle_deg: the reflector's acceptance cone (angle between its normal and the line to the
    tracker); 180 switches the check off. min_range_mm / max_range_mm: the tracker's distance range.
    """

    position_mm: Vec3 = (922.26, 2618.05, 328.26)
    acceptance_half_angle_deg: float = setting(50.0, gt=0, le=180)
    min_range_mm: float = setting(1000.0, ge=0)
    max_range_mm: float = setting(20000.0, gt=0)
    min_targets_visible: int = setting(1, ge=1)

    def validate(self) -> None:
        if self.min_range_mm >= self.max_range_mm:
            raise SettingError("min_range_mm", "must be below tracker.max_range_mm", self.min_range_mm)


@dataclass(frozen=True)
class VolumeConfig:
    """Working volume the targets must lie in (base frame): ``none``, ``box`` (min_mm / max_mm) or
    ``iso9283`` (an axis-aligned cube: center_mm, side_mm, as the ISO 9283 test cube)."""

    kind: str = setting("none", choices=VOLUME_KINDS)
    min_mm: Vec3 | None = None
    max_mm: Vec3 | None = None
    center_mm: Vec3 | None = None
    side_mm: float | None = setting(None, gt=0)

    def validate(self) -> None:
        if self.kind == "box":
            if self.min_mm is None or self.max_mm is None:
                raise SettingError("min_mm", "must be given (with volume.max_mm) for a box volume", self.min_mm)
            if np.any(np.asarray(self.min_mm) >= np.asarray(self.max_mm)):
                raise SettingError("min_mm", "must be below volume.max_mm on every axis", self.min_mm)
        if self.kind == "iso9283" and (self.center_mm is None or self.side_mm is None):
            raise SettingError("center_mm", "must be given (with volume.side_mm) for an iso9283 cube", self.center_mm)

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

    min_sigma: float = setting(0.02, ge=0)
    length_mm: float = setting(1000.0, gt=0)
    wrist_joint: int = 5
    min_wrist_deg: float = setting(10.0, ge=0)


@dataclass(frozen=True)
class CollisionConfig:
    """Self-collision by link capsules: body ``b`` (0 = base, i = moved by joint i, the tool with the last)
    is a set of segments of radius ``radius_mm[b]``; bodies at least ``skip`` apart must not touch."""

    enabled: bool = False
    radius_mm: tuple[float, ...] = setting(
        (150.0, 120.0, 100.0, 90.0, 70.0, 60.0, 40.0),
        ge=0,
        check=lambda r: None if r else "must be a list of radii >= 0, one per body",
    )
    skip: int = setting(2, ge=1)
    clearance_mm: float = setting(0.0, ge=0)


REGION_KINDS = ("working_range", "joints", "box", "poses", "cell")


@dataclass(frozen=True)
class RegionConfig:
    """The region the plan is made for: where the calibrated model must be accurate (the I-criterion, the
    predicted error map and the reported RMS are over it). ``n`` configurations of

    * ``working_range`` (default): the robot's working range, its joint limits less ``joint_margin_deg``
      (and no self-collision when the capsules are on). The tracker need not see them: the robot works there;
    * ``joints``: ``ranges_deg`` per joint (within the working range);
    * ``box``: the tool point (the first target) inside ``min_mm`` .. ``max_mm`` (robot base frame), within
      the working range -- where the parts sit;
    * ``poses``: exactly the given joint configurations (``poses``: a list of ``[q1, ..., qN]`` in degrees, or
      a CSV file with ``q1_deg .. qN_deg`` columns, e.g. a program's poses or another plan.csv);
    * ``cell``: what the candidates are drawn from, with every check of the cell (tracker range, line of sight,
      volume, singularity): only poses the tracker can measure (the planner's region before issue 23).
    """

    kind: str = setting("working_range", choices=REGION_KINDS)
    n: int = setting(400, ge=1)
    ranges_deg: tuple[tuple[float, float], ...] | None = setting(None, check=_ranges)
    min_mm: Vec3 | None = None
    max_mm: Vec3 | None = None
    poses: str | tuple[tuple[float, ...], ...] | None = None

    def validate(self) -> None:
        wants = {"joints": "ranges_deg", "box": "min_mm", "poses": "poses"}
        for kind, key in wants.items():
            if self.kind == kind and getattr(self, key) is None:
                raise SettingError(key, f"must be given for a region of kind {kind!r}", None)
        for key, kinds in (("ranges_deg", ("joints", "cell")), ("min_mm", ("box",)), ("poses", ("poses",))):
            if getattr(self, key) is not None and self.kind not in kinds:
                raise SettingError(
                    key,
                    f"is a setting of region.kind {' or '.join(map(repr, kinds))}, not {self.kind!r}",
                    getattr(self, key),
                )
        if self.kind == "box":
            if self.max_mm is None:
                raise SettingError("max_mm", "must be given (with region.min_mm) for a box region", None)
            if np.any(np.asarray(self.min_mm) >= np.asarray(self.max_mm)):
                raise SettingError("min_mm", "must be below region.max_mm on every axis", self.min_mm)

    def describe(self, margin_deg: float = 5.0) -> str:
        """One line for the console and the report: which region the plan is optimal for."""
        if self.kind == "working_range":
            return f"the robot's working range (its joint limits less {margin_deg:g} deg)"
        if self.kind == "joints":
            assert self.ranges_deg is not None
            return (
                "joint ranges "
                + ", ".join(f"q{j + 1} {lo:g}..{hi:g}" for j, (lo, hi) in enumerate(self.ranges_deg))
                + " deg"
            )
        if self.kind == "box":
            assert self.min_mm is not None and self.max_mm is not None
            lo, hi = self.min_mm, self.max_mm
            return (
                "tool point in the box "
                + ", ".join(f"{a} {lo[k]:g}..{hi[k]:g}" for k, a in enumerate("xyz"))
                + " mm (base frame)"
            )
        if self.kind == "poses":
            return f"the given poses ({self.poses})" if isinstance(self.poses, str) else "the given poses"
        return "the poses the cell allows (the tracker's view, the volume, the singularity checks)"


@dataclass(frozen=True)
class PlanConfig:
    """Settings of :func:`robocal.plan.plan_poses` (see ``conf/plan/default.yaml`` for each key)."""

    n_poses: int = setting(40, ge=1)
    criterion: str = setting("I", choices=CRITERIA, convert=_upper)
    seed: int = setting(0, ge=0)
    n_candidates: int = setting(20000, ge=1)
    joint_margin_deg: float = setting(5.0, ge=0)
    ranges_deg: tuple[tuple[float, float], ...] | None = setting(None, check=_ranges)
    noise_mm: float = setting(0.015, gt=0)
    noise_deg: float = setting(0.01, gt=0)
    orientation: bool = False
    rank_tol: float = setting(1e-6, gt=0)
    fixed: tuple[str, ...] = ()
    targets: tuple[Target, ...] = setting((Target("T1", (35.0, -20.0, 120.0)),), convert=lambda v: _targets(v))
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    volume: VolumeConfig = field(default_factory=VolumeConfig)
    singularity: SingularityConfig = field(default_factory=SingularityConfig)
    collision: CollisionConfig = field(default_factory=CollisionConfig)
    region: RegionConfig = field(default_factory=RegionConfig)
    min_orientation_spread_deg: float = setting(0.0, ge=0)
    accuracy_mm: float = setting(0.02, gt=0)
    max_exchanges: int = setting(2000, ge=0)
    active_set: int = setting(4000, ge=1)
    report: bool = True

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> PlanConfig:
        """Build from a mapping (a Hydra node, YAML, CLI overrides); errors name the key. ``measured_by_twin``
        is the pipeline's switch (the twin measures the plan), not a planning setting."""
        return parse(cls, cfg, "plan", ignore=("measured_by_twin",))


def _targets(value: Any) -> Any:
    """``{name: {position_mm, normal} or [x, y, z]}`` -> targets with unit normals (already parsed: as is)."""
    if isinstance(value, tuple) and all(isinstance(t, Target) for t in value):
        return value
    if not isinstance(value, Mapping) or not value:
        raise ValueError("must be a mapping of target names to {position_mm, normal} (or [x, y, z])")
    out = []
    for name, spec in value.items():
        if not isinstance(spec, Mapping):
            spec = {"position_mm": spec}
        elif "name" in spec:
            raise SettingError(f"{name}.name", "unknown setting (the target's name is its key)", spec["name"])
        t = parse(Target, {**spec, "name": str(name)}, str(name))
        n = np.asarray(t.normal) / np.linalg.norm(t.normal)
        out.append(replace(t, normal=(float(n[0]), float(n[1]), float(n[2]))))
    return tuple(out)
