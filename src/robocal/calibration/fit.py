"""The one geometric fit with any registered optimizer: start -> solve -> outliers -> statistics.

:func:`calibrate` (``robocal.calibrate``) and :func:`fit_with_optimizer` (the pipeline's ``optimizer`` config)
share one path, from :mod:`robocal.calibration`:

* **start** (:func:`~robocal.calibration.start.calibration_start`): registration, the nominal model's
  best rigid fit (``x_init``, the "before" figures), the identifiable (free) parameters;
* **solve**: every optimizer through the one protocol (``minimize(Problem)``, looked up in the registry). The
  gradient family (``lm``, the default, and ``gn``: :class:`~robocal.optimizers.gradient.LevenbergMarquardt`,
  :class:`~robocal.optimizers.gradient.GaussNewton`) solves the calibration's least squares
  (:func:`robocal.calibration.problem.least_squares_problem`: whitened residuals of every row over the free
  parameters, rows left out weighted zero) with the calibration's stopping rules (:func:`solve_with`); every
  other optimizer runs on the calibration's position residuals
  (:func:`robocal.calibration.problem.calibration_problem`): Ipopt without bounds (the same least squares
  as Gauss-Newton), the population methods within ``x_init ± bound_mm / bound_deg``. With ``polish: true`` a
  Gauss-Newton run (``conf/optimizer/gn.yaml`` defaults) continues from the optimizer's point;
* **outliers** (:func:`~robocal.calibration.screening.screen_outliers`) with the same solve;
* **statistics** (:func:`~robocal.calibration.result.calibration_result`) at the solve's point.

The non-gradient optimizers fit positions only (the start is taken with ``use_orientation=False``). The
gradient-versus-other fork is written here once (:func:`is_gradient`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.config import FIT_ORDER, CalibrationConfig
from robocal.calibration.problem import CalibrationSearch, calibration_problem
from robocal.calibration.result import CalibrationResult, calibration_result
from robocal.calibration.screening import screen_outliers
from robocal.calibration.solve import POLISH, gradient_fit, is_gradient, solve_at, solve_polish
from robocal.calibration.start import CalibrationStart, Solve, calibration_start
from robocal.errors import ConfigError
from robocal.identification.result import FitResult
from robocal.metrics import noise_floor as floor_of
from robocal.metrics import position_keys
from robocal.optimizers.protocol import Problem, evaluate_batch
from robocal.optimizers.registry import make_optimizer, pipeline_options, registered
from robocal.robot import RobotDescription

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign


#: the fit figures the comparison of raw and polished results reads (the fit record's keys and order)
COMPARED = (*position_keys(FIT_ORDER), "chi2")


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


def fit_from(start: CalibrationStart, solve: Solve) -> CalibrationResult:
    """solve (from ``x_init`` on the rows not listed as outliers) -> outliers -> statistics. ``solve`` is the
    caller's: :func:`robocal.calibration.solve.solve_with` runs a registered optimizer through the protocol."""
    lm = solve(start, start.x_init, start.kept)
    return calibration_result(start, screen_outliers(start, lm, solve))


