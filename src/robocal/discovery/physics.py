"""Joint-level effects of real robots that the one-at-a-time library does not hold: the gear transmission error
as a long Fourier series of the joint's own angle, and the compliance under the arm's own weight when the link
masses are unknown.

Both are joint-angle errors ``dq_j = S_j(q) · c`` (the ``joint`` shape of :mod:`robocal.discovery.candidates`)
with many coefficients, so they are fitted with a Gaussian prior on the coefficients (ridge): the prior's
standard deviation ``tau`` (rad per coefficient) is a setting or chosen by pose-grouped cross-validation.

**Transmission error** (``transmission``): ``dq_j = w(q_j) · sum_h a_h sin(h q_j) + b_h cos(h q_j)``, harmonics
``h = 1..K`` of one output revolution (a reducer's tooth-mesh and bearing errors repeat with the joint angle;
real reducers show tens of cycles per revolution). ``K`` is chosen by cross-validation. A Fourier series fitted
on part of a revolution says nothing about the rest: ``w(q_j)`` is 1 on the angles the calibration visited
(modulo one revolution, visits closer than ``gap_deg`` joined into one interval) and falls to 0 over
``taper_deg`` outside them (a raised cosine), so the effect is never extrapolated.

**Compliance under the arm's own weight** (``weight``): the gravity load torque of joint ``j`` is linear in the
unknown mass moments of the bodies it carries, ``tau_j = Y_j(q) pi`` with ``pi = (m_i, m_i c_i)`` per body
(:func:`gravity_regressor`; gravity along the robot description's ``gravity``, the base's -z by default), and a
reducer of compliance ``k_j^-1`` turns it by ``dq_j = Y_j(q) pi / k_j``. The combinations ``pi / k_j`` that the
data can tell apart are the right singular vectors of ``Y_j`` over the calibration poses (:func:`weight_basis`);
the effect's coefficients are those combinations, scaled so that each column has unit RMS on the calibration
poses, and the prior says how large a deflection is physical (``prior_deg``: the RMS deflection over the poses).
With link masses in the description the library's ``compliance`` candidate (one stiffness per joint, the torque
from those masses) competes with it; logged torques or motor currents replace it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.compensation.signals import REV_DEG
from robocal.robot import RobotDescription


def visited_intervals(q_rad: np.ndarray, gap_deg: float, min_visits: int = 1) -> list[list[float]]:
    """Angles a joint visited, modulo one revolution, as closed intervals ``[lo, hi]`` deg within [0, 360)
    (an interval may wrap: ``lo > hi``); visits closer than ``gap_deg`` are joined, and an interval of fewer than
    ``min_visits`` visits (entries of ``q_rad``: one per configuration, :func:`configurations`) is left out: an
    angle one pose saw far from the others. ``[[0, 360]]`` for a full revolution."""
    a = np.sort(np.mod(np.rad2deg(np.asarray(q_rad, dtype=float)), REV_DEG))
    if len(a) == 0:
        return []
    gaps = np.diff(np.concatenate([a, [a[0] + REV_DEG]]))  # gap after each visit, the last one wrapping
    big = np.flatnonzero(gaps > gap_deg)
    if len(big) == 0:
        return [[0.0, REV_DEG]] if len(a) >= min_visits else []
    out = []
    # each big gap ends an interval; the interval after gap k starts at a[k + 1] and ends at the next big gap
    for i, k in enumerate(big):
        k_next = big[(i + 1) % len(big)]
        if (k_next - k) % len(a) + (len(a) if len(big) == 1 else 0) < min_visits:
            continue  # its visits: a[k + 1 .. k_next] (all of them with one gap)
        lo = float(a[(k + 1) % len(a)])
        hi = float(a[k_next])
        out.append([lo, hi])
    return out


def configurations(q: np.ndarray) -> np.ndarray:
    """The distinct joint configurations of ``q (m, n)`` (a pose measured on several targets once): the visits
    :func:`visited_intervals` counts."""
    q = np.asarray(q, dtype=float)
    _, first = np.unique(np.round(q, 9), axis=0, return_index=True)
    return q[np.sort(first)]


def visited_span_deg(intervals: list[list[float]]) -> float:
    """Total angle (deg) of the visited intervals of :func:`visited_intervals`."""
    return float(sum(REV_DEG if (hi - lo) == REV_DEG else (hi - lo) % REV_DEG for lo, hi in intervals))


def lowest_harmonic(span_deg: float) -> int:
    """The lowest harmonic a periodic error over ``span_deg`` of visited angles is fitted with: at least two of its
    periods must lie within the visited angles. A slower harmonic looks like a smooth trend there, which the
    geometry (joint offset, link lengths) absorbs and which cannot be extrapolated."""
    return max(1, int(np.ceil(2.0 * REV_DEG / max(span_deg, 1e-9))))


#: A mass-moment combination whose RMS gravity torque over the calibration poses is below this share of the
#: strongest one's is left out of the ``weight`` effect: its column, scaled to unit RMS over those poses, may be
#: multiplied by up to 1 / share at a configuration that loads it. On the UR10 with 1e-6, joint 6's effect reached
#: 24 deg at configurations outside the calibration, from 0.07 deg on the calibration poses; with 0.05 (up to 20x),
#: series D of the same UR10 (ISO cubes, a narrow range of joint 2) calibrated on the lower three quarters of joint
#: 2's range was 1.48 mm off on the top quarter where the geometry alone is 0.85 (0.47 with 0.5). With 0.5 a new
#: configuration's deflection is at most ~2x what the calibration poses show for that combination. Measured with
#: ``benchmarks/real_robots.py --hold-out-range`` on four real series (0.05 -> 0.5, mean mm): UR10 B 0.109 -> 0.118
#: (held-out range 0.242 both), C 0.082 -> 0.081 (0.300 -> 0.294), D 0.118 -> 0.136 (1.477 -> 0.468); ABB T4 0.162
#: -> 0.150 (0.175 -> 0.248; geometry 0.307).
WEIGHT_MIN_EXCITATION = 0.5


def weight_basis(Y_j: np.ndarray, rtol: float = WEIGHT_MIN_EXCITATION) -> tuple[np.ndarray, np.ndarray]:
    """The mass-moment combinations of joint ``j`` the poses tell apart: ``(V (4n, r), scale (r,))`` such that
    ``S = Y_j @ V / scale`` has orthogonal columns of unit RMS over the poses, keeping the combinations whose
    RMS torque is at least ``rtol`` of the strongest (:data:`WEIGHT_MIN_EXCITATION`). ``r = 0`` when gravity
    exerts no torque on the joint (an axis along gravity)."""
    m = Y_j.shape[0]
    _U, s, Vt = np.linalg.svd(Y_j, full_matrices=False)
    if len(s) == 0 or s[0] <= 1e-9 * np.sqrt(m):  # N·m: no gravity torque at all on this joint
        return np.zeros((Y_j.shape[1], 0)), np.zeros(0)
    keep = s > rtol * s[0]
    return Vt[keep].T, s[keep] / np.sqrt(m)


#: A weight combination may deflect a configuration anywhere in the joint limits at most this many times as much as
#: the most any calibration pose shows (:func:`bounded_columns`). The excitation share above compares the
#: combinations with one another on the calibration poses only: on the UR10's series D (its ISO cubes load joint 5
#: barely) a joint-5 combination within it reached 189x its calibration maximum at the arm stretched upright, and
#: the discovered model was 20 mm off on that validation row (6.1 deg on joint 5), where the geometry is 0.3 mm.
#: On the four real series every other combination stays within 4.3x (B, C, D, ABB; also with joint 2's top quarter
#: held out): any bound from ~5 to ~180 keeps the same ones.
WEIGHT_MAX_AMPLIFICATION = 10.0


def workspace_sample(robot: RobotDescription, n: int = 512) -> np.ndarray:
    """``n`` configurations uniform in the robot's joint limits (rad; a fixed seed: the same sample every run)."""
    lo, hi = robot.q_limits[:, 0], robot.q_limits[:, 1]
    return np.asarray(lo + (hi - lo) * np.random.default_rng(0).random((n, robot.n_joints)))


