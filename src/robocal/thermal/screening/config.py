"""Screening settings (conf/screen/), constants and the drift files it reads."""

from __future__ import annotations

import json
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from robocal.config import parse, setting
from robocal.errors import ConfigError

FORMAT = "robocal.screening/1"
RULES = ("threshold", "share", "top_k", "relative")
DRIFT_STATES = ("last", "max_abs")
#: Columns of :attr:`ScreeningResult.table`, in order.
COLUMNS = (
    "parameter",
    "kind",
    "unit",
    "step",
    "mean_position_mm",
    "max_position_mm",
    "mean_orientation",
    "max_orientation",
    "mean_orientation_deg",
    "jacobian_mean_position_mm",
    "E_mean",
    "drift",
    "drift_z",
    "P_o",
    "H",
    "score",
    "share",
    "rank",
    "selected",
)
_CHUNK = 50_000  # (perturbations x configurations) per propagation chunk: bounds memory for large n_configs


# ------------------------------------------------------------------------------------------------ config


def _tools(v: Any) -> Any:
    """``{name: [x, y, z]}`` (e.g. a calibration's tools_mm) or one ``[x, y, z]`` -> a list of tool points."""
    if isinstance(v, Mapping):
        v = list(v.values())
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, list | tuple) and v and all(isinstance(x, numbers.Real) for x in v):
        return [v]
    return v


def _states(v: Any) -> Any:
    """``{parameter: value or [value per state]}``: a single value is one state."""
    if isinstance(v, Mapping):
        return {k: [x] if isinstance(x, numbers.Real) and not isinstance(x, bool) else x for k, x in v.items()}
    return v


def _drift_check(drift: Mapping[str, tuple[float, ...]] | None) -> str | None:
    if drift is None:
        return None
    if any(not d for d in drift.values()):
        return "must give every parameter a drift value (or a list of them)"
    sizes = {len(d) for d in drift.values()}
    return f"must give every parameter the same number of states, not {sorted(sizes)}" if len(sizes) > 1 else None


@dataclass(frozen=True)
class SelectionConfig:
    """The selection rule (``screen.selection``).

    rule : ``threshold`` (score >= ``h_min``), ``share`` (the fewest top parameters whose scores sum to at
    least ``share`` of the total), ``top_k`` (the ``top_k`` largest), ``relative`` (score >= ``relative`` x the
    largest score). min_z : additionally require a significant drift, ``|d_eta| >= min_z x its standard error``
    (when the drift comes with standard errors; 0 = off). include / exclude : name patterns always / never
    selected (applied after the rule). explain_band : parameters whose score lies within this factor of the
    rule's cut are "near the threshold" and explained (:attr:`ScreeningResult.what_if`); explain_z : a drift
    below this many standard errors is called not significant there.
    """

    rule: str = setting("threshold", choices=RULES)
    h_min: float = setting(0.015, ge=0)
    share: float = setting(0.95, gt=0, le=1)
    top_k: int = setting(9, ge=1)
    relative: float = setting(0.05, gt=0, le=1)
    min_z: float = setting(0.0, ge=0)
    include: tuple[str, ...] = ()
    exclude: tuple[str, ...] = ()
    explain_band: float = setting(2.0, ge=1)
    explain_z: float = setting(2.0, gt=0)

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any] | None) -> SelectionConfig:
        return parse(cls, d, "screen.selection")

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v := getattr(self, k), tuple) else v for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class ScreeningConfig:
    """Settings of :func:`screen` (``conf/screen/default.yaml``); lengths mm, angles deg as written there.

    n_configs : random joint configurations; joint_range_fraction : sample within this share of each joint
    range (about its centre; 1 = the full range of table 3); angle_step_deg / length_step_mm : the perturbation
    ``delta`` (applied with both signs); tool_mm : tool points in the flange frame, ``(K, 3)`` (None: the flange
    origin); drift : ``{parameter: value or [value per state]}`` in mm / deg; drift_state : which state gives
    ``P_o(T)`` when the drift has several (``last`` = thermal equilibrium in a warm-up, ``max_abs``, or an
    index); drift_file : a drift file for the stage (:func:`load_drift`; not read by :func:`screen`);
    selection : :class:`SelectionConfig`; seed : the stage's seed (``screen.seed``); :func:`screen` itself uses
    its ``seed`` argument, and the result's ``config["seed"]`` records the seed actually used.
    """

    n_configs: int = setting(500, ge=1)
    joint_range_fraction: float = setting(1.0, gt=0, le=1)
    angle_step_deg: float = setting(0.01, gt=0)
    length_step_mm: float = setting(0.1, gt=0)
    tool_mm: tuple[tuple[float, float, float], ...] | None = setting(
        None, convert=_tools, check=lambda t: "must hold at least one tool point" if t == () else None
    )
    drift: Mapping[str, tuple[float, ...]] | None = setting(None, convert=_states, check=_drift_check)
    drift_state: str | int = setting("last", choices=DRIFT_STATES)
    drift_file: str | None = setting(None, convert=lambda p: str(p) if isinstance(p, Path) else p)
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    seed: int | None = None

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any] | None) -> ScreeningConfig:
        """Validate a config mapping; every problem is a :class:`ConfigError` naming the key."""
        return parse(cls, d, "screen")

    def to_dict(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "n_configs": self.n_configs,
            "joint_range_fraction": self.joint_range_fraction,
            "angle_step_deg": self.angle_step_deg,
            "length_step_mm": self.length_step_mm,
            "tool_mm": None if self.tool_mm is None else [list(t) for t in self.tool_mm],
            "drift": None if self.drift is None else {k: list(v) for k, v in self.drift.items()},
            "drift_state": self.drift_state,
            "drift_file": self.drift_file,
            "selection": self.selection.to_dict(),
        }


