"""The solve step of a calibration through the one optimizer protocol: the calibration's least squares
(:func:`~robocal.calibration.problem.least_squares_problem`) minimised by a registered optimizer
(:func:`solve_with`; the gradient family's settings :func:`gradient_fit`), mapped back to the full parameter
vector (:func:`calibration_fit`); :func:`solve_at` and :func:`solve_polish` for the statistics at, and the polish
from, another optimizer's point."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.problem import WhitenedResiduals, least_squares_problem
from robocal.calibration.start import CalibrationStart, Solve
from robocal.errors import ConfigError
from robocal.identification.result import FitResult, fit_covariance, normal_inverse
from robocal.optimizers.protocol import Optimizer
from robocal.optimizers.registry import PIPELINE_KEYS, make_optimizer, pipeline_options, registered

if TYPE_CHECKING:
    pass


#: Gauss-Newton settings of the polish (conf/optimizer/gn.yaml).
POLISH: dict[str, Any] = {"max_iter": 30, "ftol": 1e-12, "xtol": 1e-10}


#: the stopping rules of the gradient family, read from its optimizer config into the CalibrationConfig
GRADIENT_KEYS = ("max_iter", "ftol", "xtol")


#: Levenberg-Marquardt's initial damping in a calibration (``lam0``): a calibration starts from the nominal
#: model's converged rigid fit, close to the minimum (Madsen, Nielsen & Tingleff's 1e-6; the class default, 1e-3,
#: is for starts that may be far). An optimizer config's ``lam0`` overrides it.
START_DAMPING = 1e-6


def is_gradient(optimizer: Mapping[str, Any] | None) -> bool:
    """True for no optimizer config (``calibrate``'s default, Levenberg-Marquardt) and the gradient family
    (each optimizer class says its family in the registry: no second list of names)."""
    return optimizer is None or optimizer.get("name") in registered("gradient")


def gradient_optimizer(cfg: CalibrationConfig, **settings: Any) -> Optimizer:
    """The registered gradient optimizer of a calibration's settings: ``cfg.method`` (``lm``, ``gn``) with the
    calibration's stopping rules (``max_iter``, ``ftol``, ``xtol``) and, for ``lm``, :data:`START_DAMPING`;
    ``settings`` (e.g. ``lam0``) override them (a key the optimizer does not take is an error naming it)."""
    spec: dict[str, Any] = {"name": cfg.method, "max_iter": cfg.max_iter, "ftol": cfg.ftol, "xtol": cfg.xtol}
    if cfg.method == "lm":
        spec["lam0"] = START_DAMPING
    return make_optimizer({**spec, **settings})


def gradient_fit(cfg: CalibrationConfig, optimizer: Mapping[str, Any] | None) -> tuple[CalibrationConfig, Solve]:
    """The settings and the solve step of a gradient-family fit: the optimizer config's name (default
    ``cfg.method``) and stopping rules (:data:`GRADIENT_KEYS`) go into the settings (``calibration.json`` records
    them under ``config``); its other keys (``lam0``) go to the optimizer; ``polish`` must be false (this is the
    gradient method itself)."""
    if optimizer is None:  # calibrate's default: the settings as they are
        return cfg, solve_with(gradient_optimizer(cfg))
    name = str(optimizer.get("name", cfg.method))
    if pipeline_options(optimizer)["polish"]:
        raise ConfigError(f"The config key 'optimizer.polish' must be false for a gradient optimizer ({name!r}).")
    gcfg = replace(cfg, method=name, **{k: optimizer[k] for k in GRADIENT_KEYS if k in optimizer})
    own = {k: v for k, v in optimizer.items() if k not in GRADIENT_KEYS and k not in PIPELINE_KEYS}
    return gcfg, solve_with(gradient_optimizer(gcfg, **own))


def calibration_fit(start: CalibrationStart, wr: WhitenedResiduals, res: FitResult, kept: np.ndarray) -> FitResult:
    """An optimizer's result on :func:`~robocal.calibration.problem.least_squares_problem` as the calibration's
    fit: the full parameter vector (``varied`` the free parameters), the whitened residuals and Jacobian of every
    row (the rows left out as predictions, listed in ``outliers``) and the covariance of the kept rows (the
    problem weighs the left-out rows zero; they are not data: ``ndata`` counts the kept residuals)."""
    x = wr.full(res.x)
    ndata = int(np.count_nonzero(wr.weights))
    cov = res.covariance
    if wr.n_prior:
        res = posterior(res, wr.n_prior, ndata)
        cov = res.covariance
    elif cov is not None and ndata != res.ndata:
        cov = fit_covariance(res.residual, res.jacobian, ndata)
    out = res.evolve(x=x, varied=start.free, names=start.model.names, ndata=ndata, covariance=cov)
    if kept.all():
        return out
    r, J = start.fun(x)
    w = start.weights
    return out.evolve(residual=w * r, jacobian=w[:, None] * J[:, start.free], outliers=tuple(np.flatnonzero(~kept)))


def posterior(res: FitResult, n_prior: int, ndata: int) -> FitResult:
    """A fit with a prior's ``n_prior`` rows at the end of its residuals as the calibration's fit: residuals,
    Jacobian and χ² of the data rows only, and the posterior covariance ``s² (JᵀJ + Λ)⁻¹`` (``Λ`` the prior's
    rows' ``JᵀJ``; ``s²`` the data's residual variance over ``ndata`` minus the effective number of parameters
    ``tr(JᵀJ (JᵀJ + Λ)⁻¹)``; 1 when no degree of freedom is left). ``(JᵀJ + Λ)⁻¹`` goes to ``extra`` for the
    gross-error test's leverages."""
    n = res.residual.size - n_prior
    r, J = np.asarray(res.residual[:n]), np.asarray(res.jacobian[:n])
    inv = normal_inverse(np.asarray(res.jacobian))
    k_eff = float(np.trace(J.T @ J @ inv))
    s2 = float(r @ r) / (ndata - k_eff) if ndata > k_eff else 1.0
    chi2 = float(r @ r)
    extra = {**res.extra, "posterior_normal_inverse": inv, "effective_parameters": k_eff}
    return res.evolve(residual=r, jacobian=J, chi2=chi2, cost=0.5 * chi2, covariance=s2 * inv, extra=extra)


