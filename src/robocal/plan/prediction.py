"""A design's predictions: Cramér-Rao standard errors ``σ²(JᵀWJ)⁻¹``, the predicted error over the validation
region and the number of poses needed for a stated accuracy.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.plan.design import criterion_value, exchange, information, observability
from robocal.plan.problem import Problem


def predict(problem: Problem, idx: np.ndarray, rng: np.random.Generator | None = None) -> dict[str, Any]:
    """Cramér-Rao predictions for the design ``idx``: criteria, indices, standard errors, the region's errors.

    ``region_rms_mm`` is the predicted RMS 3-D position error of the calibrated model over the region (the
    square root of the I-criterion); ``region_mean_measured_mm`` adds the tracker noise, i.e. what a
    held-out measurement is expected to show on average (E|e|, e ~ N(0, Σ_v + σ²I), by sampling).
    """
    pr = problem
    M = information(pr.F, idx)
    out: dict[str, Any] = {
        "D_logdet": -criterion_value(M, "D"),
        "A_trace": criterion_value(M, "A"),
        "I_mean_var_mm2": criterion_value(M, "I", pr.L),
    }
    rows = pr.F[idx].reshape(-1, pr.p)
    rows = rows[np.any(rows != 0.0, axis=1)]
    out["observability"] = observability(rows)
    out["n_rows"] = int(rows.shape[0])
    if not np.isfinite(out["A_trace"]):
        return out
    cov_s = np.linalg.inv(M)
    cov = cov_s * np.outer(pr.scale, pr.scale)
    se = np.sqrt(np.diag(cov))
    se_disp = np.where(np.array(pr.units) == "deg", np.rad2deg(se), se)
    out["stderr"] = {n: float(v) for n, v in zip(pr.names, se_disp, strict=True)}
    Sv = np.einsum("vip,pq,vjq->vij", pr.G, cov_s, pr.G)  # (V, 3, 3) mm²
    var = np.trace(Sv, axis1=1, axis2=2)
    out["region_sigma_mm"] = np.sqrt(var)
    out["region_rms_mm"] = float(np.sqrt(var.mean()))
    out["region_max_mm"] = float(np.sqrt(var.max()))
    if rng is not None:
        z = rng.standard_normal((256, 3))
        Ch = np.linalg.cholesky(Sv + (problem.config.noise_mm**2) * np.eye(3))
        e = np.linalg.norm(np.einsum("vij,sj->vsi", Ch, z), axis=-1)
        out["region_mean_measured_mm"] = float(e.mean())
    return out


def _curve_grid(n: int, n_min: int, n_cand: int) -> list[int]:
    hi = min(max(4 * n, 120), n_cand)
    grid = np.unique(np.round(np.geomspace(n_min, hi, 10)).astype(int))
    return sorted({int(v) for v in grid if n_min <= v <= n_cand} | ({n} if n <= n_cand else set()))


def region_rms(problem: Problem, idx: np.ndarray) -> float | None:
    """Predicted RMS 3-D error of the calibrated model over the region (mm), or None when M is singular."""
    M = information(problem.F, idx)
    s, _ = np.linalg.slogdet(M)
    if s <= 0:
        return None
    try:
        cov_s = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return None
    v = float(np.sum(cov_s * problem.L))
    return float(np.sqrt(v)) if v > 0 else None


def poses_needed_curve(
    problem: Problem, idx: np.ndarray, rng: np.random.Generator, n_sub: int = 5000, n_random: int = 5
) -> list[dict[str, Any]]:
    """Predicted RMS error over the region against the number of poses, planned and random.

    Each size is planned by the same exchange and criterion, warm-started from the previous size, over a
    random subset of ``n_sub`` accepted candidates plus the plan (so the curve is quick; with fewer choices
    it can only be slightly pessimistic). Random: the median of ``n_random`` draws from all accepted candidates.
    """
    pr = problem
    cfg = pr.config
    C = pr.cand.n
    sub = np.unique(np.concatenate([rng.choice(C, size=min(n_sub, C), replace=False), idx]))
    Fs = pr.F[sub]
    n = len(idx)
    rows = []
    prev = np.searchsorted(sub, idx)
    for N in _curve_grid(n, pr.n_min, len(sub)):  # a size is planned over the subset: at most its size
        if N == n:
            e_idx = idx
            prev = np.searchsorted(sub, idx)
        else:
            init = prev[:N] if len(prev) >= N else prev
            e = exchange(
                Fs, N, cfg.criterion, rng, L=pr.L, init=init, max_exchanges=cfg.max_exchanges, active_set=cfg.active_set
            )
            prev = e.idx
            e_idx = sub[e.idx]
        rr = [region_rms(pr, np.sort(rng.choice(C, size=N, replace=False))) for _ in range(n_random)]
        rr_ok = [r for r in rr if r is not None]
        rows.append(
            {
                "n_poses": N,
                "planned_region_rms_mm": region_rms(pr, e_idx),
                "random_region_rms_mm": float(np.median(rr_ok)) if rr_ok else None,
                "random_singular": n_random - len(rr_ok),
            }
        )
    return rows
