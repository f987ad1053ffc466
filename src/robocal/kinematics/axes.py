"""An external axis's own errors along its travel: the chain with six error elements on a linear axis's carriage.

A linear axis (a track, a lifting column, a gantry's axis: a prismatic joint of the description) is not a perfect
slide. Its carriage frame (the frame right after the joint's ``Trans_z(d + q)``: z along the travel) is displaced
and turned by small amounts that change with the position ``s`` along the travel (and, for a column, with the
load the arm puts on it):

=================== ============ ==========================================================================
component           element      meaning (carriage frame)
=================== ============ ==========================================================================
``straightness_x``  ``Trans_x``  transverse deviation of the path along the carriage's x (mm)
``straightness_y``  ``Trans_y``  transverse deviation along its y (mm)
``positioning``     ``Trans_z``  error of the position along the travel (mm)
``pitch``           ``Rot_x``    rotation of the carriage about its x (rad)
``yaw``             ``Rot_y``    rotation about its y (rad)
``roll``            ``Rot_z``    rotation about the travel (rad)
=================== ============ ==========================================================================

:func:`augment` inserts these six elements after the joint's own element, each driven by a *pseudo joint* (a
column appended to ``q``) with nominal value 0, so the one chain engine (:func:`robocal.kinematics.chain.propagate`,
its Jacobians) evaluates a chain whose carriage moves by per-row amounts: the twin uses it for the true errors, the
identification (:mod:`robocal.calibration.axes`) for the fitted ones (the derivative of a point by a pseudo
joint is the element's Jacobian column, :func:`robocal.kinematics.chain.point_jacobians`).

The errors are smooth functions of the travel: Legendre polynomials of ``u = 2 (s - s_min) / (s_max - s_min) - 1``
over the joint's limits (:func:`legendre`), and for a column the bending under the moment of the arm's weight
about the carriage (:func:`carried_moment`, from the description's masses, as :mod:`robocal.kinematics.gravity`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from robocal.kinematics.chain import RX, RY, RZ, TX, TY, TZ, Chain, build_chain, propagate
from robocal.kinematics.gravity import MM, _prefix, body_frame_boundaries
from robocal.robot import RobotDescription

#: the six error components of a linear axis, in the order of their elements
COMPONENTS = ("straightness_x", "straightness_y", "positioning", "pitch", "yaw", "roll")
#: the element kind of each component
KINDS = (TX, TY, TZ, RX, RY, RZ)
#: the unit of each component's value
UNITS = ("mm", "mm", "mm", "rad", "rad", "rad")


def augment(chain: Chain, joints: Sequence[int]) -> Chain:
    """The chain with the six error elements of :data:`COMPONENTS` after the element of each joint in ``joints``
    (0-based); the elements of the ``a``-th listed joint are driven by pseudo joints ``n + 6 a + c``, ``c`` the
    component's index (``n`` the chain's joint count), nominal value 0, no parameter."""
    kinds = list(chain.kinds)
    nominal = list(chain.nominal)
    joint = list(chain.joint)
    param = list(chain.param)
    fixed = list(chain.fixed)
    n = chain.n_joints
    for a, j in enumerate(joints):
        els = np.flatnonzero(np.asarray(joint) == j)
        if len(els) != 1:
            raise ValueError(f"joint {j + 1} drives {len(els)} elements; an axis error needs exactly one")
        at = int(els[0]) + 1
        for c, kind in enumerate(KINDS):
            kinds.insert(at + c, kind)
            nominal.insert(at + c, 0.0)
            joint.insert(at + c, n + 6 * a + c)
            param.insert(at + c, -1)
            fixed.insert(at + c, None)
    return Chain(
        kinds=tuple(kinds),
        nominal=np.array(nominal, dtype=float),
        joint=np.array(joint, dtype=int),
        param=np.array(param, dtype=int),
        fixed=tuple(fixed),
        param_names=chain.param_names,
        n_joints=n + 6 * len(joints),
    )


def travel_coordinate(s: np.ndarray, limits: Sequence[float]) -> np.ndarray:
    """``u`` in [-1, 1] over the travel ``limits = (s_min, s_max)`` (mm)."""
    lo, hi = float(limits[0]), float(limits[1])
    return 2.0 * (np.asarray(s, dtype=float) - lo) / (hi - lo) - 1.0


def legendre(u: np.ndarray, order: int) -> np.ndarray:
    """The Legendre polynomial ``P_order(u)``."""
    c = np.zeros(order + 1)
    c[order] = 1.0
    return np.polynomial.legendre.legval(np.asarray(u, dtype=float), c)


def carried_moment(
    robot: RobotDescription, q: np.ndarray, joint: int, payload_kg: np.ndarray | float = 0.0
) -> np.ndarray:
    """The moment (m, 3) N·m of the weight of everything joint ``joint`` carries (its own body, the bodies after
    it and the payload) about the joint's carriage origin, in the carriage frame (the frame right after the
    joint's element), at joint values ``q`` (m, n), nominal kinematics and the description's masses.

    Raises :class:`ValueError` when the description has no masses (``dynamics``)."""
    if not robot.has_dynamics:
        raise ValueError(f"robot {robot.name!r} has no dynamics (link masses): the moment on an axis needs them")
    assert robot.link_mass_kg is not None and robot.link_com_mm is not None
    q = np.asarray(q, dtype=float)
    m = q.shape[0]
    chain = build_chain(robot)
    e_joint = int(np.flatnonzero(chain.joint == joint)[0])
    carriage = propagate(_prefix(chain, e_joint + 1), q)
    o = np.broadcast_to(carriage.o, (m, 3))
    # (m, 3, 3) the carriage axes in the base frame (a frame that no joint turns comes back unbroadcast)
    R = np.stack([np.broadcast_to(a, (m, 3)) for a in (carriage.x, carriage.y, carriage.z)], axis=-1)
    g = np.asarray(robot.gravity, dtype=float)
    bounds = body_frame_boundaries(chain, robot.is_mdh)
    M = np.zeros((m, 3))
    for i in range(joint, robot.n_joints):
        st = propagate(_prefix(chain, bounds[i]), q)
        c = robot.link_com_mm[i]
        com = np.broadcast_to(st.o + st.x * c[0] + st.y * c[1] + st.z * c[2], (m, 3))
        M += np.cross((com - o) * MM, robot.link_mass_kg[i] * g)
    st = propagate(chain, q)
    pc = robot.payload_com_mm
    com = st.o + st.x * pc[0] + st.y * pc[1] + st.z * pc[2]
    pl = np.broadcast_to(np.asarray(payload_kg, dtype=float), (m,))
    M += np.cross((com - o) * MM, pl[:, None] * g)
    return np.einsum("mji,mj->mi", R, M)  # R^T M: the carriage frame


def carrying_axis(robot: RobotDescription) -> int | None:
    """The linear axis that carries the arm (0-based): the last prismatic joint with a revolute joint after it (a
    track's or a lifting column's carriage), or None."""
    slides = [j for j in range(robot.n_joints) if robot.prismatic[j] and not all(robot.prismatic[j + 1 :])]
    return slides[-1] if slides else None


def carriage_origin(robot: RobotDescription, q: np.ndarray, joint: int) -> np.ndarray:
    """The origin ``(m, 3)`` mm of joint ``joint``'s carriage frame (right after its element) in the base frame at
    joint values ``q (m, n)``, nominal kinematics (the pivot a carriage turns about; its errors, a few mm over
    metres of travel, change a tilt's lever arm by parts per thousand)."""
    q = np.asarray(q, dtype=float)
    chain = build_chain(robot)
    e_joint = int(np.flatnonzero(chain.joint == joint)[0])
    return np.broadcast_to(propagate(_prefix(chain, e_joint + 1), q).o, (q.shape[0], 3)).copy()


def arm_chain(chain: Chain, external: Sequence[int], values: Sequence[float] | np.ndarray) -> Chain:
    """The chain of the arm alone with the external axes ``external`` (0-based joints, prismatic or not) held at
    ``values`` (mm / rad): each of their elements becomes a constant element (its nominal value plus the axis'
    value, its parameter kept), and the other joints are renumbered ``0 .. n - k - 1`` in chain order. Folded
    (:func:`robocal.kinematics.chain.fold`), it is a revolute chain the compiled solver takes (the nominal inverse
    kinematics of a Cartesian target at its stated external axes, the configuration of a corrected pose)."""
    ext = [int(j) for j in external]
    if len(ext) != len(values):
        raise ValueError(f"{len(ext)} external axes but {len(values)} values")
    joint = np.asarray(chain.joint)
    nominal = np.array(chain.nominal, dtype=float)
    renumber = np.full(chain.n_joints, -1)
    arm = [j for j in range(chain.n_joints) if j not in ext]
    renumber[arm] = np.arange(len(arm))
    new_joint = np.where(joint >= 0, renumber[np.maximum(joint, 0)], -1)
    for j, v in zip(ext, values, strict=True):
        nominal[joint == j] += float(v)
    return Chain(
        kinds=chain.kinds,
        nominal=nominal,
        joint=new_joint.astype(int),
        param=np.asarray(chain.param),
        fixed=chain.fixed,
        param_names=chain.param_names,
        n_joints=len(arm),
    )


#: the bodies' first moments are per this length (m) in :func:`moment_features`: a body's centre of mass 0.1 m off
#: its frame's origin has a first-moment coefficient of its mass
FIRST_MOMENT_M = 0.1


def moment_features(robot: RobotDescription, q: np.ndarray, joint: int) -> tuple[np.ndarray, list[str]]:
    """The moment (kN·m, carriage frame; (m, 3, F)) of the arm's weight about the carriage of ``joint`` per unit of
    each unknown mass parameter, when the description has no masses: per body ``i`` after the carriage, 1 kg at its
    frame's origin (``b<i>_m``) and a first moment of 1 kg x :data:`FIRST_MOMENT_M` along its frame's x, y, z
    (``b<i>_x`` ...). Any mass distribution's moment (the bodies' masses and centres of mass, :func:`carried_moment`)
    is their sum weighted by the masses and first moments (the carriage's own weight turns with it: a constant,
    the axis's kinematic offset). Gravity along the description's ``gravity_mps2`` (default -z)."""
    q = np.asarray(q, dtype=float)
    m = q.shape[0]
    chain = build_chain(robot)
    e_joint = int(np.flatnonzero(chain.joint == joint)[0])
    carriage = propagate(_prefix(chain, e_joint + 1), q)
    o = np.broadcast_to(carriage.o, (m, 3))
    R = np.stack([np.broadcast_to(a, (m, 3)) for a in (carriage.x, carriage.y, carriage.z)], axis=-1)
    g = np.asarray(robot.gravity, dtype=float)
    bounds = body_frame_boundaries(chain, robot.is_mdh)
    cols, names = [], []
    for i in range(joint + 1, robot.n_joints):
        st = propagate(_prefix(chain, bounds[i]), q)
        cols.append(np.cross((np.broadcast_to(st.o, (m, 3)) - o) * MM, g))
        names.append(f"b{i + 1}_m")
        for axis, a in zip("xyz", (st.x, st.y, st.z), strict=True):
            cols.append(np.cross(np.broadcast_to(a, (m, 3)) * FIRST_MOMENT_M, g))
            names.append(f"b{i + 1}_{axis}")
    M = np.stack(cols, axis=-1)  # (m, 3, F) base frame, N·m per unit
    return np.einsum("mji,mjf->mif", R, M) / 1000.0, names


def rod_moment(robot: RobotDescription, q: np.ndarray, joint: int, payload_kg: np.ndarray | float) -> np.ndarray:
    """The moment (kN·m, carriage frame; (m, 3)) about the carriage of ``joint`` of the bodies it carries shaped
    like the arm's links (uniform rods, 1 kg per m: :func:`robocal.kinematics.gravity.generic_mass_moments`) and
    the payload at the flange's origin (each row's kg), for a description without masses: one moment of physical
    shape, its scale the bending's coefficient (:func:`moment_features` weighted by the rods' mass parameters). The
    per-parameter moments are 24 coefficients on a 6-axis arm, more than a column's few placements tell apart
    (newcomer pass 16: a column given as a DH table bent 2 mm at its top, the bending not found, 3 top rows called
    gross errors)."""
    from robocal.kinematics.gravity import generic_mass_moments

    Mf, _ = moment_features(robot, q, joint)
    pi0 = generic_mass_moments(robot)
    w = []
    for i in range(joint + 1, robot.n_joints):
        w += [pi0[4 * i]] + [float(v) / FIRST_MOMENT_M for v in pi0[4 * i + 1 : 4 * i + 4]]
    M = Mf @ np.asarray(w)
    pay = np.broadcast_to(np.asarray(payload_kg, dtype=float), (Mf.shape[0],))
    if np.any(pay):  # the payload at the flange: the last body's frame origin, its mass each row's
        M = M + Mf[:, :, 4 * (robot.n_joints - joint - 2)] * pay[:, None]
    return np.asarray(M)
