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

import copy
from typing import Any

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
        merge: bool = True,
    ) -> None:
        """``merge``: one entry per joint, its blocks' signals side by side (a copy); False: one entry per block
        (the same response ``v`` for the blocks of one joint; no copy of the signals)."""
        self.M, self.d = M, d
        self.ridge_pos, self.sq = np.asarray(ridge_pos, dtype=int), np.asarray(sq, dtype=float)
        if not merge:
            self.joints = [j for _, j, _ in blocks]
            self.P = [np.asarray(p, dtype=int) for p, _, _ in blocks]
            self.S = [S for _, _, S in blocks]
            V = {j: Jq[:, :, j] * w_row[None, :] for j in sorted(set(self.joints))}
            self.V = [V[j] for j in self.joints]
            return
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
        dc = self.dense_columns(J.shape[1])
        return self._gram(J[: self.M, dc], dc, J.shape[1], r, self.M, self.S, self.V, prior=True)

    def take(self, rows: np.ndarray, in_place: bool = False) -> JointGram:
        """The same blocks on the measurement rows ``rows`` (in that order; the prior's rows kept): their signals
        and responses copied once, contiguous. ``in_place``: ``rows`` a permutation of every row, and the blocks'
        arrays put in that order where they are (one array's copy at a time, not all of them: the caller owns
        them, and they are this object's own afterwards)."""
        if in_place and _permutable(rows, self.M // self.d, [*self.S, *self.V]):
            _permute_rows([*self.S, *self.V], rows)
            return self
        sub = copy.copy(self)
        sub.M = len(rows) * self.d
        sub.S = [np.ascontiguousarray(S[rows]) for S in self.S]
        sub.V = [np.ascontiguousarray(v[rows]) for v in self.V]
        return sub

    def dense_columns(self, k: int) -> np.ndarray:
        """The positions, among ``k`` columns, of those no joint-level block holds (the geometry's, the drifts')."""
        isj = np.zeros(k, dtype=bool)
        for p in self.P:
            isj[p] = True
        return np.flatnonzero(~isj)

    def on_rows(self, J_rows: np.ndarray, r_rows: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(AᵀA, Aᵀr)`` of the measurement rows ``rows`` (0-based among the fit's, in the order given) without the
        prior: ``J_rows`` and ``r_rows`` are those rows' ``d`` residuals each, in the same order (a fold of
        :class:`robocal.discovery.cv.FoldCV`)."""
        dc = self.dense_columns(J_rows.shape[1])
        return self.on_dense_rows(J_rows[:, dc], dc, J_rows.shape[1], r_rows, rows)

    def on_dense_rows(
        self, D_rows: np.ndarray, dc: np.ndarray, k: int, r_rows: np.ndarray, rows: np.ndarray | slice
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`on_rows` from the rows' dense columns ``D_rows`` alone (``dc``: their positions among ``k``)."""
        rows = rows if isinstance(rows, slice) else np.asarray(rows, dtype=int)  # a slice: the factors read in place
        G, b = self._gram(
            D_rows, dc, k, r_rows, len(D_rows), [S[rows] for S in self.S], [v[rows] for v in self.V], False
        )
        assert b is not None
        return G, b

    def _gram(
        self,
        D: np.ndarray,
        dc: np.ndarray,
        k: int,
        r: np.ndarray | None,
        M: int,
        Ss: list[np.ndarray],
        Vs: list[np.ndarray],
        prior: bool,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """``D (M, |dc|)``: the measurement rows' other columns (the geometry's, the drifts'), at ``dc``."""
        d = self.d
        m = M // d
        G = np.zeros((k, k))
        b = None if r is None else np.zeros(k)
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


class FactoredJacobian:
    """A refit's whitened Jacobian ``(M + len(ridge), k)`` held by its factors (issue 31: the residual layer's
    hundreds of columns per joint made it 0.43 GB at UR10 A's 12 000 rows, held through the solver and the
    folds): the measurement rows' other columns ``D (M, |dc|)`` dense, every joint-level block as ``v ⊗ S``
    (:class:`JointGram`), the prior's rows as their one number each. What the solver and the cross-validation ask
    of it (normal equations, products with the rows, a few columns) is formed from the factors; the same numbers
    as the dense matrix up to rounding."""

    def __init__(self, D: np.ndarray, dc: np.ndarray, k: int, gram: JointGram) -> None:
        self.D, self.dc, self.k, self.gram = D, np.asarray(dc, dtype=int), int(k), gram
        self.M, self.d = gram.M, gram.d
        self.shared = False  # read by another object (its column space): never reordered in place
        self.shape = (self.M + len(gram.ridge_pos), self.k)

    # -- what the solver asks (robocal.optimizers.solver) --------------------------------------------------------
    def normal_equations(self, r: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """``(JᵀJ, Jᵀr)`` over every row (the prior's included), ``r`` of length ``shape[0]`` (or None)."""
        g = self.gram
        return g._gram(self.D, self.dc, self.k, r, self.M, g.S, g.V, prior=True)

    def column_norms(self) -> np.ndarray:
        """Each column's Euclidean norm over every row."""
        sq = np.zeros(self.k)
        sq[self.dc] = np.einsum("mk,mk->k", self.D, self.D)
        for P, S, v in zip(self.gram.P, self.gram.S, self.gram.V, strict=True):
            sq[P] = np.einsum("m,mq->q", np.einsum("md,md->m", v, v), S * S)
        sq[self.gram.ridge_pos] += self.gram.sq**2
        return np.asarray(np.sqrt(sq))

    def all_finite(self) -> bool:
        g = self.gram
        return bool(np.all(np.isfinite(self.D)) and all(np.all(np.isfinite(a)) for a in (*g.S, *g.V)))

    def take(self, rows: np.ndarray, in_place: bool = False) -> FactoredJacobian:
        """The matrix of the measurement rows ``rows`` (in that order; the prior's rows kept): the factors' rows
        copied once, so that a contiguous run of them is read in place afterwards (the folds,
        :class:`robocal.discovery.cv.FoldCV`). ``in_place`` (``rows`` a permutation of every row, the factors the
        caller's to give up): put in that order where they are, this object returned — at 8 000 UR10 rows with the
        residual layer the copy was 94 MB beside the originals, the largest allocation of the final checks."""
        m = self.M // self.d
        D3 = self._dense_rows(None)
        if in_place and not self.shared and self.D.flags.c_contiguous and _permutable(rows, m, [D3]):
            _permute_rows([D3], rows)
            self.gram = self.gram.take(rows, in_place=True)
            return self
        D = np.ascontiguousarray(self._dense_rows(rows)).reshape(-1, len(self.dc))
        return FactoredJacobian(D, self.dc, self.k, self.gram.take(rows))

    # -- products with the measurement rows (robocal.discovery.cv) ------------------------------------------------
    def _dense_rows(self, rows: np.ndarray | slice | None) -> np.ndarray:
        D3 = self.D.reshape(-1, self.d, len(self.dc))
        return D3 if rows is None else D3[rows]

    def _count(self, rows: np.ndarray | slice | None) -> int:
        m = self.M // self.d
        return m if rows is None else len(range(m)[rows]) if isinstance(rows, slice) else len(rows)

    def mul(self, y: np.ndarray, rows: np.ndarray | slice | None = None) -> np.ndarray:
        """``J y`` on the measurement rows ``rows`` (0-based, in that order; None: all), ``d`` residuals each:
        ``(len(rows) d,)`` of ``y (k,)``, or ``(len(rows) d, p)`` of ``y (k, p)``."""
        Y = y.reshape(self.k, -1)
        n = self._count(rows)
        Yd = Y[self.dc]
        out = self._dense_rows(rows) @ Yd if np.any(Yd) else np.zeros((n, self.d, Y.shape[1]))  # (n, d, p)
        for P, S, v in zip(self.gram.P, self.gram.S, self.gram.V, strict=True):
            YP = Y[P]
            if not np.any(YP):  # a block the vector does not touch (a few columns asked for: the others' zeros)
                continue
            Sr, vr = (S, v) if rows is None else (S[rows], v[rows])
            out += vr[:, :, None] * (Sr @ YP)[:, None, :]
        out = out.reshape(-1, Y.shape[1])
        return out if y.ndim == 2 else out[:, 0]

    def rmul(self, X: np.ndarray, rows: np.ndarray | slice | None = None) -> np.ndarray:
        """``J_rowsᵀ X`` of ``X (len(rows) d, p)`` (or ``(len(rows) d,)``) on the measurement rows ``rows``."""
        X3 = X.reshape(-1, self.d, 1 if X.ndim == 1 else X.shape[1])
        out = np.empty((self.k, X3.shape[2]))
        out[self.dc] = np.einsum("ndk,ndp->kp", self._dense_rows(rows), X3, optimize=True)
        for P, S, v in zip(self.gram.P, self.gram.S, self.gram.V, strict=True):
            Sr, vr = (S, v) if rows is None else (S[rows], v[rows])
            out[P] = Sr.T @ np.einsum("nd,ndp->np", vr, X3)
        return out if X.ndim == 2 else out[:, 0]

    def columns(self, pos: np.ndarray, rows: np.ndarray | slice | None = None) -> np.ndarray:
        """The dense columns ``pos`` of the measurement rows ``rows``: ``(len(rows) d, len(pos))``."""
        E = np.zeros((self.k, len(pos)))
        E[np.asarray(pos, dtype=int), np.arange(len(pos))] = 1.0
        return self.mul(E, rows)

    def rows_dense(self, rows: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The measurement rows ``rows`` of the matrix, dense: ``(len(rows) d, k)`` (each column written from its
        factors, no product), into ``out`` when given (any memory order: :class:`FactoredSpace`'s stack)."""
        o3 = np.empty((len(rows), self.d, self.k)) if out is None else out.reshape(len(rows), self.d, self.k)
        if out is not None and not np.may_share_memory(o3, out):  # a reshape that copied: written, then lost
            raise ValueError("rows_dense: out must split its rows into (rows, d) without a copy")
        o3[:, :, self.dc] = self._dense_rows(rows)
        for P, S, v in zip(self.gram.P, self.gram.S, self.gram.V, strict=True):
            o3[:, :, P] = v[rows][:, :, None] * S[rows][:, None, :]
        return o3.reshape(-1, self.k) if out is None else out

    def joint_response(self, v: np.ndarray, rows: np.ndarray | slice | None = None) -> np.ndarray:
        """``U = Σ_d J_row v_row`` (``len(rows) x k``) of a response ``v (len(rows), d)`` (the folds' products with
        a joint-level candidate, :meth:`robocal.discovery.cv.FoldCV._u`)."""
        U = np.empty((len(v), self.k))
        U[:, self.dc] = np.einsum("ndk,nd->nk", self._dense_rows(rows), v, optimize=True)
        for P, S, vj in zip(self.gram.P, self.gram.S, self.gram.V, strict=True):
            Sr, vr = (S, vj) if rows is None else (S[rows], vj[rows])
            U[:, P] = Sr * np.einsum("nd,nd->n", vr, v)[:, None]
        return U

    def space(self) -> FactoredSpace:
        """The column space of the measurement rows (:class:`FactoredSpace`): it reads these factors, which are
        not reordered in place from then on (:meth:`take`)."""
        self.shared = True
        return FactoredSpace(self)

    def dense(self) -> np.ndarray:
        """The whole matrix (the prior's rows included): for a check, never on the way of a large fit."""
        J = np.zeros(self.shape)
        J[: self.M] = self.rows_dense(np.arange(self.M // self.d))
        J[self.M + np.arange(len(self.gram.ridge_pos)), self.gram.ridge_pos] = self.gram.sq
        return J


class FactoredSpace:
    """The column space of a :class:`FactoredJacobian`'s measurement rows ``A (M, k)``, as
    :class:`robocal.discovery.ftest.ColumnSpace` keeps it (the directions whose singular value is above 1e-10 of
    the largest) without ``A`` whole: ``R`` of ``A = Q R`` by a QR of ``R`` stacked on each block of rows in turn
    (row blocks of at most :data:`SPACE_BLOCK_BYTES`), then ``R = U Σ Vᵀ``; the basis is ``B = A V_r Σ_r⁻¹`` and a
    projection ``B Bᵀ Z = A (V_r Σ_r⁻² V_rᵀ (Aᵀ Z))`` (refined once: :meth:`project`), products with the factors."""

    def __init__(self, F: FactoredJacobian) -> None:
        from scipy import linalg

        self.F = F
        k, d = F.k, F.d
        m = F.M // d
        step = max(1, SPACE_BLOCK_BYTES // max(8 * d * k, 1))
        R = np.zeros((0, k))
        for s in range(0, m, step):
            rows = np.arange(s, min(s + step, m))
            # R over the block, stacked in column order for LAPACK in place (mode "r" made two more copies of the
            # stack and kept the whole triangle alive through its slice: 175 MB at 4 000 UR10 rows, k = 383); the
            # block's rows written into the stack from the factors (a dense block beside it was 32 MB more)
            A = np.empty((len(R) + len(rows) * d, k), order="F")
            A[: len(R)] = R
            F.rows_dense(rows, out=A[len(R) :])
            (qr, _), _ = linalg.qr(A, mode="raw", overwrite_a=True, check_finite=False)
            R = np.triu(qr[: min(k, len(qr))])
            del qr, A
        _, sv, Vt = np.linalg.svd(R, full_matrices=False)
        keep = sv > 1e-10 * sv[0] if len(sv) else np.zeros(0, dtype=bool)
        self.rank = int(keep.sum())
        self.W = Vt[keep].T / sv[keep]  # (k, r): B = A W

    def coefficients(self, Z: np.ndarray) -> np.ndarray:
        """``Bᵀ Z`` (``r x q``)."""
        return np.asarray(self.W.T @ self.F.rmul(Z))

    def project(self, Z: np.ndarray) -> np.ndarray:
        """``B Bᵀ Z``: the part of ``Z`` in the column space, as ``A x`` with ``x`` the least-squares solution of
        ``A x = Z`` from ``R``'s factors and one step of refinement on its residual (the corrected semi-normal
        equations: the accuracy of the QR's own projection, where ``A V_r Σ_r⁻¹`` alone loses the condition
        number's digits)."""
        x = self.W @ self.coefficients(Z)
        x += self.W @ self.coefficients(Z - self.F.mul(x))
        return self.F.mul(x)

    def remove(self, Z: np.ndarray) -> None:
        """``Z -= B Bᵀ Z`` in place (``Z (M, q)``): :meth:`project`'s two steps taken off ``Z`` in turn, one
        ``(M, q)`` temporary at a time instead of three (the same numbers to rounding)."""
        Z -= self.F.mul(self.W @ self.coefficients(Z))
        Z -= self.F.mul(self.W @ self.coefficients(Z))


#: bytes of one block of the measurement rows formed dense for :class:`FactoredSpace`'s QR
SPACE_BLOCK_BYTES = 32 * 2**20


def _permutable(rows: np.ndarray, m: int, arrays: list[np.ndarray]) -> bool:
    """Whether ``rows`` is a permutation of ``m`` rows and every array can be reordered where it is (``m`` rows, C
    order, writeable)."""
    return (
        len(rows) == m
        and all(a.shape[0] == m and a.flags.c_contiguous and a.flags.writeable for a in arrays)
        and bool(np.all(np.bincount(rows, minlength=m) == 1))
    )


def _permute_rows(arrays: list[np.ndarray], rows: np.ndarray) -> None:
    """Each distinct array's rows put in the order ``rows`` where it is (an array listed twice, once: the blocks of
    one joint share its response)."""
    seen: set[int] = set()
    for a in arrays:
        if id(a) not in seen:
            seen.add(id(a))
            a[:] = a[rows]


class RowsOf:
    """``S[rows]`` without the copy: a joint-level candidate's signals at the fit rows, as the cross-validation
    reads them (its shape, and the rows of one fold at a time). The residual layer's signals are one
    ``(all rows, 100)`` array its six joints share; six copies at the fit rows were the largest allocation of a
    24 000-row discovery (92 MB)."""

    __slots__ = ("S", "rows")

    def __init__(self, S: np.ndarray, rows: np.ndarray) -> None:
        self.S = S
        rows = np.asarray(rows)
        self.rows = np.flatnonzero(rows) if rows.dtype == bool else rows

    @property
    def shape(self) -> tuple[int, int]:
        return (len(self.rows), int(self.S.shape[1]))

    def __getitem__(self, idx: Any) -> np.ndarray:
        return np.asarray(self.S[self.rows[idx]])


__all__ = ["FactoredJacobian", "FactoredSpace", "JointGram", "RowsOf"]
