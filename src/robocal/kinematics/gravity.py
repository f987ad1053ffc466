"""Static gravity torques on the joints from link masses, centres of mass and a payload.

The torque gravity exerts about joint ``j`` (the *load torque*, N·m) is

    tau_j = u_j · sum_{k >= j} (c_k - o_j) x (m_k g)  (+ the payload's term),

``u_j`` the joint's world axis, ``o_j`` a point on it, ``c_k`` the centre of mass of body ``k`` (the body moved
by joint ``k``) and ``g`` gravity in the base frame (m/s²). Equivalently ``tau_j = -dV/dq_j`` with the potential
energy ``V = -sum_k m_k g · c_k`` (the tests check the two against each other).

Sign convention used throughout robocal's compliance work: a positive load torque turns joint ``j`` in its
positive direction, so a reducer of stiffness ``k_j`` deflects by ``+tau_j / k_j``. The torque a drive must
supply to hold the arm is ``-tau_j``; drives that report that sign simply give compliances of the opposite sign.

Body frames: the centre of mass of body ``i`` (``RobotDescription.link_com_mm[i]``) is given in joint ``i``'s
frame as :func:`robocal.kinematics.chain.build_chain` builds it: for MD-H the frame after link ``i``'s
elements (``Rot_x Trans_x Rot_z Trans_z [Rot_y]``); for POE the frame on axis ``i`` (z along the axis) right
after the joint rotation. The payload's centre of mass is in the flange frame.

Everything is vectorised over poses: ``q`` is ``(m, n)`` rad, the result ``(m, n)`` N·m. A prismatic joint's
entry is the load *force* along its axis, ``u_j · sum_{k >= j} m_k g`` (N), its value in mm.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.kinematics.chain import FIXED, Chain, build_chain, propagate, step
from robocal.robot import RobotDescription

MM = 1e-3  # m per mm


def body_frame_boundaries(chain: Chain, convention_mdh: bool) -> list[int]:
    """Element index just after body ``i``'s frame, one per joint: the frame is the chain state before it.

    MD-H: before link ``i + 1``'s first element (``alpha{i+2}``), the chain end for the last link.
    POE: before the FIXED element following joint ``i``'s rotation (the axis-to-axis transform or the flange).
    """
    n = chain.n_joints
    out: list[int] = []
    if convention_mdh:
        names = chain.param_names
        for i in range(n):
            if i == n - 1:
                out.append(len(chain.kinds))
                continue
            p = names.index(f"alpha{i + 2}")
            out.append(int(np.flatnonzero(chain.param == p)[0]))
        return out
    joint_el = [int(np.flatnonzero(chain.joint == i)[0]) for i in range(n)]
    for i in range(n):
        nxt = [e for e in range(joint_el[i] + 1, len(chain.kinds)) if chain.kinds[e] == FIXED]
        out.append(nxt[0] if nxt else len(chain.kinds))
    return out


def _prefix(chain: Chain, e: int) -> Chain:
    return Chain(
        kinds=chain.kinds[:e],
        nominal=chain.nominal[:e],
        joint=chain.joint[:e],
        param=chain.param[:e],
        fixed=chain.fixed[:e],
        param_names=chain.param_names,
        n_joints=chain.n_joints,
    )


def gravity_torques(
    robot: RobotDescription,
    q: np.ndarray,
    payload_kg: np.ndarray | float = 0.0,
    *,
    eta: np.ndarray | None = None,
    chain: Chain | None = None,
    link_mass_kg: np.ndarray | None = None,
    link_com_mm: np.ndarray | None = None,
    payload_com_mm: np.ndarray | None = None,
    gravity: np.ndarray | None = None,
) -> np.ndarray:
    """Gravity load torques ``(m, n)`` N·m at joint angles ``q``.

    Parameters
    ----------
    robot : RobotDescription
        Supplies the kinematics and, unless overridden, the masses (``robot.has_dynamics`` must hold).
    q : ndarray, shape (m, n)
        Joint angles, rad (the true / deflected angles when known; the difference is second order).
    payload_kg : float or ndarray, shape (m,)
        Payload mass on the flange per pose, kg (its centre of mass at ``payload_com_mm``, flange frame).
    eta : ndarray, shape (P,), optional
        Kinematic parameter errors (default nominal); millimetres do not matter for torques.
    chain : Chain, optional
        ``build_chain(robot)``, to avoid rebuilding it.
    link_mass_kg, link_com_mm, payload_com_mm, gravity : optional overrides of the robot's values
        (e.g. the twin's "true" masses), shapes (n,), (n, 3), (3,), (3,) in kg, mm, mm, m/s².
    """
    q = np.asarray(q, dtype=float)
    n = robot.n_joints
    if q.ndim != 2 or q.shape[1] != n:
        raise ValueError(f"The 'q' parameter of gravity_torques must have shape (m, {n}). Got {q.shape} instead.")
    m = q.shape[0]
    mass = robot.link_mass_kg if link_mass_kg is None else np.asarray(link_mass_kg, dtype=float)
    com = robot.link_com_mm if link_com_mm is None else np.asarray(link_com_mm, dtype=float)
    if mass is None or com is None:
        raise ValueError(
            f"robot {robot.name!r} has no dynamics (link masses and centres of mass): add a 'dynamics' section "
            "to its description or pass link_mass_kg and link_com_mm"
        )
    if mass.shape != (n,) or com.shape != (n, 3):
        raise ValueError(
            f"link_mass_kg must have shape ({n},) and link_com_mm ({n}, 3). Got {mass.shape} and {com.shape}."
        )
    pcom = robot.payload_com_mm if payload_com_mm is None else np.asarray(payload_com_mm, dtype=float)
    g = robot.gravity if gravity is None else np.asarray(gravity, dtype=float)
    pl = np.broadcast_to(np.asarray(payload_kg, dtype=float), (m,))
    ch = chain if chain is not None else build_chain(robot)

    # joint axes and points on them (world = base frame)
    st = propagate(ch, q, eta, record=True)
    joint_el = [int(np.flatnonzero(ch.joint == j)[0]) for j in range(n)]
    u = np.stack([np.broadcast_to(np.asarray(st.axes[e]), (m, 3)) for e in joint_el], axis=1)  # (m, n, 3)
    o = np.stack([np.broadcast_to(np.asarray(st.origins[e]), (m, 3)) for e in joint_el], axis=1)  # (m, n, 3)

    # centres of mass (m, n + 1, 3) in mm and their weights (m, n + 1, 3) in N
    bounds = body_frame_boundaries(ch, robot.is_mdh)
    c = np.empty((m, n + 1, 3))
    for i, e in enumerate(bounds):
        s = propagate(_prefix(ch, e), q, eta)
        c[:, i] = s.o + s.x * com[i, 0] + s.y * com[i, 1] + s.z * com[i, 2]
    c[:, n] = st.o + st.x * pcom[0] + st.y * pcom[1] + st.z * pcom[2]
    w = np.concatenate([np.broadcast_to(mass, (m, n)), pl[:, None]], axis=1)[..., None] * g  # (m, n + 1, 3)

    tau = np.zeros((m, n))
    slide = robot.prismatic
    for j in range(n):
        if slide[j]:  # a prismatic joint carries the weight along its axis: a force, N
            tau[:, j] = np.einsum("mi,mi->m", u[:, j], w[:, j:].sum(axis=1))
            continue
        r = (c[:, j:] - o[:, j : j + 1]) * MM  # bodies j..n and the payload, metres
        mom = np.cross(r, w[:, j:]).sum(axis=1)  # (m, 3) N·m
        tau[:, j] = np.einsum("mi,mi->m", u[:, j], mom)
    return tau


def potential_energy(
    robot: RobotDescription,
    q: np.ndarray,
    payload_kg: np.ndarray | float = 0.0,
    *,
    chain: Chain | None = None,
) -> np.ndarray:
    """Gravitational potential energy ``(m,)`` J (for checks: ``tau = -dV/dq``)."""
    q = np.asarray(q, dtype=float)
    n = robot.n_joints
    assert robot.link_mass_kg is not None and robot.link_com_mm is not None
    ch = chain if chain is not None else build_chain(robot)
    m = q.shape[0]
    pl = np.broadcast_to(np.asarray(payload_kg, dtype=float), (m,))
    V = np.zeros(m)
    for i, e in enumerate(body_frame_boundaries(ch, robot.is_mdh)):
        s = propagate(_prefix(ch, e), q)
        cm = robot.link_com_mm[i]
        c = s.o + s.x * cm[0] + s.y * cm[1] + s.z * cm[2]
        V -= robot.link_mass_kg[i] * (c * MM) @ robot.gravity
    st = propagate(ch, q)
    pc = robot.payload_com_mm
    c = st.o + st.x * pc[0] + st.y * pc[1] + st.z * pc[2]
    V -= pl * ((c * MM) @ robot.gravity)
    del n
    return V


__all__ = ["body_frame_boundaries", "gravity_torques", "potential_energy"]


# ------------------------------------------------------------------------------------------------------------
# the gravity regressor: the load torques per unit mass moment (compliance without known masses)
# ------------------------------------------------------------------------------------------------------------


def gravity_regressor(robot: RobotDescription, q: np.ndarray, compiled_ok: bool = True) -> np.ndarray:
    """``Y (m, n, 4 n)``: the gravity load torque of every joint (N·m) per unit mass moment of every body:
    column ``4 i`` is body ``i``'s mass (1 kg at its frame origin), columns ``4 i + 1..3`` its first mass moment
    (1 kg·m along its frame's x, y, z). ``tau = Y @ pi`` for any masses (nominal kinematics, the robot's
    gravity vector); the tests check it against :func:`robocal.kinematics.gravity.gravity_torques`.

    One pass over the chain: ``tau_j = u_j · sum_{i >= j} ((o_i - o_j) m_i + R_i (m c)_i) x g`` with ``u_j, o_j``
    joint ``j``'s world axis and a point on it, ``o_i, R_i`` body ``i``'s frame (same body frames as
    ``gravity_torques``). Compiled (:func:`robocal.kinematics.compiled.gravity_regressor`: the service evaluates
    it per Newton step) unless numba is missing or ``compiled_ok`` is False (the numpy reference)."""
    from robocal.kinematics import compiled  # numba: imported when first needed

    q = np.atleast_2d(np.asarray(q, dtype=float))
    if compiled.AVAILABLE and compiled_ok and not robot.has_prismatic:  # the kernel has revolute joints only
        args = regressor_arrays(robot)
        return compiled.gravity_regressor(*args[:5], np.ascontiguousarray(q), *args[5:])
    return _gravity_regressor_numpy(robot, q)


def _frames(chain: Chain, q: np.ndarray, want: set[int]) -> dict[int, tuple[np.ndarray, ...]]:
    """The chain's frames ``(x, y, z axes, origin)`` per pose, before each element in ``want`` and at the chain's
    end (key ``len(chain.kinds)``), at joints ``q (m, n)``: one pass through ``chain.step``."""
    m = q.shape[0]
    rec: dict[int, tuple[np.ndarray, ...]] = {}
    one = np.ones((m, 1))
    frame = (np.eye(3)[0] * one, np.eye(3)[1] * one, np.eye(3)[2] * one, np.zeros((m, 3)))
    for e, kind in enumerate(chain.kinds):
        if e in want:
            rec[e] = frame
        if kind == FIXED:
            frame = step(FIXED, 0.0, frame, chain.fixed[e])
            continue
        v = chain.nominal[e] + (q[:, chain.joint[e]] if chain.joint[e] >= 0 else 0.0)
        frame = step(kind, np.broadcast_to(v, (m,))[:, None], frame)
    rec[len(chain.kinds)] = frame
    return rec


def _gravity_regressor_numpy(robot: RobotDescription, q: np.ndarray) -> np.ndarray:
    """The reference (numpy) pass of :func:`gravity_regressor`, through ``chain.step``."""

    m, n = q.shape
    chain = _chain(robot)
    bounds = body_frame_boundaries(chain, robot.is_mdh)
    joint_el = [int(np.flatnonzero(chain.joint == j)[0]) for j in range(n)]
    rec = _frames(chain, q, set(bounds) | set(joint_el))
    g = np.asarray(robot.gravity, dtype=float)
    U = np.stack([rec[joint_el[j]][chain.kinds[joint_el[j]] % 3] for j in range(n)], axis=1)  # (m, n, 3)
    Oj = np.stack([rec[joint_el[j]][3] for j in range(n)], axis=1) * MM
    Ob = np.stack([rec[bounds[i]][3] for i in range(n)], axis=1) * MM
    Ab = np.stack([np.stack(rec[bounds[i]][:3], axis=1) for i in range(n)], axis=1)  # (m, n, 3 axes, 3)
    # u_j · ((o_i - o_j) x g) = u_j · (o_i x g) - u_j · (o_j x g); u_j · (a x g) for the body axes
    mass = np.einsum("mjk,mik->mji", U, np.cross(Ob, g)) - np.einsum("mjk,mjk->mj", U, np.cross(Oj, g))[:, :, None]
    first = np.einsum("mjk,miak->mjia", U, np.cross(Ab, g))
    slide = robot.prismatic
    if slide.any():  # a prismatic joint: the force along its axis, u_j · g per kg carried, none from first moments
        ug = np.einsum("mjk,k->mj", U, g)
        mass[:, slide, :] = ug[:, slide, None]
        first[:, slide] = 0.0
    carried = np.triu(np.ones((n, n), dtype=bool))[None, :, :]  # body i >= joint j
    Y = np.concatenate([(mass * carried)[..., None], first * carried[..., None]], axis=3).reshape(m, n, 4 * n)
    return Y


_CHAINS: dict[int, tuple[RobotDescription, Any]] = {}


_REGRESSOR_ARRAYS: dict[int, tuple[RobotDescription, tuple[Any, ...]]] = {}


def regressor_arrays(robot: RobotDescription) -> tuple[Any, ...]:
    """The compiled regressor's chain arrays for this description (built once per description object):
    ``(kinds, nominal, joint, fR, ft, slot, joint_slot, joint_axis, body_slot, g, MM)``."""
    from robocal.kinematics.compiled import chain_arrays

    hit = _REGRESSOR_ARRAYS.get(id(robot))
    if hit is not None and hit[0] is robot:
        return hit[1]
    chain = _chain(robot)
    n = robot.n_joints
    kinds, nominal, _param, _is_joint, fR, ft = chain_arrays(chain)
    bounds = body_frame_boundaries(chain, robot.is_mdh)
    joint_el = [int(np.flatnonzero(chain.joint == j)[0]) for j in range(n)]
    slot = np.full(len(kinds) + 1, -1, dtype=np.int64)
    for k, e in enumerate(sorted(set(bounds) | set(joint_el))):
        slot[e] = k
    out = (
        kinds, np.ascontiguousarray(nominal), np.asarray(chain.joint, dtype=np.int64), fR, ft, slot,
        slot[joint_el], np.array([kinds[e] % 3 for e in joint_el], dtype=np.int64), slot[bounds],
        np.asarray(robot.gravity, dtype=float), float(MM),
    )  # fmt: skip
    _REGRESSOR_ARRAYS[id(robot)] = (robot, out)
    return out


def _chain(robot: RobotDescription) -> Any:
    """The robot's chain, built once per description object (the service evaluates effects per request)."""
    hit = _CHAINS.get(id(robot))
    if hit is None or hit[0] is not robot:
        hit = (robot, build_chain(robot))
        _CHAINS[id(robot)] = hit
    return hit[1]


def generic_mass_moments(robot: RobotDescription) -> np.ndarray:
    """``pi0 (4 n,)``: a mass distribution shaped like the arm's links, for a description without masses, in the
    gravity regressor's order (:func:`gravity_regressor`: per body its mass, then its first mass moment): each body
    a uniform rod from its frame's origin to the next body's (the flange for the last), its mass its length (1 kg
    per m: only the shape matters, a fit scales it). Its load torques ``Y @ pi0`` are a torque profile of the
    right physical shape over the whole workspace: a weight model that carries to configurations the calibration
    did not visit, where the directions the poses tell apart (:func:`robocal.discovery.physics.weight_basis`)
    need not."""
    chain = _chain(robot)
    n = robot.n_joints
    bounds = body_frame_boundaries(chain, robot.is_mdh)
    rec = _frames(chain, np.zeros((1, n)), set(bounds))  # every joint at zero
    origins = [rec[b][3][0] * MM for b in bounds] + [rec[len(chain.kinds)][3][0] * MM]
    pi0 = np.zeros(4 * n)
    for i in range(n):
        axes = np.stack([rec[bounds[i]][k][0] for k in range(3)])  # body i's axes (rows) in the base frame
        d = axes @ (origins[i + 1] - origins[i])  # the next origin in body i's frame, m
        length = float(np.linalg.norm(d))
        pi0[4 * i] = length
        pi0[4 * i + 1 : 4 * i + 4] = 0.5 * length * d
    return pi0


def described_mass_moments(robot: RobotDescription, q: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """The mass moments ``pi (4 n,)`` of the description's link masses in the gravity regressor's order: the
    least-squares ``pi`` whose torques ``Y(q) pi`` are the description's gravity torques at the joint angles ``q``
    (``Y``: their regressor ``(m, n, 4 n)``; the directions no torque sees are zero). The weight model's
    combination of physical shape when the description has masses: the torque of the ``compliance`` candidate
    from those masses, beside the combinations that correct them."""
    tau = gravity_torques(robot, q)
    pi, *_ = np.linalg.lstsq(Y.reshape(-1, Y.shape[2]), tau.reshape(-1), rcond=1e-12)
    # the rounding dust of the directions no torque sees (1e-15 of the masses, its sign the BLAS kernel's) set to 0:
    # on a joint the masses load not at all (a wrist with its centre on the axis) it was that joint's whole "torque",
    # a column of noise that differed with the CPU
    pi[np.abs(pi) <= 1e-9 * float(np.max(np.abs(pi), initial=0.0))] = 0.0
    return np.asarray(pi)
