"""Identification of an external axis's own errors along its travel (issue 34), beside the arm's kinematics.

The geometric calibration (:func:`robocal.calibration.fit.calibrate`) fits the kinematic parameters of every
joint, a track's or a column's as the arm's (its identifiability analysis and poorly-determined test cover them
alike). This module fits, on top, each linear axis's errors as smooth functions of its position
(:mod:`robocal.kinematics.axes`): straightness in x and y, positioning, pitch, yaw and roll of the carriage, each a
sum of Legendre polynomials of the travel coordinate ``u`` in [-1, 1], and for a column (``role: column``) the
bending of the carriage under the moment of the arm's weight (rotations about the carriage's x and y in proportion
to that moment, ``bending_x`` / ``bending_y``, and growing with the extension, ``..._ext``: times ``u``). A
description without link masses: the moment is unknown, but linear in the bodies' masses and first moments
(:func:`robocal.kinematics.axes.moment_features`), so the bending is fitted with one coefficient per mass parameter
(``column:bending_x_b3_m``: the compliance times that body's mass, ``_b3_x``: times its first moment along its
frame's x per 0.1 m; the ones the data cannot tell apart held at 0 by the rank test below), without the growth
with the extension (twenty coefficients per rotation already; on the column twin the ``_ext`` terms cost more
held-out error than they gain). The arm's own weight only: a payload's moment needs its mass and centre of mass,
i.e. the description's masses.

Terms that the kinematic parameters already hold are not fitted: the constant of every component and the linear
part of the straightness (a tilt of the axis' direction). Jointly with the calibration's identified parameters
(started at its fit), by Gauss-Newton on the position residuals weighted by the point noise, each coefficient with
a zero-mean Gaussian prior (``prior_mm``, ``prior_urad``, ``prior_bending_urad_per_kNm``: a ridge, so that a high
order the data hardly see stays small). The polynomial order (one for all components of the axis, from 0 = no
function up to ``max_order``) and whether the column bends are chosen by cross-validation over pose ids
(``folds`` folds, seeded): the smallest model whose held-out RMS is within one standard error of the best (the
one-standard-error rule). Standard errors from the posterior covariance at the estimated noise; a term whose
function's standard error anywhere on the travel exceeds the calibration's bound (``max_stderr_mm`` /
``max_stderr_deg``) is reported as poorly determined, and a coefficient the data cannot see beyond the
calibration's parameters and the other terms (:func:`_not_identifiable`) as not identifiable (held at 0).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg

from robocal.calibration.config import point_sigma
from robocal.calibration.result import CalibrationResult
from robocal.calibration.start import fit_data
from robocal.config import parse, setting
from robocal.data.campaign import Campaign
from robocal.errors import ConfigError
from robocal.identification.model import CalibrationModel, FitData, with_base
from robocal.kinematics.axes import (
    COMPONENTS,
    UNITS,
    augment,
    carried_moment,
    legendre,
    moment_features,
    rod_moment,
    travel_coordinate,
)

#: the components' lowest fitted Legendre order (lower ones are kinematic parameters: a constant offset of every
#: component, the linear part of the straightness, which is a tilt of the axis' direction)
LOWEST_ORDER = {"straightness_x": 2, "straightness_y": 2, "positioning": 1, "pitch": 1, "yaw": 1, "roll": 1}
#: the highest Legendre order of the travel offered by discovery and designed for by planning
ORDER = 3
#: bending rotations: (component, moment axis of the carriage frame)
BENDING = (("bending_x", "pitch", 0), ("bending_y", "yaw", 1))
KNM = 1000.0  # N·m per kN·m
#: without masses, a bending coefficient is the compliance times a mass parameter: its prior is the compliance's
#: times this mass (an arm's body is a few to a hundred kg)
PRIOR_MASS_KG = 100.0


@dataclass(frozen=True)
class AxisSettings:
    """How the axis errors are fitted (module docstring).

    components : the error components fitted (:data:`robocal.kinematics.axes.COMPONENTS`); max_order : the
    highest Legendre order tried; order : a given order instead (no cross-validation of it); bending : fit a
    column's bending ("auto": for an axis whose role is
    ``column``, when the description has masses; True / False); prior_mm / prior_urad /
    prior_bending_urad_per_kNm : the coefficients' prior standard deviations; folds, seed : the cross-validation;
    max_iter : Gauss-Newton iterations per fit.
    """

    components: tuple[str, ...] = COMPONENTS
    max_order: int = setting(4, ge=0, le=10)
    bending: str | bool = "auto"
    prior_mm: float = setting(1.0, gt=0)
    prior_urad: float = setting(1000.0, gt=0)
    prior_bending_urad_per_kNm: float = setting(1000.0, gt=0)
    folds: int = setting(5, ge=2)
    seed: int = 0
    max_iter: int = setting(20, ge=1)
    order: int | None = None

    def __post_init__(self) -> None:
        bad = [c for c in self.components if c not in COMPONENTS]
        if bad:
            raise ConfigError(f"axes.components: unknown {bad}; known: {list(COMPONENTS)}")

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None, section: str = "axes") -> AxisSettings:
        return parse(cls, m, section)


@dataclass(frozen=True)
class Term:
    """One fitted coefficient: ``name`` (``track:straightness_y_P2``, ``column:bending_x``), its component
    (``track:straightness_y``), the axis (joint index, 0-based) and its position among the axes, the error
    element it drives (index into COMPONENTS), the feature (``legendre`` of ``order``, or ``moment`` about the
    carriage ``moment_axis`` times ``u ** order``) and the coefficient's unit."""

    name: str
    component: str
    joint: int
    axis_pos: int
    slot: int
    feature: str
    order: int
    unit: str
    moment_axis: int = -1
    column: int = -1  # a "masses" feature: which mass parameter (robocal.kinematics.axes.moment_features)


