"""The pose characteristics of ISO 9283:1998, as the standard states them (plain functions on arrays).

Notation of the standard: a test pose is visited in ``n`` cycles; ``x_j, y_j, z_j`` (mm) and ``a_j, b_j, c_j``
(deg, rotations about the base x, y and z axes) are the attained pose of cycle ``j``, ``x_c .. c_c`` the
commanded pose, all in the robot base frame.

- Barycentre (7.2.1): ``x̄ = (1/n) Σ x_j`` (and ``ȳ, z̄, ā, b̄, c̄``).
- Pose accuracy (7.2.1): ``AP_p = sqrt((x̄ - x_c)² + (ȳ - y_c)² + (z̄ - z_c)²)``, ``AP_x = x̄ - x_c`` ..;
  orientation ``AP_a = ā - a_c``, ``AP_b = b̄ - b_c``, ``AP_c = c̄ - c_c``.
- Pose repeatability (7.2.2): ``l_j = sqrt((x_j - x̄)² + (y_j - ȳ)² + (z_j - z̄)²)``, ``l̄ = (1/n) Σ l_j``,
  ``S_l = sqrt(Σ (l_j - l̄)² / (n - 1))``, ``RP_l = l̄ + 3 S_l``; orientation ``RP_a = ±3 S_a`` with
  ``S_a = sqrt(Σ (a_j - ā)² / (n - 1))`` (and b, c).
- Multi-directional pose accuracy variation (7.2.3): the barycentres ``x̄_h`` of the cycles approached from
  direction ``h``; ``vAP_p = max sqrt((x̄_h - x̄_k)² + (ȳ_h - ȳ_k)² + (z̄_h - z̄_k)²)`` over the pairs h, k.
- Distance accuracy and repeatability (7.3): between the poses ``P_1j`` and ``P_2j`` attained in cycle ``j``,
  ``D_j = |P_1j - P_2j|``, ``D_c = |P_c1 - P_c2|``, ``D̄ = (1/n) Σ D_j``; ``AD_p = D̄ - D_c``;
  ``RD = ±3 sqrt(Σ (D_j - D̄)² / (n - 1))``.
- Drift of pose characteristics (7.5): ``dAP = |AP_t1 - AP_tn|``, ``dRP = |RP_t1 - RP_tn|``, AP and RP computed
  from the first and from the last group of cycles.

Angles are differenced as ``(a_j - a_c)`` wrapped to (-180, 180] deg, so that a commanded 180 deg and an attained
-179.99 deg are 0.01 deg apart (the standard's arithmetic, without the branch cut of the angle reading).
"""

from __future__ import annotations

import numpy as np


