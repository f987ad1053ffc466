"""The twin's typed scenario (ScenarioConfig) is the YAML mapping read once: both write the same campaign."""

from __future__ import annotations

from pathlib import Path

import pytest

from robocal.errors import ConfigError
from robocal.sim.twin import ScenarioConfig, load_scenario, simulate


def test_a_typed_scenario_writes_the_same_bytes_as_its_mapping(tmp_path: Path) -> None:
    sc = load_scenario("geometric")
    sc.update(
        n_poses=6,
        n_validation_poses=2,
        orientation=True,
        stations={"S2": {"xyz_mm": [2000.0, -1000.0, 0.0], "rpy_deg": [0.0, 0.0, 40.0]}},
        gross_errors={"n": 1},
        unused_key="kept in scenario.yaml, ignored by the twin",
    )
    cfg = ScenarioConfig.from_mapping(sc)
    assert (cfg.n_poses, cfg.orientation, list(cfg.stations), cfg.gross_errors.n) == (6, True, ["S2"], 1)
    truth_a = simulate(sc, tmp_path / "a", seed=5)
    truth_b = simulate(cfg, tmp_path / "b", seed=5)
    assert truth_a == truth_b and truth_a["seed"] == 5
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "b").iterdir())
    for name in names:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert "unused_key" in (tmp_path / "b" / "scenario.yaml").read_text()


def test_a_station_without_its_pose_is_named() -> None:
    with pytest.raises(ConfigError, match=r"stations\.S2.*xyz_mm and rpy_deg"):
        ScenarioConfig.from_mapping({"stations": {"S2": {"xyz_mm": [0.0, 0.0, 0.0]}}})