def _drift_mapping(v: Any, where: str) -> dict[str, tuple[float, ...]] | None:
    """``{name: value or [values]}`` -> ``{name: (values,)}``, all with the same number of states."""
    if v is None:
        return None
    if not isinstance(v, Mapping):
        raise ConfigError(f"The config key '{where}' must be a mapping of parameter name to drift. Got {v!r} instead.")
    out: dict[str, tuple[float, ...]] = {}
    for k, x in v.items():
        try:
            arr = np.atleast_1d(np.asarray(x, dtype=float))
        except (TypeError, ValueError):
            raise ConfigError(
                f"The config key '{where}.{k}' must be a number or a list of numbers. Got {x!r}."
            ) from None
        if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
            raise ConfigError(f"The config key '{where}.{k}' must be a finite number or list of them. Got {x!r}.")
        out[str(k)] = tuple(float(a) for a in arr)
    sizes = {len(a) for a in out.values()}
    if len(sizes) > 1:
        raise ConfigError(f"The config key '{where}': every parameter needs the same number of states. Got {sizes}.")
    return out


def load_drift_stderr(path: str | Path) -> dict[str, float] | None:
    """Per-parameter standard error of the drift in a per-state drift file (``"stderr"`` beside ``"names"`` and
    ``"deta"``, as :meth:`robocal.thermal.identify.StateDrift.to_dict` writes), or None when it has none."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"cannot read the drift file {p}: {exc}") from None
    if isinstance(data, Mapping):
        for key in ("states", "state_drift", "drift"):
            inner = data.get(key)
            if isinstance(inner, Mapping) and "deta" in inner:
                data = inner
                break
    if not (isinstance(data, Mapping) and "stderr" in data and ("names" in data or "param_names" in data)):
        return None
    names = [str(n) for n in data.get("param_names", data.get("names"))]
    se = [np.nan if v is None else float(v) for v in data["stderr"]]
    if len(se) != len(names):
        raise ConfigError(f"drift file {p}: 'stderr' has {len(se)} entries for {len(names)} names")
    return {n: v for n, v in zip(names, se, strict=True) if np.isfinite(v)}


def load_drift(path: str | Path) -> dict[str, tuple[float, ...]]:
    """Read parameter drift from a JSON file, in mm / rad (internal units).

    Accepted forms: ``{name: value or [value per state]}``; ``{"drift": {...}}`` (same, nested); or
    ``{"names" (or "param_names"): [...], "deta": [[...] per state]}`` (a ``(states, k)`` table: the thermal
    fit's per-state solution of eq. 19-21, :meth:`robocal.thermal.identify.StateDrift.to_dict`), also nested
    under ``"states"``, ``"state_drift"`` or ``"drift"``. Parameters with NaN / null entries are left out.
    """
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(
            f"drift file {p} does not exist (run the thermal fit first, or set screen.drift_file)"
        ) from None
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"cannot read the drift file {p}: {exc}") from None
    if isinstance(data, Mapping):  # the per-state table may be nested, e.g. {"states": StateDrift.to_dict()}
        for key in ("states", "state_drift", "drift"):
            inner = data.get(key)
            if isinstance(inner, Mapping) and "deta" in inner:
                data = inner
                break
    if isinstance(data, Mapping) and "deta" in data and ("param_names" in data or "names" in data):
        names = [str(n) for n in data.get("param_names", data.get("names"))]
        table = np.asarray([[np.nan if v is None else v for v in row] for row in data["deta"]], dtype=float)
        if table.ndim != 2 or table.shape[1] != len(names):
            raise ConfigError(f"drift file {p}: 'deta' must be (states, {len(names)}). Got {table.shape}.")
        return {n: tuple(map(float, table[:, k])) for k, n in enumerate(names) if np.all(np.isfinite(table[:, k]))}
    if isinstance(data, Mapping) and isinstance(data.get("drift"), Mapping):
        data = data["drift"]
    if not isinstance(data, Mapping):
        raise ConfigError(f"drift file {p} must hold a JSON object (see robocal.thermal.screening.load_drift)")
    clean = {k: v for k, v in data.items() if v is not None and not (isinstance(v, float) and np.isnan(v))}
    out = _drift_mapping(clean, f"{p.name}")
    return out or {}
