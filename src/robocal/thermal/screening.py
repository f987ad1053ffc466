"""Sensitivity screening of the kinematic parameters for thermal compensation (Guo et al. 2026, section 3.4).

Only some kinematic parameters drift measurably with temperature, and only some of those move the tool enough to
matter. The screening ranks every parameter of the chain by its *influence* on the tool pose at a temperature
state and keeps the ones worth identifying and compensating (fewer parameters, fewer poses per warm-up state).

1. **Sensitivity** (eq. 22-25). ``n_configs`` joint configurations uniform in the joint ranges (table 3); each
   parameter is perturbed on its own by ``+/- delta`` (``angle_step_deg`` = 0.01 deg for angles,
   ``length_step_mm`` = 0.1 mm for lengths), the others held at nominal. Per configuration, sign and tool point:

   - position error ``dP_pos = |p_s - p_0|`` (mm, eq. 23), ``p`` the tool point(s) ``tool_mm`` (flange frame);
   - orientation error ``dP_ori = || R_s R_0^T - I ||_F`` (eq. 24; dimensionless, ~ sqrt(2) x the angle in rad);
   - total ``dP_total = dP_pos + dP_ori`` (eq. 25), and ``E_mean`` its mean over configurations, signs and points.

   The linear prediction ``|J_eta[:, :, k]| * delta`` from the error Jacobian (eq. 22) is reported beside it
   (``jacobian_mean_position_mm``): the two agree for steps this small, which checks both.
2. **Influence at temperature T** (eq. 26-27). With the parameter drift ``d_eta_o(T)`` identified at a
   temperature state (the thermal fit's per-state solution, e.g. at thermal equilibrium):
   ``P_o(T) = d_eta_o(T) / delta_eta_o`` and ``H = E_mean * P_o(T)`` (signed, as in table 4; "mm" with the small
   Frobenius part of eq. 25 added).
3. **Selection**: a configurable rule on the score ``|H|`` (``threshold`` on ``|H|``; ``share``: the fewest
   parameters holding a share of ``sum |H|``; ``top_k``; ``relative`` to the largest ``|H|``), then ``include`` /
   ``exclude`` name patterns. Without any drift the score is ``E_mean`` (pure sensitivity) and the result says so.

:func:`screen` computes everything (vectorised: one chain propagation over a population of ``2 x P`` perturbed
parameter vectors); :func:`screening_figures` gives the equivalents of fig. 9 and table 4; :func:`add_to_report`
writes the HTML section; :func:`load_drift` reads a drift file. Internally lengths are mm and angles rad; the
config (``conf/screen/default.yaml``) gives steps and ``drift`` in mm and degrees.
"""

from __future__ import annotations

import fnmatch
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from robocal.errors import ConfigError
from robocal.kinematics.chain import Chain, build_chain, point_jacobians, propagate
from robocal.robot import RobotDescription

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from robocal.report.html import Report

__all__ = [
    "FORMAT",
    "RULES",
    "ScreeningConfig",
    "ScreeningResult",
    "SelectionConfig",
    "add_to_report",
    "load_drift",
    "load_drift_stderr",
    "sample_configurations",
    "save_screening_figures",
    "screen",
    "screening_figures",
    "write_screening",
]

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


# ------------------------------------------------------------------------------------------------ compute


def sample_configurations(robot: RobotDescription, n: int, seed: int = 0, fraction: float = 1.0) -> np.ndarray:
    """The screening's joint configurations ``(n, n_joints)`` rad: uniform in ``fraction`` of each joint range
    (about its centre), from ``np.random.default_rng(seed)`` — the same ones :func:`screen` uses."""
    rng = np.random.default_rng(int(seed))
    lim = np.asarray(robot.q_limits, dtype=float)
    mid, half = lim.mean(axis=1), 0.5 * (lim[:, 1] - lim[:, 0]) * fraction
    return mid - half + 2.0 * half * rng.random((n, robot.n_joints))


