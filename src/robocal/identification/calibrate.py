"""The geometric calibration's steps: registration, identifiability, the solve step (given by the caller: a
registered optimizer through the protocol, :mod:`robocal.optimizers.geometric`), gross errors, statistics,
validation."""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import special, stats

from robocal.config import parse, setting
from robocal.errors import ConfigError
from robocal.identification import misfit
from robocal.identification.identifiability import Eliminated, Identifiability, analyse, keep_order, resolve_fixed
from robocal.identification.model import CalibrationModel, FitData
from robocal.identification.solver import FitResult
from robocal.kinematics.chain import fk
from robocal.kinematics.transforms import (
    inv_transform,
    kabsch,
    quat_to_matrix,
    rpy_from_matrix,
)
from robocal.metrics import ErrorStats, noise_floor, orientation_errors_deg, rotvec_errors_deg
from robocal.robot import MDH, RobotDescription

if TYPE_CHECKING:
    from robocal.data.contract import Campaign


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
        core :mod:`robocal.identification.solver`).
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


def fit_data(
    campaign: Campaign,
    use_orientation: bool = True,
    targets: tuple[str, ...] | None = None,
    stations: tuple[str, ...] | None = None,
) -> FitData:
    """Arrays for fitting; ``target_index`` refers to ``targets`` (default: the campaign's target names),
    ``station_index`` to ``stations`` (default: the campaign's stations)."""
    R = quat_to_matrix(campaign.quat) if (use_orientation and campaign.quat is not None) else None
    if targets is None:
        ti = campaign.target_index
    else:
        lookup = {t: k for k, t in enumerate(targets)}
        ti = np.array([lookup[str(t)] for t in campaign.target], dtype=int)
    st_names = campaign.station_names if stations is None else stations
    slook = {t: k for k, t in enumerate(st_names)}
    assert campaign.station is not None
    si = np.array([slook[str(t)] for t in campaign.station], dtype=int)
    return FitData(q=campaign.q, p_mm=campaign.p_mm, target_index=ti, R_meas=R, station_index=si)


def present_targets(campaign: Campaign) -> tuple[str, ...]:
    """Targets that occur in the campaign's rows, in the campaign's order."""
    seen = set(map(str, campaign.target))
    return tuple(t for t in campaign.target_names if t in seen)


def present_stations(campaign: Campaign) -> tuple[str, ...]:
    """Tracker stations that occur in the campaign's rows, in order of appearance."""
    return campaign.station_names


