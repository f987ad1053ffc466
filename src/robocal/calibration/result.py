"""A fitted calibration (:class:`CalibrationResult`) and its statistics (:func:`calibration_result`: covariance,
standard errors, chi² against the tracker noise, outliers, the "before" figures, poorly determined parameters)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import special

from robocal.calibration.config import FIT_ORDER, CalibrationConfig
from robocal.calibration.record import calibration_record, correlation_of, parameter_table
from robocal.calibration.screening import Screened, describe_outliers
from robocal.calibration.start import CalibrationStart, rigid_fit
from robocal.identification import misfit
from robocal.identification.identifiability import Eliminated, Identifiability
from robocal.identification.model import CalibrationModel
from robocal.identification.result import FitResult
from robocal.metrics import ErrorStats, noise_floor, rotvec_errors_deg

if TYPE_CHECKING:
    pass


@dataclass(frozen=True, eq=False)
class FitStart:
    """Where a calibration started and which rows it kept (the "before" of :class:`CalibrationResult`).

    x_init : the nominal model's best rigid fit on the kept rows (frames and tools fitted to convergence with
    the nominal kinematics): the "before calibration" point; x_analysis : where the identifiability analysis
    ran (``x_init`` before any row was left out); residuals_before_mm : (m, 3) at ``x_init``, every calibration
    row; kept : (m,) the rows in the fit (not left out as gross errors); row_test : the gross-error row test
    at the fit (:class:`robocal.identification.robust.RowTest`), None when the rule is off or rows are listed.
    """

    x_init: np.ndarray
    x_analysis: np.ndarray
    residuals_before_mm: np.ndarray
    kept: np.ndarray
    row_test: Any = None


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """A fitted calibration: parameters with standard errors, frames, tools and fit statistics.

    Immutable (derive a changed one with :func:`dataclasses.replace`, :meth:`with_statistics`, :meth:`with_solver`).
    The figures are attributes: ``x``, ``stderr``, ``covariance`` (over the identified parameters), :attr:`chi2`,
    :attr:`dof`, :attr:`reduced_chi2` (against the configured noise, kept rows), :attr:`status`, :attr:`message`,
    :attr:`success`, :attr:`nit`, :attr:`nfev` (of the solve that gave ``x``); ``statistics`` is the fit record
    (``calibration.json`` ``fit``, read as :attr:`fit`), laid out once when the calibration is made
    (:func:`calibration_result`) or read (:func:`~robocal.calibration.load.load_calibration`). ``solver`` is the
    solve's own :class:`~robocal.identification.result.FitResult` (whitened residuals, Jacobian, timings), None for
    a calibration read from a file; ``start`` where the fit started and which rows it kept (None when read);
    ``effects`` the joint-level effects a discovery wrote into the calibration (``effects`` records of
    ``calibration.json``, evaluated by :func:`robocal.compensation.discovered.joint_offsets`).
    """

    model: CalibrationModel
    x: np.ndarray
    identified: np.ndarray  # (n,) bool
    stderr: np.ndarray  # (n,) NaN where not identified
    covariance: np.ndarray  # (k, k) over identified parameters, in their units
    identifiability: Identifiability
    fixed_by_user: tuple[str, ...]
    statistics: dict[str, Any]  # the fit record (calibration.json ``fit``; read it as :attr:`fit`)
    residuals_mm: np.ndarray  # (m, 3)
    residuals_deg: np.ndarray | None
    config: CalibrationConfig
    solver: FitResult | None = None
    start: FitStart | None = None
    effects: tuple[dict[str, Any], ...] = ()

    @property
    def fit(self) -> dict[str, Any]:
        """The fit record (``calibration.json`` ``fit``; a new dict, so that no reader changes the calibration)."""
        return dict(self.statistics)

    def with_statistics(self, **changes: Any) -> CalibrationResult:
        """A copy with ``changes`` to the statistics (e.g. ``poorly_determined``); a key that is there keeps its
        place in the record."""
        return replace(self, statistics={**self.statistics, **changes})

    def with_solver(self, solver: FitResult) -> CalibrationResult:
        """A copy whose point came from ``solver`` (another optimizer's own result): the record's solve figures
        (:func:`solver_figures`) are its."""
        return replace(self, solver=solver, statistics={**self.statistics, **solver_figures(solver)})

    @property
    def chi2(self) -> float:
        """χ² of the kept rows against the configured noise."""
        return float(self.statistics["chi2"])

    @property
    def dof(self) -> int:
        """Degrees of freedom of :attr:`chi2` (residuals minus identified parameters, at least 1)."""
        return int(self.statistics["dof"])

    @property
    def reduced_chi2(self) -> float:
        return float(self.statistics["reduced_chi2"])

    @property
    def status(self) -> int:
        """The solve's stopping status (:data:`~robocal.identification.result.STATUS_MESSAGES`)."""
        return int(self.statistics["status"])

    @property
    def message(self) -> str:
        return str(self.statistics["message"])

    @property
    def success(self) -> bool:
        return bool(self.statistics["success"])

    @property
    def nit(self) -> int:
        return int(self.statistics["nit"])

    @property
    def nfev(self) -> int:
        return int(self.statistics["nfev"])

    @property
    def names(self) -> tuple[str, ...]:
        return self.model.names

    @property
    def eliminated(self) -> tuple[Eliminated, ...]:
        return self.identifiability.eliminated

    @property
    def correlation(self) -> np.ndarray:
        return correlation_of(self.covariance)

    @property
    def tracker_T_base(self) -> np.ndarray:
        return self.model.base_transform(self.x)

    @property
    def tools(self) -> dict[str, np.ndarray]:
        t = self.model.tools(self.x)
        return {name: t[k] for k, name in enumerate(self.model.target_names)}

    @property
    def kinematic_errors(self) -> np.ndarray:
        """Joint-level parameter errors ``eta`` (P,) in mm / rad."""
        return self.x[: self.model.chain.n_params].copy()

    def value(self, name: str) -> float:
        return float(self.x[self.model.index(name)])

    def predict(self, q: np.ndarray, target_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.model.predict(self.x, q, target_index)

    def parameter_table(self) -> list[dict[str, Any]]:
        """One row per parameter: value and standard error in display units (mm, deg)."""
        return parameter_table(self.model, self.x, self.stderr, self.identified, self.fixed_by_user)

    def to_dict(self) -> dict[str, Any]:
        """The ``calibration.json`` record (:func:`calibration_record`)."""
        return calibration_record(
            self.model,
            self.x,
            self.identified,
            self.stderr,
            self.covariance,
            self.identifiability,
            self.fixed_by_user,
            self.fit,
            self.config,
        )


def solver_figures(fr: FitResult) -> dict[str, Any]:
    """What the fit record says of the solve that produced a calibration's point: iterations, evaluations,
    stopping status and message, success, the solve's own time (``solver_time_s``)."""
    return {
        "nit": fr.nit,
        "nfev": fr.nfev,
        "status": fr.status,
        "message": fr.message,
        "success": fr.success,
        "solver_time_s": fr.wall_time_s,
    }


def fit_statistics(
    r_pos: np.ndarray,
    cfg: CalibrationConfig,
    n_params: int,
    r_rot: np.ndarray | None = None,
    sigma_mm: np.ndarray | None = None,
) -> dict[str, Any]:
    """RMS / mean / max of 3-D errors (:class:`~robocal.metrics.ErrorStats`) and chi² against the configured noise
    (``sigma_mm`` (m,): per point); the noise floor (:func:`~robocal.metrics.noise_floor`) of a positions-only fit."""
    m = r_pos.shape[0]
    M = 3 * m
    sig = np.full(m, cfg.noise_mm) if sigma_mm is None else np.asarray(sigma_mm, dtype=float)
    chi2 = float(np.sum((r_pos / sig[:, None]) ** 2))
    if r_rot is not None:
        M += 3 * m
        chi2 += float(np.sum(r_rot**2) / np.deg2rad(cfg.noise_deg) ** 2)
    dof = max(M - n_params, 1)
    stats = ErrorStats.of(r_pos, None if r_rot is None else rotvec_errors_deg(r_rot))
    out: dict[str, Any] = {
        "n_rows": int(m),
        "n_residuals": int(M),
        "n_params": int(n_params),
        **stats.position(FIT_ORDER),
        "noise_floor_rms_mm": noise_floor(sig, M, n_params) if r_rot is None else None,
        "chi2": chi2,
        "dof": int(dof),
        "reduced_chi2": chi2 / dof,
        # scipy.special's chi² functions (as scipy.stats.chi2.ppf / sf, without their ~0.1 ms of overhead each)
        "chi2_band_95": [float(special.chdtri(dof, 0.975)), float(special.chdtri(dof, 0.025))],
        "chi2_p_value": float(special.chdtrc(dof, chi2)),
    }
    out["chi2_within_band"] = bool(out["chi2_band_95"][0] <= chi2 <= out["chi2_band_95"][1])
    out.update(stats.orientation(FIT_ORDER))
    return out


def poorly_determined(model: CalibrationModel, stderr: np.ndarray, cfg: CalibrationConfig) -> list[dict[str, Any]]:
    """Identified parameters whose standard error (``stderr``: at the configured noise, see
    :func:`calibration_result`) exceeds the configured bound (``max_stderr_mm`` for lengths, ``max_stderr_deg`` for
    angles): the data do not determine them, whatever the rank test said."""
    out = []
    for i, name in enumerate(model.names):
        se = float(stderr[i])
        if not np.isfinite(se):
            continue
        mm = model.units[i] == "mm"
        bound = cfg.max_stderr_mm if mm else float(np.deg2rad(cfg.max_stderr_deg))
        if se > bound:
            out.append(
                {
                    "name": name,
                    "stderr": se if mm else float(np.rad2deg(se)),
                    "bound": cfg.max_stderr_mm if mm else cfg.max_stderr_deg,
                    "unit": "mm" if mm else "deg",
                }
            )
    return out


def calibration_result(start: CalibrationStart, screened: Screened) -> CalibrationResult:
    """The statistics of a screened fit: covariance ``s² (JᵀJ)⁻¹`` on the kept rows with ``s²`` the residual
    variance, correlations, chi² against the tracker noise, the outliers, the noise estimates and the "before"
    figures (the nominal model's best rigid fit on the kept rows)."""
    from robocal.identification.noise import noise_report

    cfg, model, data, m = start.config, start.model, start.data, start.m
    cal, use_rot, sig, weights, rows = start.campaign, start.use_rot, start.sigma_mm, start.weights, start.rows
    lm, kept, test, suspects = screened.fit, screened.kept, screened.test, screened.suspects
    free, ident = start.free, start.identifiability
    x = np.array(lm.x)  # the calibration's own copy (the fit result is read-only)
    x_init, r0 = start.x_init, start.r0
    x_analysis = x_init  # where the identifiability analysis ran
    if len(start.rigid) and not kept.all():
        # the "before" figures: the nominal model's best rigid fit on the kept rows
        x_init = rigid_fit(model, data, x_init, start.rigid, weights, rows, kept)
        r0, _ = model.residuals_and_jacobian(x_init, data)
    k = len(free)
    Mk = int(kept[rows].sum())
    # the solver's covariance is the kept rows': scaled by the whitened fit's reduced chi², or by the configured
    # noise when no residual degree of freedom is left (as many identified parameters as residuals)
    cov = lm.covariance if lm.covariance is not None else np.full((k, k), np.nan)  # None: not finite
    identified = np.zeros(model.n, dtype=bool)
    identified[free] = True
    stderr = np.full(model.n, np.nan)
    stderr[free] = np.sqrt(np.diag(cov))
    r_all = lm.residual / weights
    r_pos = r_all[: 3 * m].reshape(-1, 3)
    r_rot = r_all[3 * m :].reshape(-1, 3) if use_rot else None
    sig_k = None if cfg.noise_model == "constant" else sig[kept]
    fit = fit_statistics(r_pos[kept], cfg, k, None if r_rot is None else r_rot[kept], sigma_mm=sig_k)
    if isinstance(cfg.outliers, tuple):
        outliers = describe_outliers(cal, ~kept, r_pos, r_rot, None, listed=True)
        rule = "rows listed in the 'outliers' calibration setting"
    elif test is not None:
        outliers = describe_outliers(cal, ~kept, r_pos, r_rot, test)
        rule = (
            f"studentised row residuals (F test, {test.d} residuals per row), Bonferroni over {m} rows at "
            f"family-wise alpha {cfg.outlier_alpha:g}; robust start (Cauchy IRLS) when a row stood out"
        )
    else:
        outliers = []
        rule = "off"
    if suspects:
        rule += (
            f"; {len(suspects)} of {m} rows stood out, more than the {cfg.outlier_max_share:.0%} gross errors can "
            "be: the model misses a systematic effect (run robocal discover); no row was left out"
        )
    if screened.systematic:
        rule += "; " + misfit.RULE
    chi2_pos = float(np.sum((r_pos[kept] / sig[kept, None]) ** 2))
    dof_pos = max(3 * int(kept.sum()) - k, 1) if not use_rot else max(int(fit["dof"]) // 2, 1)
    figures = solver_figures(lm)  # the solve's iterations, evaluations, stopping status and own time
    fit.update(
        {
            "n_identified": k,
            "n_eliminated": len(ident.eliminated),
            **{key: figures[key] for key in ("nit", "nfev", "status", "message", "success")},
            "wall_time_s": time.perf_counter() - start.t0,
            "solver_time_s": figures["solver_time_s"],
            "targets": list(start.targets),
            "stations": list(start.stations),
            "uses_orientation": use_rot,
            "stderr_scale": "residual variance" if Mk > k else "configured noise (no degree of freedom left)",
            "outliers": outliers,
            "outlier_rule": rule,
            "outlier_suspects": suspects,
            "systematic_misfit": misfit.public(screened.systematic),
            "n_rows_total": int(m),
            "outlier_rounds": int(screened.rounds),
            "noise": noise_report(cal, kept, chi2_pos, dof_pos, cfg.noise_mm),
            **({"orientation_left_out": start.orientation_note} if start.orientation_note else {}),
        }
    )
    before_pos = r0[: 3 * m].reshape(-1, 3)
    fit["before"] = {
        **ErrorStats.of(before_pos[kept]).position(FIT_ORDER),
        "definition": "nominal kinematics with frames and tools fitted to convergence (best rigid fit), kept rows",
    }
    # judged on the design (the standard errors the configured noise would give): a fit that stopped early or a
    # model error inflates the residual variance, not how well the poses determine a parameter
    s_fit = float(np.sqrt(max(float(lm.redchi), 1.0))) if Mk > k and np.isfinite(lm.redchi) else 1.0
    poor = poorly_determined(model, stderr / s_fit, cfg)
    if poor:  # calibrate() holds them and fits again (poorly_determined: fix) or keeps this list (report)
        fit["poorly_determined"] = [{**p, "action": "reported (poorly_determined: report)"} for p in poor]
    return CalibrationResult(
        model=model,
        x=x,
        identified=identified,
        stderr=stderr,
        covariance=cov,
        identifiability=ident,
        fixed_by_user=tuple(sorted(start.parameters.fixed - start.parameters.held)),
        statistics=fit,
        residuals_mm=r_pos,
        residuals_deg=None if r_rot is None else np.rad2deg(r_rot),
        config=cfg,
        solver=lm,
        start=FitStart(x_init, x_analysis, before_pos, kept, test),
    )
