"""The fleet layout: one folder per robot, campaigns by date, read and checked at the door.

Layout::

    FLEET_DIR/
      fleet.yaml                 optional: {name: "plant 3"}; anything else is kept and ignored
      truth.json                 optional: the twin's planted events (robocal fleet --simulate)
      <serial>/                  one folder per robot, named by its serial number
        robot.yaml               serial: <serial>          (must equal the folder name)
                                 robot: kr16_2             (a conf/robot name, or a YAML file in this folder)
        2026-01-05/              one campaign per date (YYYY-MM-DD), in the data contract (poses.csv ...)
        2026-04-05/
        2026-04-05_2/            a second campaign on the same day: YYYY-MM-DD_<n>

Folders that start with ``.`` or ``_`` are skipped (``_notes/``, ``.dvc/``). Anything else in a robot folder
that is not a campaign is an error naming it, so a mistyped date never silently drops a campaign.

Every campaign has a content hash (sha256 over its files' relative paths and bytes) that, with the robot
description's bytes and the calibration settings, keys the cached results of :mod:`robocal.fleet.engine`.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from datetime import date
from pathlib import Path
from typing import Any

import yaml

from robocal.errors import ConfigError

#: A serial number: letters, digits, ``.``, ``_``, ``-``; starts with a letter or digit; at most 64 characters.
#: (It becomes the MLflow model name ``robot-<serial>`` and a folder name, so nothing else is allowed.)
SERIAL_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
#: A campaign folder: ``YYYY-MM-DD`` or ``YYYY-MM-DD_<n>``.
CAMPAIGN_RE = re.compile(r"^(\d{4})-(\d{2})-(\d{2})(?:_(\d+))?$")
ROBOT_FILE = "robot.yaml"
POSES_FILES = ("poses.csv", "poses.parquet")


@dataclass(frozen=True)
class CampaignRef:
    """One campaign folder of one robot: ``name`` (the folder name), ``day`` (its date), ``path``, ``sha256``."""

    name: str
    day: date
    path: Path
    sha256: str


@dataclass(frozen=True)
class RobotFolder:
    """One robot: ``serial``, its description reference ``robot`` (a conf/robot name or an absolute YAML path),
    ``robot_sha256`` (of the description file's bytes) and its campaigns in date order."""

    serial: str
    robot: str
    robot_sha256: str
    path: Path
    campaigns: tuple[CampaignRef, ...]


@dataclass(frozen=True)
class Fleet:
    path: Path
    robots: tuple[RobotFolder, ...]
    meta: dict[str, Any]

    def robot(self, serial: str) -> RobotFolder:
        for r in self.robots:
            if r.serial == serial:
                return r
        raise ConfigError(
            f"fleet {self.path}: no robot with serial {serial!r}; serials: {[r.serial for r in self.robots]}"
        )

    @property
    def n_campaigns(self) -> int:
        return sum(len(r.campaigns) for r in self.robots)


def campaign_dir(out_dir: str | Path, serial: str, campaign: str) -> Path:
    """Where the fleet engine writes one campaign's results: ``OUT/robots/<serial>/<campaign>/``."""
    return Path(out_dir) / "robots" / serial / campaign


def check_serial(serial: str, where: str | Path) -> str:
    """``serial`` if it is a valid serial number, else a ConfigError naming ``where``."""
    if not isinstance(serial, str) or not SERIAL_RE.match(serial):
        raise ConfigError(
            f"{where}: the serial number {serial!r} is not valid: use letters, digits, '.', '_' or '-' "
            "(starting with a letter or digit, at most 64 characters)"
        )
    return serial


def folder_sha256(path: Path) -> str:
    """sha256 over every file under ``path`` (relative POSIX path, NUL, size, NUL, bytes), in sorted order."""
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        rel = f.relative_to(path).as_posix()
        if any(part.startswith(".") for part in rel.split("/")):
            continue
        data = f.read_bytes()
        h.update(rel.encode() + b"\0" + str(len(data)).encode() + b"\0")
        h.update(data)
    return h.hexdigest()


def _robot_ref(folder: Path, raw: Any) -> tuple[str, str]:
    """(reference for load_robot, sha256 of the description's bytes)."""
    from robocal.robot import SHIPPED_ROBOT_DIR, find_robot

    if not isinstance(raw, str) or not raw.strip():
        raise ConfigError(f"{folder / ROBOT_FILE}: 'robot' must name a robot description (e.g. kr16_2 or a YAML file)")
    if raw.endswith((".yaml", ".yml")):
        p = (folder / raw).resolve()
        if not p.is_file():
            raise ConfigError(f"{folder / ROBOT_FILE}: the robot description {p} does not exist")
        return str(p), hashlib.sha256(p.read_bytes()).hexdigest()
    try:  # the one lookup order: the current project's conf/robot/, then the packaged robots
        p = find_robot(raw)
    except ConfigError as exc:
        raise ConfigError(f"{folder / ROBOT_FILE}: {exc}") from None
    # a packaged robot stays a name; a project's own is referenced by its path (workers may run elsewhere)
    ref = raw if p.resolve().parent == SHIPPED_ROBOT_DIR.resolve() else str(p.resolve())
    return ref, hashlib.sha256(p.read_bytes()).hexdigest()


def read_robot_folder(folder: str | Path) -> RobotFolder:
    """Read and check one robot folder (see the module docstring)."""
    d = Path(folder)
    if not d.is_dir():
        raise ConfigError(f"robot folder {d} does not exist")
    rf = d / ROBOT_FILE
    if not rf.is_file():
        raise ConfigError(f"robot folder {d}: no {ROBOT_FILE} (serial: ..., robot: ...)")
    try:
        meta = yaml.safe_load(rf.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{rf}: not valid YAML: {exc}") from None
    if not isinstance(meta, dict):
        raise ConfigError(f"{rf}: must be a mapping with 'serial' and 'robot'")
    serial = check_serial(str(meta.get("serial", "")), rf)
    if serial != d.name:
        raise ConfigError(f"{rf}: serial {serial!r} does not match its folder name {d.name!r}")
    robot, robot_sha = _robot_ref(d, meta.get("robot"))
    campaigns = []
    for sub in sorted(d.iterdir()):
        if sub.name.startswith((".", "_")) or sub.name == ROBOT_FILE or sub.is_file():
            continue
        m = CAMPAIGN_RE.match(sub.name)
        if not m:
            raise ConfigError(f"{sub}: not a campaign folder: campaign folders are named YYYY-MM-DD (or YYYY-MM-DD_2)")
        try:
            day = date(int(m[1]), int(m[2]), int(m[3]))
        except ValueError as exc:
            raise ConfigError(f"{sub}: not a valid date: {exc}") from None
        if not any((sub / f).is_file() for f in POSES_FILES):
            raise ConfigError(f"{sub}: campaign folder without poses.csv or poses.parquet")
        campaigns.append(CampaignRef(sub.name, day, sub.resolve(), folder_sha256(sub)))
    if not campaigns:
        raise ConfigError(f"robot folder {d}: no campaign folder (YYYY-MM-DD/ with poses.csv)")
    campaigns.sort(key=lambda c: (c.day, int(CAMPAIGN_RE.match(c.name)[4] or 0)))  # type: ignore[index]
    return RobotFolder(serial, robot, robot_sha, d.resolve(), tuple(campaigns))


def read_fleet(fleet_dir: str | Path, serials: list[str] | None = None) -> Fleet:
    """Read and check a fleet folder; ``serials`` keeps only those robots (each must exist)."""
    d = Path(fleet_dir)
    if not d.is_dir():
        raise ConfigError(f"fleet folder {d} does not exist")
    meta: dict[str, Any] = {}
    fy = d / "fleet.yaml"
    if fy.is_file():
        try:
            meta = dict(yaml.safe_load(fy.read_text(encoding="utf-8")) or {})
        except (OSError, yaml.YAMLError, TypeError, ValueError) as exc:
            raise ConfigError(f"{fy}: not a valid YAML mapping: {exc}") from None
    robots = []
    for sub in sorted(d.iterdir()):
        if not sub.is_dir() or sub.name.startswith((".", "_")):
            continue
        if not (sub / ROBOT_FILE).is_file():
            continue  # not a robot folder (e.g. the output of a run, a DVC folder)
        robots.append(read_robot_folder(sub))
    if not robots:
        raise ConfigError(f"fleet folder {d}: no robot folder (<serial>/robot.yaml)")
    fleet = Fleet(d.resolve(), tuple(robots), meta)
    if serials:
        fleet = Fleet(fleet.path, tuple(fleet.robot(check_serial(s, "--robot")) for s in serials), meta)
    return fleet
