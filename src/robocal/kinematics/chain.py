"""A serial chain of elementary transforms: the one kinematic engine behind MD-H and POE models.

Every robot model is compiled to a sequence of elements, each one of ``Trans_x/y/z(v)``,
``Rot_x/y/z(v)`` or a fixed rigid transform, where ``v = nominal + q_j (if the element is joint j)
+ eta_k (if the element carries calibration parameter k)``.

- MD-H link i: ``Rot_x(alpha_i) Trans_x(a_i) Rot_z(q_i + theta_i) Trans_z(d_i) [Rot_y(beta_i)]``,
  parameters ``alpha{i}, a{i}, theta{i}, d{i}`` and ``beta{i}`` where beta is free; a prismatic joint adds its
  value (mm) to ``Trans_z(d_i + q_i)`` instead (the same parameters: ``d{i}`` is then the slide's zero offset).
- POE: each joint axis gets a frame at q = 0 (z along the twist axis); the chain is
  ``F_1 Rot_z(q_1 + theta_1) [F_1^-1 F_2] link_errors_1 Rot_z(q_2 + theta_2) ... [F_n^-1 M]``; the link
  errors between joints are six elementary transforms with zero nominal value (``link{i}_tx`` ...
  ``link{i}_rz``): the "local POE" error model, which spans the same error space as perturbing the
  global twists; the base and tool frames carry the errors before joint 1 and after joint n. A prismatic
  joint is ``Trans_z(q_i + d_i)`` along its frame's z (the twist's direction), parameter ``d{i}``.

Forward kinematics and the analytic identification Jacobian are computed by propagating the
three columns of the rotation and the origin through the elements with broadcasting, so the
same code runs over poses ``(m,)`` and over a population of parameter vectors ``(pop, m)``.

Jacobian of a point ``p`` (world frame) with respect to an element value, from the element's
world axis ``u`` and world origin ``o`` (both taken just before the element):
translation ``dp = u``; rotation ``dp = u x (p - o)``, ``domega = u``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from robocal.robot import RobotDescription

TX, TY, TZ, RX, RY, RZ, FIXED = range(7)
_KIND_NAMES = ("tx", "ty", "tz", "rx", "ry", "rz", "fixed")


@dataclass(frozen=True)
class Chain:
    """Compiled kinematic chain, base frame to flange frame.

    Attributes
    ----------
    kinds : tuple of int, shape (E,)
    nominal : ndarray, shape (E,)
        Nominal element values (mm or rad).
    joint : ndarray of int, shape (E,)
        Joint index (0-based) that adds to the element, or -1.
    param : ndarray of int, shape (E,)
        Index into the kinematic parameter vector ``eta`` that adds to the element, or -1.
    fixed : tuple
        For FIXED elements, the (4, 4) transform; ``None`` elsewhere.
    param_names : tuple of str, shape (P,)
    n_joints : int
    """

    kinds: tuple[int, ...]
    nominal: np.ndarray
    joint: np.ndarray
    param: np.ndarray
    fixed: tuple[np.ndarray | None, ...]
    param_names: tuple[str, ...]
    n_joints: int

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    @property
    def param_kind(self) -> tuple[str, ...]:
        """``"length"`` or ``"angle"`` per kinematic parameter."""
        out = ["length"] * self.n_params
        for k, p in zip(self.kinds, self.param, strict=True):
            if p >= 0:
                out[p] = "length" if k in (TX, TY, TZ) else "angle"
        return tuple(out)


class _Builder:
    def __init__(self) -> None:
        self.kinds: list[int] = []
        self.nominal: list[float] = []
        self.joint: list[int] = []
        self.param: list[int] = []
        self.fixed: list[np.ndarray | None] = []
        self.names: list[str] = []

    def add(
        self,
        kind: int,
        value: float = 0.0,
        joint: int = -1,
        name: str | None = None,
        T: np.ndarray | None = None,
    ) -> None:
        self.kinds.append(kind)
        self.nominal.append(float(value))
        self.joint.append(joint)
        if name is None:
            self.param.append(-1)
        else:
            self.param.append(len(self.names))
            self.names.append(name)
        self.fixed.append(T)

    def build(self, n_joints: int) -> Chain:
        return Chain(
            kinds=tuple(self.kinds),
            nominal=np.array(self.nominal),
            joint=np.array(self.joint, dtype=int),
            param=np.array(self.param, dtype=int),
            fixed=tuple(self.fixed),
            param_names=tuple(self.names),
            n_joints=n_joints,
        )


def _axis_frame(z: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """A rotation whose z column is ``z`` and whose x column is as close as possible to ``x_hint``."""
    z = z / np.linalg.norm(z)
    x = x_hint - np.dot(x_hint, z) * z
    if np.linalg.norm(x) < 1e-9:
        alt = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = alt - np.dot(alt, z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def poe_axis_frames(w: np.ndarray, p_mm: np.ndarray) -> list[np.ndarray]:
    """The frame ``(4, 4)`` a POE description puts on each joint axis at q = 0 (base frame): z along the axis
    ``w[i]``, origin at ``p_mm[i]``, x as close as possible to the previous axis frame's x (the first: base x).
    With zero joint offsets it is also body ``i``'s frame at q = 0 (:mod:`robocal.kinematics.gravity`)."""
    frames = []
    x_hint = np.array([1.0, 0.0, 0.0])
    for wi, pi in zip(np.asarray(w, dtype=float), np.asarray(p_mm, dtype=float), strict=True):
        R = _axis_frame(wi, x_hint)
        x_hint = R[:, 0]
        F = np.eye(4)
        F[:3, :3] = R
        F[:3, 3] = pi
        frames.append(F)
    return frames


