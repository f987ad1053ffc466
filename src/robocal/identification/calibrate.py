"""Geometric calibration end to end: registration, identifiability, Levenberg-Marquardt, statistics, validation."""

from __future__ import annotations

import fnmatch
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import special

from robocal.errors import ConfigError
from robocal.identification.identifiability import Eliminated, Identifiability, analyse
from robocal.identification.model import CalibrationModel, FitData
from robocal.identification.solver import LMResult, levenberg_marquardt
from robocal.kinematics.chain import fk
from robocal.kinematics.transforms import (
    inv_transform,
    kabsch,
    matrix_to_rotvec,
    quat_to_matrix,
    rpy_from_matrix,
)
from robocal.robot import RobotDescription

if TYPE_CHECKING:
    from robocal.data.contract import Campaign


@dataclass(frozen=True)
class CalibrationConfig:
    """Settings of a geometric calibration.

    noise_mm : tracker noise per coordinate (1 sigma), for chi² and weights.
    noise_deg : orientation noise per axis (1 sigma) when the data has orientations.
    rank_tol : relative leftover below which a parameter counts as absorbed by others.
    fixed : parameter names (shell patterns allowed, e.g. ``"beta*"``) held at nominal.
    max_iter, ftol, xtol : Levenberg-Marquardt stopping rules.
    use_orientation : use measured orientations when present (``None`` = when present).
    registration_iters : alternations of point-set registration and tool estimation for the initial frames.
    """

    noise_mm: float = 0.015
    noise_deg: float = 0.01
    rank_tol: float = 1e-6
    fixed: tuple[str, ...] = ()
    max_iter: int = 100
    ftol: float = 1e-12
    xtol: float = 1e-10
    use_orientation: bool | None = None
    registration_iters: int = 20

    @classmethod
    def from_mapping(cls, cfg: Any) -> CalibrationConfig:
        """Build from a mapping (e.g. a Hydra node); unknown keys are an error naming them."""
        if cfg is None:
            return cls()
        data = dict(cfg)
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown calibration setting(s) {unknown}; known: {sorted(known)}")
        if "fixed" in data:
            data["fixed"] = tuple(data["fixed"] or ())
        out = cls(**data)
        for name in ("noise_mm", "noise_deg", "rank_tol"):
            if not float(getattr(out, name)) > 0:
                raise ConfigError(f"The '{name}' calibration setting must be > 0. Got {getattr(out, name)!r} instead.")
        return out


def fit_data(campaign: Campaign, use_orientation: bool = True, targets: tuple[str, ...] | None = None) -> FitData:
    """Arrays for fitting; ``target_index`` refers to ``targets`` (default: the campaign's target names)."""
    R = quat_to_matrix(campaign.quat) if (use_orientation and campaign.quat is not None) else None
    if targets is None:
        ti = campaign.target_index
    else:
        lookup = {t: k for k, t in enumerate(targets)}
        ti = np.array([lookup[str(t)] for t in campaign.target], dtype=int)
    return FitData(q=campaign.q, p_mm=campaign.p_mm, target_index=ti, R_meas=R)


def present_targets(campaign: Campaign) -> tuple[str, ...]:
    """Targets that occur in the campaign's rows, in the campaign's order."""
    seen = set(map(str, campaign.target))
    return tuple(t for t in campaign.target_names if t in seen)


