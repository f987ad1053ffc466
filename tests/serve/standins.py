"""Small stand-in thermal and compliance models with the interfaces the bundle loads (tests only).

StandinThermal: ``deta = G (T - T0)`` (P parameters, s sensors), fitted range per sensor.
StandinCompliance: ``dq_j = c_j * current_j`` with currents, else ``-c_j * payload * cos(q_j)``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np


class StandinThermal:
    def __init__(self, sensors: list[str], G: np.ndarray, T0: float, temperature_range: np.ndarray) -> None:
        self.sensors = tuple(sensors)
        self.G = np.asarray(G, dtype=float)  # (P, s)
        self.T0 = float(T0)
        self.temperature_range = np.asarray(temperature_range, dtype=float)  # (s, 2)

    def deta(self, temperatures: np.ndarray) -> np.ndarray:
        T = np.atleast_2d(np.asarray(temperatures, dtype=float))
        return (T - self.T0) @ self.G.T

    def to_json(self, path: str | Path) -> Path:
        p = Path(path)
        p.write_text(
            json.dumps(
                {
                    "sensors": list(self.sensors),
                    "G": self.G.tolist(),
                    "T0": self.T0,
                    "temperature_range": self.temperature_range.tolist(),
                }
            )
        )
        return p

    @classmethod
    def from_json(cls, path: str | Path) -> StandinThermal:
        d: dict[str, Any] = json.loads(Path(path).read_text())
        return cls(d["sensors"], np.array(d["G"]), d["T0"], np.array(d["temperature_range"]))


class StandinCompliance:
    def __init__(self, c: np.ndarray) -> None:
        self.c = np.asarray(c, dtype=float)

    def joint_offsets(self, q, payload_kg, current_A=None, tau_Nm=None):  # type: ignore[no-untyped-def]
        q = np.asarray(q, dtype=float)
        if current_A is not None:
            return self.c * np.asarray(current_A, dtype=float)
        return -self.c * np.asarray(payload_kg, dtype=float)[:, None] * np.cos(q)

    def to_json(self, path: str | Path) -> Path:
        p = Path(path)
        p.write_text(json.dumps({"c": self.c.tolist()}))
        return p

    @classmethod
    def from_json(cls, path: str | Path) -> StandinCompliance:
        return cls(np.array(json.loads(Path(path).read_text())["c"]))
