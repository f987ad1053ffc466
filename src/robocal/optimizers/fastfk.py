"""Target positions of a whole population of calibration parameter vectors, fast.

The population methods spend nearly all their time evaluating the nonlinear calibration model for every
individual at every pose. :class:`PopulationPositions` computes exactly what
:meth:`robocal.identification.model.CalibrationModel.batch_position_residuals` computes (same chain, same
element order, same tool offsets, position residuals ``predicted - measured``), reorganised:

* The chain is ``T_ref · B_0 · Rot(q_1) · B_1 · Rot(q_2) ··· Rot(q_n) · B_n`` where each block ``B_s`` holds
  every element between two joints, plus the constant part (nominal + parameter error) of the next joint
  rotation, since ``Rot(v + q) = Rot(v) Rot(q)``. The blocks depend on the individual only: they are built
  once per individual (~40 elements), not once per pose.
* The target point is carried *backwards* through the chain (``w = B_n t``, then ``w = B_{s-1} Rot(q_s) w``):
  per pose and joint one planar rotation with precomputed ``cos q``/``sin q`` and one rigid transform of a
  point, ~24 flops, no trigonometric call.

Two back ends, same arithmetic: the numba kernel :func:`robocal.kinematics.compiled.population_positions`
(parallel over individuals, vectorised over poses; the chain's one compiled element code and folding) when numba
is installed, else numpy broadcasting over ``(pop, m)`` with the blocks of :func:`robocal.kinematics.chain.fold`.
``backend="numpy"`` forces the latter.

Joint elements must be rotations (every chain :func:`robocal.kinematics.chain.build_chain` makes is); other
chains are rejected with :class:`ValueError` and callers fall back to the model's own method.
"""

from __future__ import annotations

import numpy as np

from robocal.identification.model import CalibrationModel, FitData
from robocal.kinematics import compiled
from robocal.kinematics.chain import RX, RZ, fold

__all__ = ["HAVE_NUMBA", "PopulationPositions"]

HAVE_NUMBA = compiled.AVAILABLE


class PopulationPositions:
    """Position residuals ``(pop, 3m)`` of a calibration model for a population of full vectors ``x``.

    Parameters
    ----------
    model : CalibrationModel
    data : FitData
        Poses and measured positions (orientations are not used).
    backend : {"auto", "numba", "numpy"}
        "auto" uses numba when installed.

    Raises
    ------
    ValueError
        When a joint drives anything but exactly one rotation element (then use the model's own
        ``batch_position_residuals``).
    """

    def __init__(self, model: CalibrationModel, data: FitData, backend: str = "auto") -> None:
        if backend not in ("auto", "numba", "numpy"):
            raise ValueError(f"The 'backend' parameter must be 'auto', 'numba' or 'numpy'. Got {backend!r} instead.")
        if backend == "numba" and not HAVE_NUMBA:
            raise ValueError("The 'backend' parameter is 'numba' but numba is not installed (pip install numba).")
        self.backend = "numba" if backend == "auto" and HAVE_NUMBA else ("numpy" if backend == "auto" else backend)
        chain = model.full_chain
        self.chain = chain
        self.arrays = compiled.chain_arrays(chain)
        kinds = self.arrays[0]
        joint = np.asarray(chain.joint)
        for ej in np.flatnonzero(joint >= 0):
            if np.count_nonzero(joint == joint[ej]) != 1 or not RX <= kinds[ej] <= RZ:
                raise ValueError(
                    f"joint {int(joint[ej]) + 1} must drive exactly one rotation element for the fast kernel"
                )
        if sorted(joint[joint >= 0].tolist()) != list(range(chain.n_joints)):
            raise ValueError("every joint must drive a rotation element for the fast kernel")
        order = joint[joint >= 0]  # joint index of each joint element, chain order
        self.axes = np.ascontiguousarray(kinds[joint >= 0] - RX)
        self.T0 = np.asarray(model.T_ref, dtype=float)
        self.n_chain = model.n_chain
        self.K = len(model.target_names)
        self.n = model.n
        q = np.asarray(data.q, dtype=float)[:, order]
        self.cq = np.ascontiguousarray(np.cos(q).T)
        self.sq = np.ascontiguousarray(np.sin(q).T)
        self.tidx = np.ascontiguousarray(data.target_index, dtype=np.int64)
        self.p_meas = np.ascontiguousarray(data.p_mm, dtype=float)
        self.m = q.shape[0]

    def __call__(self, X: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Residuals ``(pop, 3m)`` (predicted - measured, mm) of the full vectors ``X (pop, n)``."""
        X = np.ascontiguousarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != self.n:
            raise ValueError(f"The 'X' parameter must have shape (pop, {self.n}). Got {X.shape} instead.")
        if out is None:
            out = np.empty((X.shape[0], 3 * self.m))
        if self.backend == "numba":
            compiled.population_positions(
                *self.arrays, self.T0, X, self.n_chain, self.axes, self.tidx, self.cq, self.sq, self.p_meas, out,
            )  # fmt: skip
            return out
        return self._numpy(X, out)

    # ------------------------------------------------------------------ numpy back end
    def _numpy(self, X: np.ndarray, out: np.ndarray) -> np.ndarray:
        pop = X.shape[0]
        nj = self.cq.shape[0]
        B = fold(self.chain, X[:, : self.chain.n_params], self.T0).blocks  # (pop, n + 1, 3, 4)
        tools = X[:, self.n_chain : self.n_chain + 3 * self.K].reshape(pop, self.K, 3)[:, self.tidx]  # (pop, m, 3)
        w = [tools[..., 0], tools[..., 1], tools[..., 2]]
        for s in range(nj, -1, -1):
            if s < nj:  # the joint rotation Rot_axis(q) applied to a point (compiled.points_to_base)
                c, sn = self.cq[s], self.sq[s]
                ax = int(self.axes[s])
                i, j = (ax + 1) % 3, (ax + 2) % 3
                w[i], w[j] = c * w[i] - sn * w[j], sn * w[i] + c * w[j]
            Bs = B[:, s]
            w = [Bs[:, r, 0:1] * w[0] + Bs[:, r, 1:2] * w[1] + Bs[:, r, 2:3] * w[2] + Bs[:, r, 3:4] for r in range(3)]
        o3 = out.reshape(pop, self.m, 3)
        for r in range(3):
            np.subtract(w[r], self.p_meas[:, r], out=o3[:, :, r])
        return out