def _errors(chain: Chain, q: np.ndarray, eta: np.ndarray, tools: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position errors ``(pop, m, K)`` mm and orientation errors ``(pop, m)`` (eq. 23-24) of perturbations ``eta``."""
    st0 = propagate(chain, q)
    R0 = st0.R  # (m, 3, 3)
    p0 = st0.o[:, None, :] + np.einsum("mij,kj->mki", R0, tools)  # (m, K, 3)
    pop, m = eta.shape[0], q.shape[0]
    pos = np.empty((pop, m, tools.shape[0]))
    ori = np.empty((pop, m))
    step = max(1, _CHUNK // max(pop, 1))
    eye = np.eye(3)
    for a in range(0, m, step):
        b = min(m, a + step)
        st = propagate(chain, q[a:b], eta)
        R = st.R  # (pop, mc, 3, 3)
        p = st.o[:, :, None, :] + np.einsum("pmij,kj->pmki", R, tools)
        pos[:, a:b] = np.linalg.norm(p - p0[None, a:b], axis=-1)
        D = np.einsum("pmij,mlj->pmil", R, R0[a:b]) - eye  # R_s R_0^T - I
        ori[:, a:b] = np.sqrt(np.einsum("pmij,pmij->pm", D, D))
    return pos, ori


def _jacobian_position(
    chain: Chain, q: np.ndarray, tools: np.ndarray, idx: np.ndarray, steps: np.ndarray
) -> np.ndarray:
    """Mean linearised position error ``|J_eta[:, :, k]| * delta_k`` over configurations and tools (eq. 22)."""
    st = propagate(chain, q, record=True)
    R = st.R
    acc = np.zeros(len(idx))
    for t in tools:
        pts = st.o + R @ t
        J, _, _, _ = point_jacobians(chain, st, pts)
        acc += np.linalg.norm(J[:, :, idx], axis=1).mean(axis=0) * steps
    return acc / tools.shape[0]


def _select(names: Sequence[str], score: np.ndarray, sel: SelectionConfig, z: np.ndarray) -> np.ndarray:
    """Boolean mask of the selected parameters (chain order) by the rule, then include / exclude.

    Parameters whose drift is not significant (``z < min_z``; NaN z = no standard error = not tested) are
    not candidates of the rule."""
    valid = np.isfinite(score) & ~(np.isfinite(z) & (z < sel.min_z))
    s = np.where(valid, score, -np.inf)
    order = np.argsort(-s, kind="stable")
    order = order[valid[order]]
    mask = np.zeros(len(names), dtype=bool)
    if order.size:
        if sel.rule == "threshold":
            mask = valid & (s >= sel.h_min)
        elif sel.rule == "top_k":
            mask[order[: sel.top_k]] = True
        elif sel.rule == "relative":
            mask = valid & (s >= sel.relative * s[order[0]])
        else:  # share
            total = s[order].sum()
            if total > 0:
                cum = np.cumsum(s[order]) / total
                k = int(np.searchsorted(cum, sel.share - 1e-12)) + 1  # fewest parameters reaching the share
                mask[order[:k]] = True
    for key, patterns, value in (("include", sel.include, True), ("exclude", sel.exclude, False)):
        for pat in patterns:
            hits = [i for i, n in enumerate(names) if fnmatch.fnmatchcase(n, pat)]
            if not hits:
                raise ConfigError(
                    f"The config key 'screen.selection.{key}' has the pattern {pat!r}, which matches no screened "
                    f"parameter; screened: {list(names)}"
                )
            mask[hits] = value
    return mask


def _what_if(
    names: Sequence[str],
    score: np.ndarray,
    score_name: str,
    selected: np.ndarray,
    z: np.ndarray,
    rank: np.ndarray,
    share: np.ndarray,
    sel: SelectionConfig,
) -> list[dict[str, Any]]:
    """Which parameters the selection would add or drop, and why: those whose score lies within a factor
    ``explain_band`` of the rule's cut, those selected although their drift is not significant (``z <
    explain_z``), those kept out by ``min_z``, and those forced by include / exclude. Each entry says which change
    of the rule's setting would flip it (``changes``: ``{setting, op, value}`` with setting ``h_min`` / ``relative``
    / ``top_k`` / ``share`` / ``min_z``; any one of them flips it) and in words (``text``)."""
    k = len(names)
    plain = replace(sel, include=(), exclude=())
    by_rule = _select(names, score, replace(plain, min_z=0.0), np.full(k, np.nan))  # the rule alone
    with_z = _select(names, score, plain, z)  # the rule and min_z, before include / exclude
    finite = np.isfinite(score)
    if not finite.any():
        return []
    top = float(np.max(score[finite]))
    if sel.rule == "threshold":
        cut = sel.h_min
    elif sel.rule == "relative":
        cut = sel.relative * top
    else:  # top_k / share: the smallest score the rule takes
        cut = float(np.min(score[by_rule])) if by_rule.any() else top
    order = np.argsort(rank)
    cum_above = {int(i): float(np.sum(share[order[: rank[i] - 1]])) for i in range(k)}  # share ranked above i

    def condition(i: int, add: bool) -> dict[str, Any]:
        """The change of the rule's setting that flips parameter i: {setting, op, value}."""
        v = float(score[i])
        if sel.rule == "threshold":
            return {"setting": "h_min", "op": "<=" if add else ">", "value": v}
        if sel.rule == "relative":
            return {"setting": "relative", "op": "<=" if add else ">", "value": v / top if top > 0 else float("nan")}
        if sel.rule == "top_k":
            return {"setting": "top_k", "op": ">=" if add else "<", "value": int(rank[i])}
        return {"setting": "share", "op": ">" if add else "<=", "value": cum_above[i]}

    def say(c: dict[str, Any]) -> str:
        op = {"<=": "≤", ">=": "≥"}.get(c["op"], c["op"])
        val = c["value"] if isinstance(c["value"], int) else f"{c['value']:.4g}"
        return f"{c['setting']} were {op} {val}"

    out: list[dict[str, Any]] = []
    for i, n in enumerate(names):
        if not finite[i]:
            continue
        v, zz = float(score[i]), float(z[i])
        has_z = np.isfinite(zz)
        significant = bool(zz >= sel.explain_z) if has_z else None
        near = cut > 0 and cut / sel.explain_band <= v <= cut * sel.explain_band
        z_dropped = bool(by_rule[i] and not with_z[i])
        forced = bool(with_z[i] != selected[i])
        if not (near or z_dropped or forced or (selected[i] and significant is False)):
            continue
        ztxt = (
            f"drift z = {zz:.2f}" + ("" if significant else f" < {sel.explain_z:g}: not significant vs its std. error")
            if has_z
            else "drift z unknown (no standard errors)"
        )
        head = f"{score_name} = {v:.4g}, rank {int(rank[i])}"
        changes: list[dict[str, Any]] = []
        if forced:
            action = "add" if not selected[i] else "drop"
            why = f"{'selected' if selected[i] else 'left out'} by selection.{'include' if selected[i] else 'exclude'}"
            text = f"{n}: {why} ({head}; {ztxt})"
        elif z_dropped:
            action = "add"
            why = f"passes the rule but its drift is not significant (min_z = {sel.min_z:g})"
            changes = [{"setting": "min_z", "op": "<=", "value": zz}]
            text = f"would add {n} if {say(changes[0])} ({head}, passes the rule; {ztxt})"
        elif selected[i]:
            action = "drop"
            changes = [condition(i, add=False)] if near else []
            if has_z and not significant:
                changes.append({"setting": "min_z", "op": ">", "value": zz})
            why = "near the cut" if near else "selected on its influence, but the drift is not significant"
            text = f"would drop {n} if {' or '.join(say(c) for c in changes)} ({head}; {ztxt})"
        else:
            action = "add"
            why = "near the cut"
            changes = [condition(i, add=True)]
            text = f"would add {n} if {say(changes[0])} ({head}; {ztxt})"
        out.append(
            {
                "parameter": n,
                "selected": bool(selected[i]),
                "action": action,
                "score": v,
                "rank": int(rank[i]),
                "cut": float(cut),
                "drift_z": zz if has_z else float("nan"),
                "significant": significant,
                "why": why,
                "changes": changes,
                "text": text,
            }
        )
    return sorted(out, key=lambda w: w["rank"])


