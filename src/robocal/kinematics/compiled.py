"""The compiled (numba) form of the kinematic chain: the compiled kernels built on the chain's element code.

:func:`robocal.kinematics.chain.step` is the one description of a chain element; this module writes it once
more, on scalars, for numba, and builds every compiled kernel from it:

* :func:`apply_element` mirrors ``chain.step`` (same kinds, same composition: ``[R t] <- [R t] · element``,
  the rotation's columns being the frame axes ``x, y, z`` of ``step``);
* :func:`fold` folds a chain with a parameter vector into one rigid block per joint (the numpy reference is
  :func:`robocal.kinematics.chain.fold`): ``T = B_0 · Rot(q_1) · B_1 ··· Rot(q_n) · B_n``, where each block ends
  with the constant part (nominal + parameter error) of the next joint's rotation;
* :func:`forward` (one pose, joint axes and origins recorded) and :func:`points_to_base` (a point carried
  backwards, over many poses) are the forward kinematics of a folded chain from ``cos q`` / ``sin q``;
* :func:`gravity_regressor`: the gravity load torque of every joint per unit mass moment of every body (the
  numpy reference is :func:`robocal.kinematics.gravity.gravity_regressor`'s own pass over ``chain.step``);
* the kernels: :func:`population_positions` (target positions of a population of parameter vectors, used by
  :class:`robocal.optimizers.fastfk.PopulationPositions`), :func:`newton` (the service's compensation,
  :func:`robocal.kinematics.ik.solve`), :func:`fk_poses`.

A kernel and every kernel it calls live in one file on purpose: numba's on-disk cache (``cache=True``) checks
only the source file of the function it caches, so a kernel in another file calling these would keep stale
machine code after an edit here. The kernels that call no other kernel live beside (``compiled_rotations``:
:func:`rotvec` / :func:`quat`; ``compiled_harmonics``: :func:`harmonics`), numba's decorators and
:func:`chain_arrays` in ``compiled_support``; all are importable from here, as before.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.kinematics.chain import FIXED, RX, TZ
from robocal.kinematics.compiled_harmonics import harmonics
from robocal.kinematics.compiled_rotations import quat, rotvec
from robocal.kinematics.compiled_support import AVAILABLE, _jit, _jit_parallel, _prange, chain_arrays

__all__ = [
    "AVAILABLE",
    "apply_element",
    "chain_arrays",
    "fk_poses",
    "fold",
    "forward",
    "gravity_regressor",
    "harmonics",
    "joint_tables_and_weight",
    "layer_gate",
    "newton",
    "periodic_tables",
    "points_to_base",
    "population_positions",
    "quat",
    "rotvec",
]


# ----------------------------------------------------------- the element code (mirror of robocal.kinematics.chain.step)


@_jit
def rotate_columns(R: np.ndarray, ax: int, c: float, s: float) -> None:
    """``R <- R · Rot_ax(v)`` with ``c, s = cos v, sin v``: columns ``i, j`` (cyclic after the axis ``ax``) become
    ``c i + s j`` and ``c j - s i`` (``step`` for RX, RY, RZ)."""
    i = (ax + 1) % 3
    j = (ax + 2) % 3
    for r in range(3):
        a = R[r, i]
        b = R[r, j]
        R[r, i] = c * a + s * b
        R[r, j] = c * b - s * a


@_jit
def apply_transform(R: np.ndarray, t: np.ndarray, fR: np.ndarray, ft: np.ndarray) -> None:
    """``[R t] <- [R t] · [fR ft]`` in place (``step`` for FIXED)."""
    for r in range(3):
        t[r] += R[r, 0] * ft[0] + R[r, 1] * ft[1] + R[r, 2] * ft[2]
    for r in range(3):
        a0, a1, a2 = R[r, 0], R[r, 1], R[r, 2]
        R[r, 0] = a0 * fR[0, 0] + a1 * fR[1, 0] + a2 * fR[2, 0]
        R[r, 1] = a0 * fR[0, 1] + a1 * fR[1, 1] + a2 * fR[2, 1]
        R[r, 2] = a0 * fR[0, 2] + a1 * fR[1, 2] + a2 * fR[2, 2]


@_jit
def apply_element(R: np.ndarray, t: np.ndarray, kind: int, v: float, fR: np.ndarray, ft: np.ndarray) -> None:
    """``[R t] <- [R t] · element`` in place: :func:`robocal.kinematics.chain.step` on scalars.

    ``v`` the element's value (mm or rad), ``fR``/``ft`` the rotation and translation of a FIXED element."""
    if kind == FIXED:
        apply_transform(R, t, fR, ft)
    elif kind <= TZ:
        for r in range(3):
            t[r] += v * R[r, kind]
    else:
        rotate_columns(R, kind - RX, np.cos(v), np.sin(v))


