"""The consecutive harmonics of :func:`robocal.compensation.signals.fourier_signal`, compiled. The kernel calls
no kernel of another file (numba's on-disk cache checks only the file of the function it caches).
"""

from __future__ import annotations

import numpy as np

from robocal.kinematics.compiled_support import _jit


@_jit
def harmonics(z: np.ndarray, z0: np.ndarray, H: int) -> np.ndarray:
    """``Z (m, H)`` complex: ``Z[:, 0] = z0``, ``Z[:, k] = Z[:, k - 1] z`` (``z = e^{i q}``, ``z0 = e^{i h0 q}``):
    the consecutive harmonics of :func:`robocal.compensation.signals.fourier_signal`, the same operations."""
    m = len(z)
    re = np.empty((m, H))
    im = np.empty((m, H))
    for r in range(m):
        a, b = z[r].real, z[r].imag
        re[r, 0] = z0[r].real
        im[r, 0] = z0[r].imag
        for k in range(1, H):
            c, d = re[r, k - 1], im[r, k - 1]
            re[r, k] = c * a - d * b
            im[r, k] = c * b + d * a
    return re + 1j * im
