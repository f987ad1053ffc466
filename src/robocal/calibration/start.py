"""Where every geometric fit starts (:func:`calibration_start`): the calibration rows as fit data, the closed-form
registration of the tracker frames and tools, the nominal model's best rigid fit (the "before") and the identifiable
parameters there; :data:`Solve`, the shape of the solve step that continues from it."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.config import CalibrationConfig, point_sigma
from robocal.errors import ConfigError
from robocal.identification import robust
from robocal.identification.identifiability import Identifiability, ParameterSpec, analyse
from robocal.identification.model import CalibrationModel, FitData
from robocal.identification.result import FitResult
from robocal.kinematics.chain import fk
from robocal.kinematics.transforms import kabsch, quat_to_matrix
from robocal.optimizers.least_squares import least_squares
from robocal.robot import RobotDescription

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign


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


def rigid_fit(
    model: CalibrationModel,
    data: FitData,
    x: np.ndarray,
    rigid: np.ndarray,
    weights: np.ndarray,
    rows: np.ndarray,
    kept: np.ndarray,
) -> np.ndarray:
    """Frames and tools fitted to convergence with the kinematics held as in ``x`` (nominal: the "before")."""

    def fun(xx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return model.residuals_and_jacobian(xx, data)

    # an auxiliary fit: Levenberg-Marquardt starting undamped (lam0 = 0), the fastest on this small problem
    return least_squares_on(fun, x, rigid, weights, rows, kept, max_iter=100, ftol=1e-14, xtol=1e-12, lam0=0.0).x


#: The solve step of a calibration: from a start point and the kept rows, a fit (a :class:`FitResult` over the
#: full parameter vector: point, whitened residuals and Jacobian of every row, covariance of the kept rows).
#: :func:`robocal.calibration.solve.solve_with` makes one of any registered optimizer.
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
    parameters: ParameterSpec  # the model's parameters: kinds, the fixed ones (and of them the held), priority
    kept: np.ndarray  # (m,) rows not listed in the 'outliers' setting
    rigid: np.ndarray  # indices fitted by the rigid fit (empty when started from a given x0)
    x_init: np.ndarray
    r0: np.ndarray
    J0: np.ndarray
    identifiability: Identifiability
    free: np.ndarray  # sorted identifiable indices
    t0: float  # perf_counter at the start (the fit's wall time counts from here)
    prior: Any = None  # robocal.identification.thin.Prior: rows added to the least squares (thin campaigns)
    orientation_note: str | None = None  # why the campaign's orientations were left out (orientation_mismatch)

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
    note = None
    if use_rot and cfg.use_orientation is None:  # "when the campaign has them": when they are the robot's
        assert cal.quat is not None
        note = orientation_mismatch(robot, targets, stations, T_st, tools0, cal.quat, data)
        if note:
            use_rot = False
            data = fit_data(cal, False, targets, stations)
    if use_rot:
        tool_R_ref = _tool_rotations(fk(model0.chain, data.q)[:, :3, :3], data, T_st, len(targets))
    model = CalibrationModel(
        robot, targets, orientation=use_rot, T_ref=T_ref, tool_R_ref=tool_R_ref, stations=stations, station_T_ref=T_st
    )
    m = data.m
    sig = point_sigma(cal, cfg)
    weights = np.repeat(1.0 / sig, 3)
    if use_rot:
        weights = np.concatenate([weights, np.full(3 * m, 1.0 / np.deg2rad(cfg.noise_deg))])
    rows = robust.row_index(m, 3, use_rot)
    spec = ParameterSpec.of(model, cfg.fixed, "calibration.fixed").holding(held)
    kept = _outlier_rows(cal, cfg.outliers) if isinstance(cfg.outliers, tuple) else np.ones(m, dtype=bool)

    # the nominal model's best rigid fit: frames and tools to convergence (the true "before")
    if x0 is None:
        x = model.zeros()
        x[model.n_chain : model.n_chain + 3 * len(targets)] = tools0.ravel()
        rigid = spec.indices(("base", "tool", "tool_rot"))
        x = rigid_fit(model, data, x, rigid, weights, rows, kept)
    else:
        rigid = np.zeros(0, dtype=int)
        x = np.asarray(x0, dtype=float).copy()
    r0, J0 = model.residuals_and_jacobian(x, data)
    ident = analyse(J0 * weights[:, None], model.names, spec.keep_order(), rtol=cfg.rank_tol)
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
        parameters=spec,
        kept=kept,
        rigid=rigid,
        x_init=x,
        r0=r0,
        J0=J0,
        identifiability=ident,
        free=np.sort(ident.kept),
        t0=t0,
        orientation_note=note,
    )


#: measured orientations further than this (median over the rows) from the nominal robot's, with the tracker frame
#: registered on the positions and the best constant rotation of each target, are not the robot's: a real 6-DoF
#: probe agrees to hundredths of a degree and a robot's orientation errors are tenths
ORIENTATION_MISMATCH_DEG = 5.0

#: other readings of the columns qw qx qy qz tried when the orientations do not agree, and what each means
_QUAT_READINGS = (
    ("x, y, z, w (scalar last)", [3, 0, 1, 2], 1.0, "reorder them as w, x, y, z"),
    ("their inverses", [0, 1, 2, 3], -1.0, "the tool's frame seen from the tracker's: conjugate them"),
    ("the inverses of x, y, z, w", [3, 0, 1, 2], -1.0, "reorder them as w, x, y, z and conjugate them"),
)


def _tool_rotations(Rf: np.ndarray, data: FitData, T_st: np.ndarray, n_targets: int) -> np.ndarray:
    """``(K, 3, 3)``: each target's constant rotation on the flange that best maps the flange rotations ``Rf`` in
    the station frames ``T_st`` onto the measured ones (orthogonal Procrustes)."""
    assert data.R_meas is not None and data.station_index is not None
    out = np.zeros((n_targets, 3, 3))
    for k in range(n_targets):
        sel = data.target_index == k
        Rs = T_st[:, :3, :3][data.station_index[sel]]
        # measured R = Rs Rf Rt (Rs the station's rotation, base to tracker): Rt maximises tr(Rtᵀ Σ Rfᵀ Rsᵀ R).
        # (Σ Rfᵀ Rs R before: the start's tool rotation was off by 20 deg with a tracker turned 135 deg about z,
        # which the rigid fit then had to turn back)
        U, _, Vt = np.linalg.svd(np.einsum("mji,mkj,mkl->il", Rf[sel], Rs, data.R_meas[sel]))
        out[k] = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    return out


def _rotation_misfit_deg(
    robot: RobotDescription,
    targets: tuple[str, ...],
    stations: tuple[str, ...],
    T_st: np.ndarray,
    tools0: np.ndarray,
    data: FitData,
    Rf: np.ndarray,
) -> float:
    """Median angle (deg) between the measured rotations of ``data`` and the nominal model's (``Rf``: its flange
    rotations), its frames and tool offsets the registration's and each target's best constant rotation."""
    tool_R = _tool_rotations(Rf, data, T_st, len(targets))
    model = CalibrationModel(
        robot, targets, orientation=True, T_ref=T_st[0], tool_R_ref=tool_R, stations=stations, station_T_ref=T_st
    )
    x = model.zeros()
    x[model.n_chain : model.n_chain + 3 * len(targets)] = np.asarray(tools0).ravel()
    r = model.residuals(x, data)
    return float(np.degrees(np.median(np.linalg.norm(r[3 * data.m :].reshape(-1, 3), axis=1))))


def orientation_mismatch(
    robot: RobotDescription,
    targets: tuple[str, ...],
    stations: tuple[str, ...],
    T_st: np.ndarray,
    tools0: np.ndarray,
    quat: np.ndarray,
    data: FitData,
) -> str | None:
    """Why the campaign's orientations (``quat (m, 4)`` as w, x, y, z; ``data`` the fit data with them) cannot be
    the robot's, or None: further than :data:`ORIENTATION_MISMATCH_DEG` from the nominal robot's with the
    tracker frames ``T_st`` registered on the positions. Names the other reading of the columns that agrees, if
    one does (scalar last, the inverse rotation): such quaternions made the fit 10 mm worse than its start, with
    no word on orientation, where the positions alone fit to 0.025 mm."""
    Rf = fk(CalibrationModel(robot, targets, orientation=False, stations=stations).chain, data.q)[:, :3, :3]
    a0 = _rotation_misfit_deg(robot, targets, stations, T_st, tools0, data, Rf)
    if a0 <= ORIENTATION_MISMATCH_DEG:
        return None
    text = (
        f"the measured orientations (qw qx qy qz) are {a0:.0f} deg from the robot's (median, with the tracker frame "
        "from the positions and the best constant rotation of each target): left out, the fit uses the positions"
    )
    for name, order, sign, what in _QUAT_READINGS:
        alt = quat[:, order] * np.array([1.0, sign, sign, sign])
        alt_data = replace(data, R_meas=quat_to_matrix(alt))
        a = _rotation_misfit_deg(robot, targets, stations, T_st, tools0, alt_data, Rf)
        if a <= ORIENTATION_MISMATCH_DEG:
            return f"{text}. Read as {name} they agree to {a:.2g} deg: {what}"
    return f"{text}. Check the quaternion convention (w, x, y, z; the tool's rotation in the tracker's frame)"


def least_squares_on(
    fun: robust.Fun,
    x0: np.ndarray,
    free: np.ndarray,
    weights: np.ndarray,
    rows: np.ndarray,
    kept: np.ndarray,
    **kw: Any,
) -> FitResult:
    """Least squares with the excluded rows' residuals weighted zero: χ², covariance and ``ndata`` are the
    kept rows'; the returned ``residual`` and ``jacobian`` hold every row (whitened by ``weights``, the
    excluded ones as predictions) and ``outliers`` lists the excluded rows."""
    if kept.all():
        return least_squares(fun, x0, free, weights, **kw)
    w_kept = weights * kept[rows]
    lm = least_squares(fun, x0, free, w_kept, **kw)
    r, J = fun(lm.x)
    return lm.evolve(
        residual=weights * r, jacobian=weights[:, None] * J[:, free], outliers=tuple(np.flatnonzero(~kept))
    )
