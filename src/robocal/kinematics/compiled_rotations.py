"""The rotation conversions, compiled: :func:`rotvec` / :func:`quat`, mirrors of
:func:`robocal.kinematics.transforms.matrix_to_rotvec` / ``matrix_to_quat``. They call no kernel of another
file (numba's on-disk cache checks only the file of the function it caches).
"""

from __future__ import annotations

import numpy as np

from robocal.kinematics.compiled_support import _jit

# --------------------------------------------------------------------------------------------------------
# rotation conversions (mirrors of robocal.kinematics.transforms)
# --------------------------------------------------------------------------------------------------------


@_jit
def _rotvec_one(R: np.ndarray, out: np.ndarray) -> None:
    """One rotation vector, :func:`robocal.kinematics.transforms.matrix_to_rotvec` step by step."""
    cos = min(max((R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    w0 = R[2, 1] - R[1, 2]
    w1 = R[0, 2] - R[2, 0]
    w2 = R[1, 0] - R[0, 1]
    th = np.arctan2(np.sqrt(w0 * w0 + w1 * w1 + w2 * w2) / 2.0, cos)
    if th < 1e-6:
        f = 0.5 + th**2 / 12.0
    else:
        f = th / (2.0 * np.sin(th))
    out[0] = w0 * f
    out[1] = w1 * f
    out[2] = w2 * f
    if th > np.pi - 1e-3:
        # axis from the symmetric part (R + R^T)/2 = cos I + (1 - cos) a a^T: its largest diagonal's column
        best = 0
        for k in range(1, 3):
            if R[k, k] > R[best, best]:
                best = k
        a = np.empty(3)
        for r in range(3):
            a[r] = ((R[r, best] + R[best, r]) / 2.0 - (cos if r == best else 0.0)) / (1.0 - cos)
        nrm = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
        dot = a[0] * w0 + a[1] * w1 + a[2] * w2
        sign = -1.0 if dot < 0.0 else 1.0
        for r in range(3):
            out[r] = a[r] / nrm * sign * th


@_jit
def rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(m, 3)`` (rad) of rotations ``R (m, 3, 3)``, robust near 0 and pi."""
    m = R.shape[0]
    out = np.empty((m, 3))
    for i in range(m):
        _rotvec_one(R[i], out[i])
    return out


@_jit
def quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(m, 4)`` (w, x, y, z), w >= 0, of rotations ``R (m, 3, 3)``, as
    :func:`robocal.kinematics.transforms.matrix_to_quat`: ``(cos th/2, a sin th/2)`` of the rotation vector."""
    m = R.shape[0]
    out = np.empty((m, 4))
    rv = np.empty(3)
    for i in range(m):
        _rotvec_one(R[i], rv)
        th = np.sqrt(rv[0] * rv[0] + rv[1] * rv[1] + rv[2] * rv[2])
        inv = 1.0 / th if th > 0.0 else 1.0
        c = np.cos(th / 2.0)
        sn = np.sin(th / 2.0)
        sign = -1.0 if c < 0.0 else 1.0
        out[i, 0] = sign * c
        for r in range(3):
            out[i, r + 1] = sign * rv[r] * inv * sn
    return out
