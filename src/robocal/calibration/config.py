"""The settings of a geometric calibration (:class:`CalibrationConfig`) and the noise model they give each
point (:func:`point_sigma`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.config import parse, setting
from robocal.errors import ConfigError

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign


NOISE_MODELS = ("constant", "u_mm", "distance")


#: settings written into calibration.json's ``config`` only when not at their default (the thin-campaign prior,
#: :mod:`robocal.identification.thin`): a calibration made without them keeps its bytes
WRITTEN_WHEN_SET = (
    "prior", "prior_mm", "prior_deg", "prior_frame_mm", "prior_frame_deg", "thin_ratio", "sparse_ratio",
)  # fmt: skip


#: the order of the error statistics in the fit record (calibration.json ``fit`` and ``fit.before``)
FIT_ORDER = ("rms", "mean", "max")


def outlier_rule(value: Any) -> Any:
    """``key=value`` overrides read ``outliers=off`` as YAML 1.1 ``false``: that is ``"off"``."""
    return "off" if value is False else value


def data_rows(value: str | tuple[int, ...]) -> str | None:
    """The file rows of an ``outliers`` list: data rows start at 2 (the header is row 1)."""
    if isinstance(value, tuple) and any(r < 2 for r in value):
        return "lists file rows below 2; data rows start at 2 (the header is row 1)"
    return None


@dataclass(frozen=True)
class CalibrationConfig:
    """Settings of a geometric calibration.

    noise_mm : tracker noise per coordinate (1 sigma), for chi² and weights.
    noise_deg : orientation noise per axis (1 sigma) when the data has orientations.
    rank_tol : relative leftover below which a parameter counts as absorbed by others.
    fixed : parameter names (shell patterns allowed, e.g. ``"beta*"``) held at nominal.
    max_iter, ftol, xtol : Levenberg-Marquardt stopping rules.
    use_orientation : use measured orientations when present (``None`` = when present).
    registration_iters : alternations of point-set registration and tool estimation for the initial frames
        (a start: the frames and tools are then fitted to convergence with the nominal kinematics, which gives
        the true "before calibration" figures).
    method : ``"lm"`` (Levenberg-Marquardt, the default) or ``"gn"`` (Gauss-Newton with a line search): the
        registered gradient optimizer that solves the least squares (:mod:`robocal.optimizers.gradient`, the
        core :mod:`robocal.optimizers.solver`).
    outliers : ``"auto"`` (gross errors found by the test in :mod:`robocal.identification.robust`), ``"off"``,
        or a list of file rows (header = row 1) to leave out.
    outlier_alpha : family-wise false-flag rate of the outlier test over the rows of a campaign.
    max_stderr_mm, max_stderr_deg : a parameter whose standard error exceeds this (lengths, angles) is poorly
        determined by the data (e.g. a tool offset with a constant tool orientation): ``poorly_determined: fix``
        holds it at its start (nominal, or the registration's frame / tool) and fits the rest again; ``report``
        keeps it and says so. Either way it is listed under ``fit.poorly_determined``, never as identified.
    outlier_max_share : gross errors are rare: when more than this share of the rows stands out, the residuals
        are a model error, not blunders (e.g. a warm-up the geometric model cannot follow); then no row is left
        out, the rows are reported as suspects and the fit says to run discovery.
    noise_model : ``"constant"`` (``noise_mm`` for every point), ``"u_mm"`` (each point's ``u_mm`` column over
        ``u_coverage``), or ``"distance"`` (``noise_mm + noise_mm_per_m · range``, as trackers state it).
    u_coverage : coverage factor of the ``u_mm`` column (2 for a U95 export).
    noise_mm_per_m : distance term of the ``distance`` noise model, mm per metre of tracker range.
    prior : ``"auto"`` (a prior toward the nominal description when the campaign is thin, fewer configurations
        than give ``thin_ratio`` equations per model parameter; its strength chosen by leave-one-configuration-out
        cross-validation), ``"off"``, or a strength (1 = the stated widths; also for a poorly spread campaign):
        :mod:`robocal.identification.thin`. The gradient optimizers only.
    prior_mm, prior_deg : the prior's widths (1 sigma) of the joint-level lengths and angles.
    prior_frame_mm, prior_frame_deg : the (fixed, weak) prior's widths of the tracker frames and tools, around
        the nominal model's best rigid fit.
    thin_ratio : equations per model parameter below which a campaign is thin (``fit.configurations``).
    sparse_ratio : below this many equations per parameter (and not thin) ``prior: auto`` still cross-validates
        the prior by configuration and takes it only when it *clearly* beats none (its CV error lower by more than
        two standard errors of the paired difference): few configurations or a poorly spread set whose model is
        near-singular somewhere the count does not show.
    """

    noise_mm: float = setting(0.015, gt=0)
    noise_deg: float = setting(0.01, gt=0)
    rank_tol: float = setting(1e-6, gt=0)
    fixed: tuple[str, ...] = ()
    max_iter: int = 100
    ftol: float = 1e-12
    xtol: float = 1e-10
    use_orientation: bool | None = None
    registration_iters: int = 20
    method: str = setting("lm", choices=("lm", "gn"))
    outliers: str | tuple[int, ...] = setting("auto", choices=("auto", "off"), convert=outlier_rule, check=data_rows)
    outlier_alpha: float = setting(0.001, gt=0, lt=1)
    outlier_max_share: float = setting(0.05, ge=0, lt=1)
    max_stderr_mm: float = setting(1.0, gt=0)
    max_stderr_deg: float = setting(0.1, gt=0)
    poorly_determined: str = setting("fix", choices=("fix", "report"))
    noise_model: str = setting("constant", choices=NOISE_MODELS)
    u_coverage: float = setting(2.0, gt=0)
    noise_mm_per_m: float = setting(0.0, ge=0)
    prior: str | float = setting("auto", choices=("auto", "off"), gt=0, convert=outlier_rule)
    prior_mm: float = setting(0.5, gt=0)
    prior_deg: float = setting(0.05, gt=0)
    prior_frame_mm: float = setting(10.0, gt=0)
    prior_frame_deg: float = setting(1.0, gt=0)
    thin_ratio: float = setting(2.0, gt=0)
    sparse_ratio: float = setting(4.0, gt=0)

    @classmethod
    def from_mapping(cls, cfg: Any, section: str = "calibration") -> CalibrationConfig:
        """Build from a mapping (a Hydra node, YAML, ``key=value`` overrides); errors name the key."""
        return parse(cls, cfg, section)


def point_sigma(campaign: Campaign, cfg: CalibrationConfig) -> np.ndarray:
    """Per-point noise (1 sigma per coordinate, mm) under the configured noise model, ``(m,)``."""
    m = campaign.n_rows
    if cfg.noise_model == "u_mm":
        if campaign.u_mm is None:
            raise ConfigError(
                f"The 'noise_model' calibration setting is 'u_mm' but {campaign.poses_file} has no u_mm column"
            )
        return np.asarray(campaign.u_mm, dtype=float) / cfg.u_coverage
    if cfg.noise_model == "distance":
        # the tracker sits at the origin of its own frame: the range is the norm of the measured point
        return cfg.noise_mm + cfg.noise_mm_per_m * np.linalg.norm(campaign.p_mm, axis=1) / 1000.0
    return np.full(m, cfg.noise_mm)