def register_frames(
    model: CalibrationModel, data: FitData, iters: int = 20, tool_init: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form initial ``tracker_T_base`` and tool offsets from the nominal kinematics.

    Alternates Kabsch registration of the nominal target points onto the measurements (one per tracker
    station) with a linear least-squares solve for each target's flange offset. Returns
    ``(T (4, 4), tools (K, 3))``, or ``(T (S, 4, 4), tools)`` when the model has ``S > 1`` stations.
    """
    T_flange = fk(model.chain, data.q)
    Rf, of = T_flange[:, :3, :3], T_flange[:, :3, 3]
    K = len(model.target_names)
    tools = np.zeros((K, 3)) if tool_init is None else np.array(tool_init, dtype=float).reshape(K, 3)
    groups = data.station_rows(model.n_stations)
    S = len(groups)
    T = np.tile(np.eye(4), (S, 1, 1))
    for _ in range(max(1, iters)):
        pts = of + np.einsum("mij,mj->mi", Rf, tools[data.target_index])
        T_new = T.copy()
        p_base = np.zeros_like(data.p_mm)
        for s, idx in enumerate(groups):
            if len(idx) >= 3:
                T_new[s] = kabsch(pts[idx], data.p_mm[idx])
            # measured points in the base frame, then solve Rf t = p_base - of per target in least squares:
            # the Rf are rotations (Rfᵀ Rf = I), so the normal equations give the mean of Rfᵀ (p_base - of)
            p_base[idx] = (data.p_mm[idx] - T_new[s, :3, 3]) @ T_new[s, :3, :3]
        local = np.einsum("mji,mj->mi", Rf, p_base - of)
        sums = np.zeros((K, 3))
        np.add.at(sums, data.target_index, local)
        counts = np.bincount(data.target_index, minlength=K)
        new_tools = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], tools)
        change = np.abs(new_tools - tools).max() + np.abs(T_new - T).max()
        tools, T = new_tools, T_new
        if change < 1e-4:  # mm / unitless: Levenberg-Marquardt refines from here
            break
    return (T[0] if S == 1 else T), tools


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

    Immutable (derive a changed one with :func:`dataclasses.replace`); ``solver`` is the least-squares core's
    :class:`~robocal.identification.result.FitResult` (χ², covariance, status, timings of the fit itself);
    ``start`` where the fit started and which rows it kept (None for a calibration read from a file);
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
    statistics: dict[str, Any]  # the fit record without the solver's figures (see :attr:`fit`)
    residuals_mm: np.ndarray  # (m, 3)
    residuals_deg: np.ndarray | None
    config: CalibrationConfig
    solver: FitResult | None = None
    start: FitStart | None = None
    effects: tuple[dict[str, Any], ...] = ()

    @property
    def fit(self) -> dict[str, Any]:
        """The fit record (``calibration.json`` ``fit``, a new dict): :attr:`statistics` with the solver's
        figures read from :attr:`solver` (:func:`solver_figures`: after ``n_eliminated`` the iterations,
        evaluations and stopping status, after ``wall_time_s`` the solver's own time); the statistics alone
        when there is no solver (a calibration read from a file keeps its figures there)."""
        if self.solver is None:
            return dict(self.statistics)
        out: dict[str, Any] = {}
        figures = solver_figures(self.solver)
        for key, v in self.statistics.items():
            out[key] = v
            if key == "n_eliminated":
                out.update({k: figures[k] for k in ("nit", "nfev", "status", "message", "success")})
            elif key == "wall_time_s":
                out["solver_time_s"] = figures["solver_time_s"]
        return out

    def with_statistics(self, **changes: Any) -> CalibrationResult:
        """A copy with ``changes`` to the statistics (e.g. ``poorly_determined``)."""
        return replace(self, statistics={**self.statistics, **changes})

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


def correlation_of(covariance: np.ndarray) -> np.ndarray:
    """The correlation matrix of a covariance (a zero variance reads as 1: its row and column stay 0)."""
    d = np.sqrt(np.diag(covariance))
    d[d == 0] = 1.0
    return covariance / np.outer(d, d)


def parameter_table(
    model: CalibrationModel, x: np.ndarray, stderr: np.ndarray, identified: np.ndarray, fixed: tuple[str, ...]
) -> list[dict[str, Any]]:
    """One row per parameter of ``model``: value and standard error in display units (mm, deg) and status
    (identified, fixed by the user, or eliminated)."""
    rows = []
    for k, name in enumerate(model.names):
        unit = model.units[k]
        f = np.rad2deg(1.0) if unit == "rad" else 1.0
        rows.append(
            {
                "name": name,
                "kind": model.kinds[k],
                "unit": "deg" if unit == "rad" else unit,
                "value": float(x[k] * f),
                "stderr": float(stderr[k] * f) if identified[k] else None,
                "status": "identified" if identified[k] else ("fixed" if name in fixed else "eliminated"),
            }
        )
    return rows


def calibration_record(
    model: CalibrationModel,
    x: np.ndarray,
    identified: np.ndarray,
    stderr: np.ndarray,
    covariance: np.ndarray,
    identifiability: Identifiability,
    fixed: tuple[str, ...],
    fit: Mapping[str, Any],
    config: CalibrationConfig,
) -> dict[str, Any]:
    """The ``calibration.json`` record of a calibration given by its parts (what :func:`load_calibration`
    reads back): :meth:`CalibrationResult.to_dict`, and any model that writes the geometric format (the
    discovered model's geometry) without being a fitted :class:`CalibrationResult`.

    x : (n,) every parameter of ``model``; identified : (n,) bool; stderr : (n,) NaN where not identified;
    covariance : (k, k) over the identified ones; fixed : parameters fixed by the user; fit : the fit record
    (``fit`` of the file); config : the settings recorded under ``config``."""
    T = model.base_transform(x)
    idx = np.flatnonzero(identified)
    names = model.names
    elim = identifiability.eliminated
    return {
        "robot": model.robot.name,
        "convention": model.robot.convention,
        "nominal": nominal_record(model.robot),
        "parameters": parameter_table(model, x, stderr, identified, fixed),
        "kinematic_errors": {n: float(x[k]) for k, n in enumerate(model.chain.param_names)},
        "eliminated": [e.to_dict() for e in elim],
        "fixed": list(fixed),
        "tracker_T_base": T.tolist(),
        "tracker_T_base_xyz_mm": T[:3, 3].tolist(),
        "tracker_T_base_rpy_deg": np.rad2deg(rpy_from_matrix(T[:3, :3])).tolist(),
        "tools_mm": {name: t.tolist() for name, t in zip(model.target_names, model.tools(x), strict=True)},
        "tool_rotations": {k: R.tolist() for k, R in zip(model.target_names, model.tool_rotations(x), strict=True)},
        "stations": list(model.station_names),
        "stations_T_base": {s: model.base_transform(x, k).tolist() for k, s in enumerate(model.station_names)},
        "station_T_ref": model.station_T_ref.tolist(),
        "T_ref": model.T_ref.tolist(),
        "tool_R_ref": model.tool_R_ref.tolist(),
        "orientation": model.orientation,
        "x": x.tolist(),
        "names": list(names),
        "correlation": {
            "names": [names[i] for i in idx],
            "matrix": correlation_of(covariance).tolist(),
        },
        "identifiability": {
            "rank": identifiability.rank,
            "n_candidates": int(len(identifiability.kept) + len(elim)),
            "condition_number": identifiability.condition_number,
        },
        "fit": fit,
        "config": {
            k: getattr(config, k)
            for k, f in config.__dataclass_fields__.items()
            if k not in WRITTEN_WHEN_SET or getattr(config, k) != f.default
        },
    }


#: tolerance of the nominal-table comparison (mm and deg): calibration.json keeps 9 significant digits
NOMINAL_TOL = 1e-6


def nominal_record(robot: RobotDescription) -> dict[str, Any]:
    """The robot's nominal kinematics as ``calibration.json`` records them (``nominal``), so that a calibration
    is never applied to another robot (:func:`check_robot`): the joint names and the MD-H table (mm, deg) or
    the POE twists and flange pose at zero."""
    out: dict[str, Any] = {
        "convention": robot.convention,
        "n_joints": robot.n_joints,
        "joints": list(robot.joint_names),
    }
    if robot.is_mdh:
        out["mdh"] = {
            "a_mm": robot.a_mm.tolist(),
            "alpha_deg": np.rad2deg(robot.alpha).tolist(),
            "d_mm": robot.d_mm.tolist(),
            "theta_offset_deg": np.rad2deg(robot.theta_offset).tolist(),
            "beta_deg": np.rad2deg(robot.beta).tolist(),
        }
    else:
        assert robot.poe_w is not None and robot.poe_p_mm is not None and robot.poe_flange0 is not None
        out["poe"] = {"w": robot.poe_w.tolist(), "p_mm": robot.poe_p_mm.tolist(), "flange0": robot.poe_flange0.tolist()}
    return out


def check_robot(data: dict[str, Any], robot: RobotDescription, where: str = "the calibration") -> None:
    """Refuse a calibration made for another robot: its recorded robot name, joint count and (when recorded)
    nominal table must be ``robot``'s. The error names both robots."""
    theirs = data.get("robot")
    rec = data.get("nominal")
    n_theirs = rec.get("n_joints") if isinstance(rec, dict) else None
    if n_theirs is None and data.get("convention") == MDH and isinstance(data.get("names"), list):
        # older files (no nominal record): one MD-H theta<i> per joint
        n_theirs = sum(1 for n in data["names"] if re.fullmatch(r"theta\d+", str(n)))
    problems = []
    if theirs is not None and str(theirs) != robot.name:
        problems.append(f"it names robot {theirs!r}")
    if n_theirs is not None and int(n_theirs) != robot.n_joints:
        problems.append(f"it has {int(n_theirs)} joints, {robot.name!r} has {robot.n_joints}")
    if isinstance(rec, dict):
        mine = nominal_record(robot)
        if rec.get("convention") != mine["convention"]:
            problems.append(f"its convention is {rec.get('convention')!r}, {robot.name!r} uses {mine['convention']!r}")
        elif rec.get("n_joints") == mine["n_joints"]:
            section = "mdh" if robot.is_mdh else "poe"
            for key, ours in mine[section].items():
                a = np.asarray((rec.get(section) or {}).get(key), dtype=float)
                b = np.asarray(ours, dtype=float)
                if a.shape != b.shape or not np.allclose(a, b, rtol=NOMINAL_TOL, atol=NOMINAL_TOL):
                    if a.shape == b.shape and a.ndim == 1:
                        j = int(np.argmax(np.abs(a - b)))
                        problems.append(f"its nominal {key} of joint {j + 1} is {a[j]:g}, {robot.name!r} has {b[j]:g}")
                    else:
                        problems.append(f"its nominal {section} {key} differs from {robot.name!r}'s")
                    break
    if problems == [f"it names robot {theirs!r}"] and isinstance(rec, dict):
        problems.append("(the nominal tables agree: if it is the same robot, name the description it was made with)")
    if problems:
        raise ConfigError(
            f"{where} was made for robot {theirs!r}, not for {robot.name!r} ({robot.source or 'given'}): "
            f"{'; '.join(problems)}. Use the robot the calibration was made with."
        )


def load_calibration(data: dict[str, Any], robot: RobotDescription) -> CalibrationResult:
    """Rebuild a :class:`CalibrationResult` (enough to predict and compensate) from :meth:`to_dict` output.

    A calibration written by discovery also carries joint-level ``effects`` (:attr:`CalibrationResult.effects`)
    and, when it freed a Hayati beta, the robot's ``beta_free``. A calibration of another robot (name, joint count,
    nominal table: :func:`check_robot`) is refused."""
    check_robot(data, robot)
    if "beta_free" in data:
        bf = np.array(data["beta_free"], dtype=bool)
        if bf.shape != np.shape(robot.beta_free):
            raise ConfigError(f"calibration 'beta_free' has {bf.shape[0]} joints; robot {robot.name!r} has another")
        robot = replace(robot, beta_free=bf)
    stations = tuple(data.get("stations") or ())
    model = CalibrationModel(
        robot,
        tuple(data["tools_mm"].keys()),
        orientation=bool(data.get("orientation", False)),
        T_ref=np.array(data["T_ref"]),
        tool_R_ref=np.array(data["tool_R_ref"]),
        stations=stations,
        station_T_ref=np.array(data["station_T_ref"]) if "station_T_ref" in data else None,
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
    cfg_d = {k: v for k, v in data["config"].items() if k in CalibrationConfig.__dataclass_fields__}
    cfg_d["fixed"] = tuple(cfg_d.get("fixed", ()))
    if isinstance(cfg_d.get("outliers"), list):
        cfg_d["outliers"] = tuple(cfg_d["outliers"])
    cfg = CalibrationConfig(**cfg_d)
    return CalibrationResult(
        model,
        x,
        identified,
        se,
        cov,
        ident,
        tuple(data.get("fixed", ())),
        dict(data["fit"]),
        np.zeros((0, 3)),
        None,
        cfg,
        effects=tuple(data.get("effects") or ()),
    )


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


def _outlier_rows(cal: Campaign, rows_listed: tuple[int, ...]) -> np.ndarray:
    """The kept mask for an explicit list of file rows (each must be a calibration row of the campaign)."""
    present = {int(r): i for i, r in enumerate(cal.row_number)}
    missing = [r for r in rows_listed if r not in present]
    if missing:
        raise ConfigError(
            f"The 'outliers' calibration setting lists row(s) {missing} of {cal.poses_file}, which are not "
            "calibration rows of the campaign"
        )
    kept = np.ones(cal.n_rows, dtype=bool)
    kept[[present[r] for r in rows_listed]] = False
    return kept


def describe_outliers(
    cal: Campaign,
    flagged: np.ndarray,
    r_pos: np.ndarray,
    r_rot: np.ndarray | None,
    test: Any,
    listed: bool = False,
) -> list[dict[str, Any]]:
    """One object per flagged row: file row, pose, target, station, residual and why it was flagged."""
    out = []
    for i in np.flatnonzero(flagged):
        o: dict[str, Any] = {
            "row": int(cal.row_number[i]),
            "pose_id": str(cal.pose_id[i]),
            "target": str(cal.target[i]),
            "station": str(cal.station[i]) if cal.station is not None else None,
            "residual_mm": round(float(np.linalg.norm(r_pos[i])), 6),
            "residual_xyz_mm": [round(float(v), 6) for v in r_pos[i]],
        }
        if r_rot is not None:
            o["residual_deg"] = round(float(np.rad2deg(np.linalg.norm(r_rot[i]))), 6)
        if listed:
            o["reason"] = "listed in the 'outliers' calibration setting"
        else:
            o["F"] = round(float(test.F[i]), 3)
            o["p_value"] = float(f"{test.p_value[i]:.3g}")
            o["reason"] = (
                f"studentised row residual F = {test.F[i]:.4g} > {test.threshold_F:.4g} "
                f"(p = {test.p_value[i]:.2g} < {test.alpha:g}/{len(flagged)} rows, Bonferroni)"
            )
        out.append(o)
    return out


def _split_resid(r: np.ndarray, m: int, use_rot: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Unwhitened residuals ``[positions (3m), rotations (3m)]`` as ``(m, 3)`` positions and rotations."""
    return r[: 3 * m].reshape(-1, 3), (r[3 * m :].reshape(-1, 3) if use_rot else None)


def _rigid_fit(
    model: CalibrationModel,
    data: FitData,
    x: np.ndarray,
    rigid: np.ndarray,
    weights: np.ndarray,
    rows: np.ndarray,
    kept: np.ndarray,
) -> np.ndarray:
    """Frames and tools fitted to convergence with the kinematics held as in ``x`` (nominal: the "before")."""
    from robocal.identification import robust

    def fun(xx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return model.residuals_and_jacobian(xx, data)

    # an auxiliary fit: Levenberg-Marquardt starting undamped (lam0 = 0), the fastest on this small problem
    return robust.least_squares_on(fun, x, rigid, weights, rows, kept, max_iter=100, ftol=1e-14, xtol=1e-12, lam0=0.0).x


#: The solve step of a calibration: from a start point and the kept rows, a fit (a :class:`FitResult` over the
#: full parameter vector: point, whitened residuals and Jacobian of every row, covariance of the kept rows).
#: :func:`robocal.optimizers.geometric.solve_with` makes one of any registered optimizer.
Solve = Callable[["CalibrationStart", np.ndarray, np.ndarray], FitResult]


@dataclass(frozen=True, eq=False)
class CalibrationStart:
    """Where every geometric fit starts (:func:`calibration_start`): the calibration rows as fit data, the
    model with its reference frames, the noise weights, the nominal model's best rigid fit ``x_init`` (its
    residuals ``r0`` and Jacobian ``J0``) and the identifiable (free) parameters analysed there."""

    campaign: Campaign  # the calibration rows
    config: CalibrationConfig
    model: CalibrationModel
    data: FitData
    targets: tuple[str, ...]  # present in the rows, the model's target order
    stations: tuple[str, ...]
    use_rot: bool
    sigma_mm: np.ndarray  # (m,) per point (point_sigma)
    weights: np.ndarray  # (M,) 1 / sigma per residual
    rows: np.ndarray  # (M,) row of every residual
    fixed: frozenset[str]
    held: frozenset[str]  # of ``fixed``: held because the data do not determine them (poorly determined)
    kept: np.ndarray  # (m,) rows not listed in the 'outliers' setting
    rigid: np.ndarray  # indices fitted by the rigid fit (empty when started from a given x0)
    x_init: np.ndarray
    r0: np.ndarray
    J0: np.ndarray
    identifiability: Identifiability
    free: np.ndarray  # sorted identifiable indices
    t0: float  # perf_counter at the start (the fit's wall time counts from here)
    prior: Any = None  # robocal.identification.thin.Prior: rows added to the least squares (thin campaigns)

    @property
    def m(self) -> int:
        return self.data.m

    def fun(self, xx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and Jacobian of the model at ``xx``; at ``x_init`` the ones the start evaluated already
        (neither the solvers nor the tests modify them in place: one evaluation of the model saved)."""
        if np.array_equal(xx, self.x_init):
            return self.r0, self.J0
        return self.model.residuals_and_jacobian(xx, self.data)


def calibration_start(
    campaign: Campaign,
    robot: RobotDescription,
    config: CalibrationConfig,
    x0: np.ndarray | None = None,
    held: tuple[str, ...] = (),
) -> CalibrationStart:
    """Closed-form frames (registration + tool offsets, one frame per tracker station) -> the nominal model's
    best rigid fit (frames and tools fitted to convergence with the nominal kinematics: the "before" figures;
    skipped when ``x0`` is given) -> the identifiable parameter set on the unit-column-scaled Jacobian there."""
    from robocal.identification import robust

    cfg = config
    t0 = time.perf_counter()
    cal = campaign.calibration() if np.any(campaign.split == "validation") else campaign
    if cal.n_rows == 0:
        raise ConfigError(f"campaign {campaign.source} has no calibration rows")
    use_rot = (cfg.use_orientation is not False) and cal.quat is not None
    targets = present_targets(cal)
    stations = present_stations(cal)
    data = fit_data(cal, use_rot, targets, stations)
    model0 = CalibrationModel(robot, targets, orientation=False, stations=stations)
    T_reg, tools0 = register_frames(model0, data, cfg.registration_iters)
    T_st = T_reg.reshape(-1, 4, 4)
    T_ref = T_st[0]
    tool_R_ref = None
    if use_rot:
        assert data.R_meas is not None and data.station_index is not None
        Rf = fk(model0.chain, data.q)[:, :3, :3]
        tool_R_ref = np.zeros((len(targets), 3, 3))
        for k in range(len(targets)):
            sel = data.target_index == k
            Rs = T_st[:, :3, :3][data.station_index[sel]]
            Msum = np.einsum("mji,mjk,mkl->il", Rf[sel], Rs, data.R_meas[sel])
            U, _, Vt = np.linalg.svd(Msum)
            tool_R_ref[k] = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    model = CalibrationModel(
        robot, targets, orientation=use_rot, T_ref=T_ref, tool_R_ref=tool_R_ref, stations=stations, station_T_ref=T_st
    )
    m = data.m
    sig = point_sigma(cal, cfg)
    weights = np.repeat(1.0 / sig, 3)
    if use_rot:
        weights = np.concatenate([weights, np.full(3 * m, 1.0 / np.deg2rad(cfg.noise_deg))])
    rows = robust.row_index(m, 3, use_rot)
    fixed = resolve_fixed(model.names, tuple(cfg.fixed), "calibration.fixed") | set(held)
    kept = _outlier_rows(cal, cfg.outliers) if isinstance(cfg.outliers, tuple) else np.ones(m, dtype=bool)

    # the nominal model's best rigid fit: frames and tools to convergence (the true "before")
    if x0 is None:
        x = model.zeros()
        x[model.n_chain : model.n_chain + 3 * len(targets)] = tools0.ravel()
        rigid = np.array([i for i, k in enumerate(model.kinds) if k in ("base", "tool", "tool_rot")])
        rigid = np.array([i for i in rigid if model.names[i] not in fixed], dtype=int)
        x = _rigid_fit(model, data, x, rigid, weights, rows, kept)
    else:
        rigid = np.zeros(0, dtype=int)
        x = np.asarray(x0, dtype=float).copy()
    r0, J0 = model.residuals_and_jacobian(x, data)
    ident = analyse(J0 * weights[:, None], model.names, keep_order(model.kinds, model.names, fixed), rtol=cfg.rank_tol)
    return CalibrationStart(
        campaign=cal,
        config=cfg,
        model=model,
        data=data,
        targets=targets,
        stations=stations,
        use_rot=use_rot,
        sigma_mm=sig,
        weights=weights,
        rows=rows,
        fixed=frozenset(fixed),
        held=frozenset(held),
        kept=kept,
        rigid=rigid,
        x_init=x,
        r0=r0,
        J0=J0,
        identifiability=ident,
        free=np.sort(ident.kept),
        t0=t0,
    )


@dataclass(frozen=True, eq=False)
class Screened:
    """The fit after the gross-error rule: the final solve, the kept rows, the row test and what it reported."""

    fit: FitResult
    kept: np.ndarray
    test: Any  # robust.RowTest | None
    suspects: list[dict[str, Any]]
    rounds: int
    systematic: list[dict[str, Any]] = field(default_factory=list)  # identification.misfit records


def _posterior(lm: FitResult) -> np.ndarray | None:
    """``(JᵀJ + Λ)⁻¹`` of a fit with a prior (the row test's leverages with the prior), None without one."""
    v = lm.extra.get("posterior_normal_inverse")
    return None if v is None else np.asarray(v)


def screen_outliers(start: CalibrationStart, lm: FitResult, solve: Solve) -> Screened:
    """Gross errors found and left out by the rule of :mod:`robocal.identification.robust` (``outliers:
    auto``): a row test at the fit; when a row stands out, a robust start (Cauchy IRLS), then ``solve`` on the
    kept rows and the exact test until the flagged set is stable; more flagged rows than gross errors can be
    (``outlier_max_share``) are a model error: every row kept, the rows reported as suspects. Flagged rows that
    share a condition (:mod:`robocal.identification.misfit`) are a systematic misfit: kept, and named."""
    from robocal.identification import robust

    cfg, m, kept = start.config, start.m, start.kept
    test = None
    rounds = 0
    suspects: list[dict[str, Any]] = []
    systematic: list[dict[str, Any]] = []
    if cfg.outliers != "auto":
        return Screened(lm, kept, test, suspects, rounds)
    free, weights, rows, fun = start.free, start.weights, start.rows, start.fun
    test = robust.row_test(lm.residual, lm.jacobian, rows, m, kept, cfg.outlier_alpha, _posterior(lm))
    screen = robust.robust_screen(lm.residual, rows, m, cfg.outlier_alpha, len(free))
    if test.flagged.any() or screen.any():
        # masking and swamping: restart from an M-estimate, flag from there, then iterate the exact test
        x_rob = robust.irls_cauchy(fun, start.x_init, free, weights, rows, m)
        r_rob, _ = fun(x_rob)
        kept = ~robust.robust_screen(weights * r_rob, rows, m, cfg.outlier_alpha, len(free))
        for rounds in range(1, 8):  # noqa: B007 (reported)
            lm = solve(start, x_rob, kept)
            test = robust.row_test(lm.residual, lm.jacobian, rows, m, kept, cfg.outlier_alpha, _posterior(lm))
            if np.array_equal(~test.flagged, kept):
                break
            kept = ~test.flagged
        else:  # no fixed point in 7 rounds: the last flagged set, fitted and tested once more
            lm = solve(start, x_rob, kept)
            test = robust.row_test(lm.residual, lm.jacobian, rows, m, kept, cfg.outlier_alpha, _posterior(lm))
        if (~kept).sum() >= misfit.MIN_ROWS:
            # rows that misfit together under one condition: one systematic misfit, kept in the fit
            r_pos, _ = _split_resid(lm.residual / weights, m, start.use_rot)
            e2 = np.sum(r_pos**2, axis=1)
            scale = float(np.sqrt(np.median(e2[kept]) / stats.chi2.ppf(0.5, 3)))
            systematic, explained = misfit.find(start.campaign, ~kept, r_pos, scale, cfg.outlier_alpha)
            if explained.any():
                kept = kept | explained
                lm = solve(start, x_rob, kept)
                test = robust.row_test(lm.residual, lm.jacobian, rows, m, kept, cfg.outlier_alpha, _posterior(lm))
                test = robust.RowTest(test.F, test.p_value, ~kept, test.threshold_F, test.alpha, test.d)
        if (~kept).sum() > cfg.outlier_max_share * m:
            # too many to be blunders: a systematic model error; keep every row and say so
            suspects = describe_outliers(
                start.campaign, ~kept, *_split_resid(lm.residual / weights, m, start.use_rot), test
            )
            kept = np.ones(m, dtype=bool)
            lm = solve(start, start.x_init, kept)
            test = robust.row_test(lm.residual, lm.jacobian, rows, m, kept, cfg.outlier_alpha, _posterior(lm))
            test = robust.RowTest(test.F, test.p_value, np.zeros(m, dtype=bool), test.threshold_F, test.alpha, test.d)
    return Screened(lm, kept, test, suspects, rounds, systematic)


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
        x_init = _rigid_fit(model, data, x_init, start.rigid, weights, rows, kept)
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
    fit.update(
        {
            "n_identified": k,
            "n_eliminated": len(ident.eliminated),
            "wall_time_s": time.perf_counter() - start.t0,
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
        fixed_by_user=tuple(sorted(start.fixed - start.held)),
        statistics=fit,
        residuals_mm=r_pos,
        residuals_deg=None if r_rot is None else np.rad2deg(r_rot),
        config=cfg,
        solver=lm,
        start=FitStart(x_init, x_analysis, before_pos, kept, test),
    )


def fit_from(start: CalibrationStart, solve: Solve) -> CalibrationResult:
    """solve (from ``x_init`` on the rows not listed as outliers) -> outliers -> statistics. ``solve`` is the
    caller's: :func:`robocal.optimizers.geometric.solve_with` runs a registered optimizer through the protocol."""
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
    :func:`robocal.optimizers.geometric.calibrate` (``robocal.calibrate``), which gives the solve of any registered
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
        if not clear_only or prior is not None:
            design["prior"] = rec
    if prior is not None:
        res = fit_from(replace(start, prior=prior), solve)
    if design["thin"] or not design["enough"] or prior is not None:
        res = res.with_statistics(configurations=design)
    return res, prior


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


@dataclass(frozen=True, eq=False)
class Validation(Mapping[str, Any]):
    """Errors of a model on a campaign's validation rows (:func:`validate_rows`, :func:`validate`).

    stats : over the rows evaluated (``stats.n`` of them; the registration rows of a station or a target not
    seen in calibration are left out); errors_mm : (m, 3) prediction - measurement of every validation row;
    kept_rows : (m,) the rows evaluated; tool_source / tools_mm / station_source : where each target's tool
    offset and each station's frame came from (``station_source`` None when every station is the calibration's).

    Read as a mapping it is the record ``robocal.validate`` has always returned (``v["mean_position_mm"]``,
    ``v["errors_mm"]`` ...; :meth:`to_dict`); :meth:`record` is that record without the arrays (summary.json).
    """

    stats: ErrorStats
    errors_mm: np.ndarray | None = None
    kept_rows: np.ndarray | None = None
    tool_source: dict[str, str] = field(default_factory=dict)
    tools_mm: dict[str, list[float]] = field(default_factory=dict)
    station_source: dict[str, str] | None = None

    @classmethod
    def none(cls) -> Validation:
        """No validation rows."""
        return cls(ErrorStats.of(np.zeros(0)))

    @property
    def n_rows(self) -> int:
        return self.stats.n

    def to_dict(self) -> dict[str, Any]:
        """The record (keys and order as the files have them; ``{"n_rows": 0}`` without validation rows)."""
        if self.errors_mm is None:
            return {"n_rows": 0}
        out: dict[str, Any] = {
            "n_rows": self.n_rows,
            **self.stats.position(),
            "tool_source": self.tool_source,
            "tools_mm": self.tools_mm,
            "errors_mm": self.errors_mm,
            "kept_rows": self.kept_rows,
        }
        if self.station_source is not None:
            out["station_source"] = self.station_source
        out.update(self.stats.orientation(("mean", "max", "rms")))
        return out

    def record(self) -> dict[str, Any]:
        """:meth:`to_dict` without the per-row arrays (``errors_mm``, ``kept_rows``)."""
        return {k: v for k, v in self.to_dict().items() if k not in ("errors_mm", "kept_rows")}

    def __getitem__(self, key: str) -> Any:
        return self.to_dict()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.to_dict())

    def __len__(self) -> int:
        return len(self.to_dict())


def validate(result: CalibrationResult, campaign: Campaign, x: np.ndarray | None = None) -> Validation:
    """Errors of the calibrated model on the campaign's validation rows (see :func:`validate_rows`)."""
    val = campaign.validation()
    if val.n_rows == 0:
        return Validation.none()
    model = result.model
    x = result.x if x is None else x
    eta = x[: model.chain.n_params]
    base_T_flange = fk(model.chain, val.q, eta)
    stations = {s: model.base_transform(x, k) for k, s in enumerate(model.station_names)}
    tools = {t: model.tools(x)[k] for k, t in enumerate(model.target_names)}
    tool_R = None
    if model.orientation:
        tool_R = {t: R for t, R in zip(model.target_names, model.tool_rotations(x), strict=True)}
    return validate_rows(val, base_T_flange, stations, tools, tool_R)


def validate_rows(
    val: Campaign,
    base_T_flange: np.ndarray,
    stations: dict[str, np.ndarray],
    tools: dict[str, np.ndarray],
    tool_R: dict[str, np.ndarray] | None = None,
    dp_mm: np.ndarray | None = None,
) -> Validation:
    """Errors of a model's predictions on validation rows, with the tool and station handling every caller
    shares (geometric calibration and discovery alike).

    base_T_flange : (m, 4, 4) the model's flange pose of every validation row in the robot base frame;
    stations : {station: tracker_T_base} of the calibration; tools : {target: (3,) flange offset};
    tool_R : {target: (3, 3)} with orientation data, else None; dp_mm : (m, 3) a displacement the model adds
    to each predicted point (tracker frame; e.g. a parameter drift modelled to first order), or None.

    A validation station the calibration never saw is registered (rigidly, Kabsch) on every other pose of its
    rows (the 1st, 3rd, ... in file order) and evaluated on the others; those registration rows are left out
    of the statistics. A validation target not seen in calibration takes its tool offset from its own row at
    all-zero joints when there is one (that row is then left out of the statistics); otherwise its offset is
    fitted from the validation rows with the robot fixed. The result says which.
    """
    m = val.n_rows
    keep = np.ones(m, dtype=bool)
    assert val.station is not None
    T_st = np.zeros((m, 4, 4))
    station_source: dict[str, str] = {}
    for s in val.station_names:
        rows = np.flatnonzero(val.station == s)
        if s in stations:
            T_st[rows] = stations[s]
            station_source[s] = "calibration"
            continue
        poses = list(dict.fromkeys(val.pose_id[rows].tolist()))
        reg_poses = set(poses[::2])
        known_rows = rows[np.isin(val.target[rows], list(tools))]
        reg = known_rows[np.isin(val.pose_id[known_rows], list(reg_poses))]
        if len(reg) < 3 or len(poses) < 4:
            raise ConfigError(
                f"validation station {s!r} of {val.poses_file} was not measured in calibration and has too few "
                f"rows of calibrated targets ({len(reg)} for registration, {len(poses)} poses; need >= 3 and >= 4) "
                "to register it on half of its poses"
            )
        pts = np.stack([base_T_flange[i, :3, 3] + base_T_flange[i, :3, :3] @ tools[str(val.target[i])] for i in reg])
        T_st[rows] = kabsch(pts, val.p_mm[reg])
        keep[rows[np.isin(val.pose_id[rows], list(reg_poses))]] = False
        station_source[s] = (
            f"not in calibration: registered on {len(reg_poses)} of its {len(poses)} poses (every other pose in "
            "file order), evaluated on the others"
        )
    T_fl = T_st @ base_T_flange  # tracker_T_flange (m, 4, 4)
    pred = np.zeros((m, 3))
    tool_source: dict[str, str] = {}
    tools_used: dict[str, list[float]] = {}
    for name in val.target_names:
        rows = np.flatnonzero(val.target == name)
        if name in tools:
            t = np.asarray(tools[name], dtype=float)
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
    if dp_mm is not None:
        pred = pred + dp_mm
    err = pred - val.p_mm
    if not keep.any():
        raise ConfigError(f"no validation row of {val.poses_file} is left to evaluate after registration")
    eo = None
    if val.quat is not None and tool_R is not None and all(t in tools for t in val.target_names):
        R = T_fl[:, :3, :3] @ np.stack([tool_R[str(t)] for t in val.target])
        eo = orientation_errors_deg(R[keep], quat_to_matrix(val.quat[keep]))
    shown = len(station_source) > 1 or any(v != "calibration" for v in station_source.values())
    return Validation(
        ErrorStats.of(err[keep], eo), err, keep, tool_source, tools_used, station_source if shown else None
    )


__all__ = [
    "CalibrationConfig",
    "CalibrationResult",
    "FitStart",
    "Validation",
    "calibrate_with",
    "fit_data",
    "fit_statistics",
    "load_calibration",
    "register_frames",
    "validate",
    "validate_rows",
]