# --------------------------------------------------------------------- folding and forward kinematics of a folded chain


@_jit
def fold(
    kinds: np.ndarray,
    nominal: np.ndarray,
    param: np.ndarray,
    is_joint: np.ndarray,
    fR: np.ndarray,
    ft: np.ndarray,
    T0: np.ndarray,
    x: np.ndarray,
    B: np.ndarray,
) -> None:
    """Fill ``B (n + 1, 3, 4)`` with the blocks of the chain for the parameter vector ``x`` (element ``e`` adds
    ``x[param[e]]`` when ``param[e] >= 0``), starting from ``T0 (4, 4)``.

    Block ``s`` runs from joint element ``s - 1`` (after its joint rotation ``Rot(q)``) to joint element ``s``
    included with its constant value, so ``T = B_0 · Rot(q_1) · B_1 ··· Rot(q_n) · B_n`` (``Rot(v + q) =
    Rot(v) Rot(q)``); ``fR (E, 3, 3)``/``ft (E, 3)`` the FIXED transforms (anything elsewhere)."""
    R = T0[:3, :3].copy()
    t = T0[:3, 3].copy()
    seg = 0
    for e in range(kinds.shape[0]):
        v = nominal[e]
        if param[e] >= 0:
            v += x[param[e]]
        apply_element(R, t, kinds[e], v, fR[e], ft[e])
        if is_joint[e]:
            B[seg, :, :3] = R
            B[seg, :, 3] = t
            seg += 1
            R[:] = 0.0
            R[0, 0] = R[1, 1] = R[2, 2] = 1.0
            t[:] = 0.0
    B[seg, :, :3] = R
    B[seg, :, 3] = t


@_jit
def forward(
    B: np.ndarray,
    axis: np.ndarray,
    c: np.ndarray,
    s: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    U: np.ndarray,
    O: np.ndarray,
) -> None:
    """Forward kinematics of a folded chain for one pose: ``R (3, 3)``, ``t (3,)`` of ``B_0 Rot(q_1) ··· B_n``.

    ``axis (n,)`` the rotation axis (0, 1, 2) of each joint element, ``c``/``s (n,)`` cos and sin of its joint
    angle, both in chain order; ``U``/``O (3, n)`` receive the world axis and origin of each joint element."""
    R[:, :] = B[0, :, :3]
    t[:] = B[0, :, 3]
    for k in range(axis.shape[0]):
        ax = axis[k]
        for r in range(3):
            U[r, k] = R[r, ax]
            O[r, k] = t[r]
        rotate_columns(R, ax, c[k], s[k])
        apply_transform(R, t, B[k + 1, :, :3], B[k + 1, :, 3])


