"""The model-free noise routes (repeated poses, the rigid tool's inter-target distances) count only measurements
taken from one instrument placement: each tracker station's coordinates are its own frame (newcomer pass 9: every
configuration measured from two stations under one pose id read as a 1.6 m noise, and discovery fitted nothing)."""

from __future__ import annotations

import numpy as np

from robocal.identification.noise import repeat_noise, rigid_tool_noise


def _two_stations(rng: np.random.Generator, sigma: float) -> dict[str, np.ndarray]:
    """20 poses x 2 targets, each measured twice from station A and twice from B (B's frame 1.5 m away and turned)."""
    n = 20
    tool = np.array([[0.0, 0.0, 0.0], [150.0, 0.0, 0.0]])
    c, s = np.cos(0.7), np.sin(0.7)
    R_b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    rows: dict[str, list] = {"pose_id": [], "target": [], "t": [], "p": [], "station": []}
    t = 0.0
    for i in range(n):
        centre = rng.uniform(-800, 800, 3)
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        for st, (Rs, off) in {"A": (np.eye(3), np.zeros(3)), "B": (R_b, np.array([1500.0, 200.0, 0.0]))}.items():
            for _ in range(2):
                for k in range(2):
                    rows["pose_id"].append(f"p{i}")
                    rows["target"].append(f"T{k}")
                    rows["t"].append(t)
                    rows["p"].append(Rs @ (centre + R @ tool[k]) + off + rng.normal(0, sigma, 3))
                    rows["station"].append(st)
                    t += 1.0
    return {k: np.asarray(v) for k, v in rows.items()}


def test_repeats_and_tool_distances_across_stations_are_not_noise():
    rng = np.random.default_rng(0)
    sigma = 0.02
    c = _two_stations(rng, sigma)
    rp = repeat_noise(c["pose_id"], c["target"], c["t"], c["p"], station=c["station"])
    rt = rigid_tool_noise(c["pose_id"], c["target"], c["t"], c["p"], station=c["station"])
    assert rp is not None and rt is not None
    # 160 pairs (480 coordinates) and 80 distances: the estimate within 25 % of the planted noise
    assert abs(rp["sigma_mm"] / sigma - 1) < 0.25, rp
    assert abs(rt["sigma_mm"] / sigma - 1) < 0.25, rt
    # without the stations the pairs straddle them: the stations' offset read as noise (the defect)
    wrong = repeat_noise(c["pose_id"], c["target"], c["t"], c["p"])
    assert wrong is not None and wrong["sigma_mm"] > 100 * sigma