def calibrate_with(
    campaign: Campaign,
    robot: RobotDescription,
    config: CalibrationConfig,
    solve: Solve,
    x0: np.ndarray | None = None,
) -> CalibrationResult:
    """Geometric calibration from the campaign's calibration rows with the solve step ``solve``.

    Steps: start (:func:`calibration_start`: registration, the nominal model's best rigid fit, identifiable
    parameter set) -> solve (``solve``: the optimizer's, through the protocol) -> gross errors found and left out
    (:func:`screen_outliers`) -> statistics (:func:`calibration_result`); poorly determined parameters held one at
    a time and the rest fitted again (``poorly_determined: fix``). The entry point is
    :func:`robocal.calibration.fit.calibrate` (``robocal.calibrate``), which gives the solve of any registered
    optimizer (Levenberg-Marquardt by default): the optimizers build on this module, not the other way round.
    """
    cfg = config
    start = calibration_start(campaign, robot, cfg, x0)
    res = fit_from(start, solve)
    res, prior = thin_campaign(start, res, solve)
    poor = res.statistics.get("poorly_determined") or []
    if cfg.poorly_determined == "report" or not poor:
        return res
    if len(poor) >= int(res.identified.sum()):  # holding them all would leave nothing to fit: report only
        why = "reported: holding every poorly determined parameter would leave nothing to fit"
        return res.with_statistics(poorly_determined=[{**p, "action": why} for p in poor])
    # held one at a time, the worst determined first (holding one of a correlated pair usually determines the
    # other), at its start (nominal, or the registration's frame and tool), and the rest fitted again
    held: list[str] = []
    records: list[dict[str, Any]] = []
    action = "held at its start value (nominal, or the registration's frame and tool); the rest fitted again"
    while poor and len(held) < len(res.model.names):
        worst = max(poor, key=lambda p: p["stderr"] / p["bound"])
        held.append(worst["name"])
        records.append({**worst, "action": action})
        nxt_start = calibration_start(campaign, robot, cfg, x0, held=tuple(held))
        nxt = fit_from(nxt_start if prior is None else replace(nxt_start, prior=prior), solve)
        if "configurations" in res.statistics:
            nxt = nxt.with_statistics(configurations=res.statistics["configurations"])
        poor = nxt.statistics.get("poorly_determined") or []
        if len(poor) >= int(nxt.identified.sum()):
            break
        res = nxt
    left = [
        {**p, "action": "reported: holding it would leave nothing to fit"}
        for p in (res.statistics.get("poorly_determined") or [])
    ]
    return res.with_statistics(poorly_determined=records + left)


def thin_campaign(start: CalibrationStart, res: CalibrationResult, solve: Solve) -> tuple[CalibrationResult, Any]:
    """The configurations of the campaign against the model's parameters and, for a thin campaign (``prior:
    auto``; always with a strength given), the fit again with a prior toward the nominal description
    (:mod:`robocal.identification.thin`; a poorly spread campaign of enough configurations keeps the holding of
    poorly determined parameters, :func:`calibrate_with`, unless a strength is given). The fit record gets
    ``configurations`` when the campaign is thin, has too few configurations or the prior is on (a campaign
    with plenty of configurations keeps its record, and its bytes). Returns the calibration and the prior."""
    from robocal.identification import thin

    cfg = start.config
    design = thin.design_of(start)
    if cfg.prior == "off":
        why = None
    elif cfg.prior != "auto":
        why = "the 'prior' setting"
    elif design["thin"]:
        why = (
            f"thin campaign: {design['n']} configurations give {design['equations']} equations for "
            f"{design['model_parameters']} parameters, fewer than {cfg.thin_ratio:g} per parameter"
        )
    else:
        why = None
    clear_only = False
    if why is None and cfg.prior == "auto" and design["enough"] and design["sparse"]:
        why = (
            f"few configurations: {design['n']} give {design['equations']} equations for "
            f"{design['model_parameters']} parameters, fewer than {cfg.sparse_ratio:g} per parameter; the prior "
            "only where it clearly beats none in cross-validation"
        )
        clear_only = True
    prior = None
    if why is not None and design["enough"]:
        prior, rec = thin.choose_prior(start, why, clear_only=clear_only)
        design["prior"] = rec  # also when the cross-validation declined it: the status says what was done
    if prior is not None:
        res = fit_from(replace(start, prior=prior), solve)
    if design["thin"] or not design["enough"] or "prior" in design:
        res = res.with_statistics(configurations=design)
    return res, prior


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
    :func:`~robocal.calibration.fit.calibrate_with`)."""
    options = pipeline_options(optimizer or {"name": "lm"})
    if is_gradient(optimizer):
        gcfg, solve = gradient_fit(cfg, optimizer)
        cres = calibrate_with(campaign, robot, gcfg, solve)
        return FitOutcome(
            gcfg.method, cres, cres, None, None, options, {"optimizer_s": cres.statistics["solver_time_s"]}
        )
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
    raw = (
        replace(at, config=replace(at.config, max_iter=0))
        .with_solver(res)
        .with_statistics(wall_time_s=t2 - t0 - warmup_s)
    )
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
