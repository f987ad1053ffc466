"""The screening result: the table of every parameter and the selection."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from robocal.errors import ConfigError
from robocal.thermal.screening.config import COLUMNS, FORMAT

if TYPE_CHECKING:
    pass


# ------------------------------------------------------------------------------------------------ result


@dataclass
class ScreeningResult:
    """Outcome of :func:`screen`.

    table : one row per screened parameter, chain order; columns :data:`COLUMNS` — ``step`` in ``unit`` (mm or
    deg); position errors mm; orientation errors the Frobenius norm of eq. 24 (and ``mean_orientation_deg`` as an
    angle); ``E_mean`` mean total error (eq. 25); ``drift`` d_eta(T) in ``unit`` (NaN when unknown); ``P_o``,
    ``H`` (eq. 26-27); ``score`` what the rule ranks (``|H|`` or ``E_mean``); ``share`` of the summed score;
    ``rank`` (1 = most influential); ``selected``.
    selected : selected chain parameter names, chain order. score : ``"|H|"`` or ``"E_mean"``.
    what_if : the borderline parameters and which change of the rule would add or drop them, and why
    (:func:`_what_if`: ``parameter, selected, action, score, rank, cut, drift_z, significant, why, changes, text``).
    """

    robot: str
    table: pd.DataFrame
    selected: list[str]
    score: str
    config: dict[str, Any]
    seed: int
    drift_states: int = 0
    drift_state_used: int | str | None = None
    notes: list[str] = field(default_factory=list)
    what_if: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        rows = []
        for rec in self.table.to_dict(orient="records"):
            rows.append({k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in rec.items()})
        return {
            "format": FORMAT,
            "robot": self.robot,
            "seed": self.seed,
            "score": self.score,
            "selected": list(self.selected),
            "drift_states": self.drift_states,
            "drift_state_used": self.drift_state_used,
            "config": self.config,
            "notes": list(self.notes),
            "what_if": [
                {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in w.items()}
                for w in self.what_if
            ],
            "table": rows,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ScreeningResult:
        fmt = d.get("format", FORMAT)
        if fmt != FORMAT:
            raise ConfigError(f"screening result format {fmt!r} is not {FORMAT!r}")
        try:
            table = pd.DataFrame(list(d["table"]), columns=list(COLUMNS))
            for c in COLUMNS:
                if c not in ("parameter", "kind", "unit", "selected", "rank"):
                    table[c] = table[c].astype(float)
            table["selected"] = table["selected"].astype(bool)
            table["rank"] = table["rank"].astype(int)
            return cls(
                robot=str(d["robot"]),
                table=table,
                selected=[str(s) for s in d["selected"]],
                score=str(d["score"]),
                config=dict(d.get("config", {})),
                seed=int(d.get("seed", 0)),
                drift_states=int(d.get("drift_states", 0)),
                drift_state_used=d.get("drift_state_used"),
                notes=[str(s) for s in d.get("notes", [])],
                what_if=[dict(w) for w in d.get("what_if", [])],
            )
        except KeyError as exc:
            raise ConfigError(f"screening result is missing the key {exc.args[0]!r}") from None

    @classmethod
    def from_json(cls, path: str | Path) -> ScreeningResult:
        """Read ``screening.json`` (what the thermal validation stage uses for ``selected``)."""
        p = Path(path)
        try:
            return cls.from_dict(json.loads(p.read_text(encoding="utf-8")))
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"cannot read a screening result from {p}: {exc}") from None
