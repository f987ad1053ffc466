"""Candidate joint configurations and what the cell allows: every refused candidate is counted by reason.

Checks, in the order a refusal is attributed (a candidate failing several counts once under ``refused`` for
the first, and under ``failing`` for each):

``joint_limits``  a joint closer than ``joint_margin_deg`` to its limit;
``singularity``   the smallest singular value of the flange Jacobian ``[J_v / length_mm; J_w]`` below
                  ``singularity.min_sigma`` (dimensionless: 1 = a unit joint speed moves the flange by
                  ``length_mm`` or turns it by 1 rad in every direction);
``wrist``         ``|q_wrist| < singularity.min_wrist_deg`` (axes 4 and 6 aligned);
``volume``        a target outside the working volume (a box, or the ISO 9283 cube);
``self_collision`` two link capsules at least ``collision.skip`` bodies apart closer than their radii (pairs
                  joined by a chain shorter than their radii, e.g. through a zero-length wrist link, are not
                  checked: they overlap by construction);
``tracker_range`` no target within the tracker's distance range;
``line_of_sight`` fewer than ``tracker.min_targets_visible`` targets whose acceptance cone contains the
                  tracker (and, with capsules on, whose beam passes clear of the arm).

All arrays are batched over candidates ``C``; lengths mm, angles rad, base frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robocal.kinematics.chain import FIXED, Chain, point_jacobians, propagate
from robocal.plan.config import PlanConfig
from robocal.robot import RobotDescription

REASONS = (
    "joint_limits",
    "singularity",
    "wrist",
    "volume",
    "self_collision",
    "tracker_range",
    "line_of_sight",
)


def sampling_limits(robot: RobotDescription, ranges_deg: tuple[tuple[float, float], ...] | None) -> np.ndarray:
    """Joint ranges ``(n, 2)`` rad to sample from: the given ranges clipped to the limits, else the limits."""
    lim = robot.q_limits.copy()
    if ranges_deg is None:
        return lim
    r = np.deg2rad(np.asarray(ranges_deg, dtype=float))
    if r.shape != lim.shape:
        from robocal.errors import ConfigError

        raise ConfigError(
            f"The 'ranges_deg' plan setting must give [min, max] for each of the {robot.n_joints} joints. "
            f"Got {len(r)} ranges instead."
        )
    return np.clip(r, lim[:, 0:1], lim[:, 1:2])


def sample_configurations(limits: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform joint configurations ``(n, N)`` rad inside ``limits`` ``(N, 2)``."""
    return rng.uniform(limits[:, 0], limits[:, 1], size=(n, limits.shape[0]))


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Smallest distance between segments ``[p1, q1]`` and ``[p2, q2]`` (``(..., 3)`` each), shape ``(...)``.

    Closest points by clamping the parameters of the two lines (Ericson, Real-Time Collision Detection, 5.1.9);
    zero-length segments are points.
    """
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = np.sum(d1 * d1, -1)
    e = np.sum(d2 * d2, -1)
    f = np.sum(d2 * r, -1)
    c = np.sum(d1 * r, -1)
    b = np.sum(d1 * d2, -1)
    eps = 1e-12
    denom = a * e - b * b
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.where(denom > eps, denom, 1.0), 0.0, 1.0), 0.0)
    s = np.where(a <= eps, 0.0, s)
    t = np.where(e > eps, (b * s + f) / np.where(e > eps, e, 1.0), 0.0)
    # t outside [0, 1]: clamp and recompute s for the clamped t
    t_c = np.clip(t, 0.0, 1.0)
    s_c = np.where(a > eps, np.clip((b * t_c - c) / np.where(a > eps, a, 1.0), 0.0, 1.0), 0.0)
    s = np.where((t < 0.0) | (t > 1.0), s_c, s)
    t = t_c
    diff = (p1 + d1 * s[..., None]) - (p2 + d2 * t[..., None])
    return np.sqrt(np.sum(diff * diff, -1))


def link_segments(
    chain: Chain, st_origins: list[np.ndarray | None], flange: np.ndarray, targets: np.ndarray
) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Capsule segments ``(body, start (C, 3), end (C, 3))``: base to joint 1, joint i to joint i+1 (body i),
    the last joint to the flange and the flange to each target (body n, the tool)."""
    C = flange.shape[0]
    joint_origins: list[np.ndarray] = []
    for e, k in enumerate(chain.kinds):
        o = st_origins[e]
        if k != FIXED and chain.joint[e] >= 0 and o is not None:
            joint_origins.append(np.broadcast_to(o, (C, 3)))
    segs: list[tuple[int, np.ndarray, np.ndarray]] = [(0, np.zeros((C, 3)), joint_origins[0])]
    n = len(joint_origins)
    for i in range(n - 1):
        segs.append((i + 1, joint_origins[i], joint_origins[i + 1]))
    segs.append((n, joint_origins[-1], flange))
    for k in range(targets.shape[1]):
        segs.append((n, flange, targets[:, k]))
    return segs


