"""Gross measurement errors: a robust start, a stated outlier test, and the final fit on the kept rows (the
fits themselves, through the optimizer protocol, are the calibration's: :func:`robocal.calibration.screening.
irls_cauchy`, :func:`robocal.calibration.start.least_squares_on`).

A gross error (beam break, bumped reflector, a target seated in the wrong nest, a joint angle logged from the
previous move) is a whole *row* that is wrong: its 3 position residuals (and 3 orientation residuals with a
6-DoF probe) are tested together.

The rule (Pope's tau test / Baarda's data snooping generalised to row blocks, with a Bonferroni correction):

* the model is fitted by least squares on the kept rows (whitened residuals ``r``, Jacobian ``J``, ``d``
  residuals per row, ``dof = M - k``);
* a **kept** row ``i`` is tested with its externally studentised block residual
  ``F_i = [r_iᵀ (I - H_ii)⁻¹ r_i / d] / s²_(i)``, ``s²_(i) = (RSS - r_iᵀ (I - H_ii)⁻¹ r_i) / (dof - d)``
  (``H_ii`` the row's block of the hat matrix; the leave-one-row-out variance, so a blunder does not hide
  itself by inflating the scale), which is ``F(d, dof - d)``-distributed for a correct row;
* an **excluded** row is tested with its prediction residual ``F_i = [r_iᵀ (I + H̃_ii)⁻¹ r_i / d] / s²``,
  ``H̃_ii = J_i (JᵀJ)⁻¹ J_iᵀ``, ``F(d, dof)``-distributed for a correct row (so a row flagged early is let
  back in when the final model explains it);
* a row is flagged when its p-value is below ``alpha / m`` (family-wise false-flag rate ``alpha`` over the
  ``m`` rows tested).

Because least squares spreads a large blunder over its neighbours (masking, swamping), a first look uses a
robust scale (the median of the row sums of squares); when it or the exact test flags anything, the fit
restarts from an M-estimator (Cauchy loss on the row norm, by iteratively reweighted least squares), flags from
there, refits by least squares on the kept rows, and repeats the exact test until the flagged set is stable.
A clean campaign costs one extra test after the usual fit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import special

from robocal.identification.result import normal_matrix_inverse

#: Cauchy tuning constant (95 % efficiency at the normal distribution), in units of the per-component scale
CAUCHY_C = 2.385

Fun = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class RowTest:
    """The outlier test of every row: statistic, its p-value, and the threshold it was compared with."""

    F: np.ndarray  # (m,)
    p_value: np.ndarray  # (m,)
    flagged: np.ndarray  # (m,) bool
    threshold_F: float  # F above which a kept row is flagged (for the report)
    alpha: float
    d: int


def row_index(m: int, d_pos: int, with_rot: bool) -> np.ndarray:
    """Row of every residual of the layout ``[positions (3m), rotations (3m)]``."""
    idx = np.repeat(np.arange(m), d_pos)
    return np.concatenate([idx, idx]) if with_rot else idx


#: residuals per chunk of the row test (bounds its temporaries: chunk x k floats)
ROW_CHUNK = 16384
#: and bytes of a chunk's Jacobian rows: a large model's chunk is fewer rows (discovery's 1 750 columns at the
#: UR10's 12 000 rows: 4 500 residuals, 64 MB, where 16 384 residuals were 230 MB, held twice)
ROW_CHUNK_BYTES = 32 * 2**20


def row_test(
    rw: np.ndarray,
    Jw: np.ndarray | Callable[[int, int], np.ndarray],
    rows: np.ndarray,
    m: int,
    kept: np.ndarray,
    alpha: float,
    cov_w: np.ndarray | None = None,
    prior: np.ndarray | None = None,
    n_params: int | None = None,
) -> RowTest:
    """The exact test of every row at a least-squares fit on the ``kept`` rows.

    rw, Jw : whitened residuals ``(M,)`` and Jacobian on the free parameters ``(M, k)`` of *all* rows (the
    excluded ones predicted); ``Jw`` may instead be a function giving the Jacobian's rows of the measurement
    rows ``a`` to ``b`` (``((b - a) d, k)``, residuals in row order: ``rows`` sorted), evaluated a chunk at a time
    (twice: once for ``JᵀJ``, once for the leverages; the ``(M, k)`` matrix is never held, issue 31; its ``k``
    is ``n_params``); rows : (M,) the row of every residual; kept : (m,) bool; cov_w : ``(JᵀJ)⁻¹`` of the kept
    rows (computed when None); prior : ``(k,)`` precision of a prior on the parameters, added to the
    kept rows' ``JᵀJ`` when ``cov_w`` is computed (the leverages of a fit with a prior, as calibrate's; without
    it an effect determined by its prior alone leaves ``JᵀJ`` singular and the leverages round-off).
    """
    d = int(len(rw) // m)
    order = np.argsort(rows, kind="stable")
    in_order = bool(np.all(order == np.arange(len(order))))
    R = (rw if in_order else rw[order]).reshape(m, d)
    if callable(Jw):
        if not in_order or n_params is None:
            raise ValueError("row_test: a Jacobian given by row ranges needs the residuals in row order and n_params")
        jac, k = Jw, int(n_params)
    else:
        J_all, k = Jw, int(Jw.shape[1])

        def jac(a: int, b: int) -> np.ndarray:
            return np.asarray(J_all[a * d : b * d] if in_order else J_all[order[a * d : b * d]])

    # the rows in chunks of at most ROW_CHUNK residuals and ROW_CHUNK_BYTES of Jacobian (a campaign of that size
    # is one chunk): no copy of the (M, k) Jacobian (its rows in place when they are in row order), nor of its
    # kept rows, nor of its product with the covariance
    step = max(1, min(ROW_CHUNK, ROW_CHUNK_BYTES // (8 * max(k, 1))) // max(d, 1))
    chunks = [(a, min(a + step, m)) for a in range(0, m, step)]

    def block(a: int, b: int) -> np.ndarray:
        return jac(a, b).reshape(b - a, d, k)

    if cov_w is None:
        G: np.ndarray | None = None
        for a, b in chunks:
            Jb = block(a, b)
            Jk = (Jb if kept[a:b].all() else Jb[kept[a:b]]).reshape(-1, k)
            del Jb
            G = Jk.T @ Jk if G is None else G + Jk.T @ Jk
        assert G is not None  # m >= 1
        cov_w = normal_matrix_inverse(G if prior is None else G + np.diag(prior))
    H = np.empty((m, d, d))
    for a, b in chunks:
        JB = block(a, b)
        # the chunk's product with the covariance as one (rows d, k) x (k, k) product (a stacked product is one
        # small product per row: 5x slower), then each row's (d, d) block
        JC = (JB.reshape(-1, k) @ cov_w).reshape(JB.shape)
        H[a:b] = JC @ np.swapaxes(JB, 1, 2)  # (rows, d, d)
    eye = np.eye(d)
    sign = np.where(kept, -1.0, 1.0)[:, None, None]
    C = eye + sign * H
    # a kept row with H_ii -> I (a row only it determines) has no residual to test: treat as not flagged
    try:
        q = np.einsum("mi,mi->m", R, np.linalg.solve(C, R[..., None])[..., 0])
    except np.linalg.LinAlgError:
        q = np.einsum("mi,mij,mj->m", R, np.linalg.pinv(C), R)
    n_kept = int(kept.sum())
    dof = n_kept * d - k
    rss = float(np.sum(R[kept] ** 2))
    F = np.zeros(m)
    p = np.ones(m)
    if dof > d:
        s2_del = np.maximum((rss - q) / (dof - d), 1e-300)
        s2 = max(rss / dof, 1e-300)
        F = np.where(kept, (q / d) / s2_del, (q / d) / s2)
        df2 = np.where(kept, dof - d, dof)
        p = special.fdtrc(d, df2, F)
    thr = alpha / max(m, 1)
    flagged = p < thr
    thr_F = float(special.fdtri(d, max(dof - d, 1), 1.0 - thr)) if dof > d else float("inf")
    return RowTest(F=F, p_value=p, flagged=flagged, threshold_F=thr_F, alpha=alpha, d=d)


def robust_screen(rw: np.ndarray, rows: np.ndarray, m: int, alpha: float, n_params: int) -> np.ndarray:
    """A first look with a robust scale: rows whose sum of squares is beyond the Bonferroni threshold of
    ``s² F(d, dof)``, ``s²`` from the median row sum of squares. Returns the flagged mask ``(m,)``."""
    d = int(len(rw) // m)
    ss = np.bincount(rows, weights=rw**2, minlength=m)
    s2 = float(np.median(ss) / special.chdtri(d, 0.5))
    if not s2 > 0:
        return np.zeros(m, dtype=bool)
    dof = max(m * d - n_params, 1)
    thr_F = special.fdtri(d, dof, 1.0 - alpha / max(m, 1))
    return np.asarray(ss / (d * s2) > thr_F)


def outlier_line(outliers: list[dict], total: int | None = None) -> str:
    """One console line naming the flagged rows (file row, pose, target, residual), or saying there are none."""
    if not outliers:
        return "gross errors: none flagged" + (f" among {total} rows" if total else "")
    items = ", ".join(
        f"row {o['row']} (pose {o['pose_id']}, {o['target']}, {o['residual_mm']:.3f} mm)" for o in outliers
    )
    return f"gross errors: {len(outliers)} row(s) left out of the fit: {items}"