def screen(
    robot: RobotDescription,
    cfg: Mapping[str, Any] | None = None,
    params: Sequence[str] | None = None,
    seed: int = 0,
    *,
    drift: Mapping[str, Any] | None = None,
    drift_stderr: Mapping[str, float] | None = None,
) -> ScreeningResult:
    """Sensitivity screening of the kinematic parameters of ``build_chain(robot)`` (Guo et al. section 3.4).

    Parameters
    ----------
    robot : RobotDescription
    cfg : mapping, optional
        ``screen`` settings (:class:`ScreeningConfig`; defaults of ``conf/screen/default.yaml``). Unknown keys
        and bad values raise :class:`ConfigError` naming the key.
    params : sequence of str, optional
        Chain parameter names to screen (default: all, chain order).
    seed : int
        Seed of the random configurations (``np.random.default_rng(seed)``).
    drift : mapping of str to float or sequence of float, optional
        Parameter drift ``d_eta(T)`` in **mm / rad** (internal units), one value or one per temperature state
        (e.g. from :func:`load_drift` or the thermal fit). Replaces ``cfg["drift"]`` (which is in mm / deg).
        Parameters without drift get NaN ``P_o`` / ``H`` and are not selected by the rule.
    drift_stderr : mapping of str to float, optional
        Standard error of each parameter's drift (same units as ``drift``): gives ``drift_z`` and, with
        ``selection.min_z > 0``, keeps insignificant drifts out of the selection.

    Returns
    -------
    ScreeningResult
    """
    conf = ScreeningConfig.from_mapping(cfg)
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise ConfigError(f"The 'seed' parameter of screen must be an integer. Got {seed!r} instead.")
    chain = build_chain(robot)
    all_names = list(chain.param_names)
    if params is None:
        names = all_names
    else:
        if isinstance(params, str):
            raise ConfigError(f"The 'params' parameter of screen must be a list of names. Got {params!r} instead.")
        bad = [p for p in params if p not in all_names]
        if bad:
            raise ConfigError(f"unknown kinematic parameter(s) {bad} for robot {robot.name!r}; known: {all_names}")
        if len(set(params)) != len(params):
            raise ConfigError(f"The 'params' parameter of screen has duplicates: {list(params)}")
        names = [n for n in all_names if n in set(params)]  # chain order
    if not names:
        raise ConfigError("The 'params' parameter of screen must name at least one parameter.")
    idx = np.array([all_names.index(n) for n in names])
    kinds = [chain.param_kind[i] for i in idx]
    is_angle = np.array([k == "angle" for k in kinds])
    steps = np.where(is_angle, np.deg2rad(conf.angle_step_deg), conf.length_step_mm)  # internal units
    notes: list[str] = []

    # -- drift in internal units (mm / rad), one row per temperature state
    if drift is not None:
        dmap = _drift_mapping(drift, "drift")
        assert dmap is not None
        drift_internal = {k: np.asarray(v) for k, v in dmap.items()}
        unit_note = "mm / rad"
    elif conf.drift is not None:
        drift_internal = {}
        for pname, v in conf.drift.items():
            arr = np.asarray(v)
            if pname in all_names and chain.param_kind[all_names.index(pname)] == "angle":
                arr = np.deg2rad(arr)
            drift_internal[pname] = arr
        unit_note = "mm / deg (config)"
    else:
        drift_internal = {}
        unit_note = ""
    unknown = sorted(set(drift_internal) - set(all_names))
    if unknown:
        raise ConfigError(f"drift given for unknown parameter(s) {unknown} of robot {robot.name!r}; known: {all_names}")
    n_states = len(next(iter(drift_internal.values()))) if drift_internal else 0
    d_used = np.full(len(names), np.nan)
    state_used: int | str | None = None
    if n_states:
        st = conf.drift_state
        if isinstance(st, int) and not -n_states <= st < n_states:
            raise _err("drift_state", f"a state index in [-{n_states}, {n_states - 1}]", st)
        for j, n in enumerate(names):
            if n not in drift_internal:
                continue
            series = drift_internal[n]
            if st == "last":
                d_used[j] = series[-1]
            elif st == "max_abs":
                d_used[j] = series[int(np.argmax(np.abs(series)))]
            else:
                d_used[j] = series[int(st)]
        state_used = st if n_states > 1 else 0
        missing = [n for n in names if n not in drift_internal]
        if missing:
            notes.append(
                f"no drift known for {', '.join(missing)}: P_o and H are NaN and the rule does not select them"
            )
        notes.append(f"drift of {len(drift_internal)} parameter(s) over {n_states} state(s) ({unit_note})")

    z = np.full(len(names), np.nan)
    if drift_stderr is not None:
        bad_se = sorted(set(drift_stderr) - set(all_names))
        if bad_se:
            raise ConfigError(f"drift_stderr given for unknown parameter(s) {bad_se} of robot {robot.name!r}")
        se = np.array([float(drift_stderr.get(n, np.nan)) for n in names])
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(se > 0, np.abs(d_used) / se, np.nan)
    elif conf.selection.min_z > 0:
        notes.append("selection.min_z is set but the drift has no standard errors: no significance test")

    # -- sensitivity simulation (eq. 23-25)
    q = sample_configurations(robot, conf.n_configs, int(seed), conf.joint_range_fraction)
    tools = np.zeros((1, 3)) if conf.tool_mm is None else np.asarray(conf.tool_mm, dtype=float)
    if conf.tool_mm is None:
        notes.append("tool point: the flange origin (screen.tool_mm is null); theta_n cannot move it")
    k = len(names)
    eta = np.zeros((2 * k, chain.n_params))
    eta[np.arange(k), idx] = steps
    eta[k + np.arange(k), idx] = -steps
    pos, ori = _errors(chain, q, eta, tools)  # (2k, m, K), (2k, m)
    pos_k = np.concatenate([pos[:k], pos[k:]], axis=1).reshape(k, -1)  # both signs, all configs and tools
    ori_k = np.concatenate([ori[:k], ori[k:]], axis=1)
    total = pos + ori[:, :, None]
    e_mean = np.concatenate([total[:k], total[k:]], axis=1).reshape(k, -1).mean(axis=1)
    jac = _jacobian_position(chain, q, tools, idx, steps)

    # -- influence (eq. 26-27) and selection
    p_o = d_used / steps
    h = e_mean * p_o
    score = np.abs(h) if n_states else e_mean
    score_name = "|H|" if n_states else "E_mean"
    if not n_states:
        notes.append("no drift given: the rule ranks the pure sensitivity E_mean (P_o and H need the drift)")
    sel = _select(names, score, conf.selection, z)
    dropped = [n for n, zz in zip(names, z, strict=True) if np.isfinite(zz) and zz < conf.selection.min_z]
    if dropped:
        notes.append(
            f"drift not significant (|d_eta| < {conf.selection.min_z:g} std. errors), not candidates: {dropped}"
        )
    finite = np.where(np.isfinite(score), score, 0.0)
    share = finite / finite.sum() if finite.sum() > 0 else np.zeros(k)
    order = np.argsort(-np.where(np.isfinite(score), score, -np.inf), kind="stable")
    rank = np.empty(k, dtype=int)
    rank[order] = np.arange(1, k + 1)
    to_unit = np.where(is_angle, np.rad2deg(1.0), 1.0)
    table = pd.DataFrame(
        {
            "parameter": names,
            "kind": kinds,
            "unit": ["deg" if a else "mm" for a in is_angle],
            "step": steps * to_unit,
            "mean_position_mm": pos_k.mean(axis=1),
            "max_position_mm": pos_k.max(axis=1),
            "mean_orientation": ori_k.mean(axis=1),
            "max_orientation": ori_k.max(axis=1),
            # ||R - I||_F = 2 sqrt(2) sin(angle / 2)
            "mean_orientation_deg": np.rad2deg(2.0 * np.arcsin(np.clip(ori_k / (2.0 * np.sqrt(2.0)), 0, 1))).mean(
                axis=1
            ),
            "jacobian_mean_position_mm": jac,
            "E_mean": e_mean,
            "drift": d_used * to_unit,
            "drift_z": z,
            "P_o": p_o,
            "H": h,
            "score": score,
            "share": share,
            "rank": rank,
            "selected": sel,
        },
        columns=list(COLUMNS),
    )
    return ScreeningResult(
        robot=robot.name,
        table=table,
        selected=[n for n, s in zip(names, sel, strict=True) if s],
        score=score_name,
        config={**conf.to_dict(), "seed": int(seed)},
        seed=int(seed),
        drift_states=n_states,
        drift_state_used=state_used,
        notes=notes,
        what_if=_what_if(names, score, score_name, sel, z, rank, share, conf.selection),
    )