@dataclass(frozen=True)
class Screened:
    """Candidates after the checks.

    q : (C, n) rad, the accepted candidates; visible : (C, K) bool, which targets the tracker sees;
    targets_mm : (C, K, 3) target positions (base frame); flange_R : (C, 3, 3); sigma_min : (C,);
    refused : reason -> count (first failing reason); failing : reason -> count (every failing check);
    n_sampled : candidates drawn.
    """

    q: np.ndarray
    visible: np.ndarray
    targets_mm: np.ndarray
    flange_R: np.ndarray
    sigma_min: np.ndarray
    refused: dict[str, int]
    failing: dict[str, int]
    n_sampled: int

    @property
    def n(self) -> int:
        return int(self.q.shape[0])


def evaluate(robot: RobotDescription, chain: Chain, q: np.ndarray, cfg: PlanConfig) -> dict[str, np.ndarray]:
    """Every check on configurations ``q`` (C, n) rad; returns masks ``True = fails`` per reason plus
    ``visible`` (C, K), ``targets_mm`` (C, K, 3), ``flange_R`` (C, 3, 3), ``sigma_min`` (C,)."""
    C, n = q.shape
    lim = robot.q_limits
    q_lim = q if robot.coupling is None else robot.to_reported(q)  # the limits are the controller's (reported)
    margin = np.where(robot.prismatic, 0.0, np.deg2rad(cfg.joint_margin_deg))  # deg: the revolute joints
    fails: dict[str, np.ndarray] = {}
    fails["joint_limits"] = np.any((q_lim < lim[:, 0] + margin) | (q_lim > lim[:, 1] - margin), axis=1)

    st = propagate(chain, q, None, None, record=True)
    o = st.o
    R = st.R
    _, _, Jq, Wq = point_jacobians(chain, st, o)
    Jn = np.concatenate([Jq / cfg.singularity.length_mm, Wq], axis=1)
    sigma_min = np.linalg.svd(Jn, compute_uv=False)[:, -1] if n <= 6 else np.linalg.svd(Jn, compute_uv=False)[:, 5]
    fails["singularity"] = sigma_min < cfg.singularity.min_sigma
    wj = cfg.singularity.wrist_joint
    if cfg.singularity.min_wrist_deg > 0 and 1 <= wj <= n:
        fails["wrist"] = np.abs(q[:, wj - 1]) < np.deg2rad(cfg.singularity.min_wrist_deg)
    else:
        fails["wrist"] = np.zeros(C, dtype=bool)

    tool = np.array([t.position_mm for t in cfg.targets])  # (K, 3) flange frame
    nrm = np.array([t.normal for t in cfg.targets])
    targets = o[:, None, :] + np.einsum("cij,kj->cki", R, tool)
    normals = np.einsum("cij,kj->cki", R, nrm)

    bounds = cfg.volume.bounds()
    if bounds is None:
        fails["volume"] = np.zeros(C, dtype=bool)
    else:
        lo, hi = bounds
        fails["volume"] = np.any((targets < lo) | (targets > hi), axis=(1, 2))

    segs = link_segments(chain, st.origins, o, targets) if cfg.collision.enabled else []
    if cfg.collision.enabled:
        fails["self_collision"] = _self_collision(segs, cfg, n, C)
    else:
        fails["self_collision"] = np.zeros(C, dtype=bool)

    tr = cfg.tracker
    v = np.asarray(tr.position_mm) - targets  # (C, K, 3) towards the tracker
    dist = np.linalg.norm(v, axis=-1)
    in_range = (dist >= tr.min_range_mm) & (dist <= tr.max_range_mm)
    cosang = np.sum(normals * v, -1) / np.maximum(dist, 1e-9)
    in_cone = cosang >= np.cos(np.deg2rad(tr.acceptance_half_angle_deg)) - 1e-12
    visible = in_range & in_cone
    if cfg.collision.enabled:
        _block_beams(visible, targets, segs, cfg, n)
    need = tr.min_targets_visible
    fails["tracker_range"] = in_range.sum(1) < need
    fails["line_of_sight"] = visible.sum(1) < need
    return {
        **fails,
        "visible": visible,
        "targets_mm": targets,
        "flange_R": R,
        "sigma_min": sigma_min,
    }


