"""What the compiled kernels (:mod:`robocal.kinematics.compiled`) are built with and fed, no kernel itself:
numba's decorators (compiled lazily at the first call, machine code cached on disk), :data:`AVAILABLE`, and
the chain's arrays as the kernels take them (:func:`chain_arrays`).

Without numba the decorators leave plain (slow) Python and :data:`AVAILABLE` is False; callers then use their
numpy paths.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.kinematics.chain import Chain

numba: Any
try:  # numba is a dependency; every caller has a numpy path without it
    import numba
except ImportError:  # pragma: no cover - depends on the environment
    numba = None

AVAILABLE = numba is not None


def _identity(f: Any) -> Any:
    return f


# compiled lazily at the first call; cache=True keeps the machine code on disk between processes
_jit: Any = numba.njit(cache=True, nogil=True) if numba is not None else _identity
_jit_parallel: Any = numba.njit(cache=True, nogil=True, parallel=True) if numba is not None else _identity
_prange: Any = numba.prange if numba is not None else range


def chain_arrays(chain: Chain) -> tuple[np.ndarray, ...]:
    """The chain as :func:`fold` takes it: ``kinds, nominal, param, is_joint, fR (E, 3, 3), ft (E, 3)``."""
    E = len(chain.kinds)
    fR = np.zeros((E, 3, 3))
    ft = np.zeros((E, 3))
    for e, T in enumerate(chain.fixed):
        if T is not None:
            fR[e] = T[:3, :3]
            ft[e] = T[:3, 3]
    return (
        np.array(chain.kinds, dtype=np.int64),
        np.asarray(chain.nominal, dtype=float),
        np.asarray(chain.param, dtype=np.int64),
        np.asarray(chain.joint) >= 0,
        fR,
        ft,
    )
