"""Joint-compliance identification (Mao et al. 2021, eq. 21-24) on top of a geometric calibration.

Measurement model of a row: ``p = f(q + s ∘ c, x)`` with ``f`` the calibrated geometric model (tracker frame),
``q`` the reported joints, ``s`` the deflection signal of the row (currents, drive torques or computed gravity
torques, ``(m, n)``) and ``c`` the compliance per joint. Linearised (eq. 24): ``df = J_theta · diag(s) · c``.

Two methods:

- ``"sequential"`` (the paper): ``x`` is the geometric calibration of the *unloaded* rows, held fixed; ``c`` is
  fitted by Gauss-Newton on the loaded rows (by default those at the largest payload, "full load"). Standard
  errors ``s² (J̃ᵀJ̃)⁻¹`` with ``J̃ = J_theta diag(s)`` are conditional on ``x``. Caveat (measured here, see the
  benchmark): the unloaded calibration absorbs much of the arm's own-weight deflection into ``x``, so the model
  then predicts that deflection twice when applied at small loads; this is the mechanism behind the paper's
  table 4 (compensation hurts when unloaded).
- ``"joint"``: ``x`` (the geometric calibration's identified parameters) and ``c`` fitted together on all
  calibration rows (unloaded and loaded), every row with its own signal; the geometric parameters are then
  free of deflection and the covariance is complete.

Joint selection ``joints="auto"``: start from every joint with a non-zero signal and drop, one at a time, the
joint with the smallest ``|c| / stderr`` while it is below ``t_min`` (the paper leaves joints 1 and 6 out by
physics: gravity along axis 1, payload centred on axis 6).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.result import CalibrationResult
from robocal.calibration.start import fit_data
from robocal.compliance.model import KINDS, ComplianceModel
from robocal.config import parse, setting
from robocal.errors import ConfigError
from robocal.identification.model import FitData
from robocal.metrics import ErrorStats
from robocal.optimizers.least_squares import least_squares

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign
    from robocal.robot import RobotDescription

METHODS = ("sequential", "joint")


@dataclass(frozen=True)
class ComplianceConfig:
    """Settings of a compliance identification.

    kind : ``auto`` (currents if the campaign has them, else drive torques, else gravity), or one of
        ``current``, ``torque``, ``gravity``.
    joints : ``auto`` or a list of joint numbers (1-based) whose compliance is identified.
    method : ``sequential`` (the paper) or ``joint`` (geometry and compliance together).
    fit_loads : ``max`` (rows at the largest payload, the paper's "full load") or ``loaded`` (every row with a
        payload above ``unloaded_max_kg``); ``joint`` uses every calibration row regardless.
    unloaded_max_kg : rows with ``payload_kg <= unloaded_max_kg`` count as unloaded.
    t_min : automatic joint selection keeps joints with ``|c| / stderr >= t_min``.
    max_iter, tol : Gauss-Newton stopping rules (relative cost change).
    geometric : the geometric calibration settings (:class:`robocal.calibration.config.CalibrationConfig`).
    compensation : write the controller-ready compensation CSV of the validation rows.
    report : write the HTML report.
    """

    kind: str = setting("auto", choices=("auto", *KINDS))
    joints: str | tuple[int, ...] = setting("auto", choices=("auto",))
    method: str = setting("joint", choices=METHODS)
    fit_loads: str = setting("max", choices=("max", "loaded"))
    unloaded_max_kg: float = setting(0.0, ge=0)
    t_min: float = setting(3.0, ge=0)
    max_iter: int = 30
    tol: float = 1e-12
    geometric: Mapping[str, Any] = field(default_factory=dict)
    compensation: bool = True
    report: bool = True

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> ComplianceConfig:
        """Build from a mapping (a Hydra node, YAML, ``key=value`` overrides); errors name the key."""
        return parse(cls, cfg, "compliance")


def resolve_kind(kind: str, campaign: Campaign) -> str:
    """``auto`` -> ``current`` / ``torque`` / ``gravity`` by what the campaign has; checks an explicit kind."""
    if kind == "auto":
        return "current" if campaign.has_currents else ("torque" if campaign.has_torques else "gravity")
    if kind == "current" and not campaign.has_currents:
        raise ConfigError(f"compliance kind 'current' needs motor currents (i1_A..) in {campaign.poses_file}")
    if kind == "torque" and not campaign.has_torques:
        raise ConfigError(f"compliance kind 'torque' needs joint torques (tau1_Nm..) in {campaign.poses_file}")
    return kind


def base_model(kind: str, robot: RobotDescription) -> ComplianceModel:
    """An all-zero model of ``kind`` for ``robot`` (carries the dynamics for ``gravity``)."""
    n = robot.n_joints
    dyn: dict[str, Any] = {}
    if kind == "gravity":
        if not robot.has_dynamics:
            raise ConfigError(
                f"compliance kind 'gravity' needs link masses: robot {robot.name!r} has no 'dynamics' section "
                "(or give motor currents / joint torques)"
            )
        assert robot.link_mass_kg is not None and robot.link_com_mm is not None
        dyn = {
            "link_mass_kg": robot.link_mass_kg.copy(),
            "link_com_mm": robot.link_com_mm.copy(),
            "payload_com_mm": robot.payload_com_mm.copy(),
            "gravity_mps2": robot.gravity.copy(),
        }
    return ComplianceModel(
        kind=kind,
        robot=robot.name,
        joint_names=robot.joint_names,
        c=np.zeros(n),
        stderr=np.full(n, np.nan),
        identified=np.zeros(n, dtype=bool),
        dynamics=dyn,
    ).with_robot(robot)


def campaign_signal(model: ComplianceModel, campaign: Campaign) -> np.ndarray:
    """The model's deflection signal ``(m, n)`` for every row of ``campaign``."""
    return model.signal(campaign.q, campaign.payload_kg, campaign.current_A, campaign.tau_Nm)


