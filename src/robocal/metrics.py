"""Error statistics of a model's 3-D predictions: one type, one orientation error, one noise floor.

:class:`ErrorStats` holds the mean, RMS and maximum of 3-D position errors (mm) and, where the data have
orientations, of orientation errors (deg) over ``n`` rows. Its fields are the one internal naming scheme
(``mean_mm``, ``rms_mm``, ``max_mm``, ``mean_deg`` ...); the files keep the keys they always had, which
:meth:`ErrorStats.position` and :meth:`ErrorStats.orientation` write in the caller's order and scheme:
``long`` (``mean_position_mm``, ``rms_orientation_deg``: calibration.json, summary.json, the metrics files)
or ``short`` (``mean_mm``, ``rms_deg``: the compliance and planning tables).

Definitions (stated once here):

* position error of a row: the Euclidean norm of its 3-D error vector, ``|p_pred - p_meas|`` (mm);
* orientation error of a row (:func:`orientation_errors_deg`): the angle of the rotation that takes the
  measured orientation onto the predicted one, ``|rotvec(R_pred R_measᵀ)|`` (deg);
* RMS: ``sqrt(mean(e²))`` of the row errors ``e``;
* noise floor (:func:`noise_floor`): the statistic a correct model reaches on noise alone.

Importing it reads and writes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robocal.kinematics.transforms import matrix_to_rotvec

__all__ = [
    "STATS",
    "ErrorStats",
    "noise_floor",
    "orientation_errors_deg",
    "position_errors_mm",
    "position_keys",
]

#: the statistics, in the order :meth:`ErrorStats.position` writes them by default
STATS = ("mean", "rms", "max")
#: key templates of the two schemes the files use (``{s}`` is a statistic of :data:`STATS`)
SCHEMES = {
    "long": ("{s}_position_mm", "{s}_orientation_deg"),
    "short": ("{s}_mm", "{s}_deg"),
}


def position_keys(order: Sequence[str] = STATS, scheme: str = "long") -> tuple[str, ...]:
    """The file keys of the position statistics in ``order`` (e.g. ``rms_position_mm``, or ``rms_mm``)."""
    return tuple(SCHEMES[scheme][0].format(s=s) for s in order)


def position_errors_mm(err: np.ndarray) -> np.ndarray:
    """Row errors (m,) mm from error vectors (m, 3), or the row errors themselves when given (m,)."""
    e = np.asarray(err, dtype=float)
    return np.linalg.norm(e, axis=1) if e.ndim == 2 else e


def orientation_errors_deg(R_pred: np.ndarray, R_meas: np.ndarray) -> np.ndarray:
    """Orientation error of every row (m,) deg: the angle of ``R_pred R_measᵀ`` (rotations (m, 3, 3))."""
    return rotvec_errors_deg(matrix_to_rotvec(R_pred @ np.swapaxes(R_meas, -1, -2)))


def rotvec_errors_deg(rv: np.ndarray) -> np.ndarray:
    """Orientation error of every row (m,) deg from its rotation-vector error (m, 3) rad."""
    return np.rad2deg(np.linalg.norm(rv, axis=1))


def _stats(e: np.ndarray) -> tuple[float, float, float]:
    if e.size == 0:  # nothing to score: NaN (not an error: e.g. every target refused by a compensation)
        return math.nan, math.nan, math.nan
    return float(np.mean(e)), float(np.sqrt(np.mean(e**2))), float(np.max(e))


@dataclass(frozen=True)
class ErrorStats:
    """Mean / RMS / max of the position errors (mm) and, when known, of the orientation errors (deg) of ``n``
    rows (see the module docstring for the definitions; NaN for no rows)."""

    n: int
    mean_mm: float
    rms_mm: float
    max_mm: float
    mean_deg: float | None = None
    rms_deg: float | None = None
    max_deg: float | None = None

    @classmethod
    def of(cls, position: np.ndarray, orientation_deg: np.ndarray | None = None) -> ErrorStats:
        """Statistics of position errors (error vectors (m, 3) mm or row errors (m,) mm) and, optionally, of
        orientation row errors (m,) deg (:func:`orientation_errors_deg`, :func:`rotvec_errors_deg`)."""
        e = position_errors_mm(position)
        mean, rms, mx = _stats(e)
        if orientation_deg is None:
            return cls(int(e.size), mean, rms, mx)
        return cls(int(e.size), mean, rms, mx, *_stats(np.asarray(orientation_deg, dtype=float)))

    @property
    def has_orientation(self) -> bool:
        return self.mean_deg is not None

    def position(self, order: Sequence[str] = STATS, scheme: str = "long") -> dict[str, float]:
        """The position statistics as the files name them, in ``order`` (a permutation of :data:`STATS`)."""
        return {k: float(getattr(self, f"{s}_mm")) for k, s in zip(position_keys(order, scheme), order, strict=True)}

    def orientation(self, order: Sequence[str] = STATS, scheme: str = "long") -> dict[str, float]:
        """The orientation statistics as the files name them (empty without orientations)."""
        if not self.has_orientation:
            return {}
        key = SCHEMES[scheme][1]
        return {key.format(s=s): float(getattr(self, f"{s}_deg")) for s in order}

    def to_dict(self, order: Sequence[str] = STATS, scheme: str = "long") -> dict[str, Any]:
        """Position then (when known) orientation statistics, each in ``order``."""
        return {**self.position(order, scheme), **self.orientation(order, scheme)}


def noise_floor(
    sigma_mm: float | np.ndarray,
    n_residuals: int,
    n_params: int,
    statistic: str = "rms",
) -> float:
    """The 3-D position error (mm) a correct model fitted with ``n_params`` parameters to ``n_residuals``
    residuals reaches on noise alone (noise ``sigma_mm`` per coordinate, 1 sigma; per point (m,): their RMS).

    ``rms``: ``sigma sqrt(3 dof / M)`` with ``dof = max(M - k, 1)`` (M = ``n_residuals``, k = ``n_params``):
    the expected RMS of the 3-D residual, each point's three coordinates sharing the residual degrees of
    freedom of the fit. ``mean``: the mean of a 3-D normal's norm, ``sigma sqrt(8 / pi)``, with the same dof
    share (the fitness of the linearised objective of :mod:`robocal.calibration.problem`). With
    orientations, ``M`` counts their residuals too (the dof share of the whole fit).
    """
    sig = np.asarray(sigma_mm, dtype=float)
    s = float(np.sqrt(np.mean(sig**2))) if sig.ndim else float(sig)
    dof = max(n_residuals - n_params, 1)
    if statistic == "rms":
        return float(s * np.sqrt(3.0 * dof / n_residuals))
    if statistic == "mean":
        return float(s * math.sqrt(8.0 / math.pi) * math.sqrt(dof / n_residuals))
    raise ValueError(f"noise_floor: statistic must be 'rms' or 'mean', got {statistic!r}")
