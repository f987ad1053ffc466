"""Issue 31: a large campaign finds its gross errors by a search on a pose-grouped sample first (the
``outlier_screen_rows`` setting), settles the kept rows by refits, then runs one search on every kept row."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.gross import screen_sample
from robocal.discovery.search import discover
from robocal.discovery.summary import summary
from robocal.discovery.validate import validation_errors

from .conftest import make_campaign, named

GEAR = {"gear": {"joint": 4, "harmonics": [{"harmonic": 1, "amplitude_deg": 0.006, "phase_deg": 30.0}]}}
# fast settings: the rounds are what is tested, not the dictionary or the layer
FAST = {"dictionary": False, "layer": False, "grow_max_steps": 2}


def test_screen_sample_takes_whole_groups_within_the_size():
    rng = np.random.default_rng(3)
    pose_id = np.repeat([f"P{i:03d}" for i in range(60)], 3)  # three targets per pose
    q = np.repeat(rng.uniform(-2, 2, (60, 6)), 3, axis=0)
    q[30:33] = q[0:3]  # pose P010 measured again at P000's configuration: one group with it
    idx = np.arange(len(pose_id))
    a = screen_sample(pose_id, q, idx, 40, seed=0)
    assert np.array_equal(a, screen_sample(pose_id, q, idx, 40, seed=0))  # the config's seed: the same rows
    assert len(a) <= 40 and np.all(np.diff(a) > 0)
    # whole poses only, and the repeated configuration's two poses together or not at all
    taken = set(pose_id[a])
    assert all(int(np.sum(pose_id[a] == p)) == 3 for p in taken)
    assert ("P000" in taken) == ("P010" in taken)
    assert len(a) >= 40 - 6  # whole groups of 3 (or 6) rows until the next would not fit


@pytest.fixture(scope="module")
def gross(tmp_path_factory):
    camp, robot, truth = make_campaign(
        tmp_path_factory.mktemp("screen"), "geometric", 4, GEAR, n_poses=160, n_validation_poses=40,
        gross_errors={"n": 5, "min_mm": 0.6, "max_mm": 1.2},
    )  # fmt: skip
    return camp, robot, truth


def test_a_large_campaign_screens_then_searches_once(gross):
    camp, robot, truth = gross
    n_cal = int(np.sum(camp.split == "calibration"))
    res = discover(camp, robot, DiscoveryConfig.from_mapping({**FAST, "outlier_screen_rows": n_cal // 3}))
    # one search on the sample, one on every kept row (without the screen: up to three on every row)
    assert res.extra["outlier_searches"] == 2
    # discovery.json says so: the sample, the searches and the rows the final model flags among those it fitted
    scr = summary(res, validation_errors(res))["gross_error_screen"]
    assert scr["searches"] == 2 and 0 < scr["sample_rows"] <= n_cal // 3 < scr["kept_rows"]
    assert isinstance(scr["flagged_by_final_model"], list)
    assert len(res.rows) > n_cal // 3  # the final search ran on every kept row, not on the sample
    planted = {g["pose_id"] for g in truth["gross_errors"]}
    found = {o["pose_id"] for o in res.extra["outliers"]}
    assert planted <= found, (planted, found)
    assert ("gear", 4, 1) in named(res) or any(e == "transmission" and j == 4 for e, j, _ in named(res))


def test_a_campaign_within_the_size_keeps_its_rounds(gross):
    camp, robot, truth = gross
    res = discover(camp, robot, DiscoveryConfig.from_mapping(FAST))  # 3000 rows by default: no screen here
    assert "gross_error_screen" not in res.extra
    assert 1 <= res.extra["outlier_searches"] <= 3
    planted = {g["pose_id"] for g in truth["gross_errors"]}
    assert planted <= {o["pose_id"] for o in res.extra["outliers"]}
