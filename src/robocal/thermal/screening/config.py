"""Screening settings (conf/screen/), constants and the drift files it reads."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.errors import ConfigError

if TYPE_CHECKING:
    pass

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


def _err(key: str, expected: str, got: Any) -> ConfigError:
    return ConfigError(f"The config key 'screen.{key}' must be {expected}. Got {got!r} instead.")


def _number(d: Mapping[str, Any], key: str, default: float, *, positive: bool = True, prefix: str = "") -> float:
    v = d.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) or (positive and v <= 0):
        raise _err(prefix + key, "a positive number" if positive else "a number", v)
    return float(v)


def _names(d: Mapping[str, Any], key: str, prefix: str = "") -> tuple[str, ...]:
    v = d.get(key) or []
    if isinstance(v, str) or not isinstance(v, Sequence) or not all(isinstance(s, str) for s in v):
        raise _err(prefix + key, "a list of parameter names (shell patterns allowed)", v)
    return tuple(v)


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

    rule: str = "threshold"
    h_min: float = 0.015
    share: float = 0.95
    top_k: int = 9
    relative: float = 0.05
    min_z: float = 0.0
    include: tuple[str, ...] = ()
    exclude: tuple[str, ...] = ()
    explain_band: float = 2.0
    explain_z: float = 2.0

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any] | None) -> SelectionConfig:
        d = {} if d is None else d
        if not isinstance(d, Mapping):
            raise _err("selection", "a mapping", d)
        known = {
            "rule",
            "h_min",
            "share",
            "top_k",
            "relative",
            "min_z",
            "include",
            "exclude",
            "explain_band",
            "explain_z",
        }
        unknown = sorted(set(map(str, d)) - known)
        if unknown:
            raise ConfigError(
                f"unknown config key(s) {['screen.selection.' + k for k in unknown]}; known: {sorted(known)}"
            )
        rule = d.get("rule", "threshold")
        if rule not in RULES:
            raise _err("selection.rule", f"one of {list(RULES)}", rule)
        share = _number(d, "share", 0.95, prefix="selection.")
        if share > 1.0:
            raise _err("selection.share", "in (0, 1]", share)
        relative = _number(d, "relative", 0.05, prefix="selection.")
        if relative > 1.0:
            raise _err("selection.relative", "in (0, 1]", relative)
        top_k = d.get("top_k", 9)
        if isinstance(top_k, bool) or not isinstance(top_k, int) or top_k < 1:
            raise _err("selection.top_k", "a positive integer", top_k)
        h_min = _number(d, "h_min", 0.015, positive=False, prefix="selection.")
        if h_min < 0:
            raise _err("selection.h_min", "a non-negative number", h_min)
        min_z = _number(d, "min_z", 0.0, positive=False, prefix="selection.")
        if min_z < 0:
            raise _err("selection.min_z", "a non-negative number", min_z)
        explain_band = _number(d, "explain_band", 2.0, prefix="selection.")
        if explain_band < 1.0:
            raise _err("selection.explain_band", "a number >= 1", explain_band)
        return cls(
            explain_band=explain_band,
            explain_z=_number(d, "explain_z", 2.0, prefix="selection."),
            min_z=min_z,
            rule=str(rule),
            h_min=h_min,
            share=share,
            top_k=int(top_k),
            relative=relative,
            include=_names(d, "include", "selection."),
            exclude=_names(d, "exclude", "selection."),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "rule": self.rule,
            "h_min": self.h_min,
            "share": self.share,
            "top_k": self.top_k,
            "relative": self.relative,
            "min_z": self.min_z,
            "include": list(self.include),
            "exclude": list(self.exclude),
            "explain_band": self.explain_band,
            "explain_z": self.explain_z,
        }


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

    n_configs: int = 500
    joint_range_fraction: float = 1.0
    angle_step_deg: float = 0.01
    length_step_mm: float = 0.1
    tool_mm: tuple[tuple[float, float, float], ...] | None = None
    drift: Mapping[str, tuple[float, ...]] | None = None
    drift_state: str | int = "last"
    drift_file: str | None = None
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    seed: int | None = None

    KEYS = (
        "seed",
        "n_configs",
        "joint_range_fraction",
        "angle_step_deg",
        "length_step_mm",
        "tool_mm",
        "drift",
        "drift_state",
        "drift_file",
        "selection",
    )

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any] | None) -> ScreeningConfig:
        """Validate a config mapping; every problem is a :class:`ConfigError` naming the key."""
        d = {} if d is None else d
        if not isinstance(d, Mapping):
            raise ConfigError(f"The config section 'screen' must be a mapping. Got {d!r} instead.")
        unknown = sorted(set(map(str, d)) - set(cls.KEYS))
        if unknown:
            raise ConfigError(f"unknown config key(s) {['screen.' + k for k in unknown]}; known: {list(cls.KEYS)}")
        n = d.get("n_configs", 500)
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise _err("n_configs", "a positive integer", n)
        frac = _number(d, "joint_range_fraction", 1.0)
        if frac > 1.0:
            raise _err("joint_range_fraction", "in (0, 1]", frac)
        state = d.get("drift_state", "last")
        if not (state in DRIFT_STATES or (isinstance(state, int) and not isinstance(state, bool))):
            raise _err("drift_state", f"one of {list(DRIFT_STATES)} or a state index", state)
        dfile = d.get("drift_file")
        if dfile is not None and not isinstance(dfile, str | Path):
            raise _err("drift_file", "a path or null", dfile)
        seed = d.get("seed")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise _err("seed", "an integer or null", seed)
        return cls(
            seed=seed,
            n_configs=int(n),
            joint_range_fraction=frac,
            angle_step_deg=_number(d, "angle_step_deg", 0.01),
            length_step_mm=_number(d, "length_step_mm", 0.1),
            tool_mm=_tools(d.get("tool_mm")),
            drift=_drift_mapping(d.get("drift"), "screen.drift"),
            drift_state=state,
            drift_file=None if dfile is None else str(dfile),
            selection=SelectionConfig.from_mapping(d.get("selection")),
        )

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


def _tools(v: Any) -> tuple[tuple[float, float, float], ...] | None:
    if v is None:
        return None
    if isinstance(v, Mapping):  # {target name: [x, y, z]}, e.g. a calibration's tools_mm
        v = list(v.values())
    try:
        arr = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise _err("tool_mm", "[x, y, z], a list of them or {name: [x, y, z]} (mm, flange frame)", v) from None
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0 or not np.all(np.isfinite(arr)):
        raise _err("tool_mm", "[x, y, z], a list of them or {name: [x, y, z]} (mm, flange frame)", v)
    return tuple((float(a), float(b), float(c)) for a, b, c in arr)


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
