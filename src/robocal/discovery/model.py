"""The calibration model extended with accepted effects, and its joint nonlinear fit.

Parameters: the geometric calibration vector of :class:`robocal.identification.model.CalibrationModel`
(kinematic errors, base, tools) followed by the coefficients of every accepted effect. Joint-angle effects
enter exactly (the joint angles are corrected before the forward kinematics); parameter drifts enter to first
order (``dp = J_x · dx``: a drift of 0.1 mm or 1e-4 rad leaves a second-order term below 1e-5 mm).

Residuals are ordered row by row, ``d`` per row: the position (mm) and, with a 6-DoF probe, the orientation
(rad, rotation vector) of each measurement, so that ``r.reshape(m, d)`` is one row per measurement.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from robocal.discovery.candidates import Candidate, with_beta
from robocal.discovery.gram import FactoredJacobian, JointGram
from robocal.identification.identifiability import analyse
from robocal.identification.model import CalibrationModel, FitData
from robocal.metrics import ErrorStats, noise_floor
from robocal.numerics import attach_gram, gram_of
from robocal.optimizers.least_squares import least_squares
from robocal.robot import RobotDescription


@dataclass(frozen=True)
class Accepted:
    """An accepted candidate with the calibration parameters it drifts (``param`` shape)."""

    cand: Candidate
    params: tuple[str, ...] = ()

    @property
    def coef_names(self) -> tuple[str, ...]:
        c = self.cand
        if c.shape == "param":
            return tuple(f"{c.key}:{p}*{s}" for p in self.params for s in c.signal_names)
        if c.shape == "structure":
            return ()  # lives in the base model (beta parameter)
        return tuple(f"{c.key}:{n}" for n in c.coef_names)


def robot_with(robot: RobotDescription, accepted: list[Accepted]) -> RobotDescription:
    for a in accepted:
        if a.cand.shape == "structure" and a.cand.effect == "beta":
            assert a.cand.joint is not None
            robot = with_beta(robot, a.cand.joint)
    return robot


class ExtendedModel:
    """Geometric calibration model + accepted effects; residuals (predicted - measured) and Jacobian."""

    def __init__(
        self,
        robot: RobotDescription,
        targets: tuple[str, ...],
        T_ref: np.ndarray,
        accepted: list[Accepted],
        like: CalibrationModel | None = None,
        base_prior: np.ndarray | None = None,
    ) -> None:
        """``like``: a geometric model whose orientation use, tool frames and tracker stations to copy;
        ``base_prior``: precision ``(nb,)`` of a prior toward nominal (zero) on the geometric parameters, the
        calibration's on a thin or sparse campaign (:mod:`robocal.identification.thin`), or None."""
        self.robot = robot_with(robot, accepted)
        if like is None:
            self.base = CalibrationModel(self.robot, targets, orientation=False, T_ref=T_ref)
        else:
            self.base = CalibrationModel(
                self.robot,
                targets,
                orientation=like.orientation,
                T_ref=T_ref,
                tool_R_ref=like.tool_R_ref,
                stations=like.station_names,
                station_T_ref=like.station_T_ref,
            )
        self.accepted = list(accepted)
        self.nb = self.base.n
        self.base_prior = base_prior
        names = list(self.base.names)
        self.slices: list[slice] = []
        for a in self.accepted:
            k0 = len(names)
            names += list(a.coef_names)
            self.slices.append(slice(k0, len(names)))
        self.names = tuple(names)
        self.n = len(names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def prior_precision(self) -> np.ndarray:
        """``(n,)`` precision ``1 / tau²`` of the Gaussian prior on each parameter (0 = none): an effect with
        many coefficients (``Candidate.extra["prior_rad"]``, rad per coefficient) is fitted as a ridge."""
        out = np.zeros(self.n)
        if self.base_prior is not None:
            out[: self.nb] = self.base_prior
        for a, sl in zip(self.accepted, self.slices, strict=True):
            tau = a.cand.extra.get("prior_rad")
            if tau is not None and a.cand.shape == "joint":
                out[sl] = 1.0 / np.broadcast_to(np.asarray(tau, dtype=float), (sl.stop - sl.start,)) ** 2
        return out

    def map_from(self, names: tuple[str, ...], theta: np.ndarray) -> np.ndarray:
        """A parameter vector for this model from another model's (missing names start at zero)."""
        lookup = dict(zip(names, theta, strict=True))
        return np.array([lookup.get(n, 0.0) for n in self.names])

    def joint_offsets(self, theta: np.ndarray, rows: np.ndarray, m_all: int) -> np.ndarray:
        dq = np.zeros((len(rows), self.robot.n_joints))
        for a, sl in zip(self.accepted, self.slices, strict=True):
            if a.cand.shape == "joint":
                assert a.cand.joint is not None
                dq[:, a.cand.joint - 1] += a.cand.S[rows] @ theta[sl]
        return dq

    def per_row(self, data: FitData) -> int:
        """Residuals per measurement: 3 (position) or 6 (position and orientation)."""
        return 6 if (self.base.orientation and data.R_meas is not None) else 3

    def residuals_and_jacobian(
        self,
        theta: np.ndarray,
        data: FitData,
        rows: np.ndarray,
        extra_rows: int = 0,
        cols: np.ndarray | None = None,
        joint_blocks: list[tuple[np.ndarray, int, np.ndarray]] | None = None,
        order: str = "C",
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Residuals ``(d m,)`` row by row, Jacobian ``(d m, n)``, and the base Jacobians ``J_x (m, d, nb)``,
        ``J_q (m, d, N)`` (``d`` = :meth:`per_row`).

        ``rows`` index the campaign rows of ``data`` (signals are stored for every campaign row).
        ``extra_rows``: the Jacobian is allocated with that many more rows (zero) below, for a caller that
        appends rows of its own (a prior) without copying the ``(d m, n)`` matrix.
        ``cols``: only these columns of the Jacobian (sorted parameter indices: a fit's free parameters), built
        in place — the same numbers as ``J[:, cols]`` without the ``(d m, n)`` matrix.
        ``joint_blocks``: a list to which each joint-level effect's built columns are added as ``(their positions
        in J, the joint (0-based), S (m, q) on those columns)`` (its columns are ``J_q[:, :, joint] ⊗ S``).
        ``order``: the Jacobian's memory order ("F": column-major, for a QR in place; the same numbers).
        """
        x = theta[: self.nb]
        m = data.m
        dd = self.per_row(data)
        dq = self.joint_offsets(theta, rows, 0)
        d = data.with_q(data.q + dq)
        r, Jb = self.base.residuals_and_jacobian(x, d)
        r, Jb = by_row(r, m, dd), by_row(Jb, m, dd)
        Jx = Jb.reshape(m, dd, self.nb)
        Jq_p, Jq_w = self.base.joint_jacobians(x, d)
        Jq = Jq_p if Jq_w is None else np.concatenate([Jq_p, Jq_w], axis=1)
        pos = np.arange(self.n) if cols is None else column_positions(self.n, cols)
        n_out = self.n if cols is None else len(cols)
        J_all = np.zeros((dd * m + extra_rows, n_out), order="F" if order == "F" else "C")
        J = J_all[: dd * m]
        bsel = np.flatnonzero(pos[: self.nb] >= 0)
        if len(bsel) == self.nb and cols is None:
            J[:, : self.nb] = Jb
        elif len(bsel):
            J[:, pos[bsel]] = Jb[:, bsel]
        Jv = J.reshape(m, dd, n_out)  # a view in either order (one axis split)
        assert n_out == 0 or m == 0 or np.shares_memory(Jv, J)
        rv = r.reshape(m, dd).copy()

        def put(
            sl: slice, block: np.ndarray | None = None, joint: int | None = None, S: np.ndarray | None = None
        ) -> None:
            put_block(Jv, pos[sl], block, None if joint is None else Jq[:, :, joint], S)
            if joint_blocks is not None and joint is not None and S is not None:
                p = pos[sl]
                sel = np.flatnonzero(p >= 0)
                if len(sel):
                    joint_blocks.append((p[sel], joint, S if len(sel) == len(p) else S[:, sel]))

        for a, sl in zip(self.accepted, self.slices, strict=True):
            c = a.cand
            if c.shape == "joint":
                assert c.joint is not None
                put(sl, joint=c.joint - 1, S=c.S[rows])
            elif c.shape == "param":
                idx = [self.base.index(p) for p in a.params]
                S = c.S[rows]  # (m, s)
                blk = Jx[:, :, idx][:, :, :, None] * S[:, None, None, :]  # (m, d, P, s)
                blk = blk.reshape(m, dd, -1)
                put(sl, blk)
                rv += np.einsum("mij,j->mi", blk, theta[sl])
            elif c.shape == "tracker":
                blk = tracker_columns(c, rows, dd)
                put(sl, blk)
                rv += np.einsum("mij,j->mi", blk, theta[sl])
            elif c.shape == "frame":  # the base or the tool following a logged signal (first order)
                from robocal.discovery.logged import frame_rows

                blk = frame_rows(c, Jx, self.base, x, data.target_index, rows)
                put(sl, blk)
                rv += np.einsum("mij,j->mi", blk, theta[sl])
            elif c.shape == "axis":  # a linear axis's carriage error along its travel (first order)
                from robocal.discovery.axes import axis_rows

                blk = axis_rows(c, self.base, x, d, rows, dd)
                put(sl, blk)
                rv += np.einsum("mij,j->mi", blk, theta[sl])
        return rv.ravel(), J_all, Jx, Jq  # (J_all is J with extra_rows 0: the owner, not a view)

    def base_jacobians(self, theta: np.ndarray, data: FitData, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``J_x (m, d, nb)`` and ``J_q (m, d, N)`` of :meth:`residuals_and_jacobian` without its ``(d m, n)``
        Jacobian (the same numbers)."""
        x = theta[: self.nb]
        m = data.m
        dd = self.per_row(data)
        d = data.with_q(data.q + self.joint_offsets(theta, rows, 0))
        _, Jb = self.base.residuals_and_jacobian(x, d)
        Jx = by_row(Jb, m, dd).reshape(m, dd, self.nb)
        Jq_p, Jq_w = self.base.joint_jacobians(x, d)
        return Jx, (Jq_p if Jq_w is None else np.concatenate([Jq_p, Jq_w], axis=1))


#: a refit whose joint-level effects' columns would take more than this many bytes holds its Jacobian by its
#: factors (:class:`robocal.discovery.gram.FactoredJacobian`): the residual layer's (issue 31)
FACTOR_BYTES = 64 * 2**20


def joint_columns(model: ExtendedModel, free: np.ndarray, rows: np.ndarray) -> list[tuple[np.ndarray, int, np.ndarray]]:
    """Every joint-level effect's free columns as ``(their positions among free, the joint (0-based), S (m, q) on
    those columns)``: the blocks :meth:`ExtendedModel.residuals_and_jacobian` reports, without the Jacobian."""
    pos = column_positions(model.n, free)
    out = []
    for a, sl in zip(model.accepted, model.slices, strict=True):
        if a.cand.shape != "joint":
            continue
        assert a.cand.joint is not None
        p = pos[sl]
        sel = np.flatnonzero(p >= 0)
        if len(sel):
            S = a.cand.S[rows]
            out.append((p[sel], a.cand.joint - 1, S if len(sel) == len(p) else S[:, sel]))
    return out


def factor(M: int, jblocks: list[tuple[np.ndarray, int, np.ndarray]]) -> bool:
    """Whether a fit of ``M`` residuals holds its Jacobian by its factors (:data:`FACTOR_BYTES`)."""
    return M * sum(len(p) for p, _, _ in jblocks) * 8 > FACTOR_BYTES


def factored_jacobian(
    model: ExtendedModel,
    theta: np.ndarray,
    data: FitData,
    rows: np.ndarray,
    free: np.ndarray,
    w: np.ndarray,
    jblocks: list[tuple[np.ndarray, int, np.ndarray]],
) -> tuple[np.ndarray, FactoredJacobian]:
    """The refit's whitened residuals (the measurements', then the prior's rows on the free parameters under one)
    and its Jacobian on ``free`` held by its factors (``jblocks``: :func:`joint_columns`); ``w`` the measurement
    residuals' weights."""
    prec = model.prior_precision()
    ridge_pos = np.flatnonzero(prec[free] > 0)
    ridge, sq = free[ridge_pos], np.sqrt(prec[free[ridge_pos]])
    M = len(w)
    d = model.per_row(data)
    dpos = np.setdiff1d(np.arange(len(free)), np.concatenate([p for p, _, _ in jblocks]))
    r, D, _, Jq = model.residuals_and_jacobian(theta, data, rows, cols=free[dpos])
    D *= w[:, None]
    gram = JointGram(M, d, w[:d], Jq, jblocks, ridge_pos, sq, merge=False)
    return np.concatenate([w * r, sq * theta[ridge]]), FactoredJacobian(D, dpos, len(free), gram)


def column_positions(n: int, cols: np.ndarray) -> np.ndarray:
    """``(n,)``: where each of ``n`` parameters' column goes among the columns ``cols`` built (-1: not built)."""
    pos = np.full(n, -1)
    pos[np.asarray(cols, dtype=int)] = np.arange(len(cols))
    return pos


def put_block(
    Jv: np.ndarray, p: np.ndarray, block: np.ndarray | None, v: np.ndarray | None, S: np.ndarray | None
) -> None:
    """An effect's columns into ``Jv (m, d, n_out)``, only those built (``p``: each column's position, -1 none):
    ``block (m, d, q)``, or a joint effect's ``v ⊗ S`` (``v (m, d)`` the rows' response to the joint, ``S (m, q)``)
    formed on the built columns alone."""
    sel = np.flatnonzero(p >= 0)
    if not len(sel):
        return
    full = len(sel) == len(p)
    dp = p[sel]
    # consecutive columns (every column of a block: always so for a block under a prior) are a slice
    dst: slice | np.ndarray = slice(int(dp[0]), int(dp[-1]) + 1) if dp[-1] - dp[0] == len(dp) - 1 else dp
    if block is not None:
        Jv[:, :, dst] = block if full else block[:, :, sel]
        return
    assert v is not None and S is not None
    Ss = S if full else S[:, sel]
    if isinstance(dst, slice):  # the product written in place: no (m, d, q) temporary
        np.multiply(v[:, :, None], Ss[:, None, :], out=Jv[:, :, dst])
    else:
        Jv[:, :, dst] = v[:, :, None] * Ss[:, None, :]


def tracker_columns(cand: Candidate, rows: np.ndarray, d: int = 3) -> np.ndarray:
    """``(m, d, k)`` displacement columns of a tracker-scale effect on campaign rows ``rows``: the measured point
    (``cand.extra["p_mm"]``, tracker or station frame, about the tracker head) times each scale signal
    ``cand.S``; a scale turns no orientation.

    (First order: the scale ``s`` is ~1e-5, so ``s p_meas`` and ``s p_true`` differ by ``s`` times the
    residual, far below the noise.)"""
    p = np.asarray(cand.extra["p_mm"], dtype=float)[rows]
    S = cand.S[rows]
    out = np.zeros((len(p), d, S.shape[1]))
    out[:, :3, :] = p[:, :, None] * S[:, None, :]
    return out


def by_row(a: np.ndarray, m: int, d: int) -> np.ndarray:
    """Reorder residuals (or Jacobian rows) from the geometric model's layout ``[positions (3m), rotations
    (3m)]`` to row by row ``[p_1, w_1, p_2, w_2, ...]`` (unchanged when ``d == 3``)."""
    if d == 3:
        return a
    rest = a.shape[1:]
    return a.reshape(2, m, 3, *rest).swapaxes(0, 1).reshape(6 * m, *rest)


@dataclass
class Fit:
    """A joint fit of an :class:`ExtendedModel`: whitened residuals and Jacobian on the free parameters."""

    model: ExtendedModel
    theta: np.ndarray
    free: np.ndarray
    r_w: np.ndarray  # (M,) whitened residuals
    J_w: np.ndarray  # (M, k) whitened Jacobian on the free parameters
    Jx: np.ndarray  # (m, d, nb)
    Jq: np.ndarray  # (m, d, N)
    cov: np.ndarray  # (k, k) covariance of the free parameters (s² (JᵀJ)⁻¹), in their units
    s2: float
    sigma: float  # position noise (mm, per coordinate)
    eliminated: tuple[str, ...]
    rows: np.ndarray | None = None  # campaign rows fitted
    w: np.ndarray | None = None  # (M,) weights (1/sigma) of every residual; None: 1/sigma for all
    # the fit data ``J_w`` was evaluated on: with it :meth:`release` may let ``J_w`` go (evaluated again when asked)
    data: FitData | None = field(default=None, repr=False, compare=False)
    # the joint-level effects' factors of ``J_w`` (robocal.discovery.gram): the folds' Grams from them; None without
    gram: JointGram | None = field(default=None, repr=False, compare=False)
    # the whole ``J_w`` held by its factors (a fit with the residual layer: robocal.discovery.gram); None: dense
    factored: FactoredJacobian | None = field(default=None, repr=False, compare=False)

    def release(self) -> None:
        """Let go of ``J_w`` (an ``(M, k)`` matrix: the previous fit's, while the next one is fitted); the next
        read of ``J_w`` evaluates it again at ``theta`` — the same numbers, the model's Jacobian on the free
        columns whitened as the solver's. A fit without its data keeps its matrix."""
        if self.release_jacobian():
            self.gram = None  # (m, q) signals and (m, d) responses per joint: not held beside the next fit's
            self.factored = None

    def release_jacobian(self) -> bool:
        """Let go of ``J_w`` only (the joint-level factors kept); whether it was let go (a fit without its data
        keeps its matrix)."""
        if self.data is not None and self.rows is not None and self.w is not None:
            self.__dict__.pop("J_w", None)
            return True
        return False

    def __getattr__(self, name: str) -> np.ndarray:
        # only called when ``J_w`` was released (a field found in __dict__ never comes here)
        d = self.__dict__
        if name != "J_w" or d.get("data") is None:
            raise AttributeError(name)
        J = self.evaluate_jacobian()
        J.setflags(write=False)
        d["J_w"] = J
        return J

    def factors(self) -> FactoredJacobian | None:
        """``J_w`` held by its factors when the fit is of that kind (:func:`factor`: the residual layer's) and does
        not hold it whole: the solver's, or evaluated again at ``theta`` (then kept, until :meth:`release`)."""
        d = self.__dict__
        if "J_w" in d:
            return None
        if self.factored is None and self.data is not None and self.rows is not None and self.w is not None:
            jblocks = joint_columns(self.model, self.free, self.rows)
            if factor(self.M, jblocks):
                self.factored = factored_jacobian(self.model, self.theta, self.data, self.rows, self.free, self.w,
                                                  jblocks)[1]  # fmt: skip
        return self.factored

    def jacobian_columns(self, pos: np.ndarray | list[int]) -> np.ndarray:
        """``J_w[:, pos]`` (positions among the free parameters), from the factors when the fit holds its Jacobian
        by them (never formed whole for a few columns)."""
        F = self.factors()
        if F is not None:
            return F.columns(np.asarray(pos, dtype=int))
        return np.asarray(self.J_w[:, pos])

    def evaluate_jacobian(self, order: str = "C") -> np.ndarray:
        """``J_w`` evaluated again from the fit's data (a new array, the caller's, in memory ``order``; the same
        numbers as the solver's); the fit must have its data."""
        d = self.__dict__
        assert d.get("data") is not None and d.get("w") is not None
        _, J, _, _ = d["model"].residuals_and_jacobian(d["theta"], d["data"], d["rows"], cols=d["free"], order=order)
        J *= d["w"][:, None]
        return J

    @property
    def d(self) -> int:
        """Residuals per measurement row (3, or 6 with orientations)."""
        return int(self.Jx.shape[1])

    @property
    def weights(self) -> np.ndarray:
        return np.full(self.M, 1.0 / self.sigma) if self.w is None else self.w

    @property
    def M(self) -> int:
        return len(self.r_w)

    @property
    def k(self) -> int:
        return len(self.free)

    @property
    def rss(self) -> float:
        return float(self.r_w @ self.r_w)

    @property
    def dof(self) -> int:
        return max(self.M - self.k, 1)

    @property
    def residuals_mm(self) -> np.ndarray:
        """Position residuals ``(m, 3)`` mm."""
        return (self.r_w / self.weights).reshape(-1, self.d)[:, :3]

    @property
    def rms_mm(self) -> float:
        return ErrorStats.of(self.residuals_mm).rms_mm

    @property
    def noise_floor_mm(self) -> float:
        """Expected RMS of the 3-D position residual of a correct model (:func:`robocal.metrics.noise_floor`)."""
        return noise_floor(self.sigma, self.M, self.k)

    def stderr(self, name: str) -> float:
        i = self.model.index(name)
        pos = np.flatnonzero(self.free == i)
        return float(np.sqrt(self.cov[pos[0], pos[0]])) if len(pos) else float("nan")

    def cov_of(self, names: list[str]) -> np.ndarray:
        pos = []
        for nme in names:
            p = np.flatnonzero(self.free == self.model.index(nme))
            pos.append(int(p[0]) if len(p) else -1)
        out = np.full((len(names), len(names)), np.nan)
        for a, pa in enumerate(pos):
            for b, pb in enumerate(pos):
                if pa >= 0 and pb >= 0:
                    out[a, b] = self.cov[pa, pb]
        return out


def fit_model(
    model: ExtendedModel,
    theta0: np.ndarray,
    data: FitData,
    rows: np.ndarray,
    sigma: float,
    fixed: set[str],
    rank_tol: float,
    max_iter: int = 100,
    sigma_rad: float | None = None,
    held: frozenset[str] = frozenset(),
) -> Fit:
    """Identifiability analysis of the extended model, then Levenberg-Marquardt on its identifiable parameters.

    sigma : position noise (mm); sigma_rad : orientation noise (rad) when the model uses orientations; held :
    parameters the geometric calibration found not identifiable: eliminated here too, even where an effect's
    second-order terms would let the rank test keep them (a column's carriage tilting with its travel made the
    first arm joint's offset "identifiable": fitted 4.9 deg off along a flat valley, the base turned back, the
    compensation 4.9 deg off on that joint)."""

    prec = model.prior_precision()
    # a parameter the geometry held (eliminated) or the user fixed stays so under a prior too (as in calibrate)
    out = np.array([nm in held or nm in fixed for nm in model.names], dtype=bool)
    ridge = np.flatnonzero((prec > 0) & ~out)
    sq = np.sqrt(prec[ridge])

    d = model.per_row(data)
    w_row = np.array([1.0 / sigma] * 3 + ([1.0 / (sigma_rad or 1.0)] * 3 if d == 6 else []))
    w = np.tile(w_row, data.m)
    M = len(w)
    kinds = list(model.base.kinds) + ["effect"] * (model.n - model.nb)
    order = [i for i, k in enumerate(kinds) if k == "base"]
    order += [i for i, k in enumerate(kinds) if k in ("tool", "tool_rot")]
    order += [i for i, k in enumerate(kinds) if k == "kinematic"]
    order += [i for i, k in enumerate(kinds) if k == "effect" and prec[i] == 0]
    # a parameter under a prior (an effect's ridge, the geometry's prior toward nominal on a thin campaign) is
    # determined by it: always fitted (``ridge`` below), not offered to the rank test (kept there too, it was
    # listed twice among the free parameters)
    order = [i for i in order if model.names[i] not in fixed and prec[i] == 0]
    # the geometry's eliminated parameters are not offered to the rank test (not eliminated after it: where a
    # redundancy has several representatives, the test here would keep the one the geometry dropped and drop
    # the one it kept, and both would be lost)
    also = [i for i in order if model.names[i] in held]
    order = [i for i in order if model.names[i] not in held]
    # the identifiability analysis sees only the columns it may keep (an effect under a prior is always fitted,
    # a fixed parameter never): the Jacobian is built on those alone, whitened in place
    judged = np.array(sorted(order), dtype=int)
    at = {int(c): i for i, c in enumerate(judged)}
    _r0, J0, _, _ = model.residuals_and_jacobian(theta0, data, rows, cols=judged)
    J0 *= w[:, None]
    ident = analyse(J0, [model.names[c] for c in judged], [at[c] for c in order], rtol=rank_tol)
    del _r0, J0  # not held through the solver (an (M, n) matrix)
    kept = judged[np.asarray(ident.kept, dtype=int)]
    # coefficients under a prior are determined by it: always fitted, never eliminated
    free = np.sort(np.concatenate([kept, ridge]))
    w_all = np.concatenate([w, np.ones(len(ridge))])
    ridge_pos = np.searchsorted(free, ridge)  # the prior rows' columns among the free ones

    def fun_free(th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # the solver's evaluation: only the free columns, whitened in place (the same numbers as weighting
        # ``J[:, free]``, without the (M, n) matrix nor the solver's weighted copy)
        blocks: list[tuple[np.ndarray, int, np.ndarray]] = []
        r, J, _, Jq = model.residuals_and_jacobian(th, data, rows, extra_rows=len(ridge), cols=free,
                                                   joint_blocks=blocks)  # fmt: skip
        if len(ridge):
            J[len(r) + np.arange(len(ridge)), ridge_pos] = sq
            r = np.concatenate([r, sq * th[ridge]])
        J *= w_all[:, None]
        if blocks:  # the solver's normal equations from the joint-level effects' factors (robocal.discovery.gram)
            attach_gram(J, JointGram(M, d, w_row, Jq, blocks, ridge_pos, sq))
        return w_all * r, J

    jblocks = joint_columns(model, free, rows)
    if factor(M, jblocks):
        # the joint-level effects' columns held by their factors, never formed (issue 31: the residual layer)

        def fun_factored(th: np.ndarray) -> tuple[np.ndarray, FactoredJacobian]:
            return factored_jacobian(model, th, data, rows, free, w, jblocks)

        lm = least_squares(fun_factored, theta0, free, 1.0, max_iter=max_iter, ftol=1e-12, xtol=1e-10,  # type: ignore[arg-type]
                           jac_free=True)  # fmt: skip
        factored: FactoredJacobian | None = lm.extra["jacobian_factored"]
    else:
        lm = least_squares(fun_free, theta0, free, 1.0, max_iter=max_iter, ftol=1e-12, xtol=1e-10, jac_free=True)
        factored = None
    theta = np.array(lm.x)
    Jx, Jq = model.base_jacobians(theta, data, rows)  # the parts of the solver's J
    assert lm.covariance is not None  # a finite fit
    if factored is not None:
        fit = Fit(model=model, theta=theta, free=free, r_w=np.array(lm.residual)[:M], J_w=np.empty((0, 0)), Jx=Jx,
                  Jq=Jq, cov=np.array(lm.covariance), s2=lm.redchi if lm.dof > 0 else lm.chi2, sigma=sigma,
                  eliminated=tuple(e.name for e in ident.eliminated) + tuple(model.names[c] for c in also),
                  rows=np.asarray(rows), w=w, data=data, gram=factored.gram, factored=factored)  # fmt: skip
        fit.release_jacobian()  # never formed: evaluated whole only when read (Fit.J_w)
        return fit
    return Fit(
        model=model,
        theta=theta,
        free=free,
        r_w=np.array(lm.residual)[:M],
        J_w=lm.jacobian[:M],  # the solver's own read-only matrix (a view: no copy of the (M, k) Jacobian)
        Jx=Jx,
        Jq=Jq,
        cov=np.array(lm.covariance),
        s2=lm.redchi if lm.dof > 0 else lm.chi2,
        sigma=sigma,
        eliminated=tuple(e.name for e in ident.eliminated) + tuple(model.names[c] for c in also),
        rows=np.asarray(rows),
        w=w,
        data=data,
        gram=g if isinstance(g := gram_of(lm.jacobian), JointGram) else None,
    )
