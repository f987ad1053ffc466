"""The Newton compensation of :func:`robocal.serve.engine.solve`, compiled with numba, one target at a time.

A request of the online service has few targets (one per RSI cycle); numpy's per-call overhead (~60 array
calls per Newton step) then dominates. This kernel runs the *same* iteration — forward kinematics of the
compiled chain, joint Jacobian from the joint axes, damped normal equations (6x6 for the full pose, the
minimum-norm 3x3 form for position only), the per-step clip, the convergence and stall rules — in compiled
loops, per target. ``engine.solve`` uses it when numba is installed and no joint deflection model is
involved; the numpy path stays the reference (tests compare the two).
"""

from __future__ import annotations

from typing import Any

import numpy as np

njit: Any
try:  # numba is a dependency; the numpy path of engine.solve is used without it
    from numba import njit
except ImportError:  # pragma: no cover - exercised only without numba
    njit = None

AVAILABLE = njit is not None


def _newton(
    S0: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    K: np.ndarray,
    joint: np.ndarray,
    axis: np.ndarray,
    offset: np.ndarray,
    tool: np.ndarray,
    q_start: np.ndarray,
    p_des: np.ndarray,
    R_des: np.ndarray,
    use_rot: bool,
    max_iter: int,
    tol_mm: float,
    tol_rad: float,
    max_step: float,
    wrot: float,
) -> Any:
    m, n = q_start.shape
    q = q_start.copy()
    conv = np.zeros(m, dtype=np.bool_)
    iters = np.zeros(m, dtype=np.int64)
    e0 = np.zeros((m, 3))
    E0 = np.zeros((m, 3, 3))
    e1 = np.zeros((m, 3))
    E1 = np.zeros((m, 3, 3))
    before = np.zeros((n, 4, 4))
    U = np.zeros((3, n))
    O = np.zeros((3, n))
    rows = 6 if use_rot else 3
    J = np.zeros((rows, n))
    b = np.zeros(rows)
    for t in range(m):
        last = np.inf
        for it in range(max_iter + 1):
            # forward kinematics with the joint frames recorded
            T = S0.copy()
            for i in range(n):
                before[i] = T
                th = q[t, joint[i]] + offset[i]
                Mi = np.cos(th) * A[i] + np.sin(th) * B[i] + K[i]
                T = T @ Mi
            T = T @ tool
            for i in range(n):
                j = joint[i]
                for r in range(3):
                    U[r, j] = before[i, r, axis[i]]
                    O[r, j] = before[i, r, 3]
            ep = np.empty(3)
            size = 0.0
            for r in range(3):
                ep[r] = T[r, 3] - p_des[t, r]
                size = max(size, abs(ep[r]))
            ok = size < tol_mm
            E = np.eye(3)
            w = np.zeros(3)
            if use_rot:
                for r in range(3):
                    for c in range(3):
                        E[r, c] = T[r, 0] * R_des[t, c, 0] + T[r, 1] * R_des[t, c, 1] + T[r, 2] * R_des[t, c, 2]
                w[0] = 0.5 * (E[2, 1] - E[1, 2])
                w[1] = 0.5 * (E[0, 2] - E[2, 0])
                w[2] = 0.5 * (E[1, 0] - E[0, 1])
                wsize = max(abs(w[0]), max(abs(w[1]), abs(w[2])))
                ok = ok and wsize < tol_rad
                size = size + wrot * wsize
            if it == 0:
                e0[t] = ep
                E0[t] = E
            e1[t] = ep
            E1[t] = E
            iters[t] = it
            conv[t] = ok
            stalled = size > 0.5 * last and it >= 3
            last = size
            if ok or stalled or it == max_iter:
                break
            for j in range(n):
                d0 = T[0, 3] - O[0, j]
                d1 = T[1, 3] - O[1, j]
                d2 = T[2, 3] - O[2, j]
                J[0, j] = U[1, j] * d2 - U[2, j] * d1
                J[1, j] = U[2, j] * d0 - U[0, j] * d2
                J[2, j] = U[0, j] * d1 - U[1, j] * d0
                if use_rot:
                    J[3, j] = wrot * U[0, j]
                    J[4, j] = wrot * U[1, j]
                    J[5, j] = wrot * U[2, j]
            for r in range(3):
                b[r] = ep[r]
                if use_rot:
                    b[3 + r] = wrot * w[r]
            if rows >= n:
                N = J.T @ J
                tr = 0.0
                for j in range(n):
                    tr += N[j, j]
                for j in range(n):
                    N[j, j] += 1e-12 * tr
                dq = -np.linalg.solve(N, J.T @ b)
            else:
                N = J @ J.T
                tr = 0.0
                for r in range(rows):
                    tr += N[r, r]
                for r in range(rows):
                    N[r, r] += 1e-12 * tr
                dq = -(J.T @ np.linalg.solve(N, b))
            big = 0.0
            for j in range(n):
                big = max(big, abs(dq[j]))
            scale = 1.0 if big <= max_step else max_step / max(big, 1e-300)
            for j in range(n):
                q[t, j] += scale * dq[j]
    return q, conv, iters, e0, E0, e1, E1


