"""Plain functions on arrays: rotations, homogeneous transforms, quaternions, rotation vectors.

Every function accepts leading batch dimensions. Angles in radians, lengths in mm.
"""

from __future__ import annotations

import numpy as np


def rotx(a: float | np.ndarray) -> np.ndarray:
    """Rotation about x by ``a`` rad; shape ``(..., 3, 3)``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def roty(a: float | np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rotz(a: float | np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def homogeneous(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Build ``(..., 4, 4)`` transforms from rotations ``(..., 3, 3)`` and translations ``(..., 3)``."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros((*shape, 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inv_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)``."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    return homogeneous(Rt, -np.einsum("...ij,...j->...i", Rt, t))


def skew(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    z = np.zeros_like(v[..., 0])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def rotvec_to_matrix(rv: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors ``(..., 3)`` (rad) to matrices ``(..., 3, 3)``."""
    rv = np.asarray(rv, dtype=float)
    th = np.linalg.norm(rv, axis=-1)[..., None, None]
    K = skew(rv)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * K + b * (K @ K)


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` to rotation vectors ``(..., 3)`` (rad), robust near 0 and pi."""
    R = np.asarray(R, dtype=float)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    # |w| = 2 sin(th): atan2 keeps full precision near 0 and pi, where arccos(cos) loses half the digits
    th = np.arctan2(np.linalg.norm(w, axis=-1) / 2.0, cos)
    s = np.sin(th)
    small = th < 1e-6
    factor = np.where(small, 0.5 + th**2 / 12.0, th / (2.0 * np.where(small, 1.0, s)))
    out = w * factor[..., None]
    near_pi = th > np.pi - 1e-3
    if np.any(near_pi):
        # axis from the symmetric part: (R + Rᵀ)/2 = cos th I + (1 - cos th) a aᵀ, so a aᵀ is exact (the skew part,
        # O(pi - th), must not enter: taking a column of (R + I)/2 did, and left an O(pi - th) axis error)
        Rn = R[near_pi]
        c = cos[near_pi][..., None, None]
        B = ((Rn + np.swapaxes(Rn, -1, -2)) / 2.0 - c * np.eye(3)) / (1.0 - c)
        idx = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        axis = B[np.arange(len(idx)), :, idx]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        # sign so that the skew part agrees
        sign = np.sign(np.sum(axis * w[near_pi], axis=-1))
        sign[sign == 0] = 1.0
        out[near_pi] = axis * (sign * th[near_pi])[..., None]
    return out


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` as (w, x, y, z) to rotation matrices ``(..., 3, 3)``."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` to unit quaternions ``(..., 4)`` (w, x, y, z), w >= 0."""
    R = np.asarray(R, dtype=float)
    rv = matrix_to_rotvec(R)
    th = np.linalg.norm(rv, axis=-1)
    axis = rv / np.where(th > 0, th, 1.0)[..., None]
    q = np.concatenate([np.cos(th / 2)[..., None], axis * np.sin(th / 2)[..., None]], -1)
    q = np.where(q[..., :1] < 0, -q, q)
    return q


def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Closed-form rigid registration: the transform ``T`` (4, 4) minimising ``sum |T src_i - dst_i|²``.

    Parameters
    ----------
    src, dst : ndarray, shape (m, 3)
        Corresponding points, m >= 3 and not collinear.
    """
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    cs, cd = src.mean(0), dst.mean(0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    D = np.diag([1.0, 1.0, d if d != 0 else 1.0])
    R = Vt.T @ D @ U.T
    return homogeneous(R, cd - R @ cs)


def rpy_from_matrix(R: np.ndarray) -> np.ndarray:
    """ZYX angles ``(..., 3)`` as (roll, pitch, yaw) in rad, with ``R = Rz(yaw) Ry(pitch) Rx(roll)``; accurate at
    and near pitch = +-90 deg (pitch from atan2, not arcsin); at gimbal lock only roll -+ yaw is defined and it is
    all put in roll (yaw = 0). Used for URDF origins and KUKA A, B, C too."""
    R = np.asarray(R, dtype=float)
    cp = np.hypot(R[..., 0, 0], R[..., 1, 0])
    pitch = np.arctan2(-R[..., 2, 0], cp)
    lock = cp <= 1e-10
    roll = np.where(lock, np.arctan2(-R[..., 1, 2], R[..., 1, 1]), np.arctan2(R[..., 2, 1], R[..., 2, 2]))
    yaw = np.where(lock, 0.0, np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    return np.stack([roll, pitch, yaw], -1)


def matrix_from_rpy(rpy: np.ndarray) -> np.ndarray:
    rpy = np.asarray(rpy, dtype=float)
    return rotz(rpy[..., 2]) @ roty(rpy[..., 1]) @ rotx(rpy[..., 0])


def so3_left_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse left Jacobian of SO(3) at rotation vectors ``phi`` (..., 3): ``d log(exp(w) R) / dw`` at w = 0."""
    phi = np.asarray(phi, dtype=float)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    c = np.where(
        small,
        1.0 / 12.0 + th**2 / 720.0,
        1.0 / ths**2 - (1.0 + np.cos(ths)) / (2.0 * ths * np.where(small, 1.0, np.sin(ths))),
    )
    return np.eye(3) - 0.5 * K + c * (K @ K)
