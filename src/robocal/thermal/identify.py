"""Thermal parameter errors at each temperature state (Guo et al. 2026, section 2.3, eq. 18-21).

A warm-up campaign measures one pose set several times: cold (the reference state, where the geometric
calibration holds) and then at later temperature states. For every state ``s`` the drift of each measured
target relative to the reference, ``dP = [p_s - p_0, log(R_s R_0^T)]`` (eq. 18), is stacked over the pose set
and solved for the parameter drift ``d_eta_s`` with the Jacobian ``M`` of the calibrated model at the reference
(eq. 19) by the SVD pseudo-inverse (eq. 20-21), on a set of parameters the pose set can identify.

Because every state is differenced with the same reference measurement, the errors of the ``d_eta_s`` are
correlated: ``Cov(d_eta_s) = 2 V``, ``Cov(d_eta_s, d_eta_r) = V`` with ``V = sigma² (M^T M)^-1`` (whitened);
the regression uses that structure.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.calibration.start import fit_data
from robocal.errors import ConfigError, DataError
from robocal.identification.identifiability import Identifiability, analyse
from robocal.kinematics.transforms import matrix_to_rotvec, quat_to_matrix
from robocal.metrics import ErrorStats

if TYPE_CHECKING:
    from robocal.data.campaign import Campaign


def find_states(campaign: Campaign, gap_s: float = 600.0) -> np.ndarray:
    """Temperature state number per row ``(m,)``: rows in time order, a new state after a pause longer than
    ``gap_s`` or when a (pose_id, target) pair repeats. States are numbered 0, 1, ... in time order."""
    order = np.argsort(campaign.timestamp_s, kind="stable")
    state = np.zeros(campaign.n_rows, dtype=int)
    k = 0
    seen: set[tuple[str, str]] = set()
    last = None
    for i in order:
        key = (str(campaign.pose_id[i]), str(campaign.target[i]))
        t = float(campaign.timestamp_s[i])
        if last is not None and (t - last > gap_s or key in seen):
            k += 1
            seen = set()
        seen.add(key)
        state[i] = k
        last = t
    return state


@dataclass
class StateDrift:
    """Identified parameter drift of every temperature state of one warm-up.

    names : (k,) identified chain parameters; param_index : (k,) their index in the chain;
    t_min : (S,) state time (minutes after the reference state's first row); temperatures : (S, s) mean sensor
    readings of each state; sensor_names : (s,); deta : (S, k) drift (mm / rad; row 0 = reference = 0);
    V : (k, k) the per-state covariance unit (``Cov(d_eta_s) = 2 V``); sigma_scale : residual RMS of the
    whitened drift fit / sqrt(2) (about 1 when the tracker noise is as configured); n_pairs : (S,) pose/target
    pairs matched with the reference; residual_rms_mm : (S,) position misfit after the fit;
    drift_rms_mm : (S,) RMS position drift before the fit; identifiability : of the stacked Jacobian.
    """

    names: tuple[str, ...]
    param_index: np.ndarray
    t_min: np.ndarray
    temperatures: np.ndarray
    sensor_names: tuple[str, ...]
    deta: np.ndarray
    V: np.ndarray
    sigma_scale: float
    n_pairs: np.ndarray
    residual_rms_mm: np.ndarray
    drift_rms_mm: np.ndarray
    identifiability: Identifiability
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def stderr(self) -> np.ndarray:
        """(k,) standard error of each state's drift (sqrt of the diagonal of ``2 V``)."""
        return np.sqrt(2.0 * np.diag(self.V))

    def to_dict(self) -> dict[str, Any]:
        return {
            "names": list(self.names),
            "t_min": self.t_min.tolist(),
            "sensors": list(self.sensor_names),
            "temperatures_C": self.temperatures.tolist(),
            "deta": self.deta.tolist(),
            "stderr": self.stderr.tolist(),
            "sigma_scale": self.sigma_scale,
            "n_pairs": self.n_pairs.tolist(),
            "residual_rms_mm": self.residual_rms_mm.tolist(),
            "drift_rms_mm": self.drift_rms_mm.tolist(),
            "eliminated": [e.to_dict() for e in self.identifiability.eliminated],
        }


def _match(ref: Campaign, cur: Campaign) -> tuple[np.ndarray, np.ndarray]:
    """Row indices (into ``ref`` and ``cur``) of the (pose_id, target) pairs measured in both."""
    lookup = {(str(p), str(t)): i for i, (p, t) in enumerate(zip(ref.pose_id, ref.target, strict=True))}
    ia, ib = [], []
    for j, (p, t) in enumerate(zip(cur.pose_id, cur.target, strict=True)):
        i = lookup.get((str(p), str(t)))
        if i is not None:
            ia.append(i)
            ib.append(j)
    return np.array(ia, dtype=int), np.array(ib, dtype=int)


def reference_jacobian(
    result: CalibrationResult, ref: Campaign, use_orientation: bool
) -> tuple[np.ndarray, np.ndarray, int]:
    """Jacobian of the calibrated model's predictions w.r.t. the chain parameters at the reference rows.

    Returns ``(J (M, P), weights (M,), m)``: rows are positions ``[x1, y1, z1, ...]`` then (with orientation)
    rotation vectors, weights ``1/noise`` per row.
    """
    model = result.model
    data = fit_data(ref, use_orientation and model.orientation, model.target_names)
    _, J = model.residuals_and_jacobian(result.x, data)
    P = model.chain.n_params
    cfg = result.config
    w = np.full(J.shape[0], 1.0 / cfg.noise_mm)
    if J.shape[0] > 3 * data.m:
        w[3 * data.m :] = 1.0 / np.deg2rad(cfg.noise_deg)
    return J[:, :P], w, data.m


def identify_states(
    campaign: Campaign,
    state: np.ndarray,
    result: CalibrationResult,
    params: Sequence[str] | None = None,
    rank_tol: float = 1e-3,
    rcond: float = 1e-10,
    use_orientation: bool = True,
) -> StateDrift:
    """Parameter drift of every state of ``campaign`` (one warm-up) relative to its state 0.

    Parameters
    ----------
    campaign : the rows of one warm-up, with temperatures.
    state : (m,) int state numbers (:func:`find_states`); state 0 is the reference.
    result : the geometric calibration at the reference state (its Jacobian is ``M`` of eq. 19).
    params : chain parameters to solve for (default all); those the pose set cannot separate are dropped
        (pivoted QR in chain order, ``rank_tol``) and listed in ``identifiability.eliminated``.
    rcond : singular values below ``rcond`` times the largest are treated as zero in the pseudo-inverse (eq. 21).
    """
    if campaign.temperatures is None:
        raise DataError("the campaign has no temperatures (temperatures.csv)", file=campaign.source)
    model = result.model
    chain = model.chain
    P = chain.n_params
    names_all = chain.param_names
    cand = list(range(P)) if params is None else _candidate_params(names_all, params)
    n_states = int(state.max()) + 1
    ref = campaign.subset(state == 0)
    use_rot = bool(use_orientation and model.orientation and campaign.quat is not None)
    J, w, m0 = reference_jacobian(result, ref, use_rot)
    Jw = J * w[:, None]
    ident = analyse(Jw, names_all, cand, rtol=rank_tol)
    kept = np.sort(ident.kept)
    k = len(kept)
    if k == 0:
        raise DataError("no thermal parameter is identifiable from the reference pose set", file=campaign.source)
    R_ref = quat_to_matrix(ref.quat) if use_rot and ref.quat is not None else None

    deta = np.zeros((n_states, k))
    temps = np.zeros((n_states, len(campaign.sensor_names)))
    t_min = np.zeros(n_states)
    n_pairs = np.zeros(n_states, dtype=int)
    res_rms = np.zeros(n_states)
    drift_rms = np.zeros(n_states)
    rss, dof = 0.0, 0
    Vw_sum = np.zeros((k, k))
    t_start = float(ref.timestamp_s.min())
    for s in range(n_states):
        cur = campaign.subset(state == s)
        temps[s] = cur.temperatures.mean(axis=0)  # type: ignore[union-attr]
        t_min[s] = (float(cur.timestamp_s.min()) - t_start) / 60.0
        ia, ib = _match(ref, cur)
        n_pairs[s] = len(ia)
        if s == 0:
            continue
        if len(ia) * (6 if use_rot else 3) < 2 * k:
            raise DataError(
                f"temperature state {s} (t = {t_min[s]:.0f} min) shares only {len(ia)} pose/target pairs with the "
                f"reference state; {k} parameters need at least {int(np.ceil(2 * k / (6 if use_rot else 3)))}",
                file=campaign.source,
            )
        r_idx, dy, dp = _differences(ref, cur, ia, ib, m0, R_ref if use_rot else None)
        Y = dy * w[r_idx]
        M = Jw[np.ix_(r_idx, kept)]
        deta[s], Vw = _truncated_solve(M, Y, rcond)
        r = Y - M @ deta[s]
        rss += float(r @ r)
        dof += len(Y) - k
        Vw_sum += Vw
        npos = 3 * len(ia)
        res_rms[s] = ErrorStats.of((r[:npos] / w[r_idx[:npos]]).reshape(-1, 3)).rms_mm
        drift_rms[s] = ErrorStats.of(dp.reshape(-1, 3)).rms_mm
    # whitened residual variance is 2 sigma_w² (two noisy measurements per difference)
    s2 = rss / max(dof, 1) / 2.0
    V = s2 * Vw_sum / max(n_states - 1, 1)
    names = tuple(names_all[i] for i in kept)
    return StateDrift(
        names=names,
        param_index=kept,
        t_min=t_min,
        temperatures=temps,
        sensor_names=tuple(campaign.sensor_names),
        deta=deta,
        V=V,
        sigma_scale=float(np.sqrt(s2)),
        n_pairs=n_pairs,
        residual_rms_mm=res_rms,
        drift_rms_mm=drift_rms,
        identifiability=ident,
        extra={"uses_orientation": use_rot},
    )


def _candidate_params(names_all: Sequence[str], params: Sequence[str]) -> list[int]:
    """Indices (chain order) of the chain parameters ``params``; a ConfigError names unknown ones."""
    unknown = [p for p in params if p not in names_all]
    if unknown:
        raise ConfigError(f"thermal identification: unknown chain parameter(s) {unknown}; known: {names_all}")
    return [names_all.index(p) for p in names_all if p in set(params)]


def _differences(
    ref: Campaign, cur: Campaign, ia: np.ndarray, ib: np.ndarray, m0: int, R_ref: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The measured change from the reference rows ``ia`` to the current rows ``ib``: the reference Jacobian's
    rows it belongs to, the change (positions mm, then with ``R_ref`` rotation vectors rad) and the position
    change alone."""
    rows_p = (3 * ia[:, None] + np.arange(3)[None, :]).ravel()
    dp = (cur.p_mm[ib] - ref.p_mm[ia]).ravel()
    rows = [rows_p]
    dy = [dp]
    if R_ref is not None:
        assert cur.quat is not None
        R_cur = quat_to_matrix(cur.quat[ib])
        dr = matrix_to_rotvec(R_cur @ np.swapaxes(R_ref[ia], -1, -2)).ravel()
        rows.append(3 * m0 + rows_p)
        dy.append(dr)
    return np.concatenate(rows), np.concatenate(dy), dp


def _truncated_solve(M: np.ndarray, Y: np.ndarray, rcond: float) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 20-21: the least-squares solution of ``M x = Y`` on unit-norm columns (mm and rad compare), singular
    values below ``rcond`` times the largest dropped; and its unscaled covariance ``(MᵀM)⁺`` (whitened units)."""
    cn = np.linalg.norm(M, axis=0)
    U, S, Vt = np.linalg.svd(M / cn, full_matrices=False)
    inv = np.where(S > rcond * S[0], 1.0 / S, 0.0)
    sol = (Vt.T * inv) @ (U.T @ Y)
    return sol / cn, ((Vt.T * inv**2) @ Vt) / np.outer(cn, cn)


__all__ = ["StateDrift", "find_states", "identify_states", "reference_jacobian"]
