"""Discovery beyond the library: propose the equation of a joint-level error no candidate holds.

When the library's forward selection stops, every joint's error ``dq_j`` is offered a dictionary of terms built
from the signals the campaign has:

* harmonics 1..H of every joint angle, ``sin(h q_i)``, ``cos(h q_i)``;
* products of harmonics of two joints, ``{sin,cos}(h q_i) · {sin,cos}(k q_l)`` (i < l, h, k <= H2);
* the gravity torque of every joint (robot masses and payload), reported torques and motor currents;
* the principal components of the temperatures, their time derivatives, and the time since the start.

In error-Jacobian form each term ``f`` on joint ``j`` is the column ``J_q[:, :, j] · f`` (whitened, every
measured residual): hundreds to thousands of columns. What the current model explains is projected out; a
column it absorbs is dropped. Sparse selection is scikit-learn's orthogonal matching pursuit (a few terms out of
thousands), made stable by resampling whole poses: a term enters a proposal only when it is chosen in at least
``dictionary_stability`` of the resamples. A proposal (the stable terms of one joint) is then tested through
the same gate as a library effect (:func:`robocal.discovery.ftest.score_candidate`): the nested F-test with a
Bonferroni threshold over the number of ways to pick that many terms from the dictionary (the selection's
multiple testing), the BIC, the share of the excess chi², and whole-pose cross-validation; it is refitted
jointly with the geometry by the same Levenberg-Marquardt and reported as an equation, apart from the named
effects.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import comb
from typing import Any

import numpy as np

from robocal.compensation.signals import Factor, evaluate_factor, factor_label
from robocal.data.contract import Campaign
from robocal.discovery.cv import CHUNK
from robocal.discovery.gram import FactoredSpace
from robocal.robot import RobotDescription


@dataclass(frozen=True)
class Term:
    """One dictionary function of the campaign's signals: a product of factors."""

    factors: tuple[Factor, ...]

    @property
    def label(self) -> str:
        return "·".join(factor_label(f) for f in self.factors)

    @property
    def from_joints_only(self) -> bool:
        """Evaluable from the commanded joints (and the payload): what a controller or the service can apply."""
        return all(f[0] in ("sin", "cos", "gravity") for f in self.factors)

    def to_dict(self) -> dict[str, Any]:
        return {"signal": self.label, "factors": [{"kind": k, "index": i, "harmonic": h} for k, i, h in self.factors]}


class TermColumns:
    """The dictionary's columns ``(m, K)`` formed when read, at the rows asked for (``F[rows]``, ``F[rows, cols]``;
    :meth:`columns` a candidate's few): the joint terms (harmonics and products) from the angles ``q (m, n)`` at
    those rows, then the ``fixed`` columns ``(m, b)`` held (gravity torques, torques, currents, temperatures, time:
    a few per joint). Each row is formed on its own, its values the ones the whole matrix held. That ``(all rows,
    K)`` matrix (~280 columns, 54 MB at 24 000 rows) was held through the dictionary stage beside its fitted rows'
    copy (issue 31). A signal read many times is better held: the transmission error's and the residual layer's,
    formed at each read, saved 14 MB there and cost UR10 A's 12 000 rows 7 % more time."""

    ndim = 2

    def __init__(
        self, q: np.ndarray, joint_terms: list[Term], fixed: np.ndarray, cols: np.ndarray | None = None
    ) -> None:
        self.q, self.joint_terms, self.fixed, self.cols = q, joint_terms, fixed, cols
        self.n_cols = len(joint_terms) + fixed.shape[1]

    @property
    def shape(self) -> tuple[int, int]:
        return (len(self.q), self.n_cols if self.cols is None else len(self.cols))

    def __len__(self) -> int:
        return len(self.q)

    def columns(self, cols: Any) -> TermColumns:
        """The same columns restricted to ``cols`` (of this one's)."""
        cols = np.asarray(cols, dtype=int)
        return TermColumns(self.q, self.joint_terms, self.fixed, cols if self.cols is None else self.cols[cols])

    def __getitem__(self, idx: Any) -> np.ndarray:
        rows, cols = idx if isinstance(idx, tuple) else (idx, slice(None))
        one = isinstance(rows, (int, np.integer))
        q = self.q[np.array([rows]) if one else rows]
        out = np.empty((len(q), self.n_cols))
        for c, t in enumerate(self.joint_terms):
            out[:, c] = evaluate_factor(t.factors[0], q)
            for f in t.factors[1:]:
                out[:, c] *= evaluate_factor(f, q)
        out[:, len(self.joint_terms) :] = self.fixed[np.array([rows]) if one else rows]
        if self.cols is not None:
            out = out[:, self.cols]
        out = out[:, cols]
        return out[0] if one else out

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        return np.asarray(self[:], dtype=dtype)