def _fk(
    S0: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    K: np.ndarray,
    joint: np.ndarray,
    offset: np.ndarray,
    tool: np.ndarray,
    q: np.ndarray,
) -> Any:
    """Tool positions (m, 3) and rotations (m, 3, 3) of the compiled chain (as engine.forward without record)."""
    m = q.shape[0]
    n = joint.shape[0]
    p = np.empty((m, 3))
    R = np.empty((m, 3, 3))
    for t in range(m):
        T = S0.copy()
        for i in range(n):
            th = q[t, joint[i]] + offset[i]
            T = T @ (np.cos(th) * A[i] + np.sin(th) * B[i] + K[i])
        T = T @ tool
        p[t] = T[:3, 3]
        R[t] = T[:3, :3]
    return p, R


def _rotvec(E: np.ndarray) -> Any:
    """Rotation vectors (m, 3) of rotations E (m, 3, 3), exact atan2 form; rows within 2e-3 rad of pi are
    flagged (``near_pi``) for the general numpy routine."""
    m = E.shape[0]
    out = np.zeros((m, 3))
    near_pi = np.zeros(m, dtype=np.bool_)
    for t in range(m):
        w0 = 0.5 * (E[t, 2, 1] - E[t, 1, 2])
        w1 = 0.5 * (E[t, 0, 2] - E[t, 2, 0])
        w2 = 0.5 * (E[t, 1, 0] - E[t, 0, 1])
        c = 0.5 * (E[t, 0, 0] + E[t, 1, 1] + E[t, 2, 2] - 1.0)
        s = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        th = np.arctan2(s, c)
        if th > np.pi - 2e-3:
            near_pi[t] = True
            continue
        f = th / s if s > 1e-12 else 1.0
        out[t, 0] = w0 * f
        out[t, 1] = w1 * f
        out[t, 2] = w2 * f
    return out, near_pi


def _quat(R: np.ndarray) -> Any:
    """Unit quaternions (m, 4) (w, x, y, z), w >= 0, of rotations R (m, 3, 3) (Shepperd's method)."""
    m = R.shape[0]
    out = np.empty((m, 4))
    for t in range(m):
        r = R[t]
        tr = r[0, 0] + r[1, 1] + r[2, 2]
        if tr > 0.0:
            k = 2.0 * np.sqrt(1.0 + tr)
            w, x, y, z = 0.25 * k, (r[2, 1] - r[1, 2]) / k, (r[0, 2] - r[2, 0]) / k, (r[1, 0] - r[0, 1]) / k
        elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
            k = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
            w, x, y, z = (r[2, 1] - r[1, 2]) / k, 0.25 * k, (r[0, 1] + r[1, 0]) / k, (r[0, 2] + r[2, 0]) / k
        elif r[1, 1] > r[2, 2]:
            k = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
            w, x, y, z = (r[0, 2] - r[2, 0]) / k, (r[0, 1] + r[1, 0]) / k, 0.25 * k, (r[1, 2] + r[2, 1]) / k
        else:
            k = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
            w, x, y, z = (r[1, 0] - r[0, 1]) / k, (r[0, 2] + r[2, 0]) / k, (r[1, 2] + r[2, 1]) / k, 0.25 * k
        nrm = np.sqrt(w * w + x * x + y * y + z * z)
        sgn = -1.0 if w < 0.0 else 1.0
        out[t, 0] = sgn * w / nrm
        out[t, 1] = sgn * x / nrm
        out[t, 2] = sgn * y / nrm
        out[t, 3] = sgn * z / nrm
    return out


newton: Any
fk: Any
rotvec: Any
quat: Any
if njit is not None:
    newton = njit(cache=True, nogil=True)(_newton)
    fk = njit(cache=True, nogil=True)(_fk)
    rotvec = njit(cache=True, nogil=True)(_rotvec)
    quat = njit(cache=True, nogil=True)(_quat)
else:  # pragma: no cover
    newton = fk = rotvec = quat = None
