"""The one geometric fit with any registered optimizer: start -> solve -> outliers -> statistics.

:func:`calibrate` (``robocal.calibrate``) and :func:`fit_with_optimizer` (the pipeline's ``optimizer`` config)
share one path, from :mod:`robocal.identification.calibrate`:

* **start** (:func:`~robocal.identification.calibrate.calibration_start`): registration, the nominal model's
  best rigid fit (``x_init``, the "before" figures), the identifiable (free) parameters;
* **solve**: every optimizer through the one protocol (``minimize(Problem)``, looked up in the registry). The
  gradient family (``lm``, the default, and ``gn``: :class:`~robocal.optimizers.gradient.LevenbergMarquardt`,
  :class:`~robocal.optimizers.gradient.GaussNewton`) solves the calibration's least squares
  (:func:`robocal.optimizers.calibration.least_squares_problem`: whitened residuals of every row over the free
  parameters, rows left out weighted zero) with the calibration's stopping rules (:func:`solve_with`); every
  other optimizer runs on the calibration's position residuals
  (:func:`robocal.optimizers.calibration.calibration_problem`): Ipopt without bounds (the same least squares
  as Gauss-Newton), the population methods within ``x_init ± bound_mm / bound_deg``. With ``polish: true`` a
  Gauss-Newton run (``conf/optimizer/gn.yaml`` defaults) continues from the optimizer's point;
* **outliers** (:func:`~robocal.identification.calibrate.screen_outliers`) with the same solve;
* **statistics** (:func:`~robocal.identification.calibrate.calibration_result`) at the solve's point.

The non-gradient optimizers fit positions only (the start is taken with ``use_orientation=False``). The
gradient-versus-other fork is written here once (:func:`is_gradient`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.errors import ConfigError
from robocal.identification.calibrate import (
    FIT_ORDER,
    CalibrationConfig,
    CalibrationResult,
    CalibrationStart,
    Solve,
    calibrate_with,
    calibration_start,
    fit_from,
)
from robocal.identification.result import FitResult, fit_covariance, normal_inverse
from robocal.metrics import noise_floor as floor_of
from robocal.metrics import position_keys
from robocal.optimizers.calibration import (
    CalibrationSearch,
    WhitenedResiduals,
    calibration_problem,
    least_squares_problem,
)
from robocal.optimizers.protocol import Optimizer, Problem, evaluate_batch
from robocal.optimizers.registry import PIPELINE_KEYS, make_optimizer, pipeline_options, registered

if TYPE_CHECKING:
    from robocal.data.contract import Campaign
    from robocal.robot import RobotDescription

__all__ = [
    "POLISH",
    "START_DAMPING",
    "FitOutcome",
    "build_problem",
    "calibrate",
    "fit_with_optimizer",
    "gradient_fit",
    "gradient_optimizer",
    "is_gradient",
    "noise_floor",
    "position_config",
    "solve_at",
    "solve_polish",
    "solve_with",
    "warm_up",
]

#: Gauss-Newton settings of the polish (conf/optimizer/gn.yaml).
POLISH: dict[str, Any] = {"max_iter": 30, "ftol": 1e-12, "xtol": 1e-10}
#: the fit figures the comparison of raw and polished results reads (the fit record's keys and order)
COMPARED = (*position_keys(FIT_ORDER), "chi2")
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


@dataclass
class FitOutcome:
    """One optimizer on one campaign: the optimizer's own result and the calibrations it leads to."""

    method: str
    result: CalibrationResult  # the final calibration (polished when polish is on)
    raw: CalibrationResult  # at the optimizer's point
    polished: CalibrationResult | None
    optimize: FitResult | None  # the optimizer's own result (raw.solver); None for gn / lm (result.solver)
    options: dict[str, Any] = field(default_factory=dict)
    times: dict[str, float] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """The honest comparison: what the method reached alone, and after the polish."""
        out: dict[str, Any] = {
            "method": self.method,
            "raw": {k: self.raw.fit[k] for k in COMPARED},
            "options": {k: v for k, v in self.options.items() if isinstance(v, str | int | float | bool) or v is None},
            "times_s": dict(self.times),
        }
        if self.optimize is not None:
            o = self.optimize
            out["raw"].update(
                {
                    "fitness": o.cost,
                    "nit": o.nit,
                    "nfev": o.nfev,
                    "status": o.status,
                    "message": o.message,
                    "wall_time_s": o.wall_time_s,
                }
            )
        if self.polished is not None:
            p = self.polished
            out["polished"] = {k: p.fit[k] for k in (*COMPARED, "nit", "solver_time_s")}
        return out