# ------------------------------------------------------------------------------------------------ figures

_LENGTH_COLOR = "#4c72b0"
_ANGLE_COLOR = "#dd8452"
_SELECTED_COLOR = "#c44e52"
_OTHER_COLOR = "#8c8c8c"


def _style() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    from robocal.report import plots

    return matplotlib.rc_context(plots._STYLE)


def screening_figures(result: ScreeningResult) -> list[tuple[Figure, str]]:
    """Equivalents of Guo et al. fig. 9 and table 4, as ``(Figure, caption)``.

    1. sensitivity: mean (bar) and max (tick) position error and orientation error per parameter for the
       +/- delta perturbations (fig. 9);
    2. influence: signed ``H`` per parameter, selected ones highlighted, the threshold drawn (table 4);
       without drift, the pure sensitivity score ``E_mean`` instead;
    3. cumulative share of the score, parameters by rank, selected ones highlighted.
    """
    from matplotlib.figure import Figure

    t = result.table
    names = list(t["parameter"])
    x = np.arange(len(names))
    colors = [_ANGLE_COLOR if k == "angle" else _LENGTH_COLOR for k in t["kind"]]
    tilt = 60 if len(names) > 12 else 0
    step_a = t.loc[t["kind"] == "angle", "step"]
    step_l = t.loc[t["kind"] == "length", "step"]
    steps = ", ".join(
        s
        for s in (
            f"±{step_a.iloc[0]:g}° (angles)" if len(step_a) else "",
            f"±{step_l.iloc[0]:g} mm (lengths)" if len(step_l) else "",
        )
        if s
    )
    n_cfg = result.config.get("n_configs", "?")
    out: list[tuple[Figure, str]] = []
    with _style():
        fig = Figure(figsize=(min(max(6.0, 0.32 * len(names) + 2.0), 14.0), 5.6), layout="constrained")
        ax1, ax2 = fig.subplots(2, 1, sharex=True)
        ax1.bar(x, t["mean_position_mm"], color=colors)
        ax1.plot(x, t["max_position_mm"], "_", color="k", ms=9, mew=1.5, label="max")
        ax1.set_ylabel("position error (mm)")
        ax2.bar(x, 1e3 * t["mean_orientation"], color=colors)
        ax2.plot(x, 1e3 * t["max_orientation"], "_", color="k", ms=9, mew=1.5, label="max")
        ax2.set_ylabel("orientation error ‖R_s R_0ᵀ − I‖_F (×10⁻³)")
        from matplotlib.patches import Patch

        handles = [
            Patch(color=_LENGTH_COLOR, label="length (mean)"),
            Patch(color=_ANGLE_COLOR, label="angle (mean)"),
            *ax1.get_legend_handles_labels()[0],
        ]
        ax1.legend(handles=handles, loc="best")
        ax2.set_xticks(x, names, rotation=tilt, ha="right" if tilt else "center")
        ax1.grid(False, axis="x")
        ax2.grid(False, axis="x")
        out.append(
            (fig, f"Sensitivity of the tool pose to each kinematic parameter ({steps}; {n_cfg} random configurations)")
        )

        by_h = result.score == "|H|"
        val = t["H"] if by_h else t["E_mean"]
        fig = Figure(figsize=(min(max(6.0, 0.32 * len(names) + 2.0), 14.0), 3.8), layout="constrained")
        ax = fig.add_subplot()
        bar_colors = [_SELECTED_COLOR if s else _OTHER_COLOR for s in t["selected"]]
        ax.bar(x, np.nan_to_num(val.to_numpy(dtype=float)), color=bar_colors)
        sel = result.config.get("selection", {})
        if sel.get("rule") == "threshold":
            hm = float(sel.get("h_min", 0.0))
            ax.axhline(hm, color="k", ls="--", lw=0.8, label=f"threshold {hm:g}")
            if by_h:
                ax.axhline(-hm, color="k", ls="--", lw=0.8)
        ax.axhline(0.0, color="k", lw=0.7)
        ax.set_xticks(x, names, rotation=tilt, ha="right" if tilt else "center")
        ax.set_ylabel("H = E_mean · P_o(T)" if by_h else "E_mean (per step)")
        from matplotlib.patches import Patch as _P

        ax.legend(
            handles=[_P(color=_SELECTED_COLOR, label="selected"), _P(color=_OTHER_COLOR, label="not selected")]
            + ax.get_legend_handles_labels()[0],
            loc="best",
        )
        ax.grid(False, axis="x")
        cap = (
            "Influence H of each parameter at the temperature state (table 4 equivalent), selected in red"
            if by_h
            else "No drift known: sensitivity E_mean per parameter, selected in red"
        )
        out.append((fig, cap))

        order = t.sort_values("rank")
        fig = Figure(figsize=(min(max(6.0, 0.32 * len(names) + 2.0), 14.0), 3.4), layout="constrained")
        ax = fig.add_subplot()
        cum = np.cumsum(order["share"].to_numpy())
        xs = np.arange(len(order))
        ax.bar(xs, order["share"], color=[_SELECTED_COLOR if s else _OTHER_COLOR for s in order["selected"]])
        ax.plot(xs, cum, "o-", color="k", ms=3, label="cumulative share")
        if sel.get("rule") == "share":
            ax.axhline(float(sel.get("share", 1.0)), color="k", ls="--", lw=0.8, label="share rule")
        ax.set_xticks(xs, list(order["parameter"]), rotation=tilt, ha="right" if tilt else "center")
        ax.set_ylabel(f"share of Σ {result.score}")
        ax.set_ylim(0, 1.05)
        ax.legend(loc="center right")
        ax.grid(False, axis="x")
        out.append((fig, f"Share of the total {result.score} by rank; selected parameters in red"))
    return out


