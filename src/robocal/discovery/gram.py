"""The normal equations of discovery's joint refit from the joint-level effects' factors (issue 31).

A joint-level effect's columns of the whitened Jacobian are ``v ⊗ S``: row ``m``'s ``d`` residuals respond to the
joint's angle by ``v_m = w · J_q[m, :, j]`` (``d`` numbers) and the effect's ``q`` coefficients enter through the
signals ``S_m``. The Gram of two such blocks (joints ``a``, ``b``) is ``S_aᵀ diag(Σ_d v_a v_b) S_b``: ``m q_a
q_b`` operations instead of ``d m q_a q_b`` over the Jacobian's rows, and the other columns (the geometry, the
drifts) meet a block through ``U_a = Σ_d A_m v_a,m`` (``m x k_dense``). With the residual layer (hundreds of
columns on every joint) the solver's ``JᵀJ`` is the refit's largest cost: this forms it ``d`` times cheaper,
the same matrix up to rounding. The prior's rows (one per coefficient under a prior) add their squares.
"""

from __future__ import annotations

import numpy as np


class JointGram:
    """``gram(J, r) -> (JᵀJ, Jᵀr)`` of the refit's whitened Jacobian ``J`` (``M + len(ridge)`` rows: the
    measurements', then the prior's) for :func:`robocal.numerics.attach_gram`. Holds the factors, not ``J``."""

    def __init__(
        self,
        M: int,
        d: int,
        w_row: np.ndarray,
        Jq: np.ndarray,
        blocks: list[tuple[np.ndarray, int, np.ndarray]],
        ridge_pos: np.ndarray,
        sq: np.ndarray,
    ) -> None:
        self.M, self.d = M, d
        self.ridge_pos, self.sq = np.asarray(ridge_pos, dtype=int), np.asarray(sq, dtype=float)
        pos: dict[int, list[np.ndarray]] = {}
        sig: dict[int, list[np.ndarray]] = {}
        for p, j, S in blocks:
            pos.setdefault(j, []).append(np.asarray(p, dtype=int))
            sig.setdefault(j, []).append(S)
        self.joints = sorted(pos)
        self.P = [np.concatenate(pos[j]) for j in self.joints]
        self.S = [np.hstack(sig[j]) if len(sig[j]) > 1 else sig[j][0] for j in self.joints]
        self.V = [Jq[:, :, j] * w_row[None, :] for j in self.joints]  # (m, d) whitened responses

    def __call__(self, J: np.ndarray, r: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        return self._gram(J, r, self.M, self.S, self.V, prior=True)

    def on_rows(self, J_rows: np.ndarray, r_rows: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(AᵀA, Aᵀr)`` of the measurement rows ``rows`` (0-based among the fit's, in the order given) without the
        prior: ``J_rows`` and ``r_rows`` are those rows' ``d`` residuals each, in the same order (a fold of
        :class:`robocal.discovery.cv.FoldCV`)."""
        rows = np.asarray(rows, dtype=int)
        G, b = self._gram(
            J_rows, r_rows, len(rows) * self.d, [S[rows] for S in self.S], [v[rows] for v in self.V], prior=False
        )
        assert b is not None
        return G, b

    def _gram(
        self,
        J: np.ndarray,
        r: np.ndarray | None,
        M: int,
        Ss: list[np.ndarray],
        Vs: list[np.ndarray],
        prior: bool,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        d = self.d
        m = M // d
        k = J.shape[1]
        isj = np.zeros(k, dtype=bool)
        for p in self.P:
            isj[p] = True
        dc = np.flatnonzero(~isj)
        G = np.zeros((k, k))
        b = None if r is None else np.zeros(k)
        D = J[:M, dc]  # the other columns (the geometry's, the drifts'): a copy of those only
        G[np.ix_(dc, dc)] = D.T @ D
        D3 = D.reshape(m, d, len(dc))
        r3 = None if r is None else r[:M].reshape(m, d)
        if b is not None and r is not None:
            b[dc] = D.T @ r[:M]
        for a, (Pa, Sa, va) in enumerate(zip(self.P, Ss, Vs, strict=True)):
            if len(dc):
                U = np.einsum("mdk,md->mk", D3, va)
                Gda = U.T @ Sa
                G[np.ix_(dc, Pa)] = Gda
                G[np.ix_(Pa, dc)] = Gda.T
            if b is not None and r3 is not None:
                b[Pa] = Sa.T @ np.einsum("md,md->m", va, r3)
            X = Sa * np.sqrt(np.einsum("md,md->m", va, va))[:, None]
            G[np.ix_(Pa, Pa)] = X.T @ X
            for Pb, Sb, vb in zip(self.P[a + 1 :], Ss[a + 1 :], Vs[a + 1 :], strict=True):
                blk = (Sa * np.einsum("md,md->m", va, vb)[:, None]).T @ Sb
                G[np.ix_(Pa, Pb)] = blk
                G[np.ix_(Pb, Pa)] = blk.T
        if prior and len(self.ridge_pos):
            G[self.ridge_pos, self.ridge_pos] += self.sq**2
            if b is not None and r is not None:
                b[self.ridge_pos] += self.sq * r[M:]
        return G, b


__all__ = ["JointGram"]