def axis_terms(robot: Any, settings: AxisSettings, order: int, bending: bool, rods: bool = False) -> list[Term]:
    """The terms of every linear axis for a polynomial ``order`` and with or without the column's bending;
    ``rods``: a description without masses bends by the moment of links shaped like the arm's
    (:func:`robocal.kinematics.axes.rod_moment`, ``column:bending_x_rods``, ``_rods_ext``: discovery's compact
    candidate) instead of one coefficient per mass parameter."""
    out: list[Term] = []
    axes = [j for j in range(robot.n_joints) if robot.prismatic[j]]
    for a, j in enumerate(axes):
        role = robot.role(j)
        for comp in settings.components:
            c = COMPONENTS.index(comp)
            for k in range(LOWEST_ORDER[comp], order + 1):
                unit = "mm" if UNITS[c] == "mm" else "rad"
                out.append(Term(f"{role}:{comp}_P{k}", f"{role}:{comp}", j, a, c, "legendre", k, unit))
        if bending and (robot.has_dynamics or rods):  # one moment (the masses', or rods'), and times the extension
            feature, tag = ("moment", "") if robot.has_dynamics else ("rods", "_rods")
            for name, comp, ax in BENDING:
                c = COMPONENTS.index(comp)
                for k, suffix in ((0, ""), (1, "_ext")):
                    out.append(Term(f"{role}:{name}{tag}{suffix}", f"{role}:{name}", j, a, c, feature, k, "rad/kNm",
                                    ax))  # fmt: skip
        elif bending:  # no masses: the moment of each unknown mass parameter (robocal.kinematics.axes), no _ext
            for name, comp, ax in BENDING:
                c = COMPONENTS.index(comp)
                for f, pn in enumerate(mass_parameter_names(robot, j)):
                    out.append(Term(f"{role}:{name}_{pn}", f"{role}:{name}", j, a, c, "masses", 0, "rad/kNm", ax, f))
    return out


def mass_parameter_names(robot: Any, joint: int) -> list[str]:
    """The unknown mass parameters a column's bending is fitted with when the description has no masses
    (:func:`robocal.kinematics.axes.moment_features`): ``b<i>_m``, ``b<i>_x`` .. per body after the carriage."""
    return [f"b{i + 1}_{k}" for i in range(joint + 1, robot.n_joints) for k in ("m", "x", "y", "z")]


