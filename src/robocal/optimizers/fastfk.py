"""Target positions of a whole population of calibration parameter vectors, fast.

The population methods spend nearly all their time evaluating the nonlinear calibration model for every
individual at every pose. :class:`PopulationPositions` computes exactly what
:meth:`robocal.identification.model.CalibrationModel.batch_position_residuals` computes (same chain, same
element order, same tool offsets, position residuals ``predicted - measured``), reorganised:

* The chain is ``T_ref · B_0 · Rot(q_1) · B_1 · Rot(q_2) ··· Rot(q_n) · B_n`` where each block ``B_s`` holds
  every element between two joints, plus the constant part (nominal + parameter error) of the next joint
  rotation, since ``Rot(v + q) = Rot(v) Rot(q)``. The blocks depend on the individual only: they are built
  once per individual (~40 elements), not once per pose.
* The target point is carried *backwards* through the chain (``w = B_n t``, then ``w = B_{s-1} Rot(q_s) w``):
  per pose and joint one planar rotation with precomputed ``cos q``/``sin q`` and one rigid transform of a
  point, ~24 flops, no trigonometric call.

Two back ends, same arithmetic: a numba kernel (parallel over individuals, vectorised over poses) when numba
is installed, else numpy broadcasting over ``(pop, m)``. ``backend="numpy"`` forces the latter.

Joint elements must be rotations (every chain :func:`robocal.kinematics.chain.build_chain` makes is); other
chains are rejected with :class:`ValueError` and callers fall back to the model's own method.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.identification.model import CalibrationModel, FitData
from robocal.kinematics.chain import FIXED, RX, RY, RZ, TZ

__all__ = ["HAVE_NUMBA", "PopulationPositions"]

numba: Any
try:  # optional accelerator: numpy fallback below
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - depends on the environment
    numba = None
    HAVE_NUMBA = False


def _identity(f: Any) -> Any:
    return f


# compiled lazily at the first call; cache=True keeps the machine code on disk between processes
_jit: Any = numba.njit(cache=True, nogil=True) if numba is not None else _identity
_jit_parallel: Any = numba.njit(cache=True, nogil=True, parallel=True) if numba is not None else _identity
_prange: Any = numba.prange if numba is not None else range


# --------------------------------------------------------------------------------------------------------
# per-individual blocks (shared arithmetic of both back ends, written on scalars for numba)
# --------------------------------------------------------------------------------------------------------


@_jit
def _apply_element(R: np.ndarray, t: np.ndarray, kind: int, v: float, fR: np.ndarray, ft: np.ndarray) -> None:
    """``[R t] <- [R t] · element`` in place, as :func:`robocal.kinematics.chain.propagate` does."""
    if kind == FIXED:
        for r in range(3):
            t[r] += R[r, 0] * ft[0] + R[r, 1] * ft[1] + R[r, 2] * ft[2]
        for r in range(3):
            a0, a1, a2 = R[r, 0], R[r, 1], R[r, 2]
            R[r, 0] = a0 * fR[0, 0] + a1 * fR[1, 0] + a2 * fR[2, 0]
            R[r, 1] = a0 * fR[0, 1] + a1 * fR[1, 1] + a2 * fR[2, 1]
            R[r, 2] = a0 * fR[0, 2] + a1 * fR[1, 2] + a2 * fR[2, 2]
    elif kind <= TZ:
        for r in range(3):
            t[r] += v * R[r, kind]
    else:
        c, s = np.cos(v), np.sin(v)
        i, j = (1, 2) if kind == RX else ((2, 0) if kind == RY else (0, 1))
        # RX: y,z <- c y + s z, c z - s y; RY: z,x <- c z + s x, c x - s z; RZ: x,y <- c x + s y, c y - s x
        for r in range(3):
            a, b = R[r, i], R[r, j]
            R[r, i] = c * a + s * b
            R[r, j] = c * b - s * a


@_jit
def _blocks(
    kinds: np.ndarray,
    nominal: np.ndarray,
    param: np.ndarray,
    is_joint: np.ndarray,
    fR: np.ndarray,
    ft: np.ndarray,
    T0: np.ndarray,
    x: np.ndarray,
    n_joints: int,
    B: np.ndarray,
) -> None:
    """Fill ``B (n_joints + 1, 3, 4)`` with the blocks of one full parameter vector ``x``."""
    R = T0[:3, :3].copy()
    t = T0[:3, 3].copy()
    seg = 0
    for e in range(kinds.shape[0]):
        v = nominal[e]
        if param[e] >= 0:
            v += x[param[e]]
        _apply_element(R, t, kinds[e], v, fR[e], ft[e])
        if is_joint[e]:
            B[seg, :, :3] = R
            B[seg, :, 3] = t
            seg += 1
            R[:] = 0.0
            R[0, 0] = R[1, 1] = R[2, 2] = 1.0
            t[:] = 0.0
    B[n_joints, :, :3] = R
    B[n_joints, :, 3] = t


@_jit
def _residuals_one(
    B: np.ndarray,
    axes: np.ndarray,
    tools: np.ndarray,
    tidx: np.ndarray,
    cq: np.ndarray,
    sq: np.ndarray,
    p_meas: np.ndarray,
    out: np.ndarray,
    wx: np.ndarray,
    wy: np.ndarray,
    wz: np.ndarray,
) -> None:
    """Residuals ``(3m,)`` of one individual from its blocks (backward point propagation)."""
    n_joints = cq.shape[0]
    m = cq.shape[1]
    Bn = B[n_joints]
    for j in range(m):
        k = tidx[j]
        tx, ty, tz = tools[k, 0], tools[k, 1], tools[k, 2]
        wx[j] = Bn[0, 0] * tx + Bn[0, 1] * ty + Bn[0, 2] * tz + Bn[0, 3]
        wy[j] = Bn[1, 0] * tx + Bn[1, 1] * ty + Bn[1, 2] * tz + Bn[1, 3]
        wz[j] = Bn[2, 0] * tx + Bn[2, 1] * ty + Bn[2, 2] * tz + Bn[2, 3]
    for s in range(n_joints - 1, -1, -1):
        b = B[s]
        b00, b01, b02, b03 = b[0, 0], b[0, 1], b[0, 2], b[0, 3]
        b10, b11, b12, b13 = b[1, 0], b[1, 1], b[1, 2], b[1, 3]
        b20, b21, b22, b23 = b[2, 0], b[2, 1], b[2, 2], b[2, 3]
        ax = axes[s]
        c_row = cq[s]
        s_row = sq[s]
        for j in range(m):
            c = c_row[j]
            sn = s_row[j]
            x0, y0, z0 = wx[j], wy[j], wz[j]
            # point rotated by Rot_axis(q): the frame update of propagate applied to a point
            if ax == 2:
                x1, y1, z1 = c * x0 - sn * y0, sn * x0 + c * y0, z0
            elif ax == 0:
                x1, y1, z1 = x0, c * y0 - sn * z0, sn * y0 + c * z0
            else:
                x1, y1, z1 = c * x0 + sn * z0, y0, c * z0 - sn * x0
            wx[j] = b00 * x1 + b01 * y1 + b02 * z1 + b03
            wy[j] = b10 * x1 + b11 * y1 + b12 * z1 + b13
            wz[j] = b20 * x1 + b21 * y1 + b22 * z1 + b23
    for j in range(m):
        out[3 * j] = wx[j] - p_meas[j, 0]
        out[3 * j + 1] = wy[j] - p_meas[j, 1]
        out[3 * j + 2] = wz[j] - p_meas[j, 2]


@_jit_parallel
def _population_kernel(
    kinds: np.ndarray,
    nominal: np.ndarray,
    param: np.ndarray,
    is_joint: np.ndarray,
    fR: np.ndarray,
    ft: np.ndarray,
    T0: np.ndarray,
    X: np.ndarray,
    n_chain: int,
    K: int,
    axes: np.ndarray,
    tidx: np.ndarray,
    cq: np.ndarray,
    sq: np.ndarray,
    p_meas: np.ndarray,
    out: np.ndarray,
) -> None:
    n_joints, m = cq.shape
    for i in _prange(X.shape[0]):
        B = np.empty((n_joints + 1, 3, 4))
        _blocks(kinds, nominal, param, is_joint, fR, ft, T0, X[i], n_joints, B)
        tools = X[i, n_chain : n_chain + 3 * K].reshape(K, 3)
        wx = np.empty(m)
        wy = np.empty(m)
        wz = np.empty(m)
        _residuals_one(B, axes, tools, tidx, cq, sq, p_meas, out[i], wx, wy, wz)


# --------------------------------------------------------------------------------------------------------
# the public class
# --------------------------------------------------------------------------------------------------------


class PopulationPositions:
    """Position residuals ``(pop, 3m)`` of a calibration model for a population of full vectors ``x``.

    Parameters
    ----------
    model : CalibrationModel
    data : FitData
        Poses and measured positions (orientations are not used).
    backend : {"auto", "numba", "numpy"}
        "auto" uses numba when installed.

    Raises
    ------
    ValueError
        When a joint drives anything but exactly one rotation element (then use the model's own
        ``batch_position_residuals``).
    """

    def __init__(self, model: CalibrationModel, data: FitData, backend: str = "auto") -> None:
        if backend not in ("auto", "numba", "numpy"):
            raise ValueError(f"The 'backend' parameter must be 'auto', 'numba' or 'numpy'. Got {backend!r} instead.")
        if backend == "numba" and not HAVE_NUMBA:
            raise ValueError("The 'backend' parameter is 'numba' but numba is not installed (pip install numba).")
        self.backend = "numba" if backend == "auto" and HAVE_NUMBA else ("numpy" if backend == "auto" else backend)
        chain = model.full_chain
        nj = chain.n_joints
        kinds = np.array(chain.kinds, dtype=np.int64)
        joint = np.asarray(chain.joint)
        axes = np.full(nj, -1, dtype=np.int64)
        for ej in np.flatnonzero(joint >= 0):
            j = int(joint[ej])
            if axes[j] != -1 or kinds[ej] not in (RX, RY, RZ):
                raise ValueError(f"joint {j + 1} must drive exactly one rotation element for the fast kernel")
            axes[j] = kinds[ej] - RX
        if (axes < 0).any():
            raise ValueError("every joint must drive a rotation element for the fast kernel")
        E = len(kinds)
        self.fR = np.zeros((E, 3, 3))
        self.ft = np.zeros((E, 3))
        for e, T in enumerate(chain.fixed):
            if T is not None:
                self.fR[e] = T[:3, :3]
                self.ft[e] = T[:3, 3]
        self.kinds = kinds
        self.nominal = np.asarray(chain.nominal, dtype=float)
        self.param = np.asarray(chain.param, dtype=np.int64)
        self.is_joint = joint >= 0
        self.axes = axes
        self.T0 = np.asarray(model.T_ref, dtype=float)
        self.n_chain = model.n_chain
        self.K = len(model.target_names)
        self.n = model.n
        q = np.asarray(data.q, dtype=float)
        self.cq = np.ascontiguousarray(np.cos(q).T)
        self.sq = np.ascontiguousarray(np.sin(q).T)
        self.tidx = np.ascontiguousarray(data.target_index, dtype=np.int64)
        self.p_meas = np.ascontiguousarray(data.p_mm, dtype=float)
        self.m = q.shape[0]

    def __call__(self, X: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Residuals ``(pop, 3m)`` (predicted - measured, mm) of the full vectors ``X (pop, n)``."""
        X = np.ascontiguousarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != self.n:
            raise ValueError(f"The 'X' parameter must have shape (pop, {self.n}). Got {X.shape} instead.")
        if out is None:
            out = np.empty((X.shape[0], 3 * self.m))
        if self.backend == "numba":
            _population_kernel(
                self.kinds, self.nominal, self.param, self.is_joint, self.fR, self.ft, self.T0, X,
                self.n_chain, self.K, self.axes, self.tidx, self.cq, self.sq, self.p_meas, out,
            )  # fmt: skip
            return out
        return self._numpy(X, out)

    # ------------------------------------------------------------------ numpy back end
    def _numpy(self, X: np.ndarray, out: np.ndarray) -> np.ndarray:
        pop = X.shape[0]
        nj = self.cq.shape[0]
        R = np.broadcast_to(self.T0[:3, :3], (pop, 3, 3)).copy()
        t = np.broadcast_to(self.T0[:3, 3], (pop, 3)).copy()
        blocks = []
        for e, kind in enumerate(self.kinds):
            v = self.nominal[e] + (X[:, self.param[e]] if self.param[e] >= 0 else 0.0)
            if kind == FIXED:
                t = t + R @ self.ft[e]
                R = R @ self.fR[e]
            elif kind <= TZ:
                t = t + np.asarray(v)[..., None] * R[:, :, kind]
            else:
                cv = np.broadcast_to(np.cos(v), (pop,))[:, None]
                sv = np.broadcast_to(np.sin(v), (pop,))[:, None]
                i, j = (1, 2) if kind == RX else ((2, 0) if kind == RY else (0, 1))
                a, b = R[:, :, i].copy(), R[:, :, j].copy()
                R[:, :, i] = cv * a + sv * b
                R[:, :, j] = cv * b - sv * a
            if self.is_joint[e]:
                blocks.append((R, t))
                R = np.broadcast_to(np.eye(3), (pop, 3, 3)).copy()
                t = np.zeros((pop, 3))
        blocks.append((R, t))
        tools = X[:, self.n_chain : self.n_chain + 3 * self.K].reshape(pop, self.K, 3)[:, self.tidx]  # (pop, m, 3)
        Rn, tn = blocks[nj]
        w = [
            Rn[:, r, 0:1] * tools[..., 0]
            + Rn[:, r, 1:2] * tools[..., 1]
            + Rn[:, r, 2:3] * tools[..., 2]
            + tn[:, r, None]
            for r in range(3)
        ]
        for s in range(nj - 1, -1, -1):
            c, sn = self.cq[s], self.sq[s]
            x0, y0, z0 = w
            ax = self.axes[s]
            if ax == 2:
                p = (c * x0 - sn * y0, sn * x0 + c * y0, z0)
            elif ax == 0:
                p = (x0, c * y0 - sn * z0, sn * y0 + c * z0)
            else:
                p = (c * x0 + sn * z0, y0, c * z0 - sn * x0)
            Rb, tb = blocks[s]
            w = [Rb[:, r, 0:1] * p[0] + Rb[:, r, 1:2] * p[1] + Rb[:, r, 2:3] * p[2] + tb[:, r, None] for r in range(3)]
        o3 = out.reshape(pop, self.m, 3)
        for r in range(3):
            np.subtract(w[r], self.p_meas[:, r], out=o3[:, :, r])
        return out
