"""The linearised pose-grouped cross-validation of discovery, from sufficient statistics (issue 31).

Every fold's refit of the current model is a linear least-squares problem in the model's whitened Jacobian ``A``
(``M x k``) and residuals ``r``: its normal equations need only the fold's Gram ``A_fᵀ A_f`` and ``A_fᵀ r_f``.
They are accumulated once per fit, in row chunks, over the residuals sorted by fold (so a fold is a contiguous
block, never a boolean copy of the rows); the training side of a fold is the total minus the fold (a downdate),
and a candidate's block (``Aᵀ Z``, ``Zᵀ Z``, ``Zᵀ r``) enters by its Schur complement. The held-out errors the
paired test needs are the only per-row quantities: one pass over the rows, ``O(M k)``.

A joint-level candidate's regressor has a product structure: the row's ``d`` residuals respond to a joint-angle
error through ``v_row = J_q[row, :, j] · w_row`` (``d`` numbers), and the candidate's columns are ``v_row ⊗
S_row`` (``S``: its ``q`` signals at that row). Its blocks are formed from per-row projections (``U = Σ_d A_row
v_row``, ``m x k``, shared by every candidate of that joint) without the ``M x q`` matrix, ``d`` times fewer
operations (:meth:`FoldCV.with_joint_variants`).

The fold systems are solved by a Cholesky factorisation of the Jacobi-scaled matrix (``k³/3`` operations, not the
eigendecomposition of a pseudo-inverse); a matrix the factorisation finds singular to working precision falls back
to the pseudo-inverse (``rcond`` 1e-12), which is what the search used before.
"""

from __future__ import annotations

import re
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np
from scipy import linalg, stats

#: residual rows per chunk of an accumulation (bounds the temporaries: chunk x k floats)
CHUNK = 8192

#: bytes of per-row projections (one ``m x k`` matrix per joint) FoldCV keeps: every joint's up to ~12 000 rows
#: (UR10 A: 6 x ~20 MB), the most recent beyond that (at least two joints: 80 000 twin rows 3 x 38 MB)
U_CACHE_BYTES = 128 * 2**20

#: an effect of ``|D|`` columns is left out of the fold systems by bordering the whole model's factorisation
#: (``|D| + 1`` solves, ``2 k²`` each) while ``_BORDER |D|`` is below the kept columns (a new factorisation
#: costs ``k³/3``)
_BORDER = 6

#: reciprocal condition (of the Jacobi-scaled matrix, estimated from the Cholesky diagonal) below which the
#: pseudo-inverse is used instead of the factorisation
_RCOND = 1e-12


class _Variant(Protocol):
    @property
    def columns(self) -> np.ndarray | None: ...
    @property
    def prior_rad(self) -> float | np.ndarray | None: ...


class SymSolver:
    """Solves ``H x = b`` for a symmetric positive semi-definite ``H``: Cholesky of the Jacobi-scaled matrix, or
    its pseudo-inverse (``rcond`` 1e-12, as :func:`numpy.linalg.pinv`) when the factorisation fails or the matrix
    is singular to working precision."""

    def __init__(self, H: np.ndarray) -> None:
        dg = np.sqrt(np.clip(np.diag(H), 0.0, None))
        dg[dg == 0] = 1.0
        self.scale = 1.0 / dg
        self.pinv: np.ndarray | None = None
        self.chol: tuple[np.ndarray, bool] | None = None
        Hs = H * self.scale[:, None] * self.scale[None, :]
        try:
            c, low = linalg.cho_factor(Hs, lower=True, check_finite=False)
            diag = np.abs(np.diag(c))
            if len(diag) and float(np.min(diag)) ** 2 < _RCOND * float(np.max(diag)) ** 2:
                raise np.linalg.LinAlgError("singular to working precision")
            self.chol = (c, low)
        except (np.linalg.LinAlgError, linalg.LinAlgError):
            self.pinv = np.linalg.pinv(H, rcond=1e-12, hermitian=True)

    def solve(self, b: np.ndarray) -> np.ndarray:
        if self.pinv is not None:
            return np.asarray(self.pinv @ b)
        assert self.chol is not None
        s = self.scale if b.ndim == 1 else self.scale[:, None]
        return np.asarray(s * linalg.cho_solve(self.chol, s * b, check_finite=False))