def features(robot: Any, q: np.ndarray, payload_kg: np.ndarray, terms: list[Term]) -> np.ndarray:
    """The feature of every term at every row, ``(m, T)``: the value of its error element per unit coefficient."""
    F = np.zeros((q.shape[0], len(terms)))
    moments: dict[int, np.ndarray] = {}
    rods: dict[int, np.ndarray] = {}
    per_mass: dict[int, np.ndarray] = {}
    for t, term in enumerate(terms):
        u = travel_coordinate(q[:, term.joint], robot.q_limits[term.joint])
        if term.feature == "legendre":
            F[:, t] = legendre(u, term.order)
        elif term.feature == "rods":
            if term.joint not in rods:
                rods[term.joint] = rod_moment(robot, q, term.joint, payload_kg)
            F[:, t] = rods[term.joint][:, term.moment_axis] * u**term.order
        elif term.feature == "masses":
            if term.joint not in per_mass:
                per_mass[term.joint] = moment_features(robot, q, term.joint)[0]
            F[:, t] = per_mass[term.joint][:, term.moment_axis, term.column] * u**term.order
        else:
            if term.joint not in moments:
                moments[term.joint] = carried_moment(robot, q, term.joint, payload_kg) / KNM
            F[:, t] = moments[term.joint][:, term.moment_axis] * u**term.order
    return F


def axis_errors(
    robot: Any, q: np.ndarray, payload_kg: np.ndarray, terms: list[Term] | tuple[Term, ...], coef: np.ndarray
) -> np.ndarray:
    """The carriage errors ``(m, 6 · n_axes)`` of coefficients ``coef`` (T,): the pseudo joints' values of the
    chain :func:`robocal.kinematics.axes.augment` makes for the robot's linear axes, in their order."""
    n_axes = int(np.count_nonzero(robot.prismatic))
    E = np.zeros((q.shape[0], 6 * n_axes))
    F = features(robot, q, payload_kg, list(terms))
    for t, term in enumerate(terms):
        E[:, 6 * term.axis_pos + term.slot] += F[:, t] * coef[t]
    return E


def term_named(robot: Any, name: str) -> Term:
    """The :class:`Term` of a name as :func:`axis_terms` writes it (``track:straightness_y_P2``,
    ``column:bending_x_ext``); raises :class:`ConfigError` for a name no linear axis of ``robot`` has."""
    for bend, rods in ((False, False), (True, False), (True, True)):
        for t in axis_terms(robot, AxisSettings(), AxisSettings().max_order + 6, bend, rods):
            if t.name == name:
                return t
    raise ConfigError(f"no axis error term {name!r} on robot {robot.name!r}")


def _prior_sd(term: Term, s: AxisSettings) -> float:
    if term.unit == "mm":
        return s.prior_mm
    if term.unit == "rad":
        return s.prior_urad * 1e-6
    if term.feature == "masses":  # the compliance times a mass parameter (kg, or kg x 0.1 m)
        return s.prior_bending_urad_per_kNm * 1e-6 * PRIOR_MASS_KG
    return s.prior_bending_urad_per_kNm * 1e-6