def register_frames(
    model: CalibrationModel, data: FitData, iters: int = 20, tool_init: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form initial ``tracker_T_base`` and tool offsets from the nominal kinematics.

    Alternates Kabsch registration of the nominal target points onto the measurements with a linear
    least-squares solve for each target's flange offset. Returns ``(T (4, 4), tools (K, 3))``.
    """
    T_flange = fk(model.chain, data.q)
    Rf, of = T_flange[:, :3, :3], T_flange[:, :3, 3]
    K = len(model.target_names)
    tools = np.zeros((K, 3)) if tool_init is None else np.array(tool_init, dtype=float).reshape(K, 3)
    T = np.eye(4)
    for _ in range(max(1, iters)):
        pts = of + np.einsum("mij,mj->mi", Rf, tools[data.target_index])
        T_new = kabsch(pts, data.p_mm)
        # measured points in the base frame, then solve Rf t = p_base - of per target in least squares:
        # the Rf are rotations (Rfᵀ Rf = I), so the normal equations give the mean of Rfᵀ (p_base - of)
        p_base = (data.p_mm - T_new[:3, 3]) @ T_new[:3, :3]
        local = np.einsum("mji,mj->mi", Rf, p_base - of)
        sums = np.zeros((K, 3))
        np.add.at(sums, data.target_index, local)
        counts = np.bincount(data.target_index, minlength=K)
        new_tools = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], tools)
        change = np.abs(new_tools - tools).max() + np.abs(T_new - T).max()
        tools, T = new_tools, T_new
        if change < 1e-4:  # mm / unitless: Levenberg-Marquardt refines from here
            break
    return T, tools


@dataclass
class CalibrationResult:
    """A fitted calibration: parameters with standard errors, frames, tools and fit statistics."""

    model: CalibrationModel
    x: np.ndarray
    identified: np.ndarray  # (n,) bool
    stderr: np.ndarray  # (n,) NaN where not identified
    covariance: np.ndarray  # (k, k) over identified parameters, in their units
    identifiability: Identifiability
    fixed_by_user: tuple[str, ...]
    fit: dict[str, Any]
    residuals_mm: np.ndarray  # (m, 3)
    residuals_deg: np.ndarray | None
    config: CalibrationConfig
    lm: LMResult | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, ...]:
        return self.model.names

    @property
    def eliminated(self) -> tuple[Eliminated, ...]:
        return self.identifiability.eliminated

    @property
    def correlation(self) -> np.ndarray:
        d = np.sqrt(np.diag(self.covariance))
        d[d == 0] = 1.0
        return self.covariance / np.outer(d, d)

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
        rows = []
        for k, name in enumerate(self.names):
            unit = self.model.units[k]
            f = np.rad2deg(1.0) if unit == "rad" else 1.0
            rows.append(
                {
                    "name": name,
                    "kind": self.model.kinds[k],
                    "unit": "deg" if unit == "rad" else unit,
                    "value": float(self.x[k] * f),
                    "stderr": float(self.stderr[k] * f) if self.identified[k] else None,
                    "status": "identified"
                    if self.identified[k]
                    else ("fixed" if name in self.fixed_by_user else "eliminated"),
                }
            )
        return rows

    def to_dict(self) -> dict[str, Any]:
        T = self.tracker_T_base
        idx = np.flatnonzero(self.identified)
        return {
            "robot": self.model.robot.name,
            "convention": self.model.robot.convention,
            "parameters": self.parameter_table(),
            "kinematic_errors": {n: float(self.x[k]) for k, n in enumerate(self.model.chain.param_names)},
            "eliminated": [e.to_dict() for e in self.eliminated],
            "fixed": list(self.fixed_by_user),
            "tracker_T_base": T.tolist(),
            "tracker_T_base_xyz_mm": T[:3, 3].tolist(),
            "tracker_T_base_rpy_deg": np.rad2deg(rpy_from_matrix(T[:3, :3])).tolist(),
            "tools_mm": {k: v.tolist() for k, v in self.tools.items()},
            "tool_rotations": {
                k: R.tolist() for k, R in zip(self.model.target_names, self.model.tool_rotations(self.x), strict=True)
            },
            "T_ref": self.model.T_ref.tolist(),
            "tool_R_ref": self.model.tool_R_ref.tolist(),
            "orientation": self.model.orientation,
            "x": self.x.tolist(),
            "names": list(self.names),
            "correlation": {
                "names": [self.names[i] for i in idx],
                "matrix": self.correlation.tolist(),
            },
            "identifiability": {
                "rank": self.identifiability.rank,
                "n_candidates": int(len(self.identifiability.kept) + len(self.eliminated)),
                "condition_number": self.identifiability.condition_number,
            },
            "fit": self.fit,
            "config": {k: getattr(self.config, k) for k in self.config.__dataclass_fields__},
        }


def load_calibration(data: dict[str, Any], robot: RobotDescription) -> CalibrationResult:
    """Rebuild a :class:`CalibrationResult` (enough to predict and compensate) from :meth:`to_dict` output."""
    model = CalibrationModel(
        robot,
        tuple(data["tools_mm"].keys()),
        orientation=bool(data.get("orientation", False)),
        T_ref=np.array(data["T_ref"]),
        tool_R_ref=np.array(data["tool_R_ref"]),
    )
    if list(model.names) != list(data["names"]):
        raise ConfigError(
            f"calibration file does not match robot {robot.name!r}: parameter names differ "
            f"({len(data['names'])} in file, {len(model.names)} for the robot)"
        )
    x = np.array(data["x"], dtype=float)
    identified = np.array([p["status"] == "identified" for p in data["parameters"]])
    se = np.array([np.nan if p["stderr"] is None else p["stderr"] for p in data["parameters"]], dtype=float)
    se = np.where(np.array(model.units) == "rad", np.deg2rad(se), se)
    k = int(identified.sum())
    corr = np.array(data["correlation"]["matrix"], dtype=float).reshape(k, k)
    cov = corr * np.outer(se[identified], se[identified])
    elim = tuple(
        Eliminated(
            e["name"],
            tuple((a["name"], a["coefficient"]) for a in e["absorbed_by"]),
            e["leftover"],
            e["reason"],
        )
        for e in data["eliminated"]
    )
    ident = Identifiability(
        kept=np.flatnonzero(identified),
        eliminated=elim,
        rank=int(data["identifiability"]["rank"]),
        singular_values=np.array([]),
        names=model.names,
    )
    cfg = CalibrationConfig(**{**data["config"], "fixed": tuple(data["config"].get("fixed", ()))})
    return CalibrationResult(
        model,
        x,
        identified,
        se,
        cov,
        ident,
        tuple(data.get("fixed", ())),
        data["fit"],
        np.zeros((0, 3)),
        None,
        cfg,
    )


def _candidate_order(model: CalibrationModel, fixed: set[str]) -> list[int]:
    """Priority order for keeping parameters: base, tools, then joint-level parameters base -> flange."""
    order = [i for i, k in enumerate(model.kinds) if k == "base"]
    order += [i for i, k in enumerate(model.kinds) if k in ("tool", "tool_rot")]
    order += [i for i, k in enumerate(model.kinds) if k == "kinematic"]
    return [i for i in order if model.names[i] not in fixed]


def _resolve_fixed(names: tuple[str, ...], patterns: tuple[str, ...]) -> set[str]:
    out: set[str] = set()
    for p in patterns:
        hits = fnmatch.filter(names, p)
        if not hits:
            raise ConfigError(f"The 'fixed' calibration setting names {p!r}, which matches no parameter of {names}")
        out.update(hits)
    return out


def fit_statistics(
    r_pos: np.ndarray, cfg: CalibrationConfig, n_params: int, r_rot: np.ndarray | None = None
) -> dict[str, Any]:
    """RMS / mean / max of 3-D errors and chi² against the configured noise."""
    e = np.linalg.norm(r_pos, axis=1)
    m = r_pos.shape[0]
    M = 3 * m
    chi2 = float(np.sum(r_pos**2) / cfg.noise_mm**2)
    if r_rot is not None:
        M += 3 * m
        chi2 += float(np.sum(r_rot**2) / np.deg2rad(cfg.noise_deg) ** 2)
    dof = max(M - n_params, 1)
    out: dict[str, Any] = {
        "n_rows": int(m),
        "n_residuals": int(M),
        "n_params": int(n_params),
        "rms_position_mm": float(np.sqrt(np.mean(e**2))),
        "mean_position_mm": float(np.mean(e)),
        "max_position_mm": float(np.max(e)),
        "noise_floor_rms_mm": float(cfg.noise_mm * np.sqrt(3.0 * dof / M)) if r_rot is None else None,
        "chi2": chi2,
        "dof": int(dof),
        "reduced_chi2": chi2 / dof,
        # scipy.special's chi² functions (as scipy.stats.chi2.ppf / sf, without their ~0.1 ms of overhead each)
        "chi2_band_95": [float(special.chdtri(dof, 0.975)), float(special.chdtri(dof, 0.025))],
        "chi2_p_value": float(special.chdtrc(dof, chi2)),
    }
    out["chi2_within_band"] = bool(out["chi2_band_95"][0] <= chi2 <= out["chi2_band_95"][1])
    if r_rot is not None:
        eo = np.rad2deg(np.linalg.norm(r_rot, axis=1))
        out["rms_orientation_deg"] = float(np.sqrt(np.mean(eo**2)))
        out["mean_orientation_deg"] = float(np.mean(eo))
        out["max_orientation_deg"] = float(np.max(eo))
    return out


def calibrate(
    campaign: Campaign,
    robot: RobotDescription,
    config: CalibrationConfig | None = None,
    x0: np.ndarray | None = None,
) -> CalibrationResult:
    """Geometric calibration from the campaign's calibration rows.

    Steps: closed-form frames (registration + tool offsets) -> identifiable parameter set on the
    unit-column-scaled Jacobian -> Levenberg-Marquardt on the nonlinear model -> covariance
    ``s² (JᵀJ)⁻¹`` with ``s²`` the residual variance, correlations and chi² against the tracker noise.
    """
    cfg = config or CalibrationConfig()
    t0 = time.perf_counter()
    cal = campaign.calibration() if np.any(campaign.split == "validation") else campaign
    if cal.n_rows == 0:
        raise ConfigError(f"campaign {campaign.source} has no calibration rows")
    use_rot = (cfg.use_orientation is not False) and cal.quat is not None
    targets = present_targets(cal)
    data = fit_data(cal, use_rot, targets)
    model0 = CalibrationModel(robot, targets, orientation=False)
    T_ref, tools0 = register_frames(model0, data, cfg.registration_iters)
    tool_R_ref = None
    if use_rot:
        assert data.R_meas is not None
        Rf = fk(model0.chain, data.q)[:, :3, :3]
        tool_R_ref = np.zeros((len(targets), 3, 3))
        for k in range(len(targets)):
            sel = data.target_index == k
            Msum = np.einsum("mji,jk,mkl->il", Rf[sel], T_ref[:3, :3], data.R_meas[sel])
            U, _, Vt = np.linalg.svd(Msum)
            tool_R_ref[k] = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    model = CalibrationModel(robot, targets, orientation=use_rot, T_ref=T_ref, tool_R_ref=tool_R_ref)
    if x0 is None:
        x = model.zeros()
        x[model.n_chain : model.n_chain + 3 * len(targets)] = tools0.ravel()
    else:
        x = np.asarray(x0, dtype=float).copy()
    fixed = _resolve_fixed(model.names, tuple(cfg.fixed))
    weights = np.full(3 * data.m, 1.0 / cfg.noise_mm)
    if use_rot:
        weights = np.concatenate([weights, np.full(3 * data.m, 1.0 / np.deg2rad(cfg.noise_deg))])

    r0, J0 = model.residuals_and_jacobian(x, data)
    x_init = x.copy()

    def fun(xx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # the solver starts where the identifiability analysis has evaluated the model already (neither
        # modifies r0 or J0 in place): one evaluation of the model saved
        if np.array_equal(xx, x_init):
            return r0, J0
        return model.residuals_and_jacobian(xx, data)

    ident = analyse(J0 * weights[:, None], model.names, _candidate_order(model, fixed), rtol=cfg.rank_tol)
    free = np.sort(ident.kept)
    lm = levenberg_marquardt(fun, x, free, weights, max_iter=cfg.max_iter, ftol=cfg.ftol, xtol=cfg.xtol)
    x = lm.x
    k = len(free)
    M = len(lm.r)
    # the reduced chi² of the whitened fit scales the covariance; with no residual degree of freedom left
    # (as many identified parameters as residuals) it cannot be estimated: use the configured noise instead
    s2 = 2.0 * lm.cost / (M - k) if M > k else 1.0
    JtJ = lm.J.T @ lm.J
    try:
        cov_w = np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        cov_w = np.linalg.pinv(JtJ)
    cov = s2 * cov_w
    identified = np.zeros(model.n, dtype=bool)
    identified[free] = True
    stderr = np.full(model.n, np.nan)
    stderr[free] = np.sqrt(np.diag(cov))
    r_all = lm.r / weights
    r_pos = r_all[: 3 * data.m].reshape(-1, 3)
    r_rot = r_all[3 * data.m :].reshape(-1, 3) if use_rot else None
    fit = fit_statistics(r_pos, cfg, k, r_rot)
    fit.update(
        {
            "n_identified": k,
            "n_eliminated": len(ident.eliminated),
            "nit": lm.nit,
            "nfev": lm.nfev,
            "status": lm.status,
            "message": lm.message,
            "success": lm.success,
            "wall_time_s": time.perf_counter() - t0,
            "solver_time_s": lm.wall_time_s,
            "targets": list(targets),
            "uses_orientation": use_rot,
            "stderr_scale": "residual variance" if M > k else "configured noise (no degree of freedom left)",
        }
    )
    return CalibrationResult(
        model=model,
        x=x,
        identified=identified,
        stderr=stderr,
        covariance=cov,
        identifiability=ident,
        fixed_by_user=tuple(sorted(fixed)),
        fit=fit,
        residuals_mm=r_pos,
        residuals_deg=None if r_rot is None else np.rad2deg(r_rot),
        config=cfg,
        lm=lm,
        extra={"x_init": x_init, "residuals_before_mm": r0[: 3 * data.m].reshape(-1, 3)},
    )


def validate(result: CalibrationResult, campaign: Campaign, x: np.ndarray | None = None) -> dict[str, Any]:
    """Errors of the calibrated model on the campaign's validation rows.

    A validation target not seen in calibration takes its tool offset from its own row at all-zero
    joints when there is one (that row is then left out of the statistics); otherwise its offset is
    fitted from the validation rows with the robot fixed. The result says which.
    """
    val = campaign.validation()
    if val.n_rows == 0:
        return {"n_rows": 0}
    model = result.model
    x = result.x if x is None else x
    known = {t: k for k, t in enumerate(model.target_names)}
    T = model.base_transform(x)
    eta = x[: model.chain.n_params]
    T_fl = T @ fk(model.chain, val.q, eta)  # tracker_T_flange (m, 4, 4)
    pred = np.zeros((val.n_rows, 3))
    keep = np.ones(val.n_rows, dtype=bool)
    tool_source: dict[str, str] = {}
    tools_used: dict[str, list[float]] = {}
    for name in val.target_names:
        rows = np.flatnonzero(val.target == name)
        if name in known:
            t = model.tools(x)[known[name]]
            tool_source[name] = "calibration"
        else:
            zero = rows[np.all(np.abs(val.q[rows]) < 1e-12, axis=1)]
            if len(zero):
                r0 = zero[0]
                t = (inv_transform(T_fl[r0]) @ np.append(val.p_mm[r0], 1.0))[:3]
                keep[r0] = False
                tool_source[name] = f"zero-joint row {int(val.row_number[r0])} (left out of the statistics)"
            else:
                A = T_fl[rows, :3, :3].reshape(-1, 3)
                b = (val.p_mm[rows] - T_fl[rows, :3, 3]).reshape(-1)
                t = np.linalg.lstsq(A, b, rcond=None)[0]
                tool_source[name] = "fitted from the validation rows with the robot fixed"
        tools_used[name] = [float(v) for v in t]
        pred[rows] = T_fl[rows, :3, 3] + np.einsum("mij,j->mi", T_fl[rows, :3, :3], t)
    err = pred - val.p_mm
    e = np.linalg.norm(err[keep], axis=1)
    out: dict[str, Any] = {
        "n_rows": int(keep.sum()),
        "mean_position_mm": float(e.mean()),
        "rms_position_mm": float(np.sqrt(np.mean(e**2))),
        "max_position_mm": float(e.max()),
        "tool_source": tool_source,
        "tools_mm": tools_used,
        "errors_mm": err,
        "kept_rows": keep,
    }
    if val.quat is not None and model.orientation and all(t in known for t in val.target_names):
        _, R = model.predict(x, val.q, np.array([known[t] for t in val.target]))
        rv = matrix_to_rotvec(R @ np.swapaxes(quat_to_matrix(val.quat), -1, -2))
        eo = np.rad2deg(np.linalg.norm(rv[keep], axis=1))
        out.update(
            mean_orientation_deg=float(eo.mean()),
            max_orientation_deg=float(eo.max()),
            rms_orientation_deg=float(np.sqrt(np.mean(eo**2))),
        )
    return out


__all__ = [
    "CalibrationConfig",
    "CalibrationResult",
    "calibrate",
    "fit_data",
    "fit_statistics",
    "load_calibration",
    "register_frames",
    "validate",
]