@dataclass
class Dictionary:
    """The dictionary's functions on every campaign row: ``F (m_all, K)`` (formed when read), one :class:`Term`
    per column."""

    terms: list[Term]
    F: TermColumns
    skipped: list[str] = field(default_factory=list)


def build_dictionary(
    campaign: Campaign, robot: RobotDescription, harmonics: int = 3, product_harmonics: int = 2
) -> Dictionary:
    """The dictionary of a campaign (see the module docstring)."""
    q = campaign.q
    n = q.shape[1]
    joint_terms: list[Term] = []
    terms: list[Term] = []
    cols: list[np.ndarray] = []
    skipped: list[str] = []
    # harmonics of an angle: a linear axis's value (mm) is none (its errors along the travel: robocal.discovery.axes)
    moving = [i for i in range(n) if np.ptp(q[:, i]) > 1e-6 and not robot.prismatic[i]]
    _joint_terms(moving, harmonics, product_harmonics, joint_terms)
    if robot.has_dynamics:
        from robocal.kinematics.gravity import gravity_torques

        g = gravity_torques(robot, q, campaign.payload_kg)
        for i in range(n):
            if np.std(g[:, i]) > 1e-9:
                terms.append(Term((("gravity", i + 1, 0),)))
                cols.append(g[:, i])
    else:
        skipped.append("gravity torques: the robot description has no link masses")
    for kind, arr in (("tau", campaign.tau_Nm), ("current", campaign.current_A)):
        if arr is not None:
            for i in range(n):
                if np.std(arr[:, i]) > 1e-9:
                    terms.append(Term(((kind, i + 1, 0),)))
                    cols.append(np.asarray(arr[:, i], dtype=float))
    _temperature_terms(campaign, terms, cols)
    t_all = np.asarray(campaign.timestamp_s, dtype=float)
    if np.ptp(t_all) > 1.0:
        terms.append(Term((("time", 0, 0),)))
        cols.append((t_all - t_all.mean()) / 3600.0)
    fixed = np.column_stack(cols) if cols else np.zeros((campaign.n_rows, 0))
    return Dictionary(joint_terms + terms, TermColumns(q, joint_terms, fixed), skipped)


def _joint_terms(moving: list[int], harmonics: int, product_harmonics: int, terms: list[Term]) -> None:
    """The harmonics of every moving joint and the products of two joints' harmonics (appended)."""
    for i in moving:
        for h in range(1, harmonics + 1):
            for fn in ("sin", "cos"):
                terms.append(Term(((fn, i + 1, h),)))
    for a_pos, a in enumerate(moving):
        for b in moving[a_pos + 1 :]:
            for h in range(1, product_harmonics + 1):
                for k in range(1, product_harmonics + 1):
                    for fa in ("sin", "cos"):
                        for fb in ("sin", "cos"):
                            terms.append(Term(((fa, a + 1, h), (fb, b + 1, k))))


def _temperature_terms(campaign: Campaign, terms: list[Term], cols: list[np.ndarray]) -> None:
    """The temperature log's first two principal components and their rates per hour (appended), when the
    temperatures vary."""
    if campaign.temperatures is None:
        return
    T = np.asarray(campaign.temperatures, dtype=float)
    dT = T - T.mean(axis=0)
    if not (np.all(np.isfinite(dT)) and float(np.max(np.std(T, axis=0))) > 0.05):
        return
    _, s, Vt = np.linalg.svd(dT, full_matrices=False)
    t_s = np.asarray(campaign.timestamp_s, dtype=float)
    for k in range(min(2, len(s))):
        if s[k] <= 0.01 * s[0]:
            continue
        pc = dT @ Vt[k]
        terms.append(Term((("temperature", k + 1, 0),)))
        cols.append(pc)
        order = np.argsort(t_s, kind="stable")
        d = np.zeros_like(pc)
        if len(np.unique(t_s)) > 2:
            d[order] = np.gradient(pc[order], t_s[order] / 3600.0 + 1e-9 * np.arange(len(order)))
            terms.append(Term((("dtemperature", k + 1, 0),)))
            cols.append(d)


