"""Logged signals: numeric columns of ``poses.csv`` beyond the data contract, and how a user declares them.

Any numeric column the contract does not name (an inclinometer, an accelerometer, an external axis position, an
air or part temperature, a load cell, a time counter) is a *logged signal*. Discovery offers each one as the
possible driver of a base or tool rotation / translation or a joint offset (:mod:`robocal.discovery.logged`).
A signal may be declared, by name, in the robot description (``signals:``) or in a ``signals.yaml`` beside the
campaign (the campaign's declaration wins)::

    signals:
      incl_x: {unit: mrad, location: base, description: "inclinometer on the stand, tilt about base x"}
      axis7_mm: {unit: mm, location: external axis}
      note_id: {use: false}             # a numeric column that is not a signal (never tried)

``unit`` and ``description`` are reported with every effect the signal drives; ``location`` says where the
sensor sits: ``tracker`` (or ``measurement``) makes the effects it drives measurement-side (they correct the
figures, never the robot), any other place (``base``, ``stand``, ``tool``, ``joint 3``, ``cell``...) robot-side.
An undeclared numeric column is still tried, named by its column as found.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from robocal.errors import ConfigError

#: sensor locations whose signals drive measurement-side effects
MEASUREMENT_LOCATIONS = ("tracker", "measurement")
#: the keys a declaration may have
DECLARATION_KEYS = ("unit", "location", "description", "use")
#: radians per unit of an angle a logged signal may be declared in (a tilt's gain is then dimensionless)
ANGLE_UNITS = {"rad": 1.0, "mrad": 1e-3, "urad": 1e-6, "µrad": 1e-6, "deg": np.pi / 180.0,
               "arcsec": np.pi / 648000.0, "arcmin": np.pi / 10800.0}  # fmt: skip
#: the file beside a campaign that declares its signals
SIGNALS_FILE = "signals.yaml"


@dataclass(frozen=True)
class SignalDeclaration:
    """A declared logged signal: its column ``name``, ``unit``, where the sensor sits, a description, and whether
    discovery may use it."""

    name: str
    unit: str = ""
    location: str = ""
    description: str = ""
    use: bool = True

    @property
    def measurement_side(self) -> bool:
        return self.location.strip().lower() in MEASUREMENT_LOCATIONS

    def to_dict(self) -> dict[str, Any]:
        return {"unit": self.unit, "location": self.location, "description": self.description, "use": self.use}


def parse_declarations(value: Any, source: str) -> tuple[SignalDeclaration, ...]:
    """The declarations of a ``signals`` mapping (``{column: {unit, location, description, use}}``); a bad entry
    is a :class:`~robocal.errors.ConfigError` naming ``source`` and the key."""
    if value is None:
        return ()
    if not isinstance(value, Mapping):
        raise ConfigError(f"{source}: 'signals' must map column names to {{unit, location, description, use}}")
    out = []
    for name, d in value.items():
        d = {} if d is None else d
        if not isinstance(d, Mapping):
            raise ConfigError(f"{source}: signals.{name} must be a mapping with {list(DECLARATION_KEYS)}")
        unknown = sorted(set(map(str, d)) - set(DECLARATION_KEYS))
        if unknown:
            raise ConfigError(f"{source}: signals.{name} has unknown key(s) {unknown}; known: {list(DECLARATION_KEYS)}")
        use = d.get("use", True)
        if not isinstance(use, bool):
            raise ConfigError(f"{source}: signals.{name}.use must be true or false, got {use!r}")
        out.append(
            SignalDeclaration(
                str(name), str(d.get("unit", "") or ""), str(d.get("location", "") or ""),
                str(d.get("description", "") or ""), use,
            )
        )  # fmt: skip
    return tuple(out)


def read_signals_file(folder: str | Path) -> tuple[SignalDeclaration, ...]:
    """The declarations of ``signals.yaml`` in a campaign folder (none without the file)."""
    path = Path(folder) / SIGNALS_FILE
    if not path.is_file():
        return ()
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from None
    if data is None:
        return ()
    if not isinstance(data, Mapping) or set(data) - {"signals"}:
        raise ConfigError(f"{path}: must hold one key 'signals' (a mapping of column names)")
    return parse_declarations(data.get("signals"), str(path))


def merged(*groups: tuple[SignalDeclaration, ...]) -> dict[str, SignalDeclaration]:
    """The declarations by column name, a later group's replacing an earlier one's."""
    out: dict[str, SignalDeclaration] = {}
    for g in groups:
        out.update({d.name: d for d in g})
    return out