def noise_floor(noise_mm: float, m: int, k: int, objective: str = "nonlinear") -> float:
    """Expected best fitness (mm) with ``m`` poses, ``k`` fitted parameters, noise ``noise_mm`` per coordinate:
    :func:`robocal.metrics.noise_floor` over the ``3 m`` position residuals, the RMS 3-D error for the
    nonlinear objective and the mean 3-D error for the linearised one."""
    return floor_of(noise_mm, 3 * m, k, "mean" if objective == "linearized" else "rms")


def position_config(cfg: CalibrationConfig) -> CalibrationConfig:
    """The settings of a positions-only fit (the non-gradient optimizers' objectives)."""
    return replace(cfg, use_orientation=False)


def build_problem(
    start: CalibrationStart,
    options: Mapping[str, Any],
    *,
    bounded: bool,
    max_iter: int,
    seed: int,
) -> tuple[Problem, CalibrationSearch, float]:
    """The Problem of a started calibration (positions only); also the noise floor of its fitness (mm)."""
    floor = noise_floor(start.config.noise_mm, start.m, int(start.free.size), options["objective"])
    stop = options.get("stop_error")
    target = 1.1 * floor if stop == "auto" else (None if stop is None else float(stop))
    problem, search = calibration_problem(
        start.model,
        start.data,
        start.x_init,
        start.free,
        objective=options["objective"],
        bound_mm=options["bound_mm"],
        bound_deg=options["bound_deg"],
        target=target,
        max_iter=max_iter,
        seed=seed,
        bounded=bounded,
    )
    return problem, search, floor


