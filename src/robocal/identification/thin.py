"""Thin campaigns: how many joint configurations a model needs, and a prior toward the nominal robot when there
are few.

A calibration is determined by its *configurations* (distinct joint vectors), not by its rows: several targets
measured at one configuration all follow the one flange pose. :func:`design_of` counts them and the equations
they give (3 per target point, 6 per 6-DoF row, at most 6 per configuration: one configuration fixes at most
the flange's pose) and compares them with the parameters the model has. The parameter count is the model's own,
not the data's (on thin data the rank test keeps as many parameters as there are equations): the rank of the
model's Jacobian at :data:`SPREAD_CONFIGURATIONS` joint configurations drawn uniformly in 90 % of the joint
ranges (a fixed seed), with the campaign's targets and stations. The record (``fit.configurations``) says:

* ``needed``: the fewest configurations that give more equations than parameters (at this campaign's
  equations per configuration). Fewer, and the data cannot determine the model: the calibration fails;
* ``thin_below``: the configurations that give ``thin_ratio`` (2) equations per parameter. Fewer, and the
  fit follows the noise of the few poses (its held-out error is far above its fit RMS): with ``prior: auto``
  the identification is regularised (below).

The prior (:func:`choose_prior`) is a Gaussian one toward the nominal description, written as extra residual
rows of the calibration's least squares (:class:`Prior`, added by
:class:`robocal.calibration.problem.WhitenedResiduals`): ``sqrt(lambda) (p - p0) / width`` for each free
joint-level parameter (``width`` = ``prior_mm`` for lengths, ``prior_deg`` for angles; ``p0`` nominal) and
``(p - p0) / width`` for the tracker frames and tools (``prior_frame_mm``, ``prior_frame_deg``, ``p0`` the
nominal model's best rigid fit: a weak bound that does not take part in the strength's choice). With the
residuals whitened by the tracker noise, ``lambda = 1`` is the prior of the stated widths; the strength
``lambda`` is chosen by leave-one-configuration-out cross-validation (:func:`cross_validate`: every
configuration's rows predicted by a fit on the others, linearised at the start, the mean 3-D error over all
held-out rows) among :data:`STRENGTHS` and 0 by the one-standard-error rule (the strongest prior whose CV
error is within one standard error of the smallest: with few configurations the CV curve is flat within its
noise, and the rule takes the most regular model the data cannot tell from the best; on the twin's thin
scenario it beats the plain minimum, benchmarks/thin_campaigns.py). The standard errors are then the posterior's,
``s² (JᵀJ + Λ)⁻¹`` with ``s²`` the residual variance over the effective degrees of freedom.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from robocal.identification.identifiability import analyse
from robocal.identification.model import FitData

#: a :class:`robocal.calibration.start.CalibrationStart` (not imported: calibrate imports this module)
CalibrationStart = Any

__all__ = [
    "SPREAD_CONFIGURATIONS",
    "STRENGTHS",
    "CrossValidation",
    "Prior",
    "choose_prior",
    "configuration_groups",
    "cross_validate",
    "design_of",
    "model_parameters",
]

#: joint configurations of the spread design that counts the model's parameters (:func:`model_parameters`):
#: twice as many flange poses as a 6-axis robot with a few targets has parameters, so the rank is the model's
SPREAD_CONFIGURATIONS = 60
#: joint configurations closer than this (deg, every joint) are one configuration (a pose measured again: IPA's
#: UR10 series B measures 293 of its 1 495 rows at a configuration it measured before under another pose id, within
#: 0.006 deg, the next-closest configurations more than 1 deg apart); 0.05 deg moves a 1 m arm's tool by < 1 mm
SAME_CONFIGURATION_DEG = 0.05
#: the prior strengths the cross-validation compares (and 0, no prior): 1 is the prior of the stated widths
STRENGTHS = tuple(float(v) for v in 10.0 ** np.arange(-3.0, 5.01, 0.25))
#: most equations one configuration gives: one flange pose (3 positions, 3 rotations)
POSE_EQUATIONS = 6


def configuration_groups(q: np.ndarray, tol_deg: float = SAME_CONFIGURATION_DEG) -> tuple[int, np.ndarray]:
    """The distinct joint configurations of ``q`` (m, n) rad: their number and each row's group (m,). Rows whose
    joints are all within ``tol_deg`` of each other's (in a chain) are one configuration; groups are numbered in
    the order of their smallest joint vector (lexicographic, as :func:`numpy.unique` orders them)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    q = np.asarray(q, dtype=float)
    if len(q) == 0:
        return 0, np.zeros(0, dtype=int)
    _, exact = np.unique(q, axis=0, return_inverse=True)  # identical rows first, numbered in lexicographic order
    exact = np.asarray(exact).reshape(-1)
    pairs = cKDTree(q).query_pairs(float(np.deg2rad(tol_deg)), p=np.inf, output_type="ndarray")
    k = int(exact.max()) + 1
    a, b = np.concatenate([exact, exact[pairs[:, 0]]]), np.concatenate([exact, exact[pairs[:, 1]]])
    _, comp = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(k, k)), directed=False)
    # a merged configuration takes the place of its first member: the numbering is the exact one without merges
    _, group = np.unique(comp, return_inverse=True)
    first = np.full(int(group.max()) + 1, k)
    np.minimum.at(first, group, np.arange(k))
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return len(order), rank[group][exact]