@_jit
def points_to_base(
    B: np.ndarray, axis: np.ndarray, cq: np.ndarray, sq: np.ndarray, wx: np.ndarray, wy: np.ndarray, wz: np.ndarray
) -> None:
    """Points given in the flange frame, one per pose, carried to the base frame in place: ``w <- B_n w``, then
    ``w <- B_s Rot(q_s) w`` down the joints (the rotation of :func:`rotate_columns`, applied to a point).

    ``cq``/``sq (n, m)`` cos and sin of the joint angles (chain order) at the ``m`` poses; ``wx, wy, wz (m,)``."""
    n = axis.shape[0]
    m = wx.shape[0]
    for s in range(n, -1, -1):
        b = B[s]
        b00, b01, b02, b03 = b[0, 0], b[0, 1], b[0, 2], b[0, 3]
        b10, b11, b12, b13 = b[1, 0], b[1, 1], b[1, 2], b[1, 3]
        b20, b21, b22, b23 = b[2, 0], b[2, 1], b[2, 2], b[2, 3]
        ax = axis[s] if s < n else -1
        for j in range(m):
            x0, y0, z0 = wx[j], wy[j], wz[j]
            if ax >= 0:
                c = cq[s, j]
                sn = sq[s, j]
                if ax == 2:
                    x0, y0 = c * x0 - sn * y0, sn * x0 + c * y0
                elif ax == 0:
                    y0, z0 = c * y0 - sn * z0, sn * y0 + c * z0
                else:
                    z0, x0 = c * z0 - sn * x0, sn * z0 + c * x0
            wx[j] = b00 * x0 + b01 * y0 + b02 * z0 + b03
            wy[j] = b10 * x0 + b11 * y0 + b12 * z0 + b13
            wz[j] = b20 * x0 + b21 * y0 + b22 * z0 + b23


