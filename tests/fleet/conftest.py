"""A small twin fleet shared by the fleet tests (written once per session: ~1 s)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

# 3 robots x 3 campaigns, one with a zero-offset jump and one with a drifting length; 40 + 10 poses keep a
# calibration at ~20 ms while the planted events stay far above the standard errors (see test_fleet.py).
TWIN = {"n_poses": 40, "n_validation_poses": 10, "jump_share": 1 / 3, "drift_share": 1 / 3}
SETTINGS_OFF = {"tracking": {"enabled": False}}


@pytest.fixture(scope="session")
def twin_fleet(tmp_path_factory) -> Path:
    from robocal.fleet.twin import simulate_fleet

    d = tmp_path_factory.mktemp("fleet") / "fleet"
    simulate_fleet(d, 3, 3, seed=7, config=TWIN)
    return d


@pytest.fixture
def fleet_copy(twin_fleet, tmp_path) -> Path:
    d = tmp_path / "fleet"
    shutil.copytree(twin_fleet, d)
    return d


def settings(**over):
    from robocal.fleet.run import load_settings

    return load_settings(None, {**SETTINGS_OFF, **over})