def model_parameters(start: CalibrationStart) -> int:
    """The parameters the calibration model has: the rank of its Jacobian (the calibration's rank test,
    the same candidates and ``rank_tol``) at :data:`SPREAD_CONFIGURATIONS` configurations drawn uniformly in
    90 % of the joint ranges (seed 0; six per station when the stations are many), every target measured at each,
    the stations taken in turn."""
    model, cfg = start.model, start.config
    robot = model.robot
    rng = np.random.default_rng(0)
    lim = np.asarray(robot.q_limits, dtype=float)
    mid, half = lim.mean(axis=1), (lim[:, 1] - lim[:, 0]) / 2 * 0.9
    # at least 6 configurations for every station (each registers on its own points: 35 placements of a column
    # robot shared 60, and the count fell to 177 where the campaign's own fit identified 232)
    n, K = max(SPREAD_CONFIGURATIONS, 6 * model.n_stations), len(model.target_names)
    q = np.repeat(rng.uniform(mid - half, mid + half, size=(n, robot.n_joints)), K, axis=0)
    ti = np.tile(np.arange(K), n)
    si = (np.arange(n * K) // K) % model.n_stations
    x = start.x_init
    p, R = model.predict(x, q, ti)
    data = FitData(q=q, p_mm=p, target_index=ti, R_meas=R if model.orientation else None, station_index=si)
    _, J = model.residuals_and_jacobian(x, data)
    w = np.full(3 * n * K, 1.0 / cfg.noise_mm)
    if model.orientation:
        w = np.concatenate([w, np.full(3 * n * K, 1.0 / np.deg2rad(cfg.noise_deg))])
    order = start.parameters.keep_order()
    ident = analyse(J * w[:, None], model.names, order, rtol=cfg.rank_tol)
    return len(ident.kept)


def design_of(start: CalibrationStart) -> dict[str, Any]:
    """The campaign's configurations against the model's parameters (module doc): the ``configurations``
    record of the fit, without the prior's part."""
    data, kept, cfg = start.data, start.kept, start.config
    n_cfg, group = configuration_groups(data.q[kept])
    per_row = 6 if start.use_rot else 3
    eq_rows = np.bincount(group, minlength=n_cfg) * per_row
    eq = np.minimum(eq_rows, POSE_EQUATIONS)
    n_eq = int(eq.sum())
    k = model_parameters(start)
    e = n_eq / n_cfg if n_cfg else float(POSE_EQUATIONS)
    needed = math.floor(k / e) + 1
    thin_below = math.ceil(cfg.thin_ratio * k / e)
    sparse_below = math.ceil(cfg.sparse_ratio * k / e)
    return {
        "n": n_cfg,
        "n_rows": int(kept.sum()),
        "equations": n_eq,
        "equations_rule": (
            f"{per_row} per {'6-DoF row' if start.use_rot else 'target point'} and at most {POSE_EQUATIONS} per "
            "configuration, which fixes one flange pose"
        ),
        "model_parameters": k,
        "model_parameters_rule": (
            f"rank of the model's Jacobian at {max(SPREAD_CONFIGURATIONS, 6 * start.model.n_stations)} configurations "
            "spread over 90 % of the joint ranges, with the campaign's targets and stations (six per station at least)"
        ),
        "needed": needed,
        "thin_below": thin_below,
        "enough": bool(n_cfg >= needed),
        "thin": bool(n_cfg < thin_below),
        "sparse": bool(n_cfg < sparse_below),
    }


@dataclass(frozen=True, eq=False)
class Prior:
    """The prior's rows ``inv_width (x - x_init)`` over the model's parameters (n,): ``sqrt(strength) / width``
    for the joint-level ones, ``1 / frame width`` for frames and tools, 0 where there is no prior (module doc).
    ``record`` is what the fit record says of it."""

    inv_width: np.ndarray
    strength: float
    record: dict[str, Any]

    def rows(self, free: np.ndarray) -> np.ndarray:
        """The prior's weights of the free parameters (k,): rows ``w (z - z_init)``, Jacobian ``diag(w)``."""
        return self.inv_width[free]


def widths(start: CalibrationStart) -> tuple[np.ndarray, np.ndarray]:
    """The prior widths of every parameter in its unit (mm, rad) and whether it is joint-level (its strength
    is chosen by the cross-validation) or a frame / tool (a fixed weak prior)."""
    cfg, model = start.config, start.model
    joint = np.array([k == "kinematic" for k in model.kinds])
    mm = np.array([u == "mm" for u in model.units])
    w = np.where(
        joint,
        np.where(mm, cfg.prior_mm, np.deg2rad(cfg.prior_deg)),
        np.where(mm, cfg.prior_frame_mm, np.deg2rad(cfg.prior_frame_deg)),
    )
    return w.astype(float), joint


def make_prior(start: CalibrationStart, strength: float, record: dict[str, Any]) -> Prior:
    """The :class:`Prior` of ``strength`` with the settings' widths."""
    w, joint = widths(start)
    inv = np.where(joint, math.sqrt(strength), 1.0) / w
    return Prior(inv, float(strength), record)


@dataclass(frozen=True)
class CrossValidation:
    """Leave-one-configuration-out errors: ``strengths`` (s,) and the mean 3-D error (mm) of the held-out rows
    at each (``mean_mm`` (s,), standard error ``se_mm``), at no prior (``without_mm``, ``without_se_mm``), the
    folds and held-out rows."""

    strengths: np.ndarray
    mean_mm: np.ndarray
    without_mm: float
    folds: int
    rows: int
    se_mm: np.ndarray  # (s,) standard error of each mean (over the held-out rows)
    without_se_mm: float
    diff_se_mm: np.ndarray  # (s,) standard error of the mean paired difference (prior - none) over the rows

    @property
    def best(self) -> int:
        return int(np.argmin(self.mean_mm))

    def one_se(self) -> int:
        """The strongest prior whose CV error is within one standard error of the smallest (no prior included):
        the one-standard-error rule; -1 when none is (no prior)."""
        j = self.best
        if self.without_mm <= self.mean_mm[j]:
            limit = self.without_mm + self.without_se_mm
        else:
            limit = self.mean_mm[j] + self.se_mm[j]
        ok = np.flatnonzero(self.mean_mm <= limit)
        return int(ok.max()) if ok.size else -1

    def clear(self, n_se: float = 2.0) -> int:
        """The prior of the smallest CV error when it beats no prior by more than ``n_se`` standard errors of the
        paired difference (the same held-out rows); -1 otherwise (no prior)."""
        j = self.best
        gain = self.without_mm - float(self.mean_mm[j])
        return j if gain > n_se * float(self.diff_se_mm[j]) else -1


def cross_validate(start: CalibrationStart, strengths: tuple[float, ...] = STRENGTHS) -> CrossValidation:
    """Leave-one-configuration-out CV of the linearised fit at the start (module doc)."""
    free, data, kept = start.free, start.data, start.kept
    m = data.m
    n_cfg, grp = configuration_groups(data.q)
    group = np.where(kept, grp, -1)
    w = start.weights
    A_all = w[:, None] * start.J0[:, free]
    b_all = w * start.r0
    res_group = group[start.rows]
    wp, joint = widths(start)
    wf, jf = wp[free], joint[free]
    frame_diag = np.where(jf, 0.0, 1.0 / wf**2)
    joint_diag = np.where(jf, 1.0 / wf**2, 0.0)
    pos = np.arange(3 * m).reshape(m, 3)  # the position residuals of every row
    J_pos = start.J0[:, free][: 3 * m]
    r_pos = start.r0[: 3 * m]
    lams = (0.0, *strengths)
    errs: list[list[np.ndarray]] = [[] for _ in lams]
    folds = 0
    used = res_group >= 0
    N_all, g_all = A_all[used].T @ A_all[used], A_all[used].T @ b_all[used]
    for g in range(n_cfg):
        held = np.flatnonzero(group == g)
        out = res_group == g
        if held.size == 0 or not (used & ~out).any():
            continue
        folds += 1
        # the normal equations of the other configurations: all of them less this one's
        N, gvec = N_all - A_all[out].T @ A_all[out], g_all - A_all[out].T @ b_all[out]
        for i, lam in enumerate(lams):
            H = N + np.diag(frame_diag + lam * joint_diag)
            try:
                dz = -np.linalg.solve(H, gvec)
            except np.linalg.LinAlgError:
                dz = -np.linalg.lstsq(H, gvec, rcond=None)[0]
            idx = pos[held].reshape(-1)
            e = (r_pos[idx] + J_pos[idx] @ dz).reshape(-1, 3)
            errs[i].append(np.linalg.norm(e, axis=1))
    flat = [np.concatenate(e) if e else np.full(1, np.nan) for e in errs]
    means = np.array([float(np.mean(e)) for e in flat])
    n_rows = int(flat[0].size)
    root = np.sqrt(n_rows)
    se = np.array([float(np.std(e, ddof=1) / root) if n_rows > 1 else np.inf for e in flat])
    dse = np.array([float(np.std(e - flat[0], ddof=1) / root) if n_rows > 1 else np.inf for e in flat[1:]])
    return CrossValidation(np.array(strengths), means[1:], float(means[0]), folds, n_rows, se[1:], float(se[0]), dse)


def _mm(v: float) -> float:
    """A CV error as written (mm, 4 significant digits: it is an estimate from a few folds)."""
    return float(f"{v:.4g}")


def choose_prior(start: CalibrationStart, why: str, clear_only: bool = False) -> tuple[Prior | None, dict[str, Any]]:
    """The prior of a thin campaign (``why`` says why) with the strength the
    cross-validation picks (``prior: auto``) or the configured one (a number), and the record of what was done
    (``fit.configurations.prior``); no prior when the CV prefers none, or has fewer than 3 folds. ``clear_only``
    (a campaign that is not thin but has few configurations): the prior of the smallest CV error, and only when
    it beats none by more than two standard errors of the paired difference (:meth:`CrossValidation.clear`)."""
    cfg = start.config
    fixed = None if cfg.prior == "auto" else float(cfg.prior)
    cv = cross_validate(start, STRENGTHS if fixed is None else (fixed,))
    record: dict[str, Any] = {"why": why}
    if cv.folds < 3:
        record["strength"] = 0.0
        record["strength_rule"] = f"no prior: {cv.folds} configuration(s) are too few to cross-validate (3 needed)"
        return None, record
    i = (cv.clear() if clear_only else cv.one_se()) if fixed is None else 0
    strength = float(cv.strengths[i])
    chosen = float(cv.mean_mm[i])
    on = fixed is not None or i >= 0
    record.update(
        {
            "strength": float(f"{strength:.4g}") if on else 0.0,
            "strength_rule": (
                "the 'prior' setting"
                if fixed is not None
                else "chosen by leave-one-configuration-out cross-validation: the smallest CV error, more than two "
                "standard errors of the paired difference below no prior's"
                if on and clear_only
                else "chosen by leave-one-configuration-out cross-validation: the strongest within one standard "
                "error of the smallest CV error"
                if on
                else "no prior: leave-one-configuration-out cross-validation (one-standard-error rule) prefers none"
            ),
            "widths": {
                "length_mm": cfg.prior_mm,
                "angle_deg": cfg.prior_deg,
                "frame_mm": cfg.prior_frame_mm,
                "frame_deg": cfg.prior_frame_deg,
            },
            "center": "nominal joint-level parameters; frames and tools at the nominal model's best rigid fit",
            "cv_folds": cv.folds,
            "cv_rows": cv.rows,
            "cv_mean_position_mm": _mm(chosen if on else cv.without_mm),
            # the CV estimate's own standard error (over its held-out rows): few configurations, wide
            "cv_mean_position_se_mm": float(f"{float(cv.se_mm[i]) if on else cv.without_se_mm:.2g}"),
            "cv_mean_position_mm_without_prior": _mm(cv.without_mm),
        }
    )
    return (make_prior(start, strength, record) if on else None), record