@dataclass
class GNResult:
    x: np.ndarray
    c: np.ndarray
    cov: np.ndarray
    residuals_mm: np.ndarray
    nit: int
    s2: float


def _gauss_newton(
    geo: CalibrationResult,
    data: FitData,
    S: np.ndarray,
    joints: np.ndarray,
    geo_free: np.ndarray,
    c0: np.ndarray,
    max_iter: int,
    tol: float,
) -> GNResult:
    """Minimise ``|f(q + S∘c, x) - p|²`` over ``c[joints]`` (and ``x[geo_free]``): Gauss-Newton with a line
    search, by the least squares of the optimizer protocol (:func:`robocal.optimizers.least_squares.least_squares`,
    ``method="gn"``) on the stacked vector ``[x, c]``."""
    model = geo.model
    nx = len(geo.x)
    m3 = 3 * data.m

    def fun(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xx, cc = z[:nx], z[nx:]
        dd = data.with_q(data.q + S * cc)
        r, Jx = model.residuals_and_jacobian(xx, dd)
        Jq = model.joint_jacobian(xx, dd.q, dd.target_index, dd.station_index)  # (m, 3, n)
        Jc = (Jq * S[:, None, :]).reshape(m3, -1)
        return r[:m3], np.concatenate([Jx[:m3], Jc], axis=1)

    z0 = np.concatenate([geo.x, c0])
    free = np.concatenate([np.asarray(geo_free, dtype=int), nx + np.asarray(joints, dtype=int)])
    lm = least_squares(fun, z0, free, 1.0, max_iter=max_iter, ftol=tol, xtol=1e-12, method="gn")
    res = lm.residual.reshape(-1, 3)
    s2 = lm.redchi if lm.dof > 0 else lm.chi2  # the residual variance (per coordinate)
    assert lm.covariance is not None  # the fit is finite (the model's residuals always are)
    return GNResult(lm.x[:nx].copy(), lm.x[nx:].copy(), np.array(lm.covariance), res.copy(), lm.nit, s2)


@dataclass
class ComplianceFit:
    """Result of :func:`fit_compliance`: the model, the (possibly refitted) geometry and fit statistics."""

    model: ComplianceModel
    x: np.ndarray
    method: str
    fit_rows: np.ndarray
    fit: dict[str, Any]
    covariance: np.ndarray
    selection: list[dict[str, Any]]


def missing_loads(campaign: Campaign, cfg: ComplianceConfig, source: str | None = None) -> str | None:
    """Why ``campaign`` cannot give the compliance under payload, or None: the fit sits on a geometric
    calibration of the unloaded calibration rows and identifies the compliance from the loaded ones, so it needs
    both. A robot measured with its working payload always mounted (one load on every row) has no load step: its
    deflection under the arm's and the payload's weight is discovery's weight effect (``robocal discover``).
    ``source``: the campaign's name in the message (the pipeline's: the user's folder, not its interim copy)."""
    cal = campaign.split == "calibration"
    loads = np.asarray(campaign.payload_kg, dtype=float)[cal]
    unloaded = int((loads <= cfg.unloaded_max_kg).sum())
    loaded = len(loads) - unloaded
    if unloaded and loaded:
        return None
    have = ", ".join(f"{v:g}" for v in sorted(set(loads.tolist()))[:4]) or "none"
    return (
        f"campaign {source or campaign.source}: the compliance under payload needs calibration rows without a payload "
        f"(payload_kg <= {cfg.unloaded_max_kg:g}) and rows with one; its calibration rows have "
        f"{'only loaded' if loaded else 'only unloaded'} rows (payload_kg {have}). Its deflection under the arm's "
        "and its payloads' weight (each row's payload_kg) is discovery's weight effect (robocal discover)"
    )


def fit_rows_mask(campaign: Campaign, cfg: ComplianceConfig) -> np.ndarray:
    """Calibration rows used to fit ``c`` (``sequential``): full-load rows or every loaded row."""
    cal = campaign.split == "calibration"
    loaded = cal & (campaign.payload_kg > cfg.unloaded_max_kg)
    if not loaded.any():
        raise ConfigError(
            f"campaign {campaign.source}: no calibration rows with a payload above {cfg.unloaded_max_kg:g} kg "
            "(compliance needs measurements under load)"
        )
    if cfg.fit_loads == "max":
        return loaded & np.isclose(campaign.payload_kg, campaign.payload_kg[loaded].max())
    return loaded


def geometric_step(campaign: Campaign, robot: RobotDescription, cfg: ComplianceConfig) -> CalibrationResult:
    """Geometric calibration of the unloaded calibration rows (the paper's first step)."""
    unloaded = (campaign.split == "calibration") & (campaign.payload_kg <= cfg.unloaded_max_kg)
    if not unloaded.any():
        raise ConfigError(
            missing_loads(campaign, cfg)
            or f"campaign {campaign.source}: no unloaded calibration rows (payload_kg <= {cfg.unloaded_max_kg:g})"
        )
    return calibrate(
        campaign.subset(unloaded), robot, CalibrationConfig.from_mapping(cfg.geometric, "compliance.geometric")
    )


def fit_compliance(
    campaign: Campaign,
    robot: RobotDescription,
    geo: CalibrationResult,
    config: ComplianceConfig | None = None,
) -> ComplianceFit:
    """Identify the joint compliance of ``campaign`` on top of the geometric calibration ``geo``."""
    cfg = config or ComplianceConfig()
    kind = resolve_kind(cfg.kind, campaign)
    base = base_model(kind, robot)
    n = robot.n_joints
    if cfg.method == "sequential":
        rows = fit_rows_mask(campaign, cfg)
        geo_free = np.zeros(0, dtype=int)
    else:
        fit_rows_mask(campaign, cfg)  # checks there are loaded rows
        rows = campaign.split == "calibration"
        geo_free = np.flatnonzero(geo.identified)
    sub = campaign.subset(rows)
    unknown = sorted(set(map(str, sub.target)) - set(geo.model.target_names))
    if unknown:
        raise ConfigError(f"targets {unknown} of the loaded rows are not in the geometric calibration")
    data = fit_data(sub, use_orientation=False, targets=geo.model.target_names)
    S = campaign_signal(base, sub)
    if isinstance(cfg.joints, str):
        joints = [j for j in range(n) if np.any(np.abs(S[:, j]) > 0)]
    else:
        bad = [j for j in cfg.joints if not 1 <= j <= n]
        if bad:
            raise ConfigError(f"The 'joints' compliance setting names joint(s) {bad}; the robot has joints 1..{n}")
        joints = sorted({j - 1 for j in cfg.joints})
    if not joints:
        raise ConfigError("compliance: no joint to identify (every signal is zero)")
    selection: list[dict[str, Any]] = []
    while True:
        jj = np.array(joints, dtype=int)
        gn = _gauss_newton(geo, data, S, jj, geo_free, np.zeros(n), cfg.max_iter, cfg.tol)
        se = np.sqrt(np.diag(gn.cov))[len(geo_free) :]
        tval = np.abs(gn.c[jj]) / np.where(se > 0, se, np.inf)
        if not isinstance(cfg.joints, str) or len(joints) == 1 or tval.min() >= cfg.t_min:
            break
        drop = int(jj[int(np.argmin(tval))])
        selection.append({"dropped_joint": drop + 1, "t": float(tval.min()), "c": float(gn.c[drop])})
        joints.remove(drop)
    stderr = np.full(n, np.nan)
    stderr[jj] = se
    ident = np.zeros(n, dtype=bool)
    ident[jj] = True
    c = np.where(ident, gn.c, 0.0)
    m_rows = int(rows.sum())
    fit = {
        "kind": kind,
        "method": cfg.method,
        "n_rows": m_rows,
        "loads_kg": sorted({float(v) for v in sub.payload_kg}),
        **ErrorStats.of(gn.residuals_mm).position(("rms", "mean", "max")),
        "residual_sigma_mm": float(np.sqrt(gn.s2)),
        "nit": gn.nit,
        "joints": [int(j) + 1 for j in jj],
        "t_values": {robot.joint_names[j]: float(t) for j, t in zip(jj, tval, strict=True)},
    }
    model = ComplianceModel(
        kind=kind,
        robot=robot.name,
        joint_names=robot.joint_names,
        c=c,
        stderr=stderr,
        identified=ident,
        dynamics=base.dynamics,
        info={"fit": fit, "campaign": campaign.source},
    ).with_robot(robot)
    return ComplianceFit(model, gn.x, cfg.method, rows, fit, gn.cov, selection)


# ---------------------------------------------------------------------------------------------- evaluation


def position_errors(
    geo: CalibrationResult,
    x: np.ndarray,
    campaign: Campaign,
    model: ComplianceModel | None = None,
) -> np.ndarray:
    """Prediction errors ``(m, 3)`` mm of the geometric model ``x`` (with the deflection model if given)."""
    gm = geo.model
    known = {t: k for k, t in enumerate(gm.target_names)}
    unknown = sorted(set(map(str, campaign.target)) - set(known))
    if unknown:
        raise ConfigError(f"targets {unknown} are not in the geometric calibration")
    ti = np.array([known[str(t)] for t in campaign.target], dtype=int)
    q = campaign.q if model is None else campaign.q + campaign_signal(model, campaign) * model.c
    p, _ = gm.predict(x, q, ti)
    return p - campaign.p_mm


def distance_accuracy(err_mm: np.ndarray, p_meas: np.ndarray) -> float:
    """Mean ``| |p_i - p_j| - |p̂_i - p̂_j| |`` over all pairs (ISO 9283 distance accuracy in kind), mm."""
    if len(p_meas) < 2:
        return float("nan")
    pred = p_meas + err_mm
    i, j = np.triu_indices(len(p_meas), 1)
    dm = np.linalg.norm(p_meas[i] - p_meas[j], axis=1)
    dp = np.linalg.norm(pred[i] - pred[j], axis=1)
    return float(np.mean(np.abs(dm - dp)))


def _stats(e: np.ndarray) -> dict[str, float]:
    return ErrorStats.of(e).position(("mean", "max", "rms"), scheme="short")


def accuracy_by_condition(
    campaign: Campaign,
    geo: CalibrationResult,
    cfit: ComplianceFit,
    x_nominal: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """Errors per (split, payload) condition: nominal, after geometric calibration, after compliance.

    ``after_geometric`` uses the unloaded geometric calibration; ``after_compliance`` the fitted geometry
    (``cfit.x``) with the deflection model (the prediction error, i.e. the accuracy the compensated robot
    reaches when the model is right). ``distance_*`` is the distance accuracy among the condition's rows.
    """
    out: list[dict[str, Any]] = []
    e_geo = position_errors(geo, geo.x, campaign)
    e_comp = position_errors(geo, cfit.x, campaign, cfit.model)
    e_nom = position_errors(geo, x_nominal, campaign) if x_nominal is not None else None
    for split in ("calibration", "validation"):
        in_split = campaign.split == split
        for load in sorted({float(v) for v in campaign.payload_kg[in_split]}):
            sel = in_split & np.isclose(campaign.payload_kg, load)
            row: dict[str, Any] = {"split": split, "payload_kg": load, "n_rows": int(sel.sum())}
            if e_nom is not None:
                row["nominal"] = _stats(e_nom[sel])
            row["after_geometric"] = _stats(e_geo[sel])
            row["after_compliance"] = _stats(e_comp[sel])
            row["distance_after_geometric_mm"] = distance_accuracy(e_geo[sel], campaign.p_mm[sel])
            row["distance_after_compliance_mm"] = distance_accuracy(e_comp[sel], campaign.p_mm[sel])
            out.append(row)
    return out


def load_table(conditions: Sequence[Mapping[str, Any]], rated_kg: float | None = None) -> list[dict[str, Any]]:
    """Paper table 4 in kind: per validation load, accuracy before / after compensation and the verdict."""
    rows = [c for c in conditions if c["split"] == "validation"] or [
        c for c in conditions if c["split"] == "calibration"
    ]
    top = rated_kg or max((float(c["payload_kg"]) for c in rows), default=0.0) or 1.0
    out = []
    for c in sorted(rows, key=lambda r: -float(r["payload_kg"])):
        before, after = c["after_geometric"]["mean_mm"], c["after_compliance"]["mean_mm"]
        out.append(
            {
                "payload_kg": c["payload_kg"],
                "load_ratio_pct": 100.0 * float(c["payload_kg"]) / top,
                "position_before_mm": before,
                "position_after_mm": after,
                "distance_before_mm": c["distance_after_geometric_mm"],
                "distance_after_mm": c["distance_after_compliance_mm"],
                "verdict": "helps" if after < before else "hurts",
                "n_rows": c["n_rows"],
            }
        )
    return out


__all__ = [
    "METHODS",
    "ComplianceConfig",
    "ComplianceFit",
    "accuracy_by_condition",
    "base_model",
    "campaign_signal",
    "distance_accuracy",
    "fit_compliance",
    "fit_rows_mask",
    "geometric_step",
    "load_table",
    "missing_loads",
    "position_errors",
    "resolve_kind",
]