@dataclass
class Proposal:
    """Stable terms of one joint, with the selection evidence."""

    joint: int  # 1-based
    atoms: list[int]  # dictionary columns (term indices)
    stability: list[float]
    n_columns: int  # dictionary columns offered (all joints), after the absorbed ones were dropped


def select(
    Jq: np.ndarray,
    w: np.ndarray,
    F_rows: np.ndarray,
    r_w: np.ndarray,
    Q: np.ndarray | FactoredSpace,
    groups: np.ndarray,
    max_terms: int,
    n_resamples: int,
    stability: float,
    absorbed_tol: float,
    seed: int,
    merge_corr: float = 0.9,
) -> list[Proposal]:
    """Stability selection with orthogonal matching pursuit over every joint's dictionary columns.

    Jq : (m, d, n) joint Jacobian of the residuals at the current fit; w : (M,) residual weights; F_rows :
    (m, K) the dictionary at the fitted rows; r_w : (M,) whitened residuals; Q : (M, k) orthonormal basis of the
    current model's whitened Jacobian, or that basis held by the Jacobian's factors (a
    :class:`robocal.discovery.gram.FactoredSpace`); groups : (M,) pose of every residual (resampling unit).
    """
    m, d, n = Jq.shape
    K = F_rows.shape[1]
    # columns (M, n K): joint j's block is J_q[:, :, j] · F, whitened. Never formed (issue 31): every product
    # with it goes through its factors, V[:, :, j] (m, d) and F (m, K) (robocal.discovery.cv's module docstring)
    V = Jq * np.asarray(w, dtype=float).reshape(m, d)[:, :, None]
    F = np.asarray(F_rows, dtype=float)
    basis = _Basis(Q, m, d)
    B = np.empty((basis.rank, n * K))  # Qᵀ Z
    for j in range(n):
        B[:, j * K : (j + 1) * K] = basis.joint(V[:, :, j], F)
    # (n K,) norms of Z's columns, summed over row chunks (no (m, K) square of the dictionary held at once)
    V2 = np.sum(V**2, axis=1)
    sq = np.zeros((n, K))
    for c0 in range(0, m, CHUNK):
        sq += V2[c0 : c0 + CHUNK].T @ F[c0 : c0 + CHUNK] ** 2
    norms = np.sqrt(sq.reshape(-1))
    pn = np.sqrt(np.clip(norms**2 - np.sum(B**2, axis=0), 0.0, None))  # of Z - Q Qᵀ Z
    keep = pn > absorbed_tol * np.maximum(norms, 1e-300)
    idx = np.flatnonzero(keep)
    if len(idx) == 0:
        return []
    X = _Projected(V, F, basis, B, idx, pn[idx])
    rng = np.random.default_rng(seed)
    from robocal.discovery.cv import group_labels

    uniq = group_labels(groups)[0]
    counts = np.zeros(len(idx))
    picks: list[np.ndarray] = []
    for _ in range(n_resamples):
        pick = rng.choice(len(uniq), size=len(uniq) // 2, replace=False)
        rows = np.isin(groups, uniq[pick])
        sel = np.sort(_omp(X, rows, np.where(rows, r_w, 0.0), max_terms))
        counts[sel] += 1
        picks.append(sel)
    used = np.flatnonzero(counts > 0)
    at = np.full(len(idx), -1)
    at[used] = np.arange(len(used))
    freq = np.zeros(len(idx))
    freq[used] = cluster_votes(X.columns(used), counts[used], [at[p] for p in picks], n_resamples, merge_corr)
    stable = np.flatnonzero(freq >= stability)
    out: dict[int, Proposal] = {}
    for s_i in stable[np.argsort(-freq[stable])]:
        col = int(idx[s_i])
        j, atom = divmod(col, K)
        p = out.setdefault(j, Proposal(j + 1, [], [], len(idx)))
        p.atoms.append(atom)
        p.stability.append(float(freq[s_i]))
    return list(out.values())


class _Basis:
    """The current model's column space as :func:`select` reads it: an orthonormal basis ``Q (M, r)`` formed, or
    held by the model's Jacobian ``A`` (the factors of a fit with hundreds of joint-level columns,
    :class:`robocal.discovery.gram.FactoredSpace`: ``Q = A W``, never the ``(M, r)`` matrix — 191 MB at UR10
    A's 8 258 fitted rows, the largest allocation of its discovery)."""

    def __init__(self, Q: Any, m: int, d: int) -> None:
        self.dense = isinstance(Q, np.ndarray)
        self.Q = Q
        self.rank = int(Q.shape[1]) if self.dense else int(Q.rank)
        self.Q3 = Q.reshape(m, d, self.rank) if self.dense else None

    def joint(self, v: np.ndarray, F: np.ndarray) -> np.ndarray:
        """``Qᵀ Z`` (``r x K``) of one joint's dictionary columns ``Z = v ⊗ F`` (``v (m, d)``, ``F (m, K)``)."""
        if self.Q3 is not None:
            return np.einsum("rdk,rd->rk", self.Q3, v, optimize=True).T @ F
        return np.asarray(self.Q.W.T @ (self.Q.F.joint_response(v).T @ F))

    def t(self, u: np.ndarray) -> np.ndarray:
        """``Qᵀ u`` of a residual vector ``u (M,)``."""
        return np.asarray(self.Q.T @ u if self.dense else self.Q.W.T @ self.Q.F.rmul(u))

    def times(self, X: np.ndarray) -> np.ndarray:
        """``Q X`` (``M x p``) of ``X (r, p)``."""
        return np.asarray(self.Q @ X if self.dense else self.Q.F.mul(self.Q.W @ X))


class _Projected:
    """The dictionary's kept columns projected off the current model and normalised, ``X = (Z - Q B)[:, idx] /
    pn``, held by their factors: products with it cost ``O(m n K)``, not the ``(M, n K)`` matrix."""

    def __init__(self, V: np.ndarray, F: np.ndarray, Q: _Basis, B: np.ndarray, idx: np.ndarray, pn: np.ndarray) -> None:
        self.V, self.F, self.Q, self.B, self.idx, self.pn = V, F, Q, B[:, idx], idx, pn
        self.K = F.shape[1]

    def rmatvec(self, u: np.ndarray) -> np.ndarray:
        """``Xᵀ u`` for a residual vector ``u (M,)``."""
        m, d, _ = self.V.shape
        zu = (self.F.T @ np.einsum("rdn,rd->rn", self.V, u.reshape(m, d))).T.reshape(-1)  # Zᵀ u, (n K,)
        return np.asarray((zu[self.idx] - self.B.T @ self.Q.t(u)) / self.pn)

    def columns(self, cols: np.ndarray) -> np.ndarray:
        """The columns ``cols`` of ``X`` as an ``(M, len(cols))`` matrix."""
        m, d, _ = self.V.shape
        out = np.empty((m * d, len(cols)))
        for c_out, c in enumerate(cols):
            j, a = divmod(int(self.idx[c]), self.K)
            out[:, c_out] = (self.V[:, :, j] * self.F[:, a][:, None]).reshape(-1)
        out -= self.Q.times(self.B[:, cols])
        return out / self.pn[cols]


def _omp(X: _Projected, rows: np.ndarray, y: np.ndarray, n_terms: int) -> np.ndarray:
    """Orthogonal matching pursuit of ``y`` (zero outside ``rows``) on the columns of ``X`` restricted to ``rows``
    (the Cholesky form of scikit-learn's ``orthogonal_mp`` with ``n_nonzero_coefs``, same picks and stopping
    rules), from products with ``X``: ``Xᵀ y`` once and one Gram column per chosen atom."""
    eps = float(np.finfo(float).eps)
    alpha = X.rmatvec(y)
    active: list[int] = []
    gram: list[np.ndarray] = []  # X_sᵀ x_s,a for each active atom a
    L = np.zeros((n_terms, n_terms))
    gamma: np.ndarray = np.zeros(0)
    corr = alpha
    while len(active) < n_terms:
        lam = int(np.argmax(np.abs(corr)))
        if lam in active or alpha[lam] ** 2 < eps:
            break
        g = X.rmatvec(np.where(rows, X.columns(np.array([lam]))[:, 0], 0.0))
        na = len(active)
        if na > 0:
            from scipy.linalg import solve_triangular

            ln = solve_triangular(L[:na, :na], np.array([gg[lam] for gg in gram]), lower=True, check_finite=False)
            Lkk = float(g[lam] - ln @ ln)
            if Lkk <= eps:
                break
            L[na, :na] = ln
            L[na, na] = np.sqrt(Lkk)
        else:
            L[0, 0] = np.sqrt(g[lam])
        active.append(lam)
        gram.append(g)
        La = L[: na + 1, : na + 1]
        gamma = np.linalg.solve(La.T, np.linalg.solve(La, alpha[active]))
        corr = alpha - np.column_stack(gram) @ gamma
    return np.array([a for a, gm in zip(active, gamma, strict=False) if gm != 0], dtype=int)


def cluster_votes(
    X: np.ndarray, counts: np.ndarray, picks: list[np.ndarray], n_resamples: int, merge_corr: float
) -> np.ndarray:
    """Selection frequency per column with the votes of strongly correlated columns pooled: columns picked in
    any resample whose (projected, normalised) correlation exceeds ``merge_corr`` form one cluster; a cluster's
    frequency is the share of resamples that picked any of its members, credited to its most picked member
    (the others get 0). Without this, two near-copies of one term split the vote and neither looks stable."""
    freq = counts / max(n_resamples, 1)
    used = np.flatnonzero(counts > 0)
    if len(used) < 2:
        return freq
    Xu = X if len(used) == X.shape[1] else X[:, used]  # the caller passes the picked columns: no copy
    C = np.abs(Xu.T @ Xu)
    parent = list(range(len(used)))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a in range(len(used)):
        for b in range(a + 1, len(used)):
            if C[a, b] > merge_corr:
                parent[root(a)] = root(b)
    clusters: dict[int, list[int]] = {}
    for a in range(len(used)):
        clusters.setdefault(root(a), []).append(int(used[a]))
    out = freq.copy()
    for members in clusters.values():
        if len(members) == 1:
            continue
        hit = sum(1 for sel in picks if np.isin(members, sel).any())
        best = max(members, key=lambda c: (counts[c], -c))
        out[members] = 0.0
        out[best] = hit / max(n_resamples, 1)
    return out


def log10_threshold(alpha: float, n_columns: int, n_terms: int) -> float:
    """Bonferroni over the ways of choosing ``n_terms`` of ``n_columns`` dictionary columns."""
    return float(np.log10(alpha) - np.log10(max(comb(max(n_columns, 1), max(n_terms, 1)), 1)))


READINGS = {
    "own": "a periodic error of the joint's own angle: transmission (gear) error or encoder eccentricity",
    "other": "the joint's error follows another joint's angle: a coupling (cable or hose drag, a load that "
    "moves with the other axis, an axis misalignment the geometry cannot hold)",
    "pair": "the joint's error follows two other joints together: a configuration-dependent load (the moment "
    "of a link whose direction depends on both) or a coupled elasticity",
    "gravity": "proportional to a gravity torque: compliance (elastic deflection under the arm's weight)",
    "tau": "proportional to a reported torque: compliance under load",
    "current": "proportional to a motor current: compliance under load",
    "temperature": "follows the temperatures: thermal expansion or tilt",
    "dtemperature": "follows the rate of temperature change: a transient thermal gradient",
    "time": "grows with time: drift of the tracker or the base",
}


def reading(joint: int, terms: list[Term]) -> str:
    """The physical reading of a proposal (its dominant term first)."""
    t = terms[0]
    kinds = [f[0] for f in t.factors]
    if kinds[0] in ("sin", "cos"):
        js = sorted({f[1] for f in t.factors})
        key = "own" if js == [joint] else ("pair" if len(js) >= 2 else "other")
    else:
        key = kinds[0]
    return READINGS[key]