@_jit
def fk_poses(
    B: np.ndarray, axis: np.ndarray, joint: np.ndarray, tool: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Tool positions ``(m, 3)`` and rotations ``(m, 3, 3)`` of a folded chain with the flange-to-tool transform
    ``tool (4, 4)`` at joints ``q (m, n)``; ``joint (n,)`` the joint index of each joint element."""
    m = q.shape[0]
    n = axis.shape[0]
    p = np.empty((m, 3))
    Rs = np.empty((m, 3, 3))
    c = np.empty(n)
    s = np.empty(n)
    R = np.empty((3, 3))
    t = np.empty(3)
    U = np.empty((3, n))
    O = np.empty((3, n))
    tR = tool[:3, :3].copy()
    tt = tool[:3, 3].copy()
    for i in range(m):
        for k in range(n):
            c[k] = np.cos(q[i, joint[k]])
            s[k] = np.sin(q[i, joint[k]])
        forward(B, axis, c, s, R, t, U, O)
        apply_transform(R, t, tR, tt)
        p[i] = t
        Rs[i] = R
    return p, Rs


# -------------------------------------------------------------------- the population kernel (robocal.optimizers.fastfk)


@_jit_parallel
def population_positions(
    kinds: np.ndarray,
    nominal: np.ndarray,
    param: np.ndarray,
    is_joint: np.ndarray,
    fR: np.ndarray,
    ft: np.ndarray,
    T0: np.ndarray,
    X: np.ndarray,
    n_chain: int,
    axis: np.ndarray,
    tidx: np.ndarray,
    cq: np.ndarray,
    sq: np.ndarray,
    p_meas: np.ndarray,
    out: np.ndarray,
) -> None:
    """Position residuals ``out (pop, 3m)`` (predicted - measured) of the full vectors ``X (pop, n)``: chain
    parameters first, then the target offsets in the flange frame (target ``k`` at ``X[:, n_chain + 3k:][:3]``);
    pose ``j`` sees target ``tidx[j]``; ``cq``/``sq (n, m)`` cos and sin of the joint angles in chain order."""
    n_joints, m = cq.shape
    for i in _prange(X.shape[0]):
        B = np.empty((n_joints + 1, 3, 4))
        fold(kinds, nominal, param, is_joint, fR, ft, T0, X[i], B)
        wx = np.empty(m)
        wy = np.empty(m)
        wz = np.empty(m)
        for j in range(m):
            o = n_chain + 3 * tidx[j]
            wx[j] = X[i, o]
            wy[j] = X[i, o + 1]
            wz[j] = X[i, o + 2]
        points_to_base(B, axis, cq, sq, wx, wy, wz)
        for j in range(m):
            out[i, 3 * j] = wx[j] - p_meas[j, 0]
            out[i, 3 * j + 1] = wy[j] - p_meas[j, 1]
            out[i, 3 * j + 2] = wz[j] - p_meas[j, 2]


# ------------------------------------------------------ the service's Newton compensation (robocal.kinematics.ik.solve)


@_jit
def newton(  # noqa: C901, PLR0915 (one compiled per-target loop, the twin of ik.solve's numpy steps, kept flat)
    B: np.ndarray,
    axis: np.ndarray,
    joint: np.ndarray,
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
    """The Newton iteration of :func:`robocal.kinematics.ik.solve`, one target at a time.

    The same iteration as the numpy path there: forward kinematics of the folded chain, joint Jacobian from
    the joint axes (``dp = u x (p - o)``, ``dw = u``), damped normal equations (6x6 for the full pose, the
    minimum-norm 3x3 form for position only), the per-step clip, the convergence and stall rules. Returns
    ``q, converged, iterations (m,), e0 (m, 3), E0 (m, 3, 3), e1, E1`` (position errors and ``R R_d^T``
    before and after)."""
    m, n = q_start.shape
    q = q_start.copy()
    conv = np.zeros(m, dtype=np.bool_)
    iters = np.zeros(m, dtype=np.int64)
    e0 = np.zeros((m, 3))
    E0 = np.zeros((m, 3, 3))
    e1 = np.zeros((m, 3))
    E1 = np.zeros((m, 3, 3))
    nj = axis.shape[0]
    c = np.empty(nj)
    s = np.empty(nj)
    T = np.empty((3, 3))
    tp = np.empty(3)
    Uk = np.empty((3, nj))
    Ok = np.empty((3, nj))
    tR = tool[:3, :3].copy()
    tt = tool[:3, 3].copy()
    rows = 6 if use_rot else 3
    J = np.zeros((rows, n))
    b = np.zeros(rows)
    ep = np.empty(3)
    for t in range(m):
        last = np.inf
        for it in range(max_iter + 1):
            for k in range(nj):
                c[k] = np.cos(q[t, joint[k]])
                s[k] = np.sin(q[t, joint[k]])
            forward(B, axis, c, s, T, tp, Uk, Ok)
            apply_transform(T, tp, tR, tt)
            size = 0.0
            for r in range(3):
                ep[r] = tp[r] - p_des[t, r]
                size = max(size, abs(ep[r]))
            ok = size < tol_mm
            E = np.eye(3)
            w = np.zeros(3)
            if use_rot:
                for r in range(3):
                    for cc in range(3):
                        E[r, cc] = T[r, 0] * R_des[t, cc, 0] + T[r, 1] * R_des[t, cc, 1] + T[r, 2] * R_des[t, cc, 2]
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
            for k in range(nj):
                j = joint[k]
                d0 = tp[0] - Ok[0, k]
                d1 = tp[1] - Ok[1, k]
                d2 = tp[2] - Ok[2, k]
                J[0, j] = Uk[1, k] * d2 - Uk[2, k] * d1
                J[1, j] = Uk[2, k] * d0 - Uk[0, k] * d2
                J[2, j] = Uk[0, k] * d1 - Uk[1, k] * d0
                if use_rot:
                    J[3, j] = wrot * Uk[0, k]
                    J[4, j] = wrot * Uk[1, k]
                    J[5, j] = wrot * Uk[2, k]
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


# ----------------------------------------------------- gravity regressor (robocal.kinematics.gravity.gravity_regressor)


@_jit
def gravity_regressor(
    kinds: np.ndarray,
    nominal: np.ndarray,
    joint: np.ndarray,
    fR: np.ndarray,
    ft: np.ndarray,
    q: np.ndarray,
    slot: np.ndarray,
    joint_slot: np.ndarray,
    joint_axis: np.ndarray,
    body_slot: np.ndarray,
    g: np.ndarray,
    mm: float,
) -> np.ndarray:
    """``Y (m, n, 4 n)``: ``Y[r, j, 4 i]`` = the torque about joint ``j`` of 1 kg at body ``i``'s frame origin,
    ``Y[r, j, 4 i + 1 + a]`` of 1 kg·m along its frame axis ``a`` (zero for ``i < j``), at joints ``q[r]``.

    ``slot (E + 1,)``: where the frame before element ``e`` (``E``: the chain's end) is recorded, or -1;
    ``joint_slot`` / ``joint_axis`` (n,): joint ``j``'s recorded frame and the axis (0, 1, 2) it turns about;
    ``body_slot (n,)``: body ``i``'s frame; ``g (3,)`` gravity (m/s²); ``mm``: m per mm (origins are in mm).
    Frames as :func:`apply_element` composes them (the rotation's columns are the frame axes)."""
    m, n = q.shape
    E = len(kinds)
    n_slots = 0
    for e in range(E + 1):
        n_slots = max(n_slots, slot[e] + 1)
    Y = np.zeros((m, n, 4 * n))
    FR = np.zeros((n_slots, 3, 3))
    Fo = np.zeros((n_slots, 3))
    R = np.zeros((3, 3))
    t = np.zeros(3)
    for r in range(m):
        R[:, :] = 0.0
        R[0, 0] = R[1, 1] = R[2, 2] = 1.0
        t[:] = 0.0
        for e in range(E):
            if slot[e] >= 0:
                FR[slot[e]] = R
                Fo[slot[e]] = t
            v = nominal[e]
            if joint[e] >= 0:
                v += q[r, joint[e]]
            apply_element(R, t, kinds[e], v, fR[e], ft[e])
        if slot[E] >= 0:
            FR[slot[E]] = R
            Fo[slot[E]] = t
        for j in range(n):
            sj = joint_slot[j]
            u = FR[sj, :, joint_axis[j]]
            # u · (o_j x g), subtracted from every body's mass column
            oj = Fo[sj] * mm
            uoj = (
                u[0] * (oj[1] * g[2] - oj[2] * g[1])
                + u[1] * (oj[2] * g[0] - oj[0] * g[2])
                + u[2] * (oj[0] * g[1] - oj[1] * g[0])
            )
            for i in range(j, n):
                sb = body_slot[i]
                ob = Fo[sb] * mm
                Y[r, j, 4 * i] = (
                    u[0] * (ob[1] * g[2] - ob[2] * g[1])
                    + u[1] * (ob[2] * g[0] - ob[0] * g[2])
                    + u[2] * (ob[0] * g[1] - ob[1] * g[0])
                ) - uoj
                for a in range(3):
                    x = FR[sb, :, a]
                    Y[r, j, 4 * i + 1 + a] = (
                        u[0] * (x[1] * g[2] - x[2] * g[1])
                        + u[1] * (x[2] * g[0] - x[0] * g[2])
                        + u[2] * (x[0] * g[1] - x[1] * g[0])
                    )
    return Y


@_jit
def periodic_tables(
    q: np.ndarray, cols: np.ndarray, grid: np.ndarray, vals: np.ndarray, start: np.ndarray, period: float
) -> np.ndarray:
    """``(m, k)``: for each table ``t`` (``grid[start[t]:start[t + 1]]`` ascending over ``[0, period]``, values
    ``vals`` there) the linear interpolation at ``q[:, cols[t]]`` modulo ``period`` (the tabulated joint
    effects of :class:`robocal.compensation.discovered.DiscoveredEffects`)."""
    m = q.shape[0]
    k = len(cols)
    out = np.empty((m, k))
    for t in range(k):
        a = start[t]
        b = start[t + 1]
        for r in range(m):
            x = q[r, cols[t]] % period
            lo = a
            hi = b - 1
            while hi - lo > 1:  # grid[lo] <= x < grid[hi]
                mid = (lo + hi) // 2
                if grid[mid] <= x:
                    lo = mid
                else:
                    hi = mid
            out[r, t] = vals[lo] + (x - grid[lo]) * ((vals[hi] - vals[lo]) / (grid[hi] - grid[lo]))
    return out


@_jit
def layer_gate(q: np.ndarray, centres: np.ndarray, length: float, inside: float) -> np.ndarray:
    """``(m,)`` in [0, 1]: the residual layer's gate at joints ``q (m, n)`` (1 within ``inside`` of the nearest
    centre, a raised cosine to 0 one ``length`` further; :func:`robocal.compensation.signals.layer_gate`)."""
    m = q.shape[0]
    out = np.empty(m)
    d2 = np.empty(centres.shape[0])
    for r in range(m):
        out[r] = _gate(_squared_distances(q, r, centres, d2), inside, length)
    return out


@_jit
def _squared_distances(q: np.ndarray, r: int, centres: np.ndarray, d2: np.ndarray) -> float:
    """``d2[d] = |q[r] - centres[d]|²`` for every centre; returns the smallest."""
    best = np.inf
    for d in range(centres.shape[0]):
        s = 0.0
        for j in range(q.shape[1]):
            x = q[r, j] - centres[d, j]
            s += x * x
        d2[d] = s
        best = min(best, s)
    return best


@_jit
def _gate(best_d2: float, inside: float, length: float) -> float:
    """The layer's gate at squared distance ``best_d2`` to the nearest centre (raised cosine beyond ``inside``)."""
    t = min(max((np.sqrt(best_d2) - inside) / length, 0.0), 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * t))


@_jit
def joint_tables_and_weight(
    q: np.ndarray,
    cols: np.ndarray,
    grid: np.ndarray,
    vals: np.ndarray,
    start: np.ndarray,
    period: float,
    wcols: np.ndarray,
    P: np.ndarray,
    lcols: np.ndarray,
    centres: np.ndarray,
    length: float,
    inside: float,
    W: np.ndarray,
    kinds: np.ndarray,
    nominal: np.ndarray,
    joint: np.ndarray,
    fR: np.ndarray,
    ft: np.ndarray,
    slot: np.ndarray,
    joint_slot: np.ndarray,
    joint_axis: np.ndarray,
    body_slot: np.ndarray,
    g: np.ndarray,
    mm: float,
) -> np.ndarray:
    """``dq (m, n)``: the tabulated single-angle effects (:func:`periodic_tables` of joints ``cols``), the
    compliance under the arm's own weight ``Y_j(q) @ P[k]`` of joints ``wcols[k]`` (:func:`gravity_regressor`)
    and the residual layer ``gate(q) sum_d exp(-|q - c_d|² / (2 length²)) W[d, k]`` of joints ``lcols[k]``
    (:func:`layer_gate`), in one call: the stored discovered effects of
    :class:`robocal.compensation.discovered.DiscoveredEffects` as the service evaluates them at every Newton
    step (``cols``, ``wcols`` or ``lcols`` may be empty)."""
    m, n = q.shape
    dq = np.zeros((m, n))
    if len(cols) > 0:
        T = periodic_tables(q, cols, grid, vals, start, period)
        for t in range(len(cols)):
            for r in range(m):
                dq[r, cols[t]] += T[r, t]
    if len(wcols) > 0:
        Y = gravity_regressor(kinds, nominal, joint, fR, ft, q, slot, joint_slot, joint_axis, body_slot, g, mm)
        K = P.shape[1]
        for k in range(len(wcols)):
            j = wcols[k]
            for r in range(m):
                acc = 0.0
                for c in range(K):
                    acc += Y[r, j, c] * P[k, c]
                dq[r, j] += acc
    if len(lcols) > 0:
        D = centres.shape[0]
        d2 = np.empty(D)
        inv = 1.0 / (2.0 * length * length)
        for r in range(m):
            gate = _gate(_squared_distances(q, r, centres, d2), inside, length)
            if gate == 0.0:
                continue
            for d in range(D):
                d2[d] = np.exp(-d2[d] * inv)  # the kernel features
            for k in range(len(lcols)):
                acc = 0.0
                for d in range(D):
                    acc += d2[d] * W[d, k]
                dq[r, lcols[k]] += gate * acc
    return dq