def build_chain(robot: RobotDescription) -> Chain:
    """Compile a robot description (MD-H or POE) into a :class:`Chain`."""
    b = _Builder()
    n = robot.n_joints
    slide = robot.prismatic
    if robot.is_mdh:
        for i in range(n):
            k = i + 1
            b.add(RX, robot.alpha[i], name=f"alpha{k}")
            b.add(TX, robot.a_mm[i], name=f"a{k}")
            b.add(RZ, robot.theta_offset[i], joint=-1 if slide[i] else i, name=f"theta{k}")
            b.add(TZ, robot.d_mm[i], joint=i if slide[i] else -1, name=f"d{k}")
            if robot.beta_free[i]:
                b.add(RY, robot.beta[i], name=f"beta{k}")
            elif robot.beta[i] != 0.0:
                b.add(RY, robot.beta[i])
        return b.build(n)

    assert robot.poe_w is not None and robot.poe_p_mm is not None and robot.poe_flange0 is not None
    frames = poe_axis_frames(robot.poe_w, robot.poe_p_mm)
    prev = np.eye(4)
    for i in range(n):
        rel = np.linalg.inv(prev) @ frames[i]
        b.add(FIXED, T=rel)
        if i > 0:
            for kind, suffix in ((TX, "tx"), (TY, "ty"), (TZ, "tz"), (RX, "rx"), (RY, "ry"), (RZ, "rz")):
                b.add(kind, 0.0, name=f"link{i}_{suffix}")
        if slide[i]:
            b.add(TZ, 0.0, joint=i, name=f"d{i + 1}")
        else:
            b.add(RZ, robot.theta_offset[i], joint=i, name=f"theta{i + 1}")
        prev = frames[i]
    b.add(FIXED, T=np.linalg.inv(prev) @ robot.poe_flange0)
    return b.build(n)


