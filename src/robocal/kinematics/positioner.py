"""A positioner's kinematics: the axes that carry the part (a turntable, a tilt-rotate positioner), issue 34.

The description (:class:`robocal.robot.Positioner`) gives each axis ``j`` (base -> part) as a direction ``w_j`` and a
point ``p_j`` in the robot base frame at positioner angles 0. Each axis gets a nominal frame ``F_j`` (origin
``p_j``, z along ``w_j``, :func:`axis_frames`); the part carried by the last axis is

    ``P(q) = F_1 E_1 Rot_z(q_1) F_1^-1 F_2 E_2 Rot_z(q_2) ...``

in the robot base frame, a reflector on the part at ``P(q) w`` (``w`` its coordinates in the last axis' nominal
frame at angle 0). The error of axis ``j``, ``E_j = Trans_x(tx) Trans_y(ty) Rot_x(rx) Rot_y(ry)``, moves the axis
line across itself (``tx``, ``ty``, mm) and tilts it (``rx``, ``ry``, rad): the four errors of a line. A shift
along the axis and a turn about it are the part points' (not identifiable apart from them). No zero offset either:
the last axis' is a turn of the part (its points'), and a carrying axis' turns the axes it carries, which is a
move of their lines (their own four errors) and a turn of the part.
"""

from __future__ import annotations

import numpy as np

from robocal.robot import Positioner

#: the errors of each axis line, in the order of :func:`parameter_names`
LINE_ERRORS = ("tx", "ty", "rx", "ry")


def axis_frames(pos: Positioner) -> np.ndarray:
    """The nominal frames ``F_j`` (k, 4, 4) of the axes: origin on the axis, z along it, x perpendicular (the base x
    made perpendicular, or the base y when the axis is along x)."""
    out = np.tile(np.eye(4), (pos.n_axes, 1, 1))
    for j in range(pos.n_axes):
        z = pos.w[j] / np.linalg.norm(pos.w[j])
        hint = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = hint - z * (hint @ z)
        x /= np.linalg.norm(x)
        out[j, :3, :3] = np.column_stack([x, np.cross(z, x), z])
        out[j, :3, 3] = pos.p_mm[j]
    return out


def parameter_names(pos: Positioner) -> tuple[str, ...]:
    """The positioner's parameters: ``<axis>_tx``, ``_ty`` (mm), ``_rx``, ``_ry`` (rad) per axis."""
    return tuple(f"{name}_{e}" for name in pos.names for e in LINE_ERRORS)


def _rot(axis: int, a: np.ndarray) -> np.ndarray:
    """Rotations (m, 3, 3) by angles ``a`` (m,) about x, y or z (0, 1, 2)."""
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((len(a), 3, 3))
    i, j = [(1, 2), (0, 2), (0, 1)][axis]
    R[:, axis, axis] = 1.0
    R[:, i, i], R[:, j, j] = c, c
    R[:, i, j], R[:, j, i] = -s, s
    if axis == 1:  # Rot_y: [[c, 0, s], [0, 1, 0], [-s, 0, c]]
        R[:, i, j], R[:, j, i] = s, -s
    return R


def part_frames(pos: Positioner, q: np.ndarray, params: np.ndarray) -> np.ndarray:
    """``P(q)`` (m, 4, 4): the part's frame in the robot base frame at positioner angles ``q`` (m, k) rad, with the
    errors ``params`` (in the order of :func:`parameter_names`; zeros: the nominal positioner)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    m = len(q)
    F = axis_frames(pos)
    T = np.tile(np.eye(4), (m, 1, 1))
    prev = np.eye(4)
    for j in range(pos.n_axes):
        tx, ty, rx, ry = params[4 * j : 4 * j + 4]
        E = np.eye(4)
        E[:3, :3] = _rot(0, np.array([rx]))[0] @ _rot(1, np.array([ry]))[0]
        E[:3, 3] = [tx, ty, 0.0]
        Z = np.tile(np.eye(4), (m, 1, 1))
        Z[:, :3, :3] = _rot(2, q[:, j])
        T = T @ (np.linalg.inv(prev) @ F[j] @ E) @ Z
        prev = F[j]
    return T


def part_points(pos: Positioner, q: np.ndarray, params: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Reflector positions (m, 3) in the robot base frame: ``P(q) w`` with ``w`` (m, 3) or (3,) mm on the part."""
    P = part_frames(pos, q, params)
    w = np.broadcast_to(np.asarray(w, dtype=float), (len(P), 3))
    return np.einsum("mij,mj->mi", P[:, :3, :3], w) + P[:, :3, 3]