def solve_with(optimizer: Optimizer) -> Solve:
    """The solve step of an optimizer (the default fit's: the registered Levenberg-Marquardt): the calibration's
    least squares from the given point on the kept rows (:func:`~robocal.calibration.problem.
    least_squares_problem`) minimised through the protocol, mapped back by :func:`calibration_fit`."""

    def solve(start: CalibrationStart, x_from: np.ndarray, kept: np.ndarray) -> FitResult:
        problem, wr = least_squares_problem(start, x_from, kept)
        return calibration_fit(start, wr, optimizer.minimize(problem), kept)

    return solve


def solve_at(x: np.ndarray) -> Solve:
    """A solve that stays at ``x`` (the optimizer's point): a zero-iteration Levenberg-Marquardt (the statistics
    there, no step); for the outlier rule's refits, the statistics at the point it starts from."""
    stay = solve_with(make_optimizer({"name": "lm", "max_iter": 0}))

    def solve(start: CalibrationStart, x_from: np.ndarray, kept: np.ndarray) -> FitResult:
        return stay(start, x if np.array_equal(x_from, start.x_init) else x_from, kept)

    return solve


def solve_polish(x: np.ndarray) -> Solve:
    """A solve that continues from the optimizer's point ``x`` with the calibration's gradient method and the
    polish's stopping rules (:data:`POLISH`)."""

    def solve(start: CalibrationStart, x_from: np.ndarray, kept: np.ndarray) -> FitResult:
        at = x if np.array_equal(x_from, start.x_init) else x_from
        return solve_with(gradient_optimizer(replace(start.config, **POLISH)))(start, at, kept)

    return solve