@dataclass
class ChainState:
    """Result of a propagation: flange rotation columns and origin, plus per-element records.

    ``x, y, z, o`` have shape ``(..., 3)`` (broadcast over poses and population).
    ``axes[e]``/``origins[e]`` hold the world axis and origin just before element ``e`` when recorded.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    o: np.ndarray
    axes: list[np.ndarray | None]
    origins: list[np.ndarray | None]

    @property
    def R(self) -> np.ndarray:
        """Flange rotation, shape ``(..., 3, 3)``."""
        return np.stack([self.x, self.y, self.z], axis=-1)


Frame = tuple[Any, Any, Any, Any]


def step(kind: int, v: Any, frame: Frame, Tf: np.ndarray | None = None, cos: Any = np.cos, sin: Any = np.sin) -> Frame:
    """One element of the chain applied to a frame given by its world axes and origin ``(x, y, z, o)``.

    The one place the element kinds are written down: :func:`propagate` (numpy, batched), the CasADi form of
    the identification (:mod:`robocal.calibration.problem`, with ``casadi.cos`` / ``sin``) and the service's
    chain folding (:func:`robocal.kinematics.ik.compile_chain`) all step through it. ``v`` is the element's value
    (mm or rad; shaped to broadcast against the axes), ``Tf`` the transform of a ``FIXED`` element.
    """
    x, y, z, o = frame
    if kind == FIXED:
        assert Tf is not None
        Rf, tf = Tf[:3, :3], Tf[:3, 3]
        return (
            x * Rf[0, 0] + y * Rf[1, 0] + z * Rf[2, 0],
            x * Rf[0, 1] + y * Rf[1, 1] + z * Rf[2, 1],
            x * Rf[0, 2] + y * Rf[1, 2] + z * Rf[2, 2],
            o + x * tf[0] + y * tf[1] + z * tf[2],
        )
    if kind <= TZ:
        return x, y, z, o + v * (x, y, z)[kind]
    c, s = cos(v), sin(v)
    if kind == RX:
        return x, c * y + s * z, c * z - s * y, o
    if kind == RY:
        return c * x - s * z, y, s * x + c * z, o
    return c * x + s * y, c * y - s * x, z, o


def propagate(
    chain: Chain,
    q: np.ndarray,
    eta: np.ndarray | None = None,
    T0: np.ndarray | None = None,
    record: bool = False,
) -> ChainState:
    """Propagate the chain.

    Parameters
    ----------
    q : ndarray, shape (m, n)
        Joint values: rad (revolute), mm (prismatic).
    eta : ndarray, shape (P,) or (pop, P), optional
        Kinematic parameter errors added to the nominal element values. With a population the
        outputs gain a leading ``pop`` axis: ``(pop, m, 3)``.
    T0 : ndarray, shape (4, 4), optional
        Transform applied before the first element (e.g. ``tracker_T_base``).
    record : bool
        Record each element's world axis and origin (needed for Jacobians).
    """
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != chain.n_joints:
        raise ValueError(f"The 'q' parameter must have shape (m, {chain.n_joints}). Got {q.shape} instead.")
    pop = eta is not None and np.ndim(eta) == 2
    if T0 is None:
        T0 = np.eye(4)
    x = T0[:3, 0].copy()
    y = T0[:3, 1].copy()
    z = T0[:3, 2].copy()
    o = T0[:3, 3].copy()
    axes: list[np.ndarray | None] = []
    origins: list[np.ndarray | None] = []
    frame: Frame = (x, y, z, o)
    for e, kind in enumerate(chain.kinds):
        if kind == FIXED:
            frame = step(FIXED, 0.0, frame, chain.fixed[e])
            if record:
                axes.append(None)
                origins.append(None)
            continue
        v: float | np.ndarray = chain.nominal[e]
        j = chain.joint[e]
        if j >= 0:
            v = v + q[:, j]
        p = chain.param[e]
        if p >= 0 and eta is not None:
            v = v + (eta[:, p : p + 1] if pop else eta[p])
        if record:
            axes.append(frame[kind % 3])
            origins.append(frame[3])
        frame = step(kind, v[..., None] if isinstance(v, np.ndarray) else v, frame)
    x, y, z, o = frame
    return ChainState(x=x, y=y, z=z, o=o, axes=axes, origins=origins)


@dataclass(frozen=True)
class FoldedChain:
    """A chain with its parameter vector folded in: ``T = B_0 · Rot(q_1) · B_1 ··· Rot(q_n) · B_n``.

    blocks : (..., n + 1, 3, 4) rigid transforms ``[R t]``; block ``s`` ends with joint element ``s`` at its
    constant value (nominal + parameter error), since ``Rot(v + q) = Rot(v) Rot(q)``; a leading axis for a
    population of parameter vectors. joint : (n,) joint index of each joint element (chain order);
    axis : (n,) its rotation axis (0, 1, 2 for x, y, z). The compiled form is
    :func:`robocal.kinematics.compiled.fold`.
    """

    blocks: np.ndarray
    joint: np.ndarray
    axis: np.ndarray

    @property
    def n_joints(self) -> int:
        return len(self.joint)


def fold(chain: Chain, eta: np.ndarray | None = None, T0: np.ndarray | None = None) -> FoldedChain:
    """Fold the parameter errors ``eta`` (P,) or (pop, P) and ``T0`` (4, 4) into a :class:`FoldedChain`.

    Raises :class:`ValueError` unless every joint drives exactly one rotation element."""
    pop = eta is not None and np.ndim(eta) == 2
    lead: tuple[int, ...] = (len(eta),) if eta is not None and pop else ()
    T = np.eye(4) if T0 is None else np.asarray(T0, dtype=float)
    frame: Frame = tuple(np.broadcast_to(T[:3, c], (*lead, 3)) for c in range(4))  # type: ignore[assignment]
    identity: Frame = tuple(np.broadcast_to(np.eye(4)[:3, c], (*lead, 3)) for c in range(4))  # type: ignore[assignment]
    blocks: list[np.ndarray] = []
    joints: list[int] = []
    axes: list[int] = []
    for e, kind in enumerate(chain.kinds):
        if kind == FIXED:
            frame = step(FIXED, 0.0, frame, chain.fixed[e])
            continue
        v: Any = chain.nominal[e]
        p = chain.param[e]
        if p >= 0 and eta is not None:
            v = v + (eta[:, p : p + 1] if pop else eta[p])
        frame = step(kind, v, frame)
        j = int(chain.joint[e])
        if j >= 0:
            if kind < RX:
                raise ValueError(
                    f"joint {j + 1} is prismatic: the folded chain (the service's compensation, the compiled "
                    "population kernel) supports revolute joints only"
                )
            blocks.append(np.stack(frame, -1))
            joints.append(j)
            axes.append(kind - RX)
            frame = identity
    if sorted(joints) != list(range(chain.n_joints)):
        raise ValueError(f"each joint must drive exactly one element; got joints {joints}")
    blocks.append(np.stack(frame, -1))
    return FoldedChain(np.stack(blocks, -3), np.array(joints, dtype=np.int64), np.array(axes, dtype=np.int64))


def fk(chain: Chain, q: np.ndarray, eta: np.ndarray | None = None, T0: np.ndarray | None = None) -> np.ndarray:
    """Flange poses ``(m, 4, 4)`` (or ``(pop, m, 4, 4)``) for joint angles ``q`` (m, n) in rad."""
    st = propagate(chain, q, eta, T0)
    m = q.shape[0]
    lead = np.broadcast_shapes(st.x.shape[:-1], st.o.shape[:-1], (m,))
    T = np.zeros((*lead, 4, 4))
    T[..., :3, 0] = st.x
    T[..., :3, 1] = st.y
    T[..., :3, 2] = st.z
    T[..., :3, 3] = st.o
    T[..., 3, 3] = 1.0
    return T


def point_jacobians(
    chain: Chain, st: ChainState, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Jacobians of world points w.r.t. the kinematic parameters and the joint angles.

    Parameters
    ----------
    st : ChainState
        From :func:`propagate` with ``record=True`` (single parameter vector, not a population).
    points : ndarray, shape (m, 3)
        World points rigidly attached to the flange (e.g. targets).

    Returns
    -------
    J_eta : ndarray, shape (m, 3, P)
        Position Jacobian w.r.t. the kinematic parameters.
    W_eta : ndarray, shape (m, 3, P)
        Orientation (angular) Jacobian w.r.t. the kinematic parameters.
    J_q, W_q : ndarray, shape (m, 3, n)
        The same w.r.t. the joint angles.
    """
    m = points.shape[0]
    P, n = chain.n_params, chain.n_joints
    J_eta = np.zeros((m, 3, P))
    W_eta = np.zeros((m, 3, P))
    J_q = np.zeros((m, 3, n))
    W_q = np.zeros((m, 3, n))
    els = [e for e, k in enumerate(chain.kinds) if k != FIXED and (chain.param[e] >= 0 or chain.joint[e] >= 0)]
    if not els:
        return J_eta, W_eta, J_q, W_q
    # stack the recorded axes and origins of all elements: (E, m, 3), one vectorised cross product
    U = np.empty((len(els), m, 3))
    O = np.empty((len(els), m, 3))
    for k, e in enumerate(els):
        U[k] = st.axes[e]
        O[k] = st.origins[e]
    is_rot = np.array([chain.kinds[e] >= RX for e in els])
    D = points[None] - O
    C = np.empty_like(U)
    C[..., 0] = U[..., 1] * D[..., 2] - U[..., 2] * D[..., 1]
    C[..., 1] = U[..., 2] * D[..., 0] - U[..., 0] * D[..., 2]
    C[..., 2] = U[..., 0] * D[..., 1] - U[..., 1] * D[..., 0]
    dP = np.where(is_rot[:, None, None], C, U)  # (E, m, 3)
    dW = np.where(is_rot[:, None, None], U, 0.0)
    prm = np.array([chain.param[e] for e in els])
    jnt = np.array([chain.joint[e] for e in els])
    sel = prm >= 0
    J_eta[:, :, prm[sel]] = np.moveaxis(dP[sel], 0, -1)
    W_eta[:, :, prm[sel]] = np.moveaxis(dW[sel], 0, -1)
    for idx in np.flatnonzero(jnt >= 0):
        jj = int(jnt[idx])
        J_q[:, :, jj] += dP[idx]
        W_q[:, :, jj] += dW[idx]
    return J_eta, W_eta, J_q, W_q