def bounded_columns(S_cal: np.ndarray, S_ws: np.ndarray, bound: float = WEIGHT_MAX_AMPLIFICATION) -> np.ndarray:
    """Which columns stay within ``bound`` times their largest calibration value everywhere in the sample of the
    workspace ``S_ws`` (:data:`WEIGHT_MAX_AMPLIFICATION`): a boolean mask over the columns."""
    top = np.abs(S_cal).max(axis=0)
    return np.asarray(np.abs(S_ws).max(axis=0) <= bound * np.where(top > 0, top, np.inf))


#: harmonics of the shoulder's own angle offered as a counterbalance's torque (:func:`balancer_columns`)
BALANCER_HARMONICS = (1,)


def balancer_columns(
    robot: RobotDescription, q: np.ndarray, rows: np.ndarray, Y: np.ndarray, q_ws: np.ndarray, offered: bool = True
) -> tuple[int | None, np.ndarray, np.ndarray]:
    """The shoulder (the first revolute joint the arm's weight loads over the fitted ``rows``) and the signals of
    a counterbalance there, ``sin/cos(h q)`` for :data:`BALANCER_HARMONICS` less their mean over ``rows`` (``B
    (m, 2H)``, the centre). A heavy robot carries a spring or hydro-pneumatic cylinder between the base and the
    upper arm that cancels most of the shoulder's gravity torque: the torque left, and so the deflection, is not
    of the links' weight's shape but adds a function of the shoulder's angle alone (newcomer pass 11: a KR210-like
    arm with a spring cancelling 85 % of it, 18 configurations: the shoulder's weight effect not found, 0.208 mm
    held out; with this variant 0.123). ``(None, ...)`` when not ``offered`` (``counterbalance: off``), when no
    revolute joint carries a gravity torque, or when
    the columns would deflect a configuration of the workspace sample ``q_ws`` more than
    :data:`WEIGHT_MAX_AMPLIFICATION` times as much as the calibration poses show (a shoulder the calibration
    visited over a narrow range: a harmonic centred there is near zero on its poses and large elsewhere)."""
    from robocal.compensation.signals import fourier_signal

    none = None, np.zeros((len(q), 0)), np.zeros(0)
    if not offered:
        return none
    tq = np.sqrt(np.mean(Y[rows] ** 2, axis=(0, 2)))  # (n,) RMS regressor per joint
    loaded = [j for j in range(Y.shape[1]) if not robot.prismatic[j] and tq[j] > 1e-9 * max(float(tq.max()), 1e-300)]
    if not loaded:
        return none
    j = loaded[0]
    B = fourier_signal(q[:, j], np.asarray(BALANCER_HARMONICS))
    centre = B[rows].mean(axis=0)
    B_ws = fourier_signal(q_ws[:, j], np.asarray(BALANCER_HARMONICS)) - centre
    if not bounded_columns(B[rows] - centre, B_ws).all():
        return none
    return j, B - centre, centre


