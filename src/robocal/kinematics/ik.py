"""The library's one Newton solver (inverse kinematics and differential compensation), batched.

Every correction in robocal goes through :func:`solve`: the online service, program filtering and the
controller CSVs of the thermal, compliance and discovery workflows (:mod:`robocal.compensation`), and the
nominal inverse kinematics of :mod:`robocal.cell.programs`. The kinematic parameters are fixed within one
call, so the chain is first *compiled* for
that parameter vector (:func:`robocal.kinematics.chain.fold`): every run of non-joint elements between two
joints, with the joint's constant offset, is multiplied into one rigid block, leaving
``T0 · B_0 · Rot(q_1) · B_1 · ... · Rot(q_n) · B_n · tool`` (one rotation per joint). Forward kinematics then
costs ``n`` column rotations and ``n`` 3x3 products per pose, the joint Jacobian comes from the recorded joint
axes (``dp = u x (p - o)``, ``dw = u``), and each Newton step solves damped normal equations (6x6 for the full
pose; the minimum-norm 3x3 form for position only) with ``numpy.linalg.solve`` over the whole batch (compiled
per target: :func:`robocal.kinematics.compiled.newton`). The same fixed point as the reference
is reached (checked in ``tests/serve/test_engine.py``).

Shapes: ``q`` ``(m, n)`` rad; positions ``(m, 3)`` mm; rotations ``(m, 3, 3)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from robocal.kinematics import compiled as _compiled
from robocal.kinematics.chain import FIXED, RX, Chain, FoldedChain, Frame, fold, step
from robocal.kinematics.transforms import matrix_to_quat, matrix_to_rotvec

#: ``joint_offset(q_cmd (k, n), rows (k,)) -> dq (k, n)``: deflection of the targets ``rows`` at ``q_cmd``
JointOffset = Callable[[np.ndarray, np.ndarray], np.ndarray]


_DIAG = {k: np.arange(k) for k in range(1, 13)}
#: index pairs of the skew part (vee) and of the cross product components
_VI, _VJ = np.array([2, 0, 1]), np.array([1, 2, 0])
_C1, _C2 = np.array([1, 2, 0]), np.array([2, 0, 1])


#: A chain with its kinematic parameters folded in: one rotation per joint between rigid blocks
#: (:class:`robocal.kinematics.chain.FoldedChain`).
CompiledChain = FoldedChain


def compile_chain(chain: Chain, eta: np.ndarray | None = None, T0: np.ndarray | None = None) -> CompiledChain:
    """Fold the parameter vector ``eta`` (P,) and ``T0`` (4, 4) into a :class:`CompiledChain`."""
    eta = np.zeros(chain.n_params) if eta is None else np.asarray(eta, dtype=float)
    if eta.shape != (chain.n_params,):
        raise ValueError(f"The 'eta' parameter must have shape ({chain.n_params},). Got {eta.shape} instead.")
    return fold(chain, eta, T0)


def forward(
    cc: CompiledChain, q: np.ndarray, tool_T: np.ndarray, record: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Tool point ``(m, 3)`` and tool rotation ``(m, 3, 3)`` for joints ``q`` (m, n) and the flange-to-tool
    transform ``tool_T`` (4, 4); with ``record`` also the world joint axes and origins ``(m, 3, n)``
    indexed by joint number."""
    if not record and _compiled.AVAILABLE:
        return (*_compiled.fk_poses(*_kernel_args(cc), _f64(tool_T), _f64(q)), None, None)
    m = q.shape[0]
    n = cc.n_joints
    B = cc.blocks
    frame: Frame = tuple(np.broadcast_to(B[0, :, c], (m, 3)) for c in range(4))  # type: ignore[assignment]
    axes = np.empty((m, 3, n)) if record else None
    origins = np.empty((m, 3, n)) if record else None
    for k in range(n):
        j, ax = int(cc.joint[k]), int(cc.axis[k])
        if axes is not None and origins is not None:
            axes[:, :, j] = frame[ax]
            origins[:, :, j] = frame[3]
        frame = step(RX + ax, q[:, j, None], frame)  # the chain's own element code (robocal.kinematics.chain.step)
        frame = step(FIXED, 0.0, frame, B[k + 1])
    x, y, z, o = step(FIXED, 0.0, frame, tool_T)
    return o, np.stack([x, y, z], -1), axes, origins