@dataclass
class _Problem:
    """The joint fit of the calibration's identified parameters and the axis terms on some rows."""

    model: CalibrationModel
    data: FitData
    sigma: np.ndarray  # (m,)
    F: np.ndarray  # (m, T)
    terms: list[Term]
    free: np.ndarray  # the calibration's identified parameter indices
    x0: np.ndarray
    prior_sd: np.ndarray  # (T,)
    n_axes: int
    n_joints: int

    def q_aug(self, coef: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        F = self.F if rows is None else self.F[rows]
        q = self.data.q if rows is None else self.data.q[rows]
        E = np.zeros((len(q), 6 * self.n_axes))
        for t, term in enumerate(self.terms):
            E[:, 6 * term.axis_pos + term.slot] += F[:, t] * coef[t]
        return np.concatenate([q, E], axis=1), F

    def residuals(self, x: np.ndarray, coef: np.ndarray, rows: np.ndarray) -> np.ndarray:
        q, _ = self.q_aug(coef, rows)
        d = self.data.rows(rows).with_q(q)
        p, _ = self.model.predict_stations(x, d)
        return p - d.p_mm

    def fit(self, rows: np.ndarray, max_iter: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Gauss-Newton on ``rows``: the full vector, the coefficients, the normal matrix (weighted, with the
        prior) over [free, coefficients], and the weighted residual sum of squares."""
        x = self.x0.copy()
        T = len(self.terms)
        coef = np.zeros(T)
        m = len(rows)
        w = np.repeat(1.0 / self.sigma[rows], 3)
        pos = self.data.rows(rows)
        if pos.R_meas is not None:  # positions only
            pos = FitData(pos.q, pos.p_mm, pos.target_index, None, pos.station_index)
        N = np.eye(len(self.free) + T)
        rss = np.inf
        for _ in range(max_iter):
            q, F = self.q_aug(coef, rows)
            d = pos.with_q(q)
            r, J = self.model.residuals_and_jacobian(x, d)
            r, J = r[: 3 * m], J[: 3 * m]
            J_q, _ = self.model.joint_jacobians(x, d)
            Jc = np.zeros((3 * m, T))
            for t, term in enumerate(self.terms):
                col = J_q[:, :, self.n_joints + 6 * term.axis_pos + term.slot] * F[:, t : t + 1]
                Jc[:, t] = col.ravel()
            A = np.concatenate([J[:, self.free], Jc], axis=1) * w[:, None]
            b = r * w
            P = np.zeros(len(self.free) + T)
            P[len(self.free) :] = 1.0 / self.prior_sd
            N = A.T @ A + np.diag(P**2)
            g = A.T @ b
            g[len(self.free) :] += P[len(self.free) :] ** 2 * coef
            step = _solve(N, g)
            x[self.free] -= step[: len(self.free)]
            coef -= step[len(self.free) :]
            new_rss = float(np.sum(b**2) + np.sum((coef * P[len(self.free) :]) ** 2))
            if abs(rss - new_rss) <= 1e-10 * max(new_rss, 1.0) and np.abs(step).max() < 1e-9:
                break
            rss = new_rss
        r = self.residuals(x, coef, rows).ravel() * w
        return x, coef, N, float(np.sum(r**2))


def _solve(N: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``N⁻¹ g`` for a symmetric normal matrix, scaled to unit diagonal (the parameters' units differ)."""
    d = np.sqrt(np.maximum(np.diag(N), 1e-300))
    return np.linalg.lstsq(N / np.outer(d, d), g / d, rcond=1e-12)[0] / d


@dataclass(frozen=True)
class AxisFit:
    """The fitted axis errors (:func:`fit_axis_errors`).

    terms : the chosen model's terms; coef / stderr : (T,) in the terms' units (mm, rad, rad per kN·m);
    x : the calibration's full vector refitted with them; order / bending : the chosen model; cv : one record per
    candidate model (order, bending, held-out RMS and its standard error, mm); poorly_determined / not_identifiable
    : term names; validation : held-out figures (mm) without and with the axis errors; sigma_hat : the estimated
    noise scale (RMS of the weighted residuals).
    """

    terms: tuple[Term, ...]
    coef: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    x: np.ndarray
    order: int
    bending: bool
    cv: tuple[dict[str, Any], ...]
    poorly_determined: tuple[str, ...]
    not_identifiable: tuple[str, ...]
    validation: dict[str, Any] = field(default_factory=dict)
    sigma_hat: float = float("nan")
    rms_mm: float = float("nan")

    def value(self, name: str) -> float:
        return float(self.coef[[t.name for t in self.terms].index(name)])

    def error(self, name: str) -> float:
        return float(self.stderr[[t.name for t in self.terms].index(name)])

    def record(self) -> dict[str, Any]:
        """A JSON-able summary (coefficients in mm, µrad and µrad per kN·m)."""

        def scale(t: Term) -> tuple[float, str]:
            return (1.0, "mm") if t.unit == "mm" else (1e6, "urad" if t.unit == "rad" else "urad/kNm")

        terms = []
        for k, t in enumerate(self.terms):
            f, unit = scale(t)
            terms.append(
                {"name": t.name, "value": float(self.coef[k] * f), "stderr": float(self.stderr[k] * f), "unit": unit}
            )
        return {
            "order": self.order,
            "bending": self.bending,
            "terms": terms,
            "cross_validation": list(self.cv),
            "poorly_determined": list(self.poorly_determined),
            "not_identifiable": list(self.not_identifiable),
            "validation": dict(self.validation),
            "rms_position_mm": self.rms_mm,
        }


def _problem(base: CalibrationResult, cal: Campaign, terms: list[Term], settings: AxisSettings) -> _Problem:
    robot = base.model.robot
    axes = [j for j in range(robot.n_joints) if robot.prismatic[j]]
    model = copy.copy(base.model)
    model.chain = augment(base.model.chain, axes)
    model.full_chain = with_base(model.chain)
    data = fit_data(cal, False, base.model.target_names, base.model.station_names)
    return _Problem(
        model=model,
        data=data,
        sigma=point_sigma(cal, base.config),
        F=features(robot, cal.q, cal.payload_kg, terms),
        terms=terms,
        free=np.flatnonzero(base.identified),
        x0=base.x.copy(),
        prior_sd=np.array([_prior_sd(t, settings) for t in terms]),
        n_axes=len(axes),
        n_joints=robot.n_joints,
    )


def _folds(pose_id: np.ndarray, k: int, seed: int) -> list[np.ndarray]:
    ids = np.array(list(dict.fromkeys(pose_id.tolist())), dtype=object)
    perm = np.random.default_rng(seed).permutation(len(ids))
    fold_of = {ids[p]: i % k for i, p in enumerate(perm)}
    f = np.array([fold_of[p] for p in pose_id])
    return [np.flatnonzero(f == i) for i in range(k)]


def _cv(base: CalibrationResult, cal: Campaign, terms: list[Term], settings: AxisSettings) -> tuple[float, float]:
    """Held-out RMS (mm, per point) over the folds and its standard error."""
    prob = _problem(base, cal, terms, settings)
    errs = []
    for held in _folds(cal.pose_id, settings.folds, settings.seed):
        train = np.setdiff1d(np.arange(cal.n_rows), held)
        x, coef, _, _ = prob.fit(train, settings.max_iter)
        e = np.linalg.norm(prob.residuals(x, coef, held), axis=1)
        errs.append(float(np.sqrt(np.mean(e**2))))
    a = np.array(errs)
    return float(a.mean()), float(a.std(ddof=1) / np.sqrt(len(a)))


def fit_axis_errors(
    campaign: Campaign, base: CalibrationResult, settings: AxisSettings | Mapping[str, Any] | None = None
) -> AxisFit:
    """Fit the linear axes' errors along their travel on ``campaign``'s calibration rows (those ``base`` kept),
    jointly with ``base``'s identified parameters; the model order and the bending chosen by cross-validation.

    Raises :class:`ConfigError` when the robot has no prismatic joint."""
    s = settings if isinstance(settings, AxisSettings) else AxisSettings.from_mapping(settings)
    robot = base.model.robot
    if not robot.has_prismatic:
        raise ConfigError(f"robot {robot.name!r} has no prismatic joint (a track, a column): no axis error to fit")
    cal = campaign.calibration() if np.any(campaign.split == "validation") else campaign
    if base.start is not None and len(base.start.kept) == cal.n_rows:
        cal = cal.subset(base.start.kept)
    columns = [j for j in range(robot.n_joints) if robot.prismatic[j] and "column" in robot.role(j)]
    if s.bending == "auto":  # without masses the bending's moment is fitted per unknown mass parameter
        bend_options = [False, True] if columns else [False]
    else:
        bend_options = [bool(s.bending)]
    cv: list[dict[str, Any]] = []
    orders = range(s.max_order + 1) if s.order is None else [s.order]
    for bend in bend_options:
        for order in orders:
            terms = axis_terms(robot, s, order, bend)
            mean, se = _cv(base, cal, terms, s)
            cv.append({"order": order, "bending": bend, "n_terms": len(terms), "cv_rms_mm": mean, "cv_se_mm": se})
    best = min(cv, key=lambda c: c["cv_rms_mm"])
    ok = [c for c in cv if c["cv_rms_mm"] <= best["cv_rms_mm"] + best["cv_se_mm"]]
    pick = min(ok, key=lambda c: (c["n_terms"], c["cv_rms_mm"]))
    terms = axis_terms(robot, s, int(pick["order"]), bool(pick["bending"]))
    # the rank test at the start: a term the others (and the calibration's parameters) span is held at 0
    not_ident = _not_identifiable(_problem(base, cal, terms, s), base.x, np.zeros(len(terms)), base.config.rank_tol)
    terms = [t for t in terms if t.name not in not_ident]
    prob = _problem(base, cal, terms, s)
    rows = np.arange(cal.n_rows)
    x, coef, N, rss = prob.fit(rows, s.max_iter)
    nf, T = len(prob.free), len(terms)
    dof = max(3 * cal.n_rows - nf - T, 1)
    sigma_hat = float(np.sqrt(rss / dof))
    cov_all = np.linalg.pinv(N) * max(sigma_hat, 1.0) ** 2
    cov = cov_all[nf:, nf:]
    stderr = np.sqrt(np.maximum(np.diag(cov), 0.0))
    poor = _poorly_determined(prob, cov, base)
    e = np.linalg.norm(prob.residuals(x, coef, rows), axis=1)
    return AxisFit(
        terms=tuple(terms),
        coef=coef,
        stderr=stderr,
        covariance=cov,
        x=x,
        order=int(pick["order"]),
        bending=bool(pick["bending"]),
        cv=tuple(cv),
        poorly_determined=tuple(poor),
        not_identifiable=tuple(not_ident),
        validation=_validation(campaign, base, prob, x, coef),
        sigma_hat=sigma_hat,
        rms_mm=float(np.sqrt(np.mean(e**2))),
    )


def _not_identifiable(prob: _Problem, x: np.ndarray, coef: np.ndarray, rank_tol: float) -> list[str]:
    """Terms the data cannot determine: a coefficient at its prior size moves the weighted fit by less than one
    noise sigma once the calibration's identified parameters have absorbed what they can, or its column (outside
    their span, unit-scaled) is spanned by the other terms' (to ``rank_tol``)."""
    q, F = prob.q_aug(coef)
    d = prob.data.with_q(q)
    d = FitData(d.q, d.p_mm, d.target_index, None, d.station_index)
    _, J = prob.model.residuals_and_jacobian(x, d)
    J_q, _ = prob.model.joint_jacobians(x, d)
    m = prob.data.m
    cols = [J[: 3 * m, prob.free]]
    for t, term in enumerate(prob.terms):
        cols.append((J_q[:, :, prob.n_joints + 6 * term.axis_pos + term.slot] * F[:, t : t + 1]).reshape(-1, 1))
    A = np.concatenate(cols, axis=1) * np.repeat(1.0 / prob.sigma, 3)[:, None]  # in units of the noise
    nf = len(prob.free)
    # the calibration's identified parameters first (they are independent by its own rank test): each term's
    # column outside their span
    Qf, _ = np.linalg.qr(A[:, :nf])
    B = A[:, nf:] - Qf @ (Qf.T @ A[:, nf:])
    if B.shape[1] == 0:
        return []
    # no information: a coefficient as large as its prior moves the fit by less than one noise sigma in all
    seen = np.linalg.norm(B, axis=0) * prob.prior_sd >= 1.0
    out = {t.name for t, ok in zip(prob.terms, seen, strict=True) if not ok}
    # the rest: a pivoted QR of the unit-scaled parts (a term the other terms span)
    keep = np.flatnonzero(seen)
    if len(keep):
        Bk = B[:, keep] / np.linalg.norm(B[:, keep], axis=0)
        _, R, piv = scipy.linalg.qr(Bk, mode="economic", pivoting=True)
        rank = int(np.sum(np.abs(np.diag(R)) > rank_tol))
        out |= {prob.terms[keep[c]].name for c in piv[rank:].tolist()}
    return [t.name for t in prob.terms if t.name in out]


def _poorly_determined(prob: _Problem, cov: np.ndarray, base: CalibrationResult) -> list[str]:
    """Components whose function's standard error somewhere on the travel exceeds the calibration's bound."""
    out = []
    robot = base.model.robot
    comps = dict.fromkeys(t.component for t in prob.terms)
    for comp in comps:
        idx = [k for k, t in enumerate(prob.terms) if t.component == comp]
        term = prob.terms[idx[0]]
        lo, hi = (float(v) for v in robot.q_limits[term.joint])
        s = np.linspace(lo, hi, 41)
        u = travel_coordinate(s, robot.q_limits[term.joint])
        if term.feature == "legendre":
            G = np.stack([legendre(u, prob.terms[k].order) for k in idx], axis=1)
            bound = base.config.max_stderr_mm if term.unit == "mm" else np.deg2rad(base.config.max_stderr_deg)
        else:  # per kN·m of moment: bounded by the angle bound at 1 kN·m
            G = np.stack([u ** prob.terms[k].order for k in idx], axis=1)
            bound = np.deg2rad(base.config.max_stderr_deg)
        sd = np.sqrt(np.maximum(np.einsum("si,ij,sj->s", G, cov[np.ix_(idx, idx)], G), 0.0))
        if sd.max() > bound:
            out.append(comp)
    return out


def _validation(campaign: Campaign, base: CalibrationResult, prob: _Problem, x: np.ndarray, coef: np.ndarray) -> dict:
    """Held-out errors (mm) on the validation rows: the calibration alone and with the axis errors."""
    val = campaign.validation()
    assert val.station is not None
    keep = np.isin(val.target, base.model.target_names) & np.isin(val.station, base.model.station_names)
    val = val.subset(keep)
    if val.n_rows == 0:
        return {"n_rows": 0}
    d = fit_data(val, False, base.model.target_names, base.model.station_names)
    p0, _ = base.model.predict_stations(base.x, d)
    F = features(base.model.robot, val.q, val.payload_kg, prob.terms)
    E = np.zeros((val.n_rows, 6 * prob.n_axes))
    for t, term in enumerate(prob.terms):
        E[:, 6 * term.axis_pos + term.slot] += F[:, t] * coef[t]
    p1, _ = prob.model.predict_stations(x, d.with_q(np.concatenate([val.q, E], axis=1)))
    e0 = np.linalg.norm(p0 - d.p_mm, axis=1)
    e1 = np.linalg.norm(p1 - d.p_mm, axis=1)
    return {
        "n_rows": int(val.n_rows),
        "without_axes_mean_mm": float(e0.mean()),
        "without_axes_max_mm": float(e0.max()),
        "mean_position_mm": float(e1.mean()),
        "rms_position_mm": float(np.sqrt(np.mean(e1**2))),
        "max_position_mm": float(e1.max()),
    }


def calibration_axes(fit: AxisFit) -> dict[str, Any]:
    """The axis errors as ``calibration.json`` carries them (key ``axes``): :meth:`AxisFit.record` and the
    calibration vector ``x`` fitted with them, for the service's bundle (:func:`axis_fit_of`)."""
    return {**fit.record(), "x": [float(v) for v in fit.x]}


#: the factor from a term's unit in a record (:meth:`AxisFit.record`) to the fit's own (mm, rad, rad per kN·m)
RECORD_UNITS = {"mm": 1.0, "urad": 1e-6, "urad/kNm": 1e-6}


def axis_fit_of(robot: Any, record: Mapping[str, Any], x: np.ndarray, where: str = "axes") -> AxisFit:
    """The :class:`AxisFit` of a record (:func:`calibration_axes`; its ``x`` when it has one, else ``x``), for
    compensation (standard errors kept, no cross-validation). Raises :class:`ConfigError` naming ``where`` and
    the term for a term ``robot`` has not or a unit the record cannot carry."""
    terms, coef, se = [], [], []
    for k, t in enumerate(record.get("terms") or []):
        name = str(t.get("name"))
        try:
            terms.append(term_named(robot, name))
        except ConfigError as exc:
            raise ConfigError(f"{where}.terms[{k}]: {exc}") from None
        unit = str(t.get("unit"))
        if unit not in RECORD_UNITS:
            raise ConfigError(f"{where}.terms[{k}] ({name}): unit {unit!r}; known {sorted(RECORD_UNITS)}")
        coef.append(float(t["value"]) * RECORD_UNITS[unit])
        se.append(float(t.get("stderr") or 0.0) * RECORD_UNITS[unit])
    xv = np.asarray(record.get("x", x), dtype=float)
    if xv.shape != np.shape(x):
        raise ConfigError(f"{where}.x has {xv.size} values; the calibration has {np.size(x)}")
    return AxisFit(
        terms=tuple(terms),
        coef=np.array(coef),
        stderr=np.array(se),
        covariance=np.diag(np.square(se)),
        x=xv,
        order=int(record.get("order", 0)),
        bending=bool(record.get("bending", False)),
        cv=(),
        poorly_determined=tuple(record.get("poorly_determined") or ()),
        not_identifiable=tuple(record.get("not_identifiable") or ()),
    )
