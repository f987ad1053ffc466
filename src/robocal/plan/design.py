"""Optimal experimental design on the identification Jacobian: criteria, an exchange algorithm, indices.

Notation. A candidate pose ``c`` contributes the block ``F_c`` (r, p): the rows of the whitened
identification Jacobian (each residual divided by its noise sigma) of the targets the tracker sees at that
pose (invisible targets give zero rows), restricted to the ``p`` identifiable parameters and column-scaled
(``F = J_w S``, ``S = diag(s)``; parameters in the scaled coordinates are ``S⁻¹ θ``). The information matrix
of a design is ``M = Σ F_cᵀ F_c`` and the Cramér-Rao covariance of the scaled parameters is ``M⁻¹``
(of the physical ones ``S M⁻¹ S``).

Criteria (all minimised here):

- D: ``-log det M`` (invariant to the column scaling);
- A: ``tr M⁻¹`` (scaled parameters: depends on ``S``, so the scaling is stated in ``plan.json``);
- I: ``tr(M⁻¹ L)``, ``L = mean_v G_vᵀ G_v`` over the validation region, ``G_v`` the (3, p) position
  Jacobian of configuration ``v`` (mm per scaled parameter): the mean predicted squared position error
  (mm²) of the calibrated model over the region.

The exchange is DETMAX (Mitchell 1974) generalised to blocks and to the three criteria: add the candidate
with the best gain, then remove the design point with the smallest loss; when that excursion does not
improve the criterion, try longer excursions (add ``k``, remove ``k``, ``k`` up to ``max_excursion``); the
information inverse is kept by Woodbury (block rank-``r``) updates and refreshed from scratch periodically.
Gains over all candidates are evaluated at once (batched ``r × r`` solves). To stay fast on 10⁵ candidates
the moves are searched in an active set (the best candidates by gain against the current design, plus the
design); at convergence every candidate is checked again and the search resumes if one is better.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from robocal.numerics import argmax_tied


def _logdet(A: np.ndarray) -> np.ndarray:
    sign, ld = np.linalg.slogdet(A)
    return np.where(sign > 0, ld, -np.inf)


def information(F: np.ndarray, idx: Sequence[int] | np.ndarray) -> np.ndarray:
    """``M = Σ_{c in idx} F_cᵀ F_c`` (p, p)."""
    B = F[np.asarray(idx, dtype=int)]
    Bf = B.reshape(-1, B.shape[-1])
    return Bf.T @ Bf


def criterion_value(M: np.ndarray, criterion: str, L: np.ndarray | None = None) -> float:
    """The criterion to minimise (``-log det M``, ``tr M⁻¹`` or ``tr M⁻¹ L``); ``inf`` when M is singular."""
    if criterion == "D":
        s, ld = np.linalg.slogdet(M)
        return float(-ld) if s > 0 else float("inf")
    try:
        Minv = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return float("inf")
    if not np.all(np.isfinite(Minv)) or np.min(np.linalg.eigvalsh(M)) <= 0:
        return float("inf")
    if criterion == "A":
        return float(np.trace(Minv))
    assert L is not None
    return float(np.sum(Minv * L))


class _State:
    """The current design and ``M⁻¹`` (with a tiny ridge so that the first steps from a singular design work)."""

    def __init__(self, F: np.ndarray, idx: np.ndarray, criterion: str, L: np.ndarray | None, ridge: float) -> None:
        self.F = F
        self.p = F.shape[-1]
        self.criterion = criterion
        self.L = np.eye(self.p) if L is None else L
        self.ridge = ridge
        self.idx = list(int(i) for i in idx)
        self.in_design = np.zeros(F.shape[0], dtype=bool)
        self.in_design[self.idx] = True
        self.refresh()

    def refresh(self) -> None:
        M = information(self.F, self.idx) + self.ridge * np.eye(self.p)
        self.Minv = np.linalg.inv(M)
        self.Minv = 0.5 * (self.Minv + self.Minv.T)
        self.value = self._value()

    def _value(self) -> float:
        if self.criterion == "D":
            s, ld = np.linalg.slogdet(self.Minv)
            return float(ld) if s > 0 else float("inf")  # -log det M = log det M⁻¹
        if self.criterion == "A":
            return float(np.trace(self.Minv))
        return float(np.sum(self.Minv * self.L))

    def gains(self, cand: np.ndarray, sign: float) -> np.ndarray:
        """Decrease of the criterion when the blocks ``cand`` are added (sign +1) or removed (sign -1)."""
        B = self.F[cand]  # (c, r, p)
        c, r, p = B.shape
        A = (B.reshape(-1, p) @ self.Minv).reshape(c, r, p)
        G = np.matmul(A, B.transpose(0, 2, 1))
        Ir = np.eye(r)
        Kmat = Ir + sign * G
        if self.criterion == "D":
            return _logdet(Kmat)  # adding: log det(I + G) > 0; removing: log det(I - G) < 0
        AL = A if self.criterion == "A" else (A.reshape(-1, p) @ self.L).reshape(c, r, p)
        H = np.matmul(AL, A.transpose(0, 2, 1))
        try:
            X = np.linalg.solve(Kmat, H)
        except np.linalg.LinAlgError:
            return np.full(c, -np.inf)
        return sign * np.trace(X, axis1=1, axis2=2)

    def add(self, j: int) -> None:
        self._update(j, +1.0)
        self.idx.append(int(j))
        self.in_design[j] = True

    def remove(self, j: int) -> None:
        self._update(j, -1.0)
        self.idx.remove(int(j))
        self.in_design[j] = False

    def _update(self, j: int, sign: float) -> None:
        B = self.F[j]
        A = B @ self.Minv
        K = np.eye(B.shape[0]) + sign * (A @ B.T)
        self.Minv = self.Minv - sign * A.T @ np.linalg.solve(K, A)
        self.Minv = 0.5 * (self.Minv + self.Minv.T)
        self.value = self._value()


@dataclass(frozen=True)
class ExchangeResult:
    """Selected candidate indices (sorted), the criterion value, exchanges made and refreshes of the active set."""

    idx: np.ndarray
    value: float
    n_exchanges: int
    n_rounds: int
    converged: bool


def exchange(
    F: np.ndarray,
    n: int,
    criterion: str,
    rng: np.random.Generator,
    L: np.ndarray | None = None,
    init: Sequence[int] | np.ndarray | None = None,
    max_exchanges: int = 2000,
    active_set: int = 4000,
    max_excursion: int = 3,
    tol: float = 1e-9,
) -> ExchangeResult:
    """Choose ``n`` of the candidate blocks ``F`` (C, r, p) minimising the criterion.

    Parameters
    ----------
    F : ndarray, shape (C, r, p)
        Whitened, column-scaled Jacobian blocks of the candidates.
    n : int
        Design size (distinct candidates).
    criterion : ``"D"``, ``"A"`` or ``"I"``
    rng : numpy Generator
        Draws the starting design when ``init`` is not given (the only randomness).
    L : ndarray, shape (p, p), optional
        The I-criterion's region matrix.
    init : sequence of int, optional
        Starting design; completed at random (or cut) to ``n`` points.
    """
    C, _, p = F.shape
    if n > C:
        raise ValueError(f"The 'n' parameter of exchange must be at most the number of candidates {C}. Got {n}.")
    if criterion == "I" and L is None:
        raise ValueError("The 'L' parameter of exchange is required for the I criterion.")
    start = _start_design(C, n, rng, init)
    # ridge: 1e-10 of the mean information per scaled parameter of one candidate, times n
    scale = float(np.einsum("crp,crp->", F, F)) / (C * p)
    st = _State(F, np.array(start), criterion, L, ridge=1e-10 * max(scale, 1e-300) * n)
    if n == C:  # every candidate is in the design: there is nothing to exchange
        return ExchangeResult(idx=np.arange(C), value=st.value, n_exchanges=0, n_rounds=0, converged=True)
    n_ex = 0
    rounds = 0
    converged = False
    since_refresh = 0
    while n_ex < max_exchanges:
        rounds += 1
        act = _active_set(st, C, n, active_set)
        moves = 0
        while n_ex < max_exchanges:
            # the shortest excursion that improves the design is kept (longer ones are tried only when it fails)
            if not any(_excursion(st, act, exc, tol) for exc in range(1, max_excursion + 1)):
                break
            n_ex += 1
            since_refresh += 1
            if since_refresh >= 50:
                st.refresh()
                since_refresh = 0
            moves += 1
        if moves == 0:
            # no excursion from the best candidates over all C improves the design
            converged = True
            break
    st.refresh()
    return ExchangeResult(
        idx=np.sort(np.asarray(st.idx, dtype=int)),
        value=st.value,
        n_exchanges=n_ex,
        n_rounds=rounds,
        converged=converged,
    )


def _start_design(C: int, n: int, rng: np.random.Generator, init: Sequence[int] | np.ndarray | None) -> list[int]:
    """``init`` without repeats, cut to ``n`` points or completed to ``n`` by distinct random candidates."""
    start = [] if init is None else list(dict.fromkeys(int(i) for i in init))[:n]
    if len(start) < n:
        pool = np.setdiff1d(np.arange(C), np.asarray(start, dtype=int))
        start += [int(i) for i in rng.choice(pool, size=n - len(start), replace=False)]
    return start


def _active_set(st: _State, C: int, n: int, active_set: int) -> np.ndarray:
    """The candidates searched in this round: the ``active_set`` best by gain against the current design (over
    all C), or every candidate outside the design when that is not more."""
    k = min(active_set, C - n)
    if k < C - n:
        g_all = st.gains(np.arange(C), +1.0)
        g_all[st.in_design] = -np.inf
        return np.sort(np.argpartition(-g_all, k - 1)[:k])
    return np.flatnonzero(~st.in_design)


def _excursion(st: _State, act: np.ndarray, exc: int, tol: float) -> bool:
    """Add the ``exc`` best candidates of ``act`` one by one, then remove the ``exc`` design points whose removal
    raises the criterion least; keep the result (True) when it improves the criterion by more than ``tol``
    (relative), else undo it (False)."""
    if int(np.count_nonzero(~st.in_design[act])) < exc:
        return False  # fewer of this round's candidates are outside the design than the excursion would add
    before = st.value
    added: list[int] = []
    for _ in range(exc):
        g = st.gains(act, +1.0)
        g[st.in_design[act]] = -np.inf
        j = int(act[argmax_tied(g)])
        st.add(j)
        added.append(j)
    removed: list[int] = []
    for _ in range(exc):
        d = np.asarray(st.idx)
        dec = st.gains(d, -1.0)  # <= 0: the removal that raises the criterion least
        i = int(d[argmax_tied(dec)])
        st.remove(i)
        removed.append(i)
    if set(added) != set(removed) and st.value < before - tol * max(1.0, abs(before)):
        return True
    for i in removed:  # undo the excursion
        st.add(i)
    for j in added:
        st.remove(j)
    st.refresh()
    return False


def observability(J: np.ndarray) -> dict[str, float]:
    """Observability indices O1-O5 (Sun & Hollerbach 2008) of a (whitened, column-scaled) Jacobian (m, L).

    With singular values ``σ_1 ≥ … ≥ σ_L`` and ``m`` measured coordinates: O1 = (σ_1 ⋯ σ_L)^(1/L) / √m
    (Borm & Menq), O2 = σ_L / σ_1 (inverse condition number, Driels & Pathre), O3 = σ_L (Nahvi et al.),
    O4 = σ_L² / σ_1 (noise amplification index, Nahvi & Hollerbach), O5 = 1 / Σ 1/σ_i (Sun & Hollerbach,
    the A-optimality counterpart). Larger is better for all five.
    """
    m, Lp = J.shape
    s = np.linalg.svd(J, compute_uv=False)
    if len(s) < Lp or s[-1] <= 0:
        return {"O1": 0.0, "O2": 0.0, "O3": 0.0, "O4": 0.0, "O5": 0.0, "condition_number": float("inf")}
    return {
        "O1": float(np.exp(np.mean(np.log(s))) / np.sqrt(m)),
        "O2": float(s[-1] / s[0]),
        "O3": float(s[-1]),
        "O4": float(s[-1] ** 2 / s[0]),
        "O5": float(1.0 / np.sum(1.0 / s)),
        "condition_number": float(s[0] / s[-1]),
    }
