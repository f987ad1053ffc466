"""The screening computation: sensitivities, influence at temperature, selection (see the package docstring)."""

from __future__ import annotations

import fnmatch
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from robocal.config import SettingError
from robocal.errors import ConfigError
from robocal.kinematics.chain import Chain, build_chain, point_jacobians, propagate
from robocal.robot import RobotDescription
from robocal.thermal.screening.config import (
    _CHUNK,
    COLUMNS,
    ScreeningConfig,
    SelectionConfig,
    _drift_mapping,
)
from robocal.thermal.screening.result import ScreeningResult

if TYPE_CHECKING:
    pass


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
        if forced:
            action, why, changes = _forced(bool(selected[i]))
            text = f"{n}: {why} ({head}; {ztxt})"
        elif z_dropped:
            action = "add"
            why = f"passes the rule but its drift is not significant (min_z = {sel.min_z:g})"
            changes = [{"setting": "min_z", "op": "<=", "value": zz}]
            text = f"would add {n} if {_say(changes[0])} ({head}, passes the rule; {ztxt})"
        elif selected[i]:
            action = "drop"
            changes = [condition(i, add=False)] if near else []
            if has_z and not significant:
                changes.append({"setting": "min_z", "op": ">", "value": zz})
            why = "near the cut" if near else "selected on its influence, but the drift is not significant"
            text = f"would drop {n} if {' or '.join(_say(c) for c in changes)} ({head}; {ztxt})"
        else:
            action, why, changes = "add", "near the cut", [condition(i, add=True)]
            text = f"would add {n} if {_say(changes[0])} ({head}; {ztxt})"
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


def _forced(selected: bool) -> tuple[str, str, list[dict[str, Any]]]:
    """A parameter include / exclude forced against the rule: the action that undoes it and why (no setting of
    the rule flips it)."""
    action = "add" if not selected else "drop"
    why = f"{'selected' if selected else 'left out'} by selection.{'include' if selected else 'exclude'}"
    return action, why, []


def _say(c: Mapping[str, Any]) -> str:
    """A change of a setting in words: ``h_min were ≤ 0.01``."""
    op = {"<=": "≤", ">=": "≥"}.get(c["op"], c["op"])
    val = c["value"] if isinstance(c["value"], int) else f"{c['value']:.4g}"
    return f"{c['setting']} were {op} {val}"


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
    names = _screened_names(all_names, params, robot.name)
    idx = np.array([all_names.index(n) for n in names])
    kinds = [chain.param_kind[i] for i in idx]
    is_angle = np.array([k == "angle" for k in kinds])
    steps = np.where(is_angle, np.deg2rad(conf.angle_step_deg), conf.length_step_mm)  # internal units
    notes: list[str] = []
    d_used, n_states, state_used = _drift_used(conf, drift, chain, names, robot.name, notes)
    z = _drift_z(conf, drift_stderr, all_names, names, d_used, robot.name, notes)

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


def _screened_names(all_names: list[str], params: Sequence[str] | None, robot: str) -> list[str]:
    """The parameters to screen, in chain order (all of them by default); unknown or repeated names are errors."""
    if params is None:
        names = all_names
    else:
        if isinstance(params, str):
            raise ConfigError(f"The 'params' parameter of screen must be a list of names. Got {params!r} instead.")
        bad = [p for p in params if p not in all_names]
        if bad:
            raise ConfigError(f"unknown kinematic parameter(s) {bad} for robot {robot!r}; known: {all_names}")
        if len(set(params)) != len(params):
            raise ConfigError(f"The 'params' parameter of screen has duplicates: {list(params)}")
        names = [n for n in all_names if n in set(params)]  # chain order
    if not names:
        raise ConfigError("The 'params' parameter of screen must name at least one parameter.")
    return names


def _drift_used(
    conf: ScreeningConfig,
    drift: Mapping[str, Any] | None,
    chain: Any,
    names: list[str],
    robot: str,
    notes: list[str],
) -> tuple[np.ndarray, int, int | str | None]:
    """The drift of each screened parameter in internal units (mm / rad; NaN where none is known) at the state
    ``conf.drift_state``, the number of temperature states, and the state used; notes appended to ``notes``."""
    all_names = list(chain.param_names)
    if drift is not None:
        dmap = _drift_mapping(drift, "drift")
        assert dmap is not None
        drift_internal = {k: np.asarray(v) for k, v in dmap.items()}
        unit_note = "lengths in mm, angles in deg"  # read in mm / rad; every table shows deg
    elif conf.drift is not None:
        drift_internal = {}
        for pname, v in conf.drift.items():
            arr = np.asarray(v)
            if pname in all_names and chain.param_kind[all_names.index(pname)] == "angle":
                arr = np.deg2rad(arr)
            drift_internal[pname] = arr
        unit_note = "lengths in mm, angles in deg, from the config"
    else:
        drift_internal = {}
        unit_note = ""
    unknown = sorted(set(drift_internal) - set(all_names))
    if unknown:
        raise ConfigError(f"drift given for unknown parameter(s) {unknown} of robot {robot!r}; known: {all_names}")
    n_states = len(next(iter(drift_internal.values()))) if drift_internal else 0
    d_used = np.full(len(names), np.nan)
    if not n_states:
        return d_used, 0, None
    st = conf.drift_state
    if isinstance(st, int) and not -n_states <= st < n_states:
        raise SettingError("screen.drift_state", f"must be a state index in [-{n_states}, {n_states - 1}]", st)
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
    missing = [n for n in names if n not in drift_internal]
    if missing:
        notes.append(
            f"no drift known for {', '.join(missing)}: P_o and H are undefined (shown as –) and the rule does "
            "not select them"
        )
    notes.append(f"drift of {len(drift_internal)} parameter(s) over {n_states} state(s) ({unit_note})")
    return d_used, n_states, st if n_states > 1 else 0


def _drift_z(
    conf: ScreeningConfig,
    drift_stderr: Mapping[str, float] | None,
    all_names: list[str],
    names: list[str],
    d_used: np.ndarray,
    robot: str,
    notes: list[str],
) -> np.ndarray:
    """|drift| / its standard error per screened parameter (NaN without standard errors)."""
    z = np.full(len(names), np.nan)
    if drift_stderr is not None:
        bad_se = sorted(set(drift_stderr) - set(all_names))
        if bad_se:
            raise ConfigError(f"drift_stderr given for unknown parameter(s) {bad_se} of robot {robot!r}")
        se = np.array([float(drift_stderr.get(n, np.nan)) for n in names])
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(se > 0, np.abs(d_used) / se, np.nan)
    elif conf.selection.min_z > 0:
        notes.append("selection.min_z is set but the drift has no standard errors: no significance test")
    return z
