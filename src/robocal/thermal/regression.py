"""Regression of the identified parameter drift on the sensor temperatures (Guo et al. 2026, eq. 5-8).

For one parameter, the data are its drift ``y_s`` at the warm states ``s = 1..S-1`` of a warm-up and the mean
sensor readings there, as differences ``x_s = T_s - T_ref`` from the reference (cold) state, where the drift is
zero by definition (so no constant term). Forms:

- ``expansion`` (lengths, eq. 5-6): ``y = c x_j``, one sensor j;
- ``polynomial`` (angles, eq. 7-8): all monomials of total order 1..p of the chosen sensors;
- ``none``: no drift (offered to cross-validation, so that a parameter that does not move is not fitted noise).

Errors of the ``y_s`` share the reference measurement: ``Cov(y) = v (I + 1 1^T)`` (see
:mod:`robocal.thermal.identify`), so coefficients are generalised least squares with that covariance, their
covariance ``(X^T C^-1 X)^-1`` scaled by the reduced chi² when that exceeds 1 (model misfit). The form, the
sensors (from per-parameter candidates) and the order are chosen by leave-one-state-out cross-validation: the
smallest model whose CV error is within ``cv_tolerance`` of the best.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from robocal.config import parse, setting
from robocal.errors import ConfigError
from robocal.identification.result import normal_matrix_inverse
from robocal.kinematics.chain import Chain
from robocal.robot import RobotDescription
from robocal.thermal.identify import StateDrift
from robocal.thermal.model import ParameterModel, ThermalModel, design, monomials


@dataclass(frozen=True)
class RegressionConfig:
    """Settings of the per-parameter regression.

    max_order : highest polynomial order p for angles (eq. 7-8). max_sensors : most sensors in one polynomial.
    candidates : ``auto`` (sensors on the joints and links next to the parameter's joint) or a mapping
        ``parameter -> [sensor, ...]`` (a parameter not in it falls back to ``auto``); a single-element list
        fixes the sensor. allow_none : offer "no drift" to cross-validation. cv_tolerance : choose the smallest
        model whose CV error is at most ``(1 + cv_tolerance)`` times the best. neighbourhood : joints on each
        side of the parameter's joint whose sensors are candidates. alpha : a drift model is kept only when it beats
        "no drift" in a chi² test at this level (the reference noise shared by every state can look like a drift
        that saturates).
    """

    max_order: int = setting(2, ge=1)
    max_sensors: int = setting(2, ge=1)
    candidates: str | Mapping[str, Sequence[str]] = setting("auto", choices=("auto",))
    allow_none: bool = True
    cv_tolerance: float = setting(0.1, ge=0)
    neighbourhood: int = setting(1, ge=0)
    alpha: float = 1e-3

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> RegressionConfig:
        return parse(cls, cfg, "thermal.regression")


def joint_of(param: str) -> int | None:
    """1-based joint number in an MD-H / POE parameter name (``theta4`` -> 4, ``link3_tx`` -> 3)."""
    m = re.search(r"(\d+)", param)
    return int(m.group(1)) if m else None


def candidate_sensors(robot: RobotDescription, param: str, sensors: Sequence[str], cfg: RegressionConfig) -> list[str]:
    """Sensors that may drive ``param``: configured, else those on joints / links ``j - n .. j + n``."""
    if isinstance(cfg.candidates, Mapping) and param in cfg.candidates:
        chosen = [str(s) for s in cfg.candidates[param]]
        bad = [s for s in chosen if s not in sensors]
        if bad:
            raise ConfigError(
                f"thermal regression: candidates of {param!r} name unknown sensor(s) {bad}; known: {list(sensors)}"
            )
        return chosen
    j = joint_of(param)
    where = {s.name: s for s in robot.sensors}
    out = []
    for name in sensors:
        s = where.get(name)
        if j is None or s is None or s.index is None:
            out.append(name)
        elif abs(int(s.index) - j) <= cfg.neighbourhood:
            out.append(name)
    return out or list(sensors)


@dataclass
class Candidate:
    form: str
    sensors: tuple[str, ...]
    terms: tuple[tuple[int, ...], ...]
    cv_rmse: float = np.inf

    @property
    def k(self) -> int:
        return len(self.terms)

    def label(self) -> str:
        if self.form == "none":
            return "none"
        return f"{self.form}(p={max(sum(e) for e in self.terms)}; {', '.join(self.sensors)})"


def _gls(X: np.ndarray, y: np.ndarray, Cinv: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Coefficients, their (unscaled) covariance and chi² of ``y = X b`` with ``Cov(y)^-1 = Cinv``."""
    cov = normal_matrix_inverse(X.T @ Cinv @ X)
    b = cov @ (X.T @ Cinv @ y)
    r = y - X @ b
    return b, cov, float(r @ Cinv @ r)


def _cinv(n: int, v: float) -> np.ndarray:
    """Inverse of ``v (I + 1 1^T)`` (n x n)."""
    return (np.eye(n) - np.ones((n, n)) / (n + 1)) / v


@dataclass
class ParameterChoice:
    """The chosen model of one parameter and the cross-validation table behind the choice."""

    model: ParameterModel | None
    chosen: Candidate
    table: list[dict[str, Any]] = field(default_factory=list)
    p_value: float = float("nan")


def fit_parameter(
    name: str,
    kind: str,
    x: np.ndarray,
    y: np.ndarray,
    v: float,
    sensors: Sequence[str],
    candidates: Sequence[str],
    cfg: RegressionConfig,
    forms: Sequence[str] = ("expansion",),
    nominal: float = 0.0,
) -> ParameterChoice:
    """Fit one parameter's drift.

    Parameters
    ----------
    x : (n, s) temperature differences of the warm states from the reference, all ``sensors``.
    y : (n,) identified drift (mm or rad) at those states.
    v : the variance unit of ``y`` (``Cov(y) = v (I + 1 1^T)``), > 0.
    candidates : sensors the model may use. forms : ``expansion`` and/or ``polynomial`` (plus ``none`` when
        ``cfg.allow_none``). nominal : the nominal length (mm) of an expansion model (for lambda).
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n = len(y)
    if x.shape != (n, len(sensors)):
        raise ValueError(f"The 'x' parameter of fit_parameter must have shape ({n}, {len(sensors)}). Got {x.shape}.")
    if n < 2:
        raise ConfigError(f"thermal regression of {name!r}: needs at least 2 warm states, got {n}")
    v = float(v) if v > 0 else 1e-30
    col = {s: k for k, s in enumerate(sensors)}
    cands = _candidate_models(name, n, candidates, forms, cfg)
    for c in cands:
        c.cv_rmse = _loo_rmse(c, x[:, [col[s] for s in c.sensors]], y, v)
    drifting = [c for c in cands if c.form != "none"]
    best = min(c.cv_rmse for c in drifting)
    ok = [c for c in drifting if c.cv_rmse <= best * (1.0 + cfg.cv_tolerance) + 1e-300]
    chosen = min(ok, key=lambda c: (c.k, c.cv_rmse))
    # "no drift" unless the chosen model explains significantly more than the shared reference noise can
    X = design(x[:, [col[s] for s in chosen.sensors]], chosen.terms)
    Cinv = _cinv(n, v)
    _, _, chi2_model = _gls(X, y, Cinv)
    chi2_null = float(y @ Cinv @ y)
    p_value = float(stats.chi2.sf(max(chi2_null - chi2_model, 0.0), chosen.k))
    null = next((c for c in cands if c.form == "none"), None)
    if null is not None and p_value > cfg.alpha:
        chosen = null
    table = [
        {"model": c.label(), "n_coefficients": c.k, "cv_rmse": c.cv_rmse, "chosen": c is chosen}
        for c in sorted(cands, key=lambda c: c.cv_rmse)
    ]
    if chosen.form == "none":
        return ParameterChoice(None, chosen, table, p_value)
    b, cov, chi2 = _gls(X, y, Cinv)
    dof = n - chosen.k
    red = chi2 / dof if dof > 0 else 1.0
    cov = cov * max(1.0, red)
    r = y - X @ b
    model = ParameterModel(
        name=name,
        kind=kind,
        form=chosen.form,
        sensors=chosen.sensors,
        terms=chosen.terms,
        coefficients=b,
        stderr=np.sqrt(np.diag(cov)),
        covariance=cov,
        nominal=nominal if chosen.form == "expansion" else 0.0,
        stats={
            "n_states": int(n),
            "rmse": float(np.sqrt(np.mean(r**2))),
            "cv_rmse": chosen.cv_rmse,
            "chi2": chi2,
            "dof": int(dof),
            "reduced_chi2": red,
            "state_stderr": float(np.sqrt(2.0 * v)),
            "p_value_vs_no_drift": p_value,
            # how cross-validation chose the sensors and the order (leave-one-state-out)
            "candidate_sensors": list(candidates),
            "n_candidates": len(cands),
            "cv_best_rmse": best,
            "cv_tolerance": cfg.cv_tolerance,
            "cv_alternatives": [row for row in table if not row["chosen"]][:3],
            "no_drift_cv_rmse": float(np.sqrt(np.mean(y**2))),
        },
    )
    return ParameterChoice(model, chosen, table, p_value)


def _candidate_models(
    name: str, n: int, candidates: Sequence[str], forms: Sequence[str], cfg: RegressionConfig
) -> list[Candidate]:
    """Every model the cross-validation compares for ``n`` states: ``none`` (with ``cfg.allow_none``), an expansion
    per candidate sensor, polynomials of up to ``cfg.max_sensors`` sensors and order ``cfg.max_order``."""
    cands: list[Candidate] = []
    if cfg.allow_none:
        cands.append(Candidate("none", (), ()))
    for form in forms:
        if form == "expansion":
            cands += [Candidate("expansion", (s,), ((1,),)) for s in candidates]
        elif form == "polynomial":
            for r in range(1, min(cfg.max_sensors, len(candidates)) + 1):
                for combo in itertools.combinations(candidates, r):
                    for p in range(1, cfg.max_order + 1):
                        terms = tuple(monomials(r, p))
                        if len(terms) <= n - 2:  # leave-one-out must leave a residual degree of freedom
                            cands.append(Candidate("polynomial", combo, terms))
        else:
            raise ConfigError(f"thermal regression of {name!r}: unknown form {form!r}")
    if not any(c.form != "none" for c in cands):
        raise ConfigError(f"thermal regression of {name!r}: no candidate model fits {n} states (too few states)")
    return cands


def _loo_rmse(c: Candidate, xs: np.ndarray, y: np.ndarray, v: float) -> float:
    """Leave-one-state-out RMS prediction error of model ``c`` on its sensors' readings ``xs`` (n, len(sensors));
    of ``none``, the RMS of ``y``."""
    if c.form == "none":
        return float(np.sqrt(np.mean(y**2)))
    n = len(y)
    X = design(xs, c.terms)
    err = np.zeros(n)
    for i in range(n):
        keep = np.arange(n) != i
        b, _, _ = _gls(X[keep], y[keep], _cinv(n - 1, v))
        err[i] = y[i] - X[i] @ b
    return float(np.sqrt(np.mean(err**2)))


def forms_for(kind: str, nominal: float, expansion_only: bool = False) -> tuple[str, ...]:
    """Model forms of a parameter: expansion for a length with a non-zero nominal value (eq. 5-6), polynomials
    for angles and zero-length offsets (eq. 7-8); ``expansion_only`` (the traditional method) allows lengths only."""
    if kind == "length" and nominal != 0.0:
        return ("expansion",)
    return () if expansion_only else ("polynomial",)


def fit_drift(
    drift: StateDrift,
    robot: RobotDescription,
    chain: Chain,
    cfg: RegressionConfig,
    params: Sequence[str] | None = None,
    expansion_only: bool = False,
    allow_none: bool | None = None,
    info: Mapping[str, Any] | None = None,
) -> tuple[ThermalModel, dict[str, ParameterChoice]]:
    """A :class:`ThermalModel` from the identified drift of one warm-up: one regression per parameter.

    params : parameters to model (default: every identified one); expansion_only : the traditional method
    (only non-zero lengths, linear expansion); allow_none : overrides ``cfg.allow_none``.
    """
    names = list(drift.names if params is None else [p for p in drift.names if p in set(params)])
    warm = np.arange(1, drift.deta.shape[0])
    T_ref = drift.temperatures[0]
    x = drift.temperatures[warm] - T_ref
    c = cfg if allow_none is None else RegressionConfig(**{**cfg.__dict__, "allow_none": allow_none})
    nominal = {chain.param_names[p]: float(chain.nominal[e]) for e, p in enumerate(chain.param) if p >= 0}
    kinds = dict(zip(chain.param_names, chain.param_kind, strict=True))
    outcomes: dict[str, ParameterChoice] = {}
    models = []
    for name in names:
        forms = forms_for(kinds[name], nominal[name], expansion_only)
        if not forms:
            continue
        j = drift.names.index(name)
        out = fit_parameter(
            name,
            kinds[name],
            x,
            drift.deta[warm, j],
            float(drift.V[j, j]),
            drift.sensor_names,
            candidate_sensors(robot, name, drift.sensor_names, c),
            c,
            forms=forms,
            nominal=nominal[name],
        )
        outcomes[name] = out
        if out.model is not None:
            models.append(out.model)
    model = ThermalModel(
        robot=robot.name,
        param_names=tuple(chain.param_names),
        sensors=tuple(drift.sensor_names),
        T_ref_C=np.asarray(T_ref, dtype=float),
        fitted_range_C=np.column_stack([drift.temperatures.min(axis=0), drift.temperatures.max(axis=0)]),
        parameters=tuple(models),
        info=dict(info or {}),
    )
    return model, outcomes


__all__ = [
    "Candidate",
    "ParameterChoice",
    "RegressionConfig",
    "candidate_sensors",
    "fit_drift",
    "fit_parameter",
    "forms_for",
    "joint_of",
]
