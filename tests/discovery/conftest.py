"""Twin campaigns with one hidden effect, shared by the discovery tests."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from robocal.data.contract import read_campaign
from robocal.discovery.candidates import Candidate
from robocal.robot import load_robot
from robocal.sim.twin import EFFECTS, load_scenario, register_effect, simulate


def make_campaign(tmp: Path, scenario: str, seed: int, effects: dict[str, Any] | None = None, **over: Any):
    """Simulate ``scenario`` with ``effects`` (replacing the scenario's) and read it back: (campaign, robot, truth)."""
    sc = copy.deepcopy(load_scenario(scenario))
    if effects is not None:
        sc["effects"] = effects
    sc.update(over)
    robot = load_robot(sc["robot"])
    d = tmp / f"{scenario}_{seed}_{abs(hash(str(effects))) % 10**8}"
    truth = simulate(sc, d, seed=seed)
    return read_campaign(d, robot), robot, truth


def joint_candidate(key: str, joint: int, S: np.ndarray, prior_rad: float | None) -> Candidate:
    """A joint-level candidate of signals ``S`` (one coefficient per column, rad), under a prior when ``prior_rad``."""
    q = S.shape[1]
    return Candidate(
        key, "test", joint, None, cause="test", signal="test", shape="joint", S=S,
        coef_names=tuple(f"c{i}" for i in range(q)), coef_units=("rad",) * q,
        extra={} if prior_rad is None else {"prior_rad": prior_rad},
    )  # fmt: skip


def named(summary_or_result: Any) -> list[tuple[str, int | None, int | None]]:
    if isinstance(summary_or_result, dict):
        return [(n["effect"], n["joint"], n["harmonic"]) for n in summary_or_result["named"]]
    return [(a.cand.effect, a.cand.joint, a.cand.harmonic) for a in summary_or_result.accepted]


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


if "test_q1q5" not in EFFECTS:

    @register_effect("test_q1q5")
    class _Q1Q5:
        """Outside the library: a joint-4 error driven by the angles of joints 1 and 5 together."""

        name = "test_q1q5"

        def __init__(self, cfg):
            self.amp = np.deg2rad(float(cfg["amplitude_deg"]))

        def plan(self, rows, ctx):
            return rows

        def apply(self, rows, ctx):
            rows.dq[:, 3] += self.amp * np.sin(2 * rows.q_cmd[:, 0]) * np.cos(rows.q_cmd[:, 4])