__all__ = [
    "BALANCER_HARMONICS",
    "WEIGHT_MAX_AMPLIFICATION",
    "balancer_columns",
    "bounded_columns",
    "layer_centres",
    "lowest_harmonic",
    "periodic_window",
    "visited_intervals",
    "visited_span_deg",
    "weight_basis",
    "workspace_sample",
]


# ------------------------------------------------------------------------------------------ the residual layer
def layer_centres(q_rad: np.ndarray, n_centres: int, seed: int) -> np.ndarray:
    """``(D, n)`` rad: centres of the residual layer's kernel, k-means of the calibration poses' joint angles
    (scikit-learn, seeded; all poses when there are fewer)."""
    q = np.asarray(q_rad, dtype=float)
    uniq = np.unique(np.round(q, 9), axis=0)
    if len(uniq) <= n_centres:
        return uniq
    from sklearn.cluster import KMeans

    km = KMeans(n_clusters=n_centres, n_init=1, random_state=seed).fit(uniq)
    return np.asarray(km.cluster_centers_)


def periodic_window(cfg: Any, h_max: int) -> tuple[float, float]:
    """``(gap_deg, taper_deg)`` of the coverage window of a periodic joint error up to harmonic ``h_max``:
    visits closer than a quarter of the shortest period (and at least ``transmission_gap_deg``) are joined,
    and the error falls to zero over an eighth of it (at least ``transmission_taper_deg``) outside."""
    period = 360.0 / max(int(h_max), 1)
    return max(cfg.transmission_gap_deg, period / 4.0), max(cfg.transmission_taper_deg, period / 8.0)