def _points(p: np.ndarray, name: str = "attained") -> np.ndarray:
    a = np.asarray(p, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0 or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be a non-empty (n, 3) array of finite numbers; got shape {a.shape}")
    return a


def wrap_deg(a: np.ndarray) -> np.ndarray:
    """Angles in degrees wrapped to (-180, 180]."""
    w = np.mod(np.asarray(a, dtype=float) + 180.0, 360.0) - 180.0
    return np.where(w == -180.0, 180.0, w)


def barycentre(p: np.ndarray) -> np.ndarray:
    """``(x̄, ȳ, z̄)`` of the attained positions ``(n, 3)``."""
    return _points(p).mean(axis=0)


def pose_accuracy(p: np.ndarray, commanded: np.ndarray) -> tuple[float, np.ndarray]:
    """``(AP_p, (AP_x, AP_y, AP_z))`` in mm: barycentre of the attained positions minus the commanded position."""
    d = barycentre(p) - np.asarray(commanded, dtype=float).reshape(3)
    return float(np.sqrt(np.sum(d**2))), d


def pose_repeatability(p: np.ndarray) -> tuple[float, float, float]:
    """``(RP_l, l̄, S_l)`` in mm; needs at least two cycles (``S_l`` divides by ``n - 1``)."""
    a = _points(p)
    if len(a) < 2:
        raise ValueError("pose repeatability needs at least 2 cycles")
    lj = np.sqrt(np.sum((a - a.mean(axis=0)) ** 2, axis=1))
    lbar = float(lj.mean())
    s = float(np.sqrt(np.sum((lj - lbar) ** 2) / (len(a) - 1)))
    return lbar + 3.0 * s, lbar, s


def orientation_accuracy(angles_deg: np.ndarray, commanded_deg: np.ndarray) -> np.ndarray:
    """``(AP_a, AP_b, AP_c)`` deg: the mean attained angle minus the commanded one (differences wrapped)."""
    d = wrap_deg(np.asarray(angles_deg, dtype=float) - np.asarray(commanded_deg, dtype=float).reshape(1, 3))
    return d.mean(axis=0)


def orientation_repeatability(angles_deg: np.ndarray, commanded_deg: np.ndarray) -> np.ndarray:
    """``(RP_a, RP_b, RP_c)`` deg: ``3 S`` of each angle (the standard's ``±3 S_a``; the half-width is given)."""
    d = wrap_deg(np.asarray(angles_deg, dtype=float) - np.asarray(commanded_deg, dtype=float).reshape(1, 3))
    if len(d) < 2:
        raise ValueError("orientation repeatability needs at least 2 cycles")
    return 3.0 * np.sqrt(np.sum((d - d.mean(axis=0)) ** 2, axis=0) / (len(d) - 1))


def multidirectional_variation(barycentres: np.ndarray) -> float:
    """``vAP_p`` mm: the largest distance between the barycentres ``(h, 3)`` of the approach directions."""
    b = _points(barycentres, "barycentres")
    if len(b) < 2:
        raise ValueError("vAP needs at least two approach directions")
    d = np.sqrt(np.sum((b[:, None, :] - b[None, :, :]) ** 2, axis=2))
    return float(d.max())


def distance_characteristics(
    p1: np.ndarray, p2: np.ndarray, c1: np.ndarray, c2: np.ndarray
) -> tuple[float, float, float, float]:
    """``(AD_p, RD_l, D̄, D_c)`` mm for the attained positions of two poses paired by cycle (``(n, 3)`` each)."""
    a, b = _points(p1, "p1"), _points(p2, "p2")
    if a.shape != b.shape:
        raise ValueError(f"p1 and p2 must be paired by cycle; shapes {a.shape} and {b.shape}")
    if len(a) < 2:
        raise ValueError("distance repeatability needs at least 2 cycles")
    Dj = np.sqrt(np.sum((a - b) ** 2, axis=1))
    Dc = float(np.sqrt(np.sum((np.asarray(c1, float).reshape(3) - np.asarray(c2, float).reshape(3)) ** 2)))
    Dbar = float(Dj.mean())
    rd = 3.0 * float(np.sqrt(np.sum((Dj - Dbar) ** 2) / (len(a) - 1)))
    return Dbar - Dc, rd, Dbar, Dc


def gross_errors(p: np.ndarray, k: float, floor_mm: float, window: int = 5) -> np.ndarray:
    """The stated gross-error rule: a mask of the cycles left out of one pose (and approach).

    ``p`` in cycle order. Each cycle's distance ``d_j`` to the coordinate-wise median of the ``window`` cycles around
    it (shifted at the ends; all cycles when fewer) is compared with ``median(d) + k · max(1.4826 · MAD(d), floor_mm)``
    (MAD the median absolute deviation of the ``d_j``; 1.4826 makes it a standard deviation for normal data;
    ``floor_mm`` the smallest spread credited, so that a few identical readings do not make every other one an
    outlier). A local median follows a slow drift (a warm-up), so only jumps stand out. One pass, no iteration.
    """
    a = _points(p)
    n = len(a)
    if n <= window:
        ref = np.broadcast_to(np.median(a, axis=0), a.shape)
    else:
        start = np.clip(np.arange(n) - window // 2, 0, n - window)
        ref = np.array([np.median(a[s : s + window], axis=0) for s in start])
    d = np.sqrt(np.sum((a - ref) ** 2, axis=1))
    med = float(np.median(d))
    mad = float(np.median(np.abs(d - med)))
    limit = med + k * max(1.4826 * mad, floor_mm)
    return d > limit


__all__ = [
    "barycentre",
    "distance_characteristics",
    "gross_errors",
    "multidirectional_variation",
    "orientation_accuracy",
    "orientation_repeatability",
    "pose_accuracy",
    "pose_repeatability",
    "wrap_deg",
]
