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
With link masses in the description the library's ``compliance`` candidate (one stiffness per joint) is used
instead.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.robot import RobotDescription

REV_DEG = 360.0


def visited_intervals(q_rad: np.ndarray, gap_deg: float) -> list[list[float]]:
    """Angles a joint visited, modulo one revolution, as closed intervals ``[lo, hi]`` deg within [0, 360)
    (an interval may wrap: ``lo > hi``); visits closer than ``gap_deg`` are joined. ``[[0, 360]]`` for a full
    revolution."""
    a = np.sort(np.mod(np.rad2deg(np.asarray(q_rad, dtype=float)), REV_DEG))
    if len(a) == 0:
        return []
    gaps = np.diff(np.concatenate([a, [a[0] + REV_DEG]]))  # gap after each visit, the last one wrapping
    big = np.flatnonzero(gaps > gap_deg)
    if len(big) == 0:
        return [[0.0, REV_DEG]]
    out = []
    # each big gap ends an interval; the interval after gap k starts at a[k + 1] and ends at the next big gap
    for i, k in enumerate(big):
        k_next = big[(i + 1) % len(big)]
        lo = float(a[(k + 1) % len(a)])
        hi = float(a[k_next])
        out.append([lo, hi])
    return out


def visited_span_deg(intervals: list[list[float]]) -> float:
    """Total angle (deg) of the visited intervals of :func:`visited_intervals`."""
    return float(sum(REV_DEG if (hi - lo) == REV_DEG else (hi - lo) % REV_DEG for lo, hi in intervals))


def lowest_harmonic(span_deg: float) -> int:
    """The lowest harmonic a periodic error over ``span_deg`` of visited angles is fitted with: at least two of its
    periods must lie within the visited angles. A slower harmonic looks like a smooth trend there, which the
    geometry (joint offset, link lengths) absorbs and which cannot be extrapolated."""
    return max(1, int(np.ceil(2.0 * REV_DEG / max(span_deg, 1e-9))))


def coverage_weight(q_rad: np.ndarray, intervals: list[list[float]], taper_deg: float) -> np.ndarray:
    """``w (m,)`` in [0, 1]: 1 on the visited intervals, a raised cosine to 0 over ``taper_deg`` outside."""
    a = np.mod(np.rad2deg(np.asarray(q_rad, dtype=float)), REV_DEG)
    if not intervals:
        return np.zeros(a.shape)
    iv = np.asarray(intervals, dtype=float)
    lo, hi = iv[:, 0], iv[:, 1]  # (K,) every interval at once: the service evaluates this per Newton step
    A = a[..., None]
    inside = np.where(lo <= hi, (A >= lo) & (A <= hi), (A >= lo) | (A <= hi))  # lo > hi: wraps through 0
    d = np.minimum(np.mod(lo - A, REV_DEG), np.mod(A - hi, REV_DEG))
    dist = np.where(inside, 0.0, d).min(axis=-1)
    if taper_deg <= 0:
        return (dist == 0).astype(float)
    t = np.clip(dist / taper_deg, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * t))