def _self_collision(segs: list[tuple[int, np.ndarray, np.ndarray]], cfg: PlanConfig, n: int, C: int) -> np.ndarray:
    """(C,) True where two link capsules ``segs`` (body, start, end) of the arm come closer than their radii."""
    rad = _radii(cfg, n)
    hit = np.zeros(C, dtype=bool)
    length = [np.linalg.norm(np.broadcast_to(s1 - s0, (C, 3)), axis=-1) for _, s0, s1 in segs]
    for a in range(len(segs)):
        for b in range(a + 1, len(segs)):
            ba, bb = segs[a][0], segs[b][0]
            if abs(ba - bb) < cfg.collision.skip:
                continue
            reach = rad[ba] + rad[bb]
            # capsules joined through short bodies (zero-length wrist links, an elbow offset) overlap by
            # construction: a pair counts only when the chain between them is longer than their radii
            gap = sum((length[k] for k in range(a + 1, b) if ba < segs[k][0] < bb), np.zeros(C))
            dist = segment_distance(segs[a][1], segs[a][2], segs[b][1], segs[b][2])
            hit |= (dist < reach + cfg.collision.clearance_mm) & (gap >= reach)
    return hit


def _block_beams(
    visible: np.ndarray, targets: np.ndarray, segs: list[tuple[int, np.ndarray, np.ndarray]], cfg: PlanConfig, n: int
) -> None:
    """Clear ``visible`` (C, K) in place where the beam from a target to the tracker passes through one of the
    arm's capsules ``segs`` (not the tool's own)."""
    C = targets.shape[0]
    rad = _radii(cfg, n)
    trk = np.broadcast_to(np.asarray(cfg.tracker.position_mm), (C, 3))
    for k in range(targets.shape[1]):
        blocked = np.zeros(C, dtype=bool)
        for body, s0, s1 in segs:
            if body >= n:
                continue
            blocked |= segment_distance(targets[:, k], trk, s0, s1) < rad[body]
        visible[:, k] &= ~blocked


def _radii(cfg: PlanConfig, n: int) -> np.ndarray:
    r = np.asarray(cfg.collision.radius_mm, dtype=float)
    if r.size < n + 1:
        from robocal.errors import ConfigError

        raise ConfigError(
            f"The 'collision.radius_mm' plan setting must give {n + 1} radii (base and one per joint body). "
            f"Got {r.size} instead."
        )
    return r


def screen(robot: RobotDescription, chain: Chain, q: np.ndarray, cfg: PlanConfig, chunk: int = 25000) -> Screened:
    """Run every check on ``q`` (C, n) rad in chunks; keep the accepted configurations, count the refused."""
    keep_q, vis, tg, Rs, sm = [], [], [], [], []
    refused = dict.fromkeys(REASONS, 0)
    failing = dict.fromkeys(REASONS, 0)
    for s in range(0, q.shape[0], chunk):
        qc = q[s : s + chunk]
        ev = evaluate(robot, chain, qc, cfg)
        bad = np.zeros(qc.shape[0], dtype=bool)
        for reason in REASONS:
            f = ev[reason]
            failing[reason] += int(f.sum())
            refused[reason] += int((f & ~bad).sum())
            bad |= f
        ok = ~bad
        keep_q.append(qc[ok])
        vis.append(ev["visible"][ok])
        tg.append(ev["targets_mm"][ok])
        Rs.append(ev["flange_R"][ok])
        sm.append(ev["sigma_min"][ok])
    K = len(cfg.targets)
    n = robot.n_joints
    return Screened(
        q=np.concatenate(keep_q) if keep_q else np.zeros((0, n)),
        visible=np.concatenate(vis) if vis else np.zeros((0, K), dtype=bool),
        targets_mm=np.concatenate(tg) if tg else np.zeros((0, K, 3)),
        flange_R=np.concatenate(Rs) if Rs else np.zeros((0, 3, 3)),
        sigma_min=np.concatenate(sm) if sm else np.zeros(0),
        refused=refused,
        failing=failing,
        n_sampled=int(q.shape[0]),
    )