def warm_up(problem: Problem) -> float:
    """Evaluate the population kernel once on two points so that its just-in-time compilation (numba) is not
    counted in the timed runs; returns the seconds it took."""
    t0 = time.perf_counter()
    x = np.asarray(problem.x0 if problem.x0 is not None else problem.lower, dtype=float)
    evaluate_batch(problem, np.tile(x, (2, 1)))
    return time.perf_counter() - t0


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
    """An optimizer's result on :func:`~robocal.optimizers.calibration.least_squares_problem` as the calibration's
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
    least squares from the given point on the kept rows (:func:`~robocal.optimizers.calibration.
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


def fit_with_optimizer(
    campaign: Campaign,
    robot: RobotDescription,
    cfg: CalibrationConfig,
    optimizer: Mapping[str, Any] | None,
    *,
    seed: int = 0,
) -> FitOutcome:
    """Calibrate with the optimizer config ``optimizer`` (``conf/optimizer/*.yaml``; None: the registered
    Levenberg-Marquardt with ``cfg``'s stopping rules). See the module docstring. The gradient family holds
    poorly determined parameters and fits again (``poorly_determined: fix``,
    :func:`~robocal.identification.calibrate.calibrate_with`)."""
    options = pipeline_options(optimizer or {"name": "lm"})
    if is_gradient(optimizer):
        gcfg, solve = gradient_fit(cfg, optimizer)
        cres = calibrate_with(campaign, robot, gcfg, solve)
        return FitOutcome(gcfg.method, cres, cres, None, None, options, {"optimizer_s": cres.fit["solver_time_s"]})
    assert optimizer is not None
    name = str(optimizer.get("name"))
    opt = make_optimizer(optimizer)  # validates name and keys
    if name == "ipopt" and options["objective"] != "nonlinear":
        raise ConfigError("The config key 'optimizer.objective' must be 'nonlinear' for ipopt (least squares).")
    population = name in registered("population")
    t0 = time.perf_counter()
    start = calibration_start(campaign, robot, position_config(cfg))
    max_iter = int(optimizer.get("max_iter") or 200)
    problem, search, floor = build_problem(start, options, bounded=population, max_iter=max_iter, seed=seed)
    warmup_s = warm_up(problem) if population else 0.0
    t1 = time.perf_counter()
    res = opt.minimize(problem)
    t2 = time.perf_counter()
    x_raw = search.full(res.x)
    at = fit_from(start, solve_at(x_raw))  # the statistics at the optimizer's point ...
    # ... whose solve is the optimizer's (its FitResult gives the fit record's iterations, status and time); its
    # config says the least-squares core made no step; its wall time is the method's own, not the statistics'
    raw = replace(at, config=replace(at.config, max_iter=0), solver=res).with_statistics(wall_time_s=t2 - t0 - warmup_s)
    options["noise_floor_fitness_mm"] = floor
    options["stop_fitness_mm"] = problem.target
    polished = None
    t3 = time.perf_counter()
    if options["polish"]:
        polished = fit_from(start, solve_polish(x_raw))
    times = {
        "setup_s": t1 - t0 - warmup_s,
        "jit_warmup_s": warmup_s,
        "optimizer_s": t2 - t1,
        "polish_s": time.perf_counter() - t3 if polished is not None else 0.0,
    }
    if polished is not None:  # the final result's time is the whole fit: method + polish
        polished = replace(  # the settings of the polish (its stopping rules)
            polished, config=replace(polished.config, **POLISH)
        ).with_statistics(wall_time_s=raw.statistics["wall_time_s"] + times["polish_s"])
    return FitOutcome(name, polished or raw, raw, polished, res, options, times)


def optimizer_config(optimizer: str | Mapping[str, Any] | None) -> dict[str, Any] | None:
    """An optimizer config from a registered name (the class defaults) or a mapping (a Hydra/YAML node)."""
    if optimizer is None:
        return None
    if isinstance(optimizer, str):
        if optimizer not in registered():
            raise ConfigError(
                f"The 'optimizer' parameter must be one of {sorted(registered())}. Got {optimizer!r} instead."
            )
        return {"name": optimizer}
    if not isinstance(optimizer, Mapping):
        raise ConfigError(
            f"The 'optimizer' parameter must be a registered name or a config mapping. Got "
            f"{type(optimizer).__name__} instead."
        )
    return dict(optimizer)


def calibrate(
    campaign: Campaign,
    robot: RobotDescription,
    config: CalibrationConfig | None = None,
    x0: np.ndarray | None = None,
    *,
    optimizer: str | Mapping[str, Any] | None = None,
    seed: int = 0,
) -> CalibrationResult:
    """Geometric calibration (``robocal.calibrate``): start -> solve -> outliers -> statistics.

    ``optimizer``: None (Levenberg-Marquardt, ``config``'s stopping rules), a registered name (``"gn"``,
    ``"lm"``, ``"ipopt"``, ``"igoa"``, ``"goa"``, ``"woa"``, with the class defaults) or an optimizer config
    mapping (``conf/optimizer/*.yaml``: coefficients, ``polish``, ``objective``, bounds). ``seed`` seeds the
    population methods. ``x0`` starts the least-squares core from a given point (gradient family only).
    Returns the final calibration (the polished one when ``polish`` is on).
    """
    cfg = config or CalibrationConfig()
    ocfg = optimizer_config(optimizer)
    if is_gradient(ocfg):
        gcfg, solve = gradient_fit(cfg, ocfg)
        return calibrate_with(campaign, robot, gcfg, solve, x0)
    assert ocfg is not None  # None is the gradient default
    if x0 is not None:
        raise ConfigError(f"The 'x0' parameter is for the gradient optimizers; {ocfg.get('name')!r} is not one.")
    return fit_with_optimizer(campaign, robot, cfg, ocfg, seed=seed).result
