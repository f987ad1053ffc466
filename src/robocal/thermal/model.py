"""The fitted thermal model: kinematic parameter drift as a function of the sensor temperatures.

Each drifting parameter ``eta_k`` of the chain follows one of the forms of Guo et al. (2026), eq. 5-8, written
in temperature differences ``x_j = T_j - T_ref_j`` from the reference (cold) state at which the geometric
calibration holds:

- ``expansion`` (lengths, eq. 5-6): ``d_eta = c * x_j`` with ``c = lambda * L`` (mm/°C) for one sensor j;
- ``polynomial`` (angles, eq. 7-8): ``d_eta = b + sum_t c_t * prod_j x_j ** e_tj``, the monomials of total
  order 1..p in the chosen sensors (``b`` is 0 unless the model was fitted with an intercept).

:meth:`ThermalModel.deta` evaluates every parameter at once for temperatures ``(m, s)`` given in
:attr:`ThermalModel.sensors` order and returns the drift ``(m, P)`` in the chain's parameter order (mm / rad):
it is what an online compensation service calls.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from robocal.errors import ConfigError

FORMAT = "robocal.thermal_model/1"
FORMS = ("expansion", "polynomial")


def monomials(n_sensors: int, order: int) -> list[tuple[int, ...]]:
    """Exponent tuples of all monomials of total order 1..``order`` in ``n_sensors`` variables.

    Ordered by total order, then lexicographically descending (``x1, x2, x1², x1 x2, x2²`` for 2 sensors).
    """
    out: list[tuple[int, ...]] = []

    def rec(prefix: tuple[int, ...], left: int, k: int) -> None:
        if k == n_sensors - 1:
            out.append((*prefix, left))
            return
        for e in range(left, -1, -1):
            rec((*prefix, e), left - e, k + 1)

    for total in range(1, order + 1):
        rec((), total, 0)
    return out


def design(x: np.ndarray, terms: Sequence[Sequence[int]]) -> np.ndarray:
    """Design matrix ``(m, len(terms))``: each column ``prod_j x[:, j] ** e_j``."""
    x = np.atleast_2d(np.asarray(x, dtype=float))
    cols = [np.prod(x ** np.asarray(e, dtype=float)[None, :], axis=1) for e in terms]
    return np.column_stack(cols) if cols else np.zeros((x.shape[0], 0))


@dataclass(frozen=True)
class ParameterModel:
    """The drift model of one kinematic parameter.

    name : chain parameter name (``d1``, ``theta4`` ...); kind : ``length`` / ``angle``; form : see module doc;
    sensors : the sensor columns used; terms : exponent tuples, one per coefficient (over ``sensors``);
    coefficients, stderr : (t,) in mm or rad per °C^order; covariance : (t, t);
    intercept : constant term (mm / rad); nominal : the nominal length (mm) for ``expansion`` (0 for angles);
    stats : fit statistics (rmse, cv_rmse, n_states, chi2 ...).
    """

    name: str
    kind: str
    form: str
    sensors: tuple[str, ...]
    terms: tuple[tuple[int, ...], ...]
    coefficients: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    intercept: float = 0.0
    nominal: float = 0.0
    stats: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.form not in FORMS:
            raise ConfigError(f"thermal model parameter {self.name!r}: form must be one of {FORMS}, got {self.form!r}")
        if len(self.terms) != len(self.coefficients):
            raise ConfigError(
                f"thermal model parameter {self.name!r}: {len(self.terms)} terms but "
                f"{len(self.coefficients)} coefficients"
            )
        for e in self.terms:
            if len(e) != len(self.sensors):
                raise ConfigError(
                    f"thermal model parameter {self.name!r}: term {e} does not match sensors {self.sensors}"
                )

    @property
    def order(self) -> int:
        return max((sum(e) for e in self.terms), default=0)

    def evaluate(self, x: np.ndarray) -> np.ndarray:
        """Drift ``(m,)`` for temperature differences ``x (m, len(sensors))`` from the reference."""
        return self.intercept + design(x, self.terms) @ self.coefficients

    @property
    def lambda_per_C(self) -> float | None:
        """Linear expansion coefficient ``c / L`` (1/°C) of an ``expansion`` model with a non-zero length."""
        if self.form != "expansion" or self.nominal == 0.0:
            return None
        return float(self.coefficients[0] / self.nominal)

    def equation(self, T_ref: Mapping[str, float], stderr: bool = False, deg: bool = False) -> str:
        """The model in the style of Guo et al. eq. 28 (angles in rad, lengths in mm, temperatures in °C), in
        differences from the reference temperatures; ``stderr``: every coefficient as ``(c ± standard error)``;
        ``deg``: an angle's drift in degrees (as the reports' tables give angles)."""
        short = [_short(s) for s in self.sensors]
        f = math.degrees(1.0) if deg and self.kind != "length" else 1.0

        def coef(c: float, se: float, signed: bool) -> str:
            c, se = c * f, se * f
            if stderr:
                return f"{'+' if signed else ''}({c:.4g} ± {se:.2g})"
            return f"{c:+.4g}" if signed else f"{c:.4g}"

        if self.form == "expansion":
            s = self.sensors[0]
            c0 = coef(float(self.coefficients[0]), float(self.stderr[0]), False)
            return f"Δ{self.name} = {c0} × ({short[0]} − {T_ref[s]:.2f})"
        parts = [f"{self.intercept * f:.4g}"] if self.intercept != 0.0 else []
        for c, se, e in zip(self.coefficients, self.stderr, self.terms, strict=True):
            mono = "·".join((f"Δ{n}" if k == 1 else f"Δ{n}^{k}") for n, k in zip(short, e, strict=True) if k > 0)
            parts.append(f"{coef(float(c), float(se), True)}·{mono}")
        refs = ", ".join(f"Δ{n} = {n} − {T_ref[s]:.2f}" for n, s in zip(short, self.sensors, strict=True))
        body = " ".join(parts).lstrip("+") if parts else "0"
        return f"Δ{self.name} = {body}    ({refs})"

    def absolute(self, T_ref: Mapping[str, float]) -> tuple[tuple[tuple[int, ...], ...], np.ndarray, np.ndarray]:
        """The polynomial in absolute temperatures ``t_j`` (as the paper prints eq. 28 for angles): exponent
        tuples (the constant first), coefficients and their standard errors (the covariance carried through the
        linear change of variables ``Δt_j = t_j − T_ref_j``)."""
        ref = np.array([T_ref[s] for s in self.sensors], dtype=float)
        out_terms: list[tuple[int, ...]] = [tuple(0 for _ in self.sensors)]
        out_terms += [t for p in range(1, self.order + 1) for t in monomials(len(self.sensors), p) if sum(t) == p]
        out_terms = list(dict.fromkeys(out_terms))
        row = {t: i for i, t in enumerate(out_terms)}
        M = np.zeros((len(out_terms), len(self.terms)))
        for col, e in enumerate(self.terms):
            for ks in itertools.product(*[range(k + 1) for k in e]):
                w = 1.0
                for j, (k, ej) in enumerate(zip(ks, e, strict=True)):
                    w *= math.comb(ej, k) * (-ref[j]) ** (ej - k)
                M[row[tuple(ks)], col] += w
        keep = np.flatnonzero(np.any(M != 0.0, axis=1) | (np.arange(len(out_terms)) == 0))  # drop unused monomials
        M = M[keep]
        coef = M @ self.coefficients
        coef[0] += self.intercept
        cov = M @ np.asarray(self.covariance, dtype=float) @ M.T
        return tuple(out_terms[i] for i in keep), coef, np.sqrt(np.clip(np.diag(cov), 0.0, None))

    def equation_absolute(self, T_ref: Mapping[str, float], deg: bool = False) -> str:
        """Guo et al. eq. 28 as printed there: expansions as ``c × (t − T_ref)``, polynomials expanded in the
        absolute temperatures with a constant term (``deg``: an angle's drift in degrees)."""
        if self.form == "expansion":
            return self.equation(T_ref, deg=deg)
        short = [_short(s) for s in self.sensors]
        terms, coef, _ = self.absolute(T_ref)
        coef = coef * (math.degrees(1.0) if deg and self.kind != "length" else 1.0)
        parts = []
        for c, e in zip(coef, terms, strict=True):
            mono = "·".join((n if k == 1 else f"{n}^{k}") for n, k in zip(short, e, strict=True) if k > 0)
            parts.append(f"{c:+.4g}" + (f"·{mono}" if mono else ""))
        return f"Δ{self.name} = " + " ".join(parts).lstrip("+")

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": self.kind,
            "unit": "mm" if self.kind == "length" else "rad",
            "form": self.form,
            "order": self.order,
            "sensors": list(self.sensors),
            "terms": [list(e) for e in self.terms],
            "coefficients": [float(v) for v in self.coefficients],
            "stderr": [float(v) for v in self.stderr],
            "covariance": np.asarray(self.covariance, dtype=float).tolist(),
            "intercept": float(self.intercept),
            "nominal": float(self.nominal),
            "lambda_per_C": self.lambda_per_C,
            "stats": dict(self.stats),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ParameterModel:
        try:
            coef = np.asarray(d["coefficients"], dtype=float)
            t = len(coef)
            se = np.asarray(d.get("stderr", [np.nan] * t), dtype=float)
            cov = np.asarray(d.get("covariance", np.diag(np.nan_to_num(se) ** 2)), dtype=float).reshape(t, t)
            return cls(
                name=str(d["name"]),
                kind=str(d.get("kind", "angle")),
                form=str(d["form"]),
                sensors=tuple(d["sensors"]),
                terms=tuple(tuple(int(v) for v in e) for e in d["terms"]),
                coefficients=coef,
                stderr=se,
                covariance=cov,
                intercept=float(d.get("intercept", 0.0)),
                nominal=float(d.get("nominal", 0.0)),
                stats=dict(d.get("stats", {})),
            )
        except KeyError as exc:
            raise ConfigError(f"thermal model parameter entry is missing the key {exc.args[0]!r}: {dict(d)}") from None


def _short(sensor: str) -> str:
    """The name a sensor has in an equation: its column name (``T_j4_C``), as in every table and file (the paper
    writes t4; one name per sensor keeps a report readable)."""
    return sensor


@dataclass(frozen=True)
class ThermalModel:
    """Temperature-dependent kinematic parameters of one robot.

    robot : robot name; param_names : the chain's parameter names (order of :meth:`deta`'s columns);
    sensors : the sensor columns :meth:`deta` expects, in order; T_ref_C : (s,) reference temperatures (the
    state of the geometric calibration); fitted_range_C : (s, 2) min / max temperature seen in the fit;
    parameters : the drifting parameters' models; info : provenance (method, states, config).
    """

    robot: str
    param_names: tuple[str, ...]
    sensors: tuple[str, ...]
    T_ref_C: np.ndarray
    fitted_range_C: np.ndarray
    parameters: tuple[ParameterModel, ...]
    info: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        s = len(self.sensors)
        if np.shape(self.T_ref_C) != (s,) or np.shape(self.fitted_range_C) != (s, 2):
            raise ConfigError(f"thermal model: T_ref_C must have shape ({s},) and fitted_range_C ({s}, 2)")
        for p in self.parameters:
            if p.name not in self.param_names:
                raise ConfigError(f"thermal model parameter {p.name!r} is not a chain parameter {self.param_names}")
            missing = [x for x in p.sensors if x not in self.sensors]
            if missing:
                raise ConfigError(f"thermal model parameter {p.name!r} uses unknown sensor(s) {missing}")

    # ------------------------------------------------------------------ evaluation
    @property
    def names(self) -> tuple[str, ...]:
        """Names of the drifting parameters."""
        return tuple(p.name for p in self.parameters)

    def parameter(self, name: str) -> ParameterModel:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(f"the thermal model has no parameter {name!r}; it has {list(self.names)}")

    def _temps(self, temperatures: Any) -> np.ndarray:
        T = np.asarray(temperatures, dtype=float)
        if T.ndim == 1:
            T = T[None, :]
        if T.ndim != 2 or T.shape[1] != len(self.sensors):
            raise ValueError(
                f"The 'temperatures' parameter of ThermalModel.deta must have shape (m, {len(self.sensors)}) in the "
                f"order {list(self.sensors)}. Got {np.shape(temperatures)} instead."
            )
        if not np.all(np.isfinite(T)):
            raise ValueError("The 'temperatures' parameter of ThermalModel.deta must be finite.")
        return T

    def deta(self, temperatures: Any) -> np.ndarray:
        """Parameter drift ``(m, P)`` (mm / rad, chain order) at temperatures ``(m, s)`` in :attr:`sensors` order."""
        T = self._temps(temperatures)
        out = np.zeros((T.shape[0], len(self.param_names)))
        col = {s: k for k, s in enumerate(self.sensors)}
        for p in self.parameters:
            idx = [col[s] for s in p.sensors]
            x = T[:, idx] - self.T_ref_C[idx]
            out[:, self.param_names.index(p.name)] = p.evaluate(x)
        return out

    def out_of_range(self, temperatures: Any, margin_C: float = 0.0) -> np.ndarray:
        """(m, s) bool: readings outside the fitted range (extrapolation) by more than ``margin_C``."""
        T = self._temps(temperatures)
        lo, hi = self.fitted_range_C[:, 0] - margin_C, self.fitted_range_C[:, 1] + margin_C
        return (T < lo) | (T > hi)

    def equations(self, stderr: bool = False, absolute: bool = False, deg: bool = False) -> list[str]:
        """The model in the form of Guo et al. eq. 28, one line per parameter: in temperature differences from
        the reference (default; ``stderr`` adds each coefficient's standard error) or, ``absolute``, with the
        polynomials expanded in absolute temperatures as the paper prints them. ``deg``: angles in degrees
        (the reports), else rad (the paper, the JSON files)."""
        ref = dict(zip(self.sensors, self.T_ref_C.tolist(), strict=True))
        if absolute:
            return [p.equation_absolute(ref, deg=deg) for p in self.parameters]
        return [p.equation(ref, stderr=stderr, deg=deg) for p in self.parameters]

    # ------------------------------------------------------------------ persistence
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "robot": self.robot,
            "param_names": list(self.param_names),
            "sensors": list(self.sensors),
            "T_ref_C": [float(v) for v in self.T_ref_C],
            "fitted_range_C": np.asarray(self.fitted_range_C, dtype=float).tolist(),
            "parameters": [p.to_dict() for p in self.parameters],
            "equations": self.equations(),
            "info": dict(self.info),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ThermalModel:
        fmt = d.get("format", FORMAT)
        if fmt != FORMAT:
            raise ConfigError(f"thermal model format {fmt!r} is not {FORMAT!r}")
        try:
            sensors = tuple(d["sensors"])
            rng = d.get("fitted_range_C")
            T_ref = np.asarray(d["T_ref_C"], dtype=float)
            return cls(
                robot=str(d["robot"]),
                param_names=tuple(d["param_names"]),
                sensors=sensors,
                T_ref_C=T_ref,
                fitted_range_C=np.asarray(rng, dtype=float) if rng is not None else np.column_stack([T_ref, T_ref]),
                parameters=tuple(ParameterModel.from_dict(p) for p in d["parameters"]),
                info=dict(d.get("info", {})),
            )
        except KeyError as exc:
            raise ConfigError(f"thermal model is missing the key {exc.args[0]!r}") from None

    @classmethod
    def from_json(cls, path: str | Path) -> ThermalModel:
        """Read a model written by :meth:`to_dict` (a ``thermal.json`` with a ``model`` key also works)."""
        p = Path(path)
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"cannot read a thermal model from {p}: {exc}") from None
        if isinstance(data, dict) and "parameters" not in data and isinstance(data.get("model"), dict):
            data = data["model"]
        return cls.from_dict(data)


__all__ = ["FORMAT", "ParameterModel", "ThermalModel", "design", "monomials"]