def fourier_signal(q_rad: np.ndarray, harmonics: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
    """``S (m, 2H)``: ``[sin(h q) ..., cos(h q) ...]`` for the harmonics ``h`` (times ``weight`` when given)."""
    q = np.asarray(q_rad, dtype=float)
    h = np.asarray(harmonics, dtype=int)
    if len(h) and np.array_equal(h, np.arange(h[0], h[0] + len(h))):
        # consecutive harmonics: e^{i h q} by repeated multiplication (one sin/cos per pose; the service and
        # compensation.csv evaluate tens of harmonics per Newton step), exact to ~len(h) ulp
        from robocal.kinematics import compiled

        z = np.exp(1j * q)
        z0 = np.exp(1j * h[0] * q)
        if compiled.AVAILABLE:  # the same recurrence, compiled (a Python loop over tens of harmonics otherwise)
            Z = compiled.harmonics(z, z0, len(h))
        else:
            Z = np.empty((len(q), len(h)), dtype=complex)
            Z[:, 0] = z0
            for k in range(1, len(h)):
                Z[:, k] = Z[:, k - 1] * z
        S = np.concatenate([Z.imag, Z.real], axis=1)
    else:
        S = np.concatenate([np.sin(h[None, :] * q[:, None]), np.cos(h[None, :] * q[:, None])], axis=1)
    return S if weight is None else S * np.asarray(weight, dtype=float)[:, None]


def held_harmonic_signal(q_rad: np.ndarray, harmonic: int, held_deg: list[float] | None) -> np.ndarray:
    """``S (m, 2)``: ``sin(h q), cos(h q)`` of a joint's angle on the arc ``held_deg = [lo, hi]`` (deg) its
    calibration visited, and held outside it at the value of the nearer end: over the first and the last quarter
    of the arc never visited the value at ``hi`` and at ``lo``, and linearly from one to the other over its middle
    half (continuous and periodic, as the service needs). ``held_deg`` None: the harmonic everywhere.

    A harmonic whose period the visited angles do not cover is a smooth trend there (a proxy fitted jointly with
    the geometry), not an identified periodic error: continuing its curve beyond the visited angles extrapolates
    the trend, and dropping it to zero leaves the geometry fitted with it inconsistent. Held at its edge values,
    the model outside the visited angles is the one the calibration saw at its nearest edge."""
    q = np.asarray(q_rad, dtype=float)
    h = int(harmonic)
    if held_deg is None:
        return np.column_stack([np.sin(h * q), np.cos(h * q)])
    lo, hi = np.deg2rad(float(held_deg[0])), np.deg2rad(float(held_deg[1]))
    span = hi - lo
    two_pi = 2.0 * np.pi
    d = np.mod(q - lo, two_pi)  # angle from lo around the circle
    f = np.clip(2.0 * (d - span) / max(two_pi - span, 1e-12) - 0.5, 0.0, 1.0)[:, None]  # 0 near hi, 1 near lo
    inside = (d <= span)[:, None]
    edge_hi = np.array([np.sin(h * hi), np.cos(h * hi)])
    edge_lo = np.array([np.sin(h * lo), np.cos(h * lo)])
    return np.where(inside, np.column_stack([np.sin(h * q), np.cos(h * q)]), (1.0 - f) * edge_hi + f * edge_lo)


def transmission_signal(q_rad: np.ndarray, record: dict[str, Any]) -> np.ndarray:
    """The transmission-error signal of a stored effect (``harmonics``, ``visited_deg``, ``taper_deg``, and the
    ``centre`` subtracted: the signal's mean over the calibration poses, whose constant part the geometry's
    joint offset carries)."""
    w = coverage_weight(q_rad, record["visited_deg"], float(record["taper_deg"]))
    S = fourier_signal(q_rad, np.asarray(record["harmonics"], dtype=int), w)
    return S - np.asarray(record.get("centre", 0.0), dtype=float)


def gravity_regressor(robot: RobotDescription, q: np.ndarray, compiled_ok: bool = True) -> np.ndarray:
    """``Y (m, n, 4 n)``: the gravity load torque of every joint (N·m) per unit mass moment of every body:
    column ``4 i`` is body ``i``'s mass (1 kg at its frame origin), columns ``4 i + 1..3`` its first mass moment
    (1 kg·m along its frame's x, y, z). ``tau = Y @ pi`` for any masses (nominal kinematics, the robot's
    gravity vector); the tests check it against :func:`robocal.kinematics.gravity.gravity_torques`.

    One pass over the chain: ``tau_j = u_j · sum_{i >= j} ((o_i - o_j) m_i + R_i (m c)_i) x g`` with ``u_j, o_j``
    joint ``j``'s world axis and a point on it, ``o_i, R_i`` body ``i``'s frame (same body frames as
    ``gravity_torques``). Compiled (:func:`robocal.kinematics.compiled.gravity_regressor`: the service evaluates
    it per Newton step) unless numba is missing or ``compiled_ok`` is False (the numpy reference)."""
    from robocal.kinematics import compiled

    q = np.atleast_2d(np.asarray(q, dtype=float))
    if compiled.AVAILABLE and compiled_ok:
        args = _regressor_arrays(robot)
        return compiled.gravity_regressor(*args[:5], np.ascontiguousarray(q), *args[5:])
    return _gravity_regressor_numpy(robot, q)


def _gravity_regressor_numpy(robot: RobotDescription, q: np.ndarray) -> np.ndarray:
    """The reference (numpy) pass of :func:`gravity_regressor`, through ``chain.step``."""
    from robocal.kinematics.chain import FIXED, step
    from robocal.kinematics.gravity import MM, body_frame_boundaries

    m, n = q.shape
    chain = _chain(robot)
    bounds = body_frame_boundaries(chain, robot.is_mdh)
    joint_el = [int(np.flatnonzero(chain.joint == j)[0]) for j in range(n)]
    want = set(bounds) | set(joint_el)
    rec: dict[int, tuple[np.ndarray, ...]] = {}
    one = np.ones((m, 1))
    frame = (np.eye(3)[0] * one, np.eye(3)[1] * one, np.eye(3)[2] * one, np.zeros((m, 3)))
    for e, kind in enumerate(chain.kinds):
        if e in want:
            rec[e] = frame
        if kind == FIXED:
            frame = step(FIXED, 0.0, frame, chain.fixed[e])
            continue
        v = chain.nominal[e] + (q[:, chain.joint[e]] if chain.joint[e] >= 0 else 0.0)
        frame = step(kind, np.broadcast_to(v, (m,))[:, None], frame)
    rec[len(chain.kinds)] = frame
    g = np.asarray(robot.gravity, dtype=float)
    U = np.stack([rec[joint_el[j]][chain.kinds[joint_el[j]] % 3] for j in range(n)], axis=1)  # (m, n, 3)
    Oj = np.stack([rec[joint_el[j]][3] for j in range(n)], axis=1) * MM
    Ob = np.stack([rec[bounds[i]][3] for i in range(n)], axis=1) * MM
    Ab = np.stack([np.stack(rec[bounds[i]][:3], axis=1) for i in range(n)], axis=1)  # (m, n, 3 axes, 3)
    # u_j · ((o_i - o_j) x g) = u_j · (o_i x g) - u_j · (o_j x g); u_j · (a x g) for the body axes
    mass = np.einsum("mjk,mik->mji", U, np.cross(Ob, g)) - np.einsum("mjk,mjk->mj", U, np.cross(Oj, g))[:, :, None]
    first = np.einsum("mjk,miak->mjia", U, np.cross(Ab, g))
    carried = np.triu(np.ones((n, n), dtype=bool))[None, :, :]  # body i >= joint j
    Y = np.concatenate([(mass * carried)[..., None], first * carried[..., None]], axis=3).reshape(m, n, 4 * n)
    return Y


_CHAINS: dict[int, tuple[RobotDescription, Any]] = {}
_REGRESSOR_ARRAYS: dict[int, tuple[RobotDescription, tuple[Any, ...]]] = {}


def _regressor_arrays(robot: RobotDescription) -> tuple[Any, ...]:
    """The compiled regressor's chain arrays for this description (built once per description object):
    ``(kinds, nominal, joint, fR, ft, slot, joint_slot, joint_axis, body_slot, g, MM)``."""
    from robocal.kinematics.compiled import chain_arrays
    from robocal.kinematics.gravity import MM, body_frame_boundaries

    hit = _REGRESSOR_ARRAYS.get(id(robot))
    if hit is not None and hit[0] is robot:
        return hit[1]
    chain = _chain(robot)
    n = robot.n_joints
    kinds, nominal, _param, _is_joint, fR, ft = chain_arrays(chain)
    bounds = body_frame_boundaries(chain, robot.is_mdh)
    joint_el = [int(np.flatnonzero(chain.joint == j)[0]) for j in range(n)]
    slot = np.full(len(kinds) + 1, -1, dtype=np.int64)
    for k, e in enumerate(sorted(set(bounds) | set(joint_el))):
        slot[e] = k
    out = (
        kinds, np.ascontiguousarray(nominal), np.asarray(chain.joint, dtype=np.int64), fR, ft, slot,
        slot[joint_el], np.array([kinds[e] % 3 for e in joint_el], dtype=np.int64), slot[bounds],
        np.asarray(robot.gravity, dtype=float), float(MM),
    )  # fmt: skip
    _REGRESSOR_ARRAYS[id(robot)] = (robot, out)
    return out


def _chain(robot: RobotDescription) -> Any:
    """The robot's chain, built once per description object (the service evaluates effects per request)."""
    from robocal.kinematics.chain import build_chain

    hit = _CHAINS.get(id(robot))
    if hit is None or hit[0] is not robot:
        hit = (robot, build_chain(robot))
        _CHAINS[id(robot)] = hit
    return hit[1]


#: A mass-moment combination whose RMS gravity torque over the calibration poses is below this share of the
#: strongest one's is left out of the ``weight`` effect: its column, scaled to unit RMS over those poses, would be
#: multiplied by up to 1 / share at a configuration that loads it (on the UR10 with 1e-6, joint 6's effect reached
#: 24 deg at configurations outside the calibration, from 0.07 deg on the calibration poses). With 0.05, a new
#: configuration's deflection is at most ~20x the prior's size, and bounded by the torque the arm can exert.
WEIGHT_MIN_EXCITATION = 0.05


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


def weight_signal(
    robot: RobotDescription, q: np.ndarray, record: dict[str, Any], Y: np.ndarray | None = None
) -> np.ndarray:
    """The compliance-under-own-weight signal of a stored effect (``basis``, ``scale``); ``Y``: the
    :func:`gravity_regressor` at ``q`` when already computed (one for every joint's effect)."""
    j = int(record["joint"]) - 1
    Yj = (gravity_regressor(robot, q) if Y is None else Y)[:, j, :]
    return Yj @ np.asarray(record["basis"], dtype=float) / np.asarray(record["scale"], dtype=float)


__all__ = [
    "coverage_weight",
    "fourier_signal",
    "gravity_regressor",
    "transmission_signal",
    "visited_intervals",
    "weight_basis",
    "weight_signal",
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


def layer_features(q_rad: np.ndarray, centres: np.ndarray, length_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian kernel features ``exp(-|q - c|² / (2 l²))`` ``(m, D)`` and each pose's distance to its nearest
    centre ``(m,)`` rad (scikit-learn's pairwise kernels)."""
    from sklearn.metrics.pairwise import euclidean_distances

    d = euclidean_distances(np.atleast_2d(np.asarray(q_rad, dtype=float)), centres)
    return np.exp(-(d**2) / (2.0 * length_rad**2)), d.min(axis=1)


def layer_gate(dist_rad: np.ndarray, inside_rad: float, length_rad: float) -> np.ndarray:
    """1 within ``inside_rad`` of a centre (the calibrated region), a raised cosine to 0 one length scale
    further: outside the calibrated region the layer is not applied (the parametric model alone)."""
    t = np.clip((np.asarray(dist_rad, dtype=float) - inside_rad) / length_rad, 0.0, 1.0)
    return np.asarray(0.5 * (1.0 + np.cos(np.pi * t)))


def layer_signal(q_rad: np.ndarray, record: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The residual layer's gated features ``(m, D)`` of a stored effect and the gate ``(m,)`` (1 = inside the
    calibrated region, 0 = outside: parametric correction only)."""
    ell = float(record["length_rad"])
    F, d = layer_features(q_rad, np.asarray(record["centres_rad"], dtype=float), ell)
    g = layer_gate(d, float(record["inside_rad"]), ell)
    return F * g[:, None], g