def gram_by_blocks(A: np.ndarray, r: np.ndarray, bounds: Sequence[tuple[int, int]], chunk: int = CHUNK) -> tuple[
    list[np.ndarray], list[np.ndarray]
]:  # fmt: skip
    """Per block ``[s, e)`` of rows: ``A_sᵀ A_s`` and ``A_sᵀ r_s``, accumulated over row chunks of at most ``chunk``
    rows (no temporary larger than ``chunk x k``)."""
    G, b = [], []
    for s, e in bounds:
        Gi = np.zeros((A.shape[1], A.shape[1]))
        bi = np.zeros(A.shape[1])
        for c0 in range(s, e, chunk):
            Ac = A[c0 : min(c0 + chunk, e)]
            Gi += Ac.T @ Ac
            bi += Ac.T @ r[c0 : min(c0 + chunk, e)]
        G.append(Gi)
        b.append(bi)
    return G, b


class FoldCV:
    """Linearised pose-grouped cross-validation at one joint fit (see :mod:`robocal.discovery.grow`).

    ``base_err`` (M,): every residual's held-out error, the model refitted without its fold (original order)."""

    def __init__(self, fit: Any, groups: np.ndarray, folds: int, seed: int) -> None:
        self.fit = fit
        uniq, gidx, _ = group_labels(groups)
        self.gidx = gidx
        self.n_groups = len(uniq)
        perm = np.random.default_rng(seed).permutation(len(uniq))
        self.fold = (perm % folds)[gidx]
        self.folds = [k for k in range(folds) if np.any(self.fold == k)]
        # residuals sorted by fold: each fold a contiguous block
        self.order = np.argsort(self.fold, kind="stable")
        counts = np.bincount(self.fold, minlength=folds)
        ends = np.cumsum(counts)
        self.bounds = [(int(ends[k] - counts[k]), int(ends[k])) for k in self.folds]
        self.d = int(fit.d)
        # the fit's Jacobian in fold order, never a second (M, k) matrix: a fit that can evaluate it again
        # (``Fit.release``) gives up its own, whose rows are put in fold order in place (the folds then read
        # contiguous rows); any other is read fold by fold where it is (:meth:`_fold`, one fold at a time)
        gram = getattr(fit, "gram", None)  # taken before the fit lets its Jacobian go (and the factors)
        self._F = self._factors_in_fold_order(fit)
        self._A: np.ndarray | None = None
        self._J: np.ndarray | None = None
        if self._F is not None:
            self.k = int(self._F.k)
        else:
            J = fit.J_w
            self.k = int(J.shape[1])
            self._A = _sorted_in_place(J, self.order) if _can_release(fit) and len(J) == len(self.order) else None
            self._J = J if self._A is None else None
            del J
            if self._A is not None:
                fit.release()
        self._r = np.asarray(fit.r_w)[self.order]
        self.prec = fit.model.prior_precision()[fit.free]
        self.th = fit.theta[fit.free]
        self._Gf, self._bf = [], []
        for i in range(len(self.bounds)):
            if self._F is not None:
                fr = self._frows(i)
                Gi, bi = self._F.gram.on_dense_rows(self._F.D[slice(*self.bounds[i])], self._F.dc, self.k,
                                                    self._r[slice(*self.bounds[i])], fr)  # fmt: skip
                self._Gf.append(Gi)
                self._bf.append(bi)
                continue
            if gram is not None:  # from the joint-level effects' factors (robocal.discovery.gram): d times cheaper
                Gi, bi = gram.on_rows(self._fold(i), self._r[slice(*self.bounds[i])], self._rows_of_fold(i))
                self._Gf.append(Gi)
                self._bf.append(bi)
                continue
            G1, b1 = gram_by_blocks(self._fold(i), self._r[slice(*self.bounds[i])], [(0, self._count(i))])
            self._Gf += G1
            self._bf += b1
        self.G = np.sum(self._Gf, axis=0) if self._Gf else np.zeros((self.k,) * 2)
        self.b = np.sum(self._bf, axis=0) if self._bf else np.zeros(self.k)
        self._solver: list[SymSolver] = []
        self._g: list[np.ndarray] = []
        err = np.empty_like(self._r)
        for i, (s, e) in enumerate(self.bounds):
            H = self.G - self._Gf[i] + np.diag(self.prec)
            g = self.b - self._bf[i] + self.prec * self.th
            sol = SymSolver(H)
            self._solver.append(sol)
            self._g.append(g)
            err[s:e] = self._r[s:e] - self._mul(i, sol.solve(g))
        self._err_sorted = err
        self.base_err = self._unsort(err)
        self._U: OrderedDict[int, list[np.ndarray]] = OrderedDict()

    # -- helpers ---------------------------------------------------------------------------------------------
    def _factors_in_fold_order(self, fit: Any) -> Any:
        """A fit holding its Jacobian by its factors (the residual layer's, robocal.discovery.gram) is read by them:
        their rows put in fold order once (a fold is then a slice of them, read in place), the fit's own let go
        (evaluated again if read). None for a fit of a dense Jacobian."""
        F: Any = fit.factors() if hasattr(fit, "factors") else None
        if F is None:
            return None
        own_gram = getattr(fit, "gram", None) is F.gram
        own = getattr(fit, "factored", None) is F
        if own:
            fit.factored = None
            if own_gram:
                fit.gram = None
        # the factors the fit gives up (its own: evaluated for it, held by nothing else) reordered where they are
        return F.take(self.order[:: self.d] // self.d, in_place=own)

    def _mul(self, i: int, y: np.ndarray) -> np.ndarray:
        """``A_i y``: fold ``i``'s rows of the whitened Jacobian times ``y (k,)`` or ``(k, p)``."""
        if self._F is not None:
            return self._F.mul(y, self._frows(i))
        return self._fold(i) @ y

    def _rmul(self, i: int, X: np.ndarray) -> np.ndarray:
        """``A_iᵀ X`` of fold ``i``'s rows ``X``."""
        if self._F is not None:
            return self._F.rmul(X, self._frows(i))
        return self._fold(i).T @ X

    def _fold(self, i: int) -> np.ndarray:
        """The whitened Jacobian's rows of fold ``i`` in the sorted order (a copy of that fold only)."""
        s, e = self.bounds[i]
        if self._A is not None:
            return self._A[s:e]
        assert self._J is not None  # read in place
        return np.asarray(self._J[self.order[s:e]])

    def _count(self, i: int) -> int:
        s, e = self.bounds[i]
        return e - s

    def _unsort(self, e_sorted: np.ndarray) -> np.ndarray:
        out = np.empty_like(e_sorted)
        out[self.order] = e_sorted
        return out

    def group_sse(self, err: np.ndarray) -> np.ndarray:
        return np.bincount(self.gidx, weights=err**2, minlength=self.n_groups)

    def base_err_without(self, keep: np.ndarray) -> np.ndarray:
        """The held-out errors of the fit seen with only the free parameters ``keep`` (positions in
        ``fit.free``; the residual gains back what the others explained, first order, as
        :func:`robocal.discovery.grow.replace_fit_columns`), from this fit's fold sums: no pass over the rows but
        the prediction of the held-out residuals."""
        keep = np.asarray(keep, dtype=int)
        drop = np.setdiff1d(np.arange(self.k), keep)
        th_d = self.th[drop]
        if not len(drop):
            r2 = self._r
        elif self._F is not None:  # the dropped columns' share from the factors, never the (M, |drop|) columns
            y = np.zeros(self.k)
            y[drop] = th_d
            r2 = self._r - self._F.mul(y)  # (its rows in fold order)
        elif self._A is not None:
            r2 = self._r - self._A[:, drop] @ th_d
        else:
            assert self._J is not None
            r2 = self._r - self._J[self.order[:, None], drop[None, :]] @ th_d
        if 0 < len(drop) and _BORDER * len(drop) < len(keep) and all(s.chol is not None for s in self._solver):
            return self._unsort(self._bordered(r2, drop, th_d))
        Gkd = [Gi[np.ix_(keep, drop)] for Gi in self._Gf]
        bf = [bi[keep] - Gd @ th_d for bi, Gd in zip(self._bf, Gkd, strict=True)]
        b = np.sum(bf, axis=0)
        G = self.G[np.ix_(keep, keep)]
        prec, th = self.prec[keep], self.th[keep]
        err = np.empty_like(self._r)
        for i, (s, e) in enumerate(self.bounds):
            H = G - self._Gf[i][np.ix_(keep, keep)] + np.diag(prec)
            g = b - bf[i] + prec * th
            y = np.zeros(self.k)  # the step on the kept columns, zero on the others: no column copy
            y[keep] = SymSolver(H).solve(g)
            err[s:e] = r2[s:e] - self._mul(i, y)
        return self._unsort(err)

    def _bordered(self, r2: np.ndarray, drop: np.ndarray, th_d: np.ndarray) -> np.ndarray:
        """:meth:`base_err_without` (sorted order) from each fold's factorisation of the whole model: the step on
        the kept columns is the whole system's solution constrained to zero on the dropped ones (bordering:
        ``y = u - W (W_D)⁻¹ u_D``, ``u = H⁻¹ g'``, ``W = H⁻¹ E_D``), ``|D| + 1`` solves instead of a new
        factorisation of the kept columns (the same numbers to round-off)."""
        err = np.empty_like(self._r)
        nd = len(drop)
        E = np.zeros((self.k, nd))
        E[drop, np.arange(nd)] = 1.0
        for i, (s, e) in enumerate(self.bounds):
            sol = self._solver[i]
            Hd = self.G[:, drop] - self._Gf[i][:, drop]
            Hd[drop, np.arange(nd)] += self.prec[drop]
            u = sol.solve(self._g[i] - Hd @ th_d)  # the kept columns' right-hand side (g_K - H_KD th_D)
            W = sol.solve(E)
            y = u - W @ np.linalg.solve(W[drop], u[drop])
            y[drop] = 0.0
            err[s:e] = r2[s:e] - self._mul(i, y)
        return err

    # -- candidates ------------------------------------------------------------------------------------------
    def with_variants(self, Z: np.ndarray, variants: Sequence[_Variant]) -> list[np.ndarray]:
        """Held-out errors (M,) of each variant (columns of ``Z (M, q)`` and a prior). The products with the
        model's Jacobian are formed once for all columns; each variant slices them (``W = H⁻¹ C`` commutes with
        taking columns) and solves only its own Schur complement."""
        Zs = Z[self.order]
        Ct, Z2t, bzt = [], [], []
        for i, (s, e) in enumerate(self.bounds):
            Zt = Zs[s:e]
            Ct.append(self._rmul(i, Zt))
            Z2t.append(Zt.T @ Zt)
            bzt.append(Zt.T @ self._r[s:e])

        def apply_z(i: int, DZ: np.ndarray) -> np.ndarray:
            s, e = self.bounds[i]
            return np.asarray(Zs[s:e] @ DZ)

        return self._variants(Z.shape[1], Ct, Z2t, bzt, apply_z, variants)

    def _frows(self, i: int) -> slice:
        """Fold ``i``'s measurement rows among the fold-ordered factors (``self._F``): a slice."""
        s, e = self.bounds[i]
        return slice(s // self.d, e // self.d)

    def _rows_of_fold(self, i: int) -> np.ndarray:
        """The fit rows (measurement rows, not residuals) of fold ``i`` in the sorted order."""
        s, e = self.bounds[i]
        return np.asarray(self.order[s : e : self.d] // self.d)

    def _u(self, j: int, v: np.ndarray) -> list[np.ndarray]:
        """Per fold, ``U = Σ_d A_row v_row`` (rows x k) for joint ``j`` (0-based) with ``v (m, d)``: kept for the
        joints met last within :data:`U_CACHE_BYTES` (the pool visits the joints in turn, and a pooled candidate
        all of them; each is ``m x k``)."""
        if j in self._U:
            self._U.move_to_end(j)
            return self._U[j]
        out = []
        for i, (s, e) in enumerate(self.bounds):
            rows = self._rows_of_fold(i)
            if self._F is not None:
                out.append(self._F.joint_response(v[rows], self._frows(i)))
                continue
            A3 = self._fold(i).reshape((e - s) // self.d, self.d, -1)
            out.append(np.einsum("rdk,rd->rk", A3, v[rows], optimize=True))
        self._U[j] = out
        size = sum(u.nbytes for u in out)
        while len(self._U) > max(2, U_CACHE_BYTES // max(size, 1)):
            self._U.popitem(last=False)
        return out

    def joint_v(self, j: int) -> np.ndarray:
        """``v (m, d)``: the whitened response of each row's residuals to joint ``j``'s (0-based) angle."""
        fit = self.fit
        return np.asarray(fit.Jq[:, :, j] * fit.weights.reshape(-1, self.d))

    def with_joint_variants(
        self, blocks: Sequence[tuple[int, np.ndarray]], variants: Sequence[_Variant]
    ) -> list[np.ndarray]:
        """:meth:`with_variants` for joint-level candidates given by their factors: ``blocks`` of ``(joint
        (0-based), S (m, q_b))`` (the signals at the fit rows), the columns of ``Z`` in block order. The same
        numbers without forming ``Z`` (see the module docstring)."""
        vs = {j: self.joint_v(j) for j, _ in blocks}
        offs = np.cumsum([0] + [S.shape[1] for _, S in blocks])
        q = int(offs[-1])
        Z2t: list[np.ndarray] = []

        def fold_blocks(i: int) -> list[tuple[np.ndarray, np.ndarray]]:
            """``(v_t, S_t)`` per block on fold ``i``'s rows: gathered again where needed, not kept for every fold
            (the residual layer's six 100-column blocks are 0.4 GB at 80 000 rows)."""
            rows = self._rows_of_fold(i)
            return [(vs[ja][rows], Sa[rows]) for ja, Sa in blocks]

        nf = len(self.bounds)
        Ct = [np.empty((self.k, q)) for _ in range(nf)]
        bzt = [np.empty(q) for _ in range(nf)]
        # each block's joint response read once for all the folds (block by block: fold by fold, the residual
        # layer's six joints turned the cache over and every joint's response was formed again per fold, 30 for 6)
        for a, (ja, Sa) in enumerate(blocks):
            U = self._u(ja, vs[ja])
            for i, (s, e) in enumerate(self.bounds):
                rows = self._rows_of_fold(i)
                Sat, r3 = Sa[rows], self._r[s:e].reshape(-1, self.d)
                Ct[i][:, offs[a] : offs[a + 1]] = U[i].T @ Sat
                bzt[i][offs[a] : offs[a + 1]] = Sat.T @ np.einsum("rd,rd->r", vs[ja][rows], r3)
            del U
        for i in range(nf):
            Z2 = np.empty((q, q))
            fb = fold_blocks(i)
            for a in range(len(blocks)):
                va, Sat = fb[a]
                for b in range(a, len(blocks)):
                    vb, Sbt = fb[b]
                    blk = (Sat * np.einsum("rd,rd->r", va, vb)[:, None]).T @ Sbt
                    Z2[offs[a] : offs[a + 1], offs[b] : offs[b + 1]] = blk
                    if b != a:
                        Z2[offs[b] : offs[b + 1], offs[a] : offs[a + 1]] = blk.T
            Z2t.append(Z2)
            del fb

        def apply_z(i: int, DZ: np.ndarray) -> np.ndarray:
            fb = fold_blocks(i)
            out = np.zeros((*fb[0][0].shape, DZ.shape[1]))
            for a, (va, Sat) in enumerate(fb):
                Da = DZ[offs[a] : offs[a + 1]]
                if np.any(Da):
                    out += va[:, :, None] * (Sat @ Da)[:, None, :]
            return out.reshape(-1, DZ.shape[1])

        return self._variants(q, Ct, Z2t, bzt, apply_z, variants)

    def _variants(
        self,
        q_all: int,
        Ct: list[np.ndarray],
        Z2t: list[np.ndarray],
        bzt: list[np.ndarray],
        apply_z: Callable[[int, np.ndarray], np.ndarray],
        variants: Sequence[_Variant],
    ) -> list[np.ndarray]:
        """Each variant's held-out errors: per fold, every variant's small Schur system solved first, then the
        held-out rows' response to all variants at once (``Z_t DZ - A_t (W DZ)``: one pass over the fold's rows
        of the model's Jacobian for all variants, not one per variant)."""
        C_all, Z2_all, bz_all = sum(Ct), sum(Z2t), sum(bzt)
        per_fold = []
        for i in range(len(self.bounds)):
            C = C_all - Ct[i]
            per_fold.append((Z2_all - Z2t[i], bz_all - bzt[i], C, self._solver[i].solve(C)))
        cols_of, pz_of = [], []
        for v in variants:
            cols = np.arange(q_all) if v.columns is None else np.asarray(v.columns)
            cols_of.append(cols)
            pz_of.append(
                np.zeros(len(cols)) if v.prior_rad is None else 1.0 / np.broadcast_to(v.prior_rad, (len(cols),)) ** 2
            )
        errs = np.repeat(self._err_sorted[:, None], len(variants), axis=1)
        for i, (s, e) in enumerate(self.bounds):
            Z2, bz, C, W = per_fold[i]
            DZ = np.zeros((q_all, len(variants)))
            for vi, cols in enumerate(cols_of):
                Wc = W[:, cols]
                Sz = Z2[np.ix_(cols, cols)] + np.diag(pz_of[vi]) - C[:, cols].T @ Wc
                rhs = bz[cols] - Wc.T @ self._g[i]
                try:
                    DZ[cols, vi] = -np.linalg.solve(Sz, rhs)
                except np.linalg.LinAlgError:
                    DZ[cols, vi] = -np.linalg.lstsq(Sz, rhs, rcond=1e-12)[0]
            # held-out response to the candidate with the model refitted: Z_t dz - A_t (W dz), every variant
            errs[s:e] += apply_z(i, DZ) - self._mul(i, W @ DZ)
        return [self._unsort(errs[:, vi]) for vi in range(len(variants))]


def _can_release(fit: Any) -> bool:
    """Whether ``fit`` lets its ``J_w`` go on :meth:`robocal.discovery.model.Fit.release` (evaluated again when
    read later)."""
    return hasattr(fit, "release") and all(getattr(fit, a, None) is not None for a in ("data", "rows", "w"))


def _sorted_in_place(J: np.ndarray, order: np.ndarray) -> np.ndarray | None:
    """``J[order]`` in ``J``'s own memory (the rows moved along the permutation's cycles, one row's buffer),
    or None when ``J`` cannot be written (not C-contiguous, or its owner read-only to the end)."""
    owner = J if J.base is None else J.base
    if not (J.flags.c_contiguous and isinstance(owner, np.ndarray) and owner.base is None):
        return None
    try:
        owner.setflags(write=True)
        J.setflags(write=True)
    except ValueError:
        return None
    done = np.zeros(len(order), dtype=bool)
    for i in range(len(order)):
        if done[i] or order[i] == i:
            continue
        tmp = J[i].copy()
        j = i
        while True:
            done[j] = True
            src = int(order[j])
            if src == i:
                J[j] = tmp
                break
            J[j] = J[src]
            j = src
    J.setflags(write=False)
    owner.setflags(write=False)
    return J


_LAST: list[tuple[Any, np.ndarray, int, int, FoldCV]] = []


def group_labels(groups: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(groups, return_inverse=True, return_counts=True)`` with the labels in natural order (runs of
    digits compared as numbers), the order the folds are drawn in: a campaign whose pose ids are integers (0, 1, 2,
    ..., 10) gets the folds its zero-padded ids (p00, p01, ...) get. ``np.unique`` sorts them as text ("10" before
    "2"), so the same poses fell in other folds and, on a near tie, other effects were named. Ids of one padded
    width keep ``np.unique``'s order. The last array asked for is answered again without sorting (the search asks
    for its one ``groups`` at every fold set: 16 ms a time at 12 000 rows)."""
    if _LABELS and _LABELS[0][0] is groups:
        return _LABELS[0][1]
    uniq, inv, counts = np.unique(np.asarray(groups).astype(str), return_inverse=True, return_counts=True)

    def key(label: str) -> tuple[tuple[int, int, str], ...]:
        return tuple((0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", label) if t)

    order = sorted(range(len(uniq)), key=lambda i: key(str(uniq[i])))
    rank = np.empty(len(uniq), dtype=int)
    rank[order] = np.arange(len(uniq))
    out = (uniq[order], rank[inv], counts[order])
    if isinstance(groups, np.ndarray) and not groups.flags.writeable:  # an array nobody can change: kept
        _LABELS[:] = [(groups, out)]
    return out


#: the last read-only ``groups`` array :func:`group_labels` sorted, and its answer
_LABELS: list[tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]] = []


def pose_groups(pose_id: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The cross-validation's groups, one label per row: the rows of one pose, joined with every row measured at
    the same joint configuration under another pose id (:func:`robocal.identification.thin.configuration_groups`),
    so that no fold is judged on a configuration another fold was fitted on. Labelled by the pose id of the
    group's first row (a campaign without repeats keeps its pose ids)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from robocal.identification.thin import configuration_groups

    pid = np.asarray(pose_id).astype(str)
    m = len(pid)
    if m == 0:
        return pid
    _, pose = np.unique(pid, return_inverse=True)
    n_cfg, cfg = configuration_groups(q)
    # a graph of poses and configurations, each row an edge between its pose and its configuration
    n_pose = int(pose.max()) + 1
    graph = coo_matrix((np.ones(m), (pose, n_pose + cfg)), shape=(n_pose + n_cfg,) * 2)
    _, comp = connected_components(graph, directed=False)
    _, first, group = np.unique(comp[pose], return_index=True, return_inverse=True)
    return pid[first[group]]


def fold_cv(fit: Any, groups: np.ndarray, folds: int, seed: int) -> FoldCV:
    """:class:`FoldCV` of ``fit``, reused when the last one asked for was of the same fit object, groups, folds
    and seed (the selection, the layer and the held-out check ask for the same fit's folds in turn)."""
    if _LAST:
        f, g, k, s, cv = _LAST[0]
        if f is fit and (g is groups or np.array_equal(g, groups)) and k == folds and s == seed:
            return cv
    _LAST.clear()  # the previous fit's sums are let go before the new ones are formed
    cv = FoldCV(fit, groups, folds, seed)
    _LAST.append((fit, groups, folds, seed, cv))
    return cv


def clear_cache() -> None:
    """Let go of the :func:`fold_cv` kept (its fit's Jacobian and the fold sums): at the end of a search."""
    _LAST.clear()


def paired_log10_p(sse0: np.ndarray, sse1: np.ndarray) -> float:
    """log10 p of the one-sided paired t-test that the held-out error per pose fell (``sse0 - sse1 > 0``)."""
    d = sse0 - sse1
    # differences at the round-off of the held-out sums (a candidate the model absorbs changes them by ~1e-12
    # relative) carry no evidence: their t statistic is the arithmetic's noise, any sign and size
    if len(d) < 3 or float(np.std(d)) == 0.0 or float(np.max(np.abs(d))) <= 1e-9 * float(np.max(sse0)):
        return 0.0
    t = float(np.mean(d) / (np.std(d, ddof=1) / np.sqrt(len(d))))
    return float(stats.t.logsf(t, len(d) - 1) / np.log(10.0))


def pose_paired_log10_p(
    groups: np.ndarray, with_: tuple[np.ndarray, np.ndarray], without: tuple[np.ndarray, np.ndarray]
) -> float:
    """log10 p of the paired test over poses that the held-out error of the sessions left out fell without the
    effect (``with_`` / ``without``: :meth:`robocal.discovery.session_cv.Sessions.errors`' residuals and rows)."""
    _, gidx, _ = group_labels(groups)
    (e1, m1), (e0, m0) = with_, without
    n = int(gidx.max()) + 1 if len(gidx) else 0
    sse1 = np.bincount(gidx[m1], weights=e1[m1] ** 2, minlength=n)
    sse0 = np.bincount(gidx[m0], weights=e0[m0] ** 2, minlength=n)
    seen = np.bincount(gidx[m1 | m0], minlength=n) > 0
    return paired_log10_p(sse1[seen], sse0[seen])


__all__ = [
    "CHUNK",
    "FoldCV",
    "SymSolver",
    "clear_cache",
    "fold_cv",
    "gram_by_blocks",
    "group_labels",
    "paired_log10_p",
    "pose_groups",
    "pose_paired_log10_p",
]
