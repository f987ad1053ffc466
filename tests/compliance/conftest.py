"""Small heavy-load twins shared by the compliance tests (30 poses instead of 50 to stay fast)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest


def make_twin(out: Path, seed: int, **changes: Any) -> dict[str, Any]:
    from robocal.sim.twin import load_scenario, simulate

    sc = load_scenario("heavy_load")
    sc["n_poses"] = changes.pop("n_poses", 30)
    eff = dict(sc["effects"]["compliance"])
    eff.update(changes)
    sc["effects"] = {"compliance": eff}
    return simulate(sc, out, seed=seed)


@pytest.fixture(scope="session")
def twin_dirs(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    """Two seeds of the heavy-load twin (results must hold on both, not on one tuned seed)."""
    out = {}
    for seed in (0, 7):
        d = tmp_path_factory.mktemp(f"heavy{seed}")
        make_twin(d, seed)
        out[seed] = d
    return out


@pytest.fixture(scope="session")
def twin_factory():
    """``make_twin(out_dir, seed, **effect_changes)``."""
    return make_twin
