"""Shared fixtures. Robots come from the repository's conf/robot; ../shared is optional."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"

ABB_POE = {
    "name": "abb-poe",
    "convention": "poe",
    "joints": [
        {"name": f"j{i + 1}", "q_min_deg": lo, "q_max_deg": hi}
        for i, (lo, hi) in enumerate([(-165, 165), (-110, 110), (-110, 70), (-160, 160), (-120, 120), (-400, 400)])
    ],
    "poe": {
        "twists": [
            {"w": [0, 0, 1], "p_mm": [0, 0, 0]},
            {"w": [0, 1, 0], "p_mm": [0, 0, 290]},
            {"w": [0, 1, 0], "p_mm": [0, 0, 560]},
            {"w": [1, 0, 0], "p_mm": [0, 0, 630]},
            {"w": [0, 1, 0], "p_mm": [302, 0, 630]},
            {"w": [1, 0, 0], "p_mm": [0, 0, 630]},
        ],
        "flange_at_zero_mm": [374.0, 0.0, 630.0],
        "flange_R_at_zero": [[0, 0, 1], [0, 1, 0], [-1, 0, 0]],
    },
}


@pytest.fixture(scope="session")
def kr16():
    from robocal.robot import load_robot

    return load_robot("kr16_2")


@pytest.fixture(scope="session")
def abb():
    from robocal.robot import load_robot

    return load_robot("abb_irb120")


@pytest.fixture(scope="session")
def abb_poe():
    from robocal.robot import robot_from_dict

    return robot_from_dict(ABB_POE, "abb-poe")


@pytest.fixture(scope="session")
def sr210():
    from robocal.robot import load_robot

    return load_robot("sr210")


@pytest.fixture()
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} is not present (real-data tests need ../shared)")
    return SHARED