def rotation_error(R: np.ndarray, R_desired: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(m, 3)`` of ``R R_desired^T`` (rad)."""
    return rotvec(R @ np.swapaxes(R_desired, -1, -2))


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float)


def _kernel_args(cc: CompiledChain) -> tuple[np.ndarray, ...]:
    """The folded chain's arrays as the numba kernels take them (cached on the frozen object)."""
    args = cc.__dict__.get("_kernel_args")
    if args is None:
        args = (
            _f64(cc.blocks),
            np.ascontiguousarray(cc.axis, dtype=np.int64),
            np.ascontiguousarray(cc.joint, dtype=np.int64),
        )
        object.__setattr__(cc, "_kernel_args", args)
    return args


def quaternions(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(m, 4)`` (w, x, y, z), w >= 0, of rotations ``(m, 3, 3)`` (compiled when possible)."""
    if _compiled.AVAILABLE:
        return _compiled.quat(_f64(R))
    return matrix_to_quat(R)


def rotvec(E: np.ndarray) -> np.ndarray:
    """Rotation vectors of rotations ``E`` (m, 3, 3): :func:`robocal.kinematics.compiled.rotvec` when numba is
    there, else the numpy reference :func:`~robocal.kinematics.transforms.matrix_to_rotvec` (the same steps)."""
    if _compiled.AVAILABLE:
        return _compiled.rotvec(_f64(E))
    return matrix_to_rotvec(E)


#: Joint-space tolerance (rad) of the inversion ``q + dq(q) = q_true`` (1e-6 mm at a metre's reach, a hundredth of
#: the Cartesian Newton's default tolerance) and the forward-difference step of its Jacobian.
INVERT_TOL_RAD = 1e-9
INVERT_EPS_RAD = 1e-6


def offsets_and_jacobian(joint_offset: JointOffset, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``dq(q) (m, n)`` and ``I + d dq / dq (m, n, n)`` by forward differences, in one batched call."""
    m, n = q.shape
    rows = np.arange(m)
    Q = np.concatenate([q[:, None, :], q[:, None, :] + INVERT_EPS_RAD * np.eye(n)[None]], axis=1)
    out = joint_offset(Q.reshape(m * (n + 1), n), np.repeat(rows, n + 1)).reshape(m, n + 1, n)
    d = out[:, 0, :]
    return d, np.eye(n)[None] + np.swapaxes(out[:, 1:, :] - d[:, None, :], 1, 2) / INVERT_EPS_RAD


def invert_offsets(
    joint_offset: JointOffset, q_true: np.ndarray, q0: np.ndarray, max_iter: int = 20, tol_rad: float = INVERT_TOL_RAD
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Commanded joints ``q`` (m, n) with ``q + joint_offset(q) = q_true``, from ``q0``: Newton steps with
    ``I + d dq / dq`` at ``q0`` (:func:`offsets_and_jacobian`, one batched call), kept for every step (chord
    method: ``q0`` is within a correction's size of the answer and the offsets are small). Returns
    ``(q, dq(q), converged (m,), iterations)``; converged: ``|q + dq(q) - q_true| < tol_rad`` on every joint."""
    m = len(q_true)
    q = np.array(q0, dtype=float)
    d, J = offsets_and_jacobian(joint_offset, q)
    ok = np.zeros(m, dtype=bool)
    it = 0
    for it in range(max_iter + 1):
        r = q + d - q_true
        ok = np.abs(r).max(axis=1) < tol_rad
        if ok.all() or it == max_iter:
            break
        act = np.flatnonzero(~ok)
        q[act] -= np.linalg.solve(J[act], r[act][:, :, None])[:, :, 0]
        d[act] = joint_offset(q[act], act)
    return q, d, ok, it


def _solve_through_joints(
    cc: CompiledChain,
    tool_T: np.ndarray,
    q_start: np.ndarray,
    p_desired: np.ndarray,
    R_desired: np.ndarray,
    joint_offset: JointOffset,
    max_iter: int,
    tol_mm: float,
    tol_rad: float,
    max_step_rad: float,
    rot_weight_mm: float,
) -> Solution:
    """:func:`solve` with joint offsets, a full pose and six joints, in two stages: the joints ``q_true`` the robot
    must reach (the compiled Newton from where the start command takes it, ``q_start + dq(q_start)``), then the
    command ``q`` with ``q + dq(q) = q_true`` (:func:`invert_offsets`). The error before is at the start
    command, as in the one-stage loop; the residual is the robot's at ``q + dq(q)``."""
    d0 = joint_offset(np.asarray(q_start, dtype=float), np.arange(len(q_start)))
    true = solve(cc, tool_T, q_start + d0, p_desired, R_desired, None, max_iter, tol_mm, tol_rad, max_step_rad,
                 rot_weight_mm, compiled=True)  # fmt: skip
    # as tight as the orientation asked of the Cartesian stage, and at least INVERT_TOL_RAD
    q, d, inverted, it = invert_offsets(joint_offset, true.q, true.q - d0, max_iter, min(INVERT_TOL_RAD, tol_rad))
    p, R, _, _ = forward(cc, q + d, tool_T)
    return Solution(
        q,
        true.converged & inverted,
        true.iterations + it,
        true.error_before_mm,
        true.error_before_rad,
        p - p_desired,
        rotvec(R @ np.swapaxes(R_desired, -1, -2)),
    )


@dataclass
class Solution:
    """Result of :func:`solve`.

    q : (m, n) corrected joints (rad); converged : (m,) bool; iterations : int;
    error_before_mm / error_before_rad : (m, 3) tool error at the start joints;
    residual_mm / residual_rad : (m, 3) predicted error at ``q``.
    """

    q: np.ndarray
    converged: np.ndarray
    iterations: int
    error_before_mm: np.ndarray
    error_before_rad: np.ndarray
    residual_mm: np.ndarray
    residual_rad: np.ndarray


def solve(
    cc: CompiledChain,
    tool_T: np.ndarray,
    q_start: np.ndarray,
    p_desired: np.ndarray,
    R_desired: np.ndarray | None = None,
    joint_offset: JointOffset | None = None,
    max_iter: int = 20,
    tol_mm: float = 1e-6,
    tol_rad: float = 1e-9,
    max_step_rad: float = 0.05,
    rot_weight_mm: float = 1000.0,
    compiled: bool | None = None,
    stall: bool = True,
) -> Solution:
    """Newton iterations from ``q_start`` (m, n) until the robot ``cc`` with tool ``tool_T`` (4, 4) and joint
    deflection ``joint_offset(q_cmd, rows) -> dq`` (added to the commanded joints; ``rows`` are the
    indices of the targets passed) puts the tool at ``p_desired``
    (m, 3) and, when given, ``R_desired`` (m, 3, 3).

    The orientation error driven to zero is ``w = vee(E - E^T) / 2`` (``E = R R_d^T``), which equals the
    rotation vector to third order and vanishes exactly where it does; rotation rows are weighted by
    ``rot_weight_mm`` (mm per rad). Each joint step is clipped to ``max_step_rad`` (a target near a
    singularity then fails to converge instead of running away); converged targets stop moving.

    ``compiled`` : run the same iteration compiled with numba (:func:`robocal.kinematics.compiled.newton`), per target;
    None = when numba is available and there is no ``joint_offset``; False = this numpy reference path. With a
    ``joint_offset``, a full pose and six joints (one solution, not a redundant one), None solves in two stages
    (:func:`_solve_through_joints`): the compiled Newton finds the joints the robot must reach, then the joint
    offsets are inverted in joint space; the same solution, with the offsets evaluated a few times instead of at
    every Cartesian step.
    ``stall`` : stop a target whose error stops halving (compensation: a small correction is expected, and a
    target that needs a large one is near a singularity); False for inverse kinematics over large moves
    (numpy path only).
    """
    if (
        joint_offset is not None
        and R_desired is not None
        and cc.n_joints == 6
        and compiled is not False
        and _compiled.AVAILABLE
        and stall
    ):
        return _solve_through_joints(
            cc, tool_T, q_start, p_desired, R_desired, joint_offset, max_iter, tol_mm, tol_rad, max_step_rad,
            rot_weight_mm,
        )  # fmt: skip
    if compiled is None:
        compiled = _compiled.AVAILABLE and joint_offset is None and stall
    if compiled and not stall:
        raise ValueError("the compiled solver always applies the stall rule (stall=True)")
    if compiled:
        if joint_offset is not None or not _compiled.AVAILABLE:
            raise ValueError("the compiled solver needs numba and no joint_offset")
        return _solve_compiled(cc, tool_T, q_start, p_desired, R_desired, max_iter, tol_mm, tol_rad, max_step_rad,
                               rot_weight_mm)  # fmt: skip
    q = np.array(q_start, dtype=float)
    m = len(q)
    Rd_T = np.swapaxes(R_desired, -1, -2) if R_desired is not None else None
    conv = np.zeros(m, dtype=bool)
    e_p = np.zeros((m, 3))
    E = np.tile(np.eye(3), (m, 1, 1))
    e_p0, E0 = e_p, E
    active = np.arange(m)  # targets still iterating
    last = np.full(m, np.inf)  # previous error size, for stall detection
    it = 0
    for it in range(max_iter + 1):
        qs = q[active]
        qa = qs if joint_offset is None else qs + joint_offset(qs, active)
        p, R, U, O = forward(cc, qa, tool_T, record=True)
        assert U is not None and O is not None
        ep = p - p_desired[active]
        size = np.abs(ep).max(axis=1)
        ok = size < tol_mm
        if Rd_T is not None:
            Ea = R @ Rd_T[active]
            w = 0.5 * (Ea[:, _VI, _VJ] - Ea[:, _VJ, _VI])
            wsize = np.abs(w).max(axis=1)
            ok &= wsize < tol_rad
            size = size + rot_weight_mm * wsize
            E[active] = Ea
        e_p[active] = ep
        if it == 0:
            e_p0, E0 = ep.copy(), E.copy()
        conv[active] = ok
        # Newton contracts quadratically near a regular solution: a target whose error stops halving
        # (after the first steps, which may be clipped) is near a singularity and stops here, unconverged
        stalled = (size > 0.5 * last[active]) & (it >= 3) & stall
        last[active] = size
        keep = ~(ok | stalled)
        if not keep.any() or it == max_iter:
            break
        active = active[keep]
        q[active] += _newton_step(
            U[keep], O[keep], p[keep], ep[keep], None if Rd_T is None else w[keep], rot_weight_mm, max_step_rad
        )
    zeros = np.zeros((m, 3))
    if R_desired is None:
        return Solution(q, conv, it, e_p0, zeros, e_p, zeros)
    return Solution(q, conv, it, e_p0, rotvec(E0), e_p, rotvec(E))


def _solve_compiled(
    cc: CompiledChain,
    tool_T: np.ndarray,
    q_start: np.ndarray,
    p_desired: np.ndarray,
    R_desired: np.ndarray | None,
    max_iter: int,
    tol_mm: float,
    tol_rad: float,
    max_step_rad: float,
    rot_weight_mm: float,
) -> Solution:
    """:func:`solve` without joint offsets, compiled (:func:`robocal.kinematics.compiled.newton`, per target)."""
    qs = _f64(q_start)
    Rd = _f64(R_desired) if R_desired is not None else np.zeros((len(qs), 3, 3))
    qf, cf, itf, e0, E0f, e1, E1f = _compiled.newton(
        *_kernel_args(cc),
        _f64(tool_T),
        qs,
        _f64(p_desired),
        Rd,
        R_desired is not None,
        int(max_iter),
        float(tol_mm),
        float(tol_rad),
        float(max_step_rad),
        float(rot_weight_mm),
    )
    iters = int(itf.max(initial=0))
    zeros3 = np.zeros((len(qs), 3))
    if R_desired is None:
        return Solution(qf, cf, iters, e0, zeros3, e1, zeros3)
    return Solution(qf, cf, iters, e0, rotvec(E0f), e1, rotvec(E1f))


def _newton_step(
    U: np.ndarray,
    O: np.ndarray,
    p: np.ndarray,
    ep: np.ndarray,
    w: np.ndarray | None,
    rot_weight_mm: float,
    max_step_rad: float,
) -> np.ndarray:
    """The joint step ``(k, n)`` of the targets still iterating, from their joint axes ``U`` and points ``O``
    (k, 3, n), tool positions ``p`` (k, 3), position errors ``ep`` (k, 3) and, with an orientation, rotation
    errors ``w`` (k, 3): damped normal equations when (over)determined, the minimum-norm step when redundant,
    each target's largest joint step clipped to ``max_step_rad``."""
    n = U.shape[2]
    D = p[:, :, None] - O
    Jp = U[:, _C1] * D[:, _C2] - U[:, _C2] * D[:, _C1]  # u x (p - o), (m, 3, n)
    if w is not None:
        A = np.concatenate([Jp, rot_weight_mm * U], axis=1)  # (m, 6, n)
        b = np.concatenate([ep, rot_weight_mm * w], axis=1)
    else:
        A, b = Jp, ep
    At = np.swapaxes(A, 1, 2)
    k = A.shape[1]
    if k >= n:  # (over)determined: damped normal equations
        N = At @ A
        N[:, _DIAG[n], _DIAG[n]] += 1e-12 * np.einsum("mii->m", N)[:, None]
        dq = -np.linalg.solve(N, At @ b[:, :, None])[:, :, 0]
    else:  # redundant (position only): minimum-norm step
        N = A @ At
        N[:, _DIAG[k], _DIAG[k]] += 1e-12 * np.einsum("mii->m", N)[:, None]
        dq = -(At @ np.linalg.solve(N, b[:, :, None]))[:, :, 0]
    big = np.abs(dq).max(axis=1)
    if big.max() > max_step_rad:
        dq *= np.minimum(1.0, max_step_rad / np.maximum(big, 1e-300))[:, None]
    return dq