def write_screening(result: ScreeningResult, directory: str | Path) -> list[Path]:
    """Write ``screening.json`` (:meth:`ScreeningResult.to_dict`) and ``screening.csv`` (the table), atomically."""
    from robocal.io import atomic_write, write_json

    d = Path(directory)
    return [
        write_json(d / "screening.json", result.to_dict()),
        atomic_write(d / "screening.csv", lambda p: result.table.to_csv(p, index=False, float_format="%.9g")),
    ]


FIGURE_FILES = ("screen_sensitivity.png", "screen_influence.png", "screen_cumulative_share.png")


def save_screening_figures(result: ScreeningResult, directory: str | Path) -> list[Path]:
    """Write :func:`screening_figures` to ``directory`` as :data:`FIGURE_FILES` (PNG); returns the paths."""
    from robocal.report.plots import save_figure

    d = Path(directory)
    return [save_figure(fig, d / name) for (fig, _), name in zip(screening_figures(result), FIGURE_FILES, strict=True)]


def add_to_report(result: ScreeningResult, report: Report, level: int = 2) -> Report:
    """Append the screening section (settings, selected set, table, figures) to an HTML :class:`Report`."""
    cfg = result.config
    sel = cfg.get("selection", {})
    rule = sel.get("rule")
    rule_text = {
        "threshold": f"{result.score} ≥ {sel.get('h_min')}",
        "share": f"fewest parameters holding {sel.get('share')} of Σ {result.score}",
        "top_k": f"the {sel.get('top_k')} largest {result.score}",
        "relative": f"{result.score} ≥ {sel.get('relative')} × the largest",
    }.get(str(rule), str(rule))
    report.heading("Sensitivity screening of the kinematic parameters", level)
    report.paragraph(
        "Each parameter is perturbed on its own by ± its step at random joint configurations; position error = "
        "tool-point displacement (eq. 23), orientation error = ‖R_s R_0ᵀ − I‖_F (eq. 24), total = their sum "
        "(eq. 25), E_mean its mean. With the identified drift Δη(T): P_o = Δη(T) / δη (eq. 26) and "
        "H = E_mean · P_o (eq. 27). Guo et al. 2026, section 3.4."
    )
    report.kv(
        {
            "robot": result.robot,
            "configurations": cfg.get("n_configs"),
            "steps": f"±{cfg.get('angle_step_deg')}° / ±{cfg.get('length_step_mm')} mm",
            "tool points (flange frame, mm)": "flange origin"
            if cfg.get("tool_mm") is None
            else "; ".join("x {:.3f}, y {:.3f}, z {:.3f}".format(*t) for t in cfg["tool_mm"]),
            "temperature states in the drift": result.drift_states,
            "state used for P_o(T)": "-" if result.drift_state_used is None else str(result.drift_state_used),
            "score": result.score,
            "selection rule": rule_text,
            "selected": ", ".join(result.selected) or "(none)",
            "seed": result.seed,
        },
        caption="Screening settings and outcome",
    )
    for n in result.notes:
        report.note(n)
    cols = [
        "parameter",
        "unit",
        "step",
        "mean_position_mm",
        "E_mean",
        "drift",
        "drift_z",
        "P_o",
        "H",
        "share",
        "rank",
        "selected",
    ]
    shown = result.table[cols].rename(
        columns={
            "step": "step (unit)",
            "mean_position_mm": "E_pos mean (mm)",
            "drift": "drift (unit)",
        }
    )
    report.table(
        shown,
        caption="Per-parameter sensitivity and influence (table 4 equivalent), step and drift in the row's unit; "
        "orientation errors, maxima and the Jacobian cross-check: screening.csv",
    )
    band, zlim = sel.get("explain_band", 2.0), sel.get("explain_z", 2.0)
    if result.what_if:
        report.paragraph(
            f"Which parameters the selection would add or drop, and why: scores within a factor {band:g} of the "
            f"rule's cut ({result.what_if[0]['cut']:.4g}), selected parameters whose drift is below {zlim:g} "
            "standard errors (not significant: tracker noise can make such a drift), and parameters kept out by "
            "min_z or forced by include / exclude."
        )
        report.table(
            [
                {
                    "parameter": w["parameter"],
                    "selected": w["selected"],
                    result.score: w["score"],
                    "rank": w["rank"],
                    "drift_z": w["drift_z"],
                    "what would change it": w["text"],
                }
                for w in result.what_if
            ],
            caption="Borderline parameters: what would add or drop them",
        )
    else:
        report.paragraph(
            f"No parameter lies within a factor {band:g} of the rule's cut, and every selected drift is significant "
            f"(≥ {zlim:g} std. errors, when known): the selection is not borderline."
        )
    for fig, cap in screening_figures(result):
        report.figure(fig, cap)
    return report
