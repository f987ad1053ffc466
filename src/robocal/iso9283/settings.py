"""Settings of the ISO 9283 test (``conf/iso9283/default.yaml``), checked by the one settings parser.

Errors name the key: ``iso9283.test.cycles: must be an integer >= 2; got 1``. Where the standard gives a choice
(cube size, load, speed, number of cycles) its default is the setting's default.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from robocal.config import SettingError, parse, setting
from robocal.plan.config import VolumeConfig

DEFAULT_FILE = Path(__file__).resolve().parents[3] / "conf" / "iso9283" / "default.yaml"


def _labels(value: tuple[str, ...]) -> str | None:
    if not value or any(not str(v).strip() for v in value) or len(set(value)) != len(value):
        return "must be a non-empty list of distinct labels"
    return None


@dataclass(frozen=True)
class TestConfig:
    """The test the standard describes: cycles, load, speed, approach directions and the cube (base frame)."""

    cycles: int = setting(30, ge=2)
    load_percent: float = setting(100.0, ge=0, le=100)
    speed_percent: float = setting(100.0, gt=0, le=100)
    rated_payload_kg: float | None = setting(None, ge=0)
    approaches: tuple[str, ...] = setting(("-x", "-y", "-z"), check=_labels)
    volume: VolumeConfig = field(
        default_factory=lambda: VolumeConfig(kind="iso9283", center_mm=(1300.0, 0.0, 1000.0), side_mm=400.0)
    )
    inset: float = setting(0.1, gt=0, lt=0.5)
    interval_s: float = setting(8.0, gt=0)
    approach_mm: float = setting(100.0, gt=0)
    tcp_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def validate(self) -> None:
        if self.volume.kind != "iso9283":
            raise SettingError("volume.kind", "must be iso9283 (the test cube: center_mm, side_mm)", self.volume.kind)
        for a in self.approaches:
            if a not in AXES:
                raise SettingError("approaches", f"each must be one of {sorted(AXES)}", list(self.approaches))


#: approach label -> direction of travel into the pose (base frame)
AXES = {
    "-x": (-1.0, 0.0, 0.0),
    "+x": (1.0, 0.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-z": (0.0, 0.0, -1.0),
    "+z": (0.0, 0.0, 1.0),
}


@dataclass(frozen=True)
class TwinConfig:
    """The twin's ISO test: which scenario's cell, and the robot's own scatter (repeatability)."""

    scenario: str = "geometric"
    repeatability_mm: float = setting(0.01, ge=0)
    repeatability_deg: float = setting(0.001, ge=0)
    seed_q_deg: tuple[float, ...] | None = None


@dataclass(frozen=True)
class AnalysisConfig:
    """How a measured test is evaluated: which target and approach, the distance pair, drift and gross errors."""

    target: str | None = None
    ap_approach: str | None = None
    distance_pair: tuple[str, str] = ("P2", "P4")
    drift_group_cycles: int = setting(10, ge=2)
    gross_error_k: float = setting(7.0, gt=0)
    gross_error_floor_mm: float = setting(0.005, ge=0)


@dataclass(frozen=True)
class CertificateConfig:
    serial: str | None = None
    cell: str | None = None


@dataclass(frozen=True)
class IsoSettings:
    """Every setting of ``conf/iso9283/default.yaml`` (see the file for each key)."""

    test: TestConfig = field(default_factory=TestConfig)
    twin: TwinConfig = field(default_factory=TwinConfig)
    analysis: AnalysisConfig = field(default_factory=AnalysisConfig)
    certificate: CertificateConfig = field(default_factory=CertificateConfig)
    #: the pipeline's ``iso9283`` stage: the calibration.json that registers the tracker to the base and predicts
    #: the "after" (default: the geometric stage's reports/geometric/calibration.json)
    calibration: str | None = None

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> IsoSettings:
        return parse(cls, cfg, "iso9283")

    @classmethod
    def load(cls, overrides: Mapping[str, Any] | None = None, path: str | Path = DEFAULT_FILE) -> IsoSettings:
        """The defaults file merged with ``overrides`` (nested mappings merge key by key)."""
        base = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
        return cls.from_mapping(merge(base, dict(overrides or {})))


def merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``over`` on top of ``base``, nested mappings merged key by key."""
    out = dict(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


SECTIONS = ("test", "twin", "analysis", "certificate")

__all__ = ["AXES", "SECTIONS", "AnalysisConfig", "CertificateConfig", "IsoSettings", "TestConfig", "TwinConfig"]
