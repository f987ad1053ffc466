"""Fixtures of the service tests: a real geometric calibration of a twin campaign, bundled with stand-in
thermal / compliance models (tests/serve/standins.py) that have the interfaces the bundle loads."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from standins import StandinCompliance, StandinThermal

LOADERS = {"thermal": StandinThermal.from_json, "compliance": StandinCompliance.from_json}


def standin_thermal(robot, seed: int = 0) -> StandinThermal:
    """Linear drift of every parameter: 2 um/degC for lengths, 0.1 urad/degC for angles (per sensor);
    fitted range 15..45 degC."""
    from robocal.kinematics.chain import build_chain

    chain = build_chain(robot)
    s = len(robot.sensor_names)
    scale = np.where(np.array(chain.param_kind) == "length", 2e-3, 1e-7)[:, None]
    G = np.random.default_rng(seed).normal(0, 1, (chain.n_params, s)) * scale
    return StandinThermal(list(robot.sensor_names), G, robot.T0_C or 24.3, np.tile([15.0, 45.0], (s, 1)))


@pytest.fixture(scope="session")
def calibration_file(tmp_path_factory, kr16) -> Path:
    from robocal.calibration.fit import calibrate
    from robocal.data import read_campaign
    from robocal.io import write_json
    from robocal.sim.twin import load_scenario, simulate

    d = tmp_path_factory.mktemp("cal")
    sc = load_scenario("geometric")
    sc.update(n_poses=40, n_validation_poses=0)
    simulate(sc, d / "camp", seed=3)
    res = calibrate(read_campaign(d / "camp", kr16), kr16)
    return write_json(d / "calibration.json", res.to_dict())


@pytest.fixture(scope="session")
def geometric_bundle(tmp_path_factory, calibration_file) -> Path:
    from robocal.serve.bundle import write_bundle

    return write_bundle(tmp_path_factory.mktemp("bundle_geo"), "kr16_2", calibration_file)


@pytest.fixture(scope="session")
def full_bundle(tmp_path_factory, calibration_file, kr16) -> Path:
    from robocal.serve.bundle import write_bundle

    d = tmp_path_factory.mktemp("bundle_full")
    th = standin_thermal(kr16).to_json(d / "th_src.json")
    co = StandinCompliance(np.array([0.0, 2e-5, 1.5e-5, 0.0, 1e-5, 0.0])).to_json(d / "co_src.json")
    return write_bundle(d / "bundle", "kr16_2", calibration_file, th, co)
