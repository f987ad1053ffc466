"""A twin cell calibrated once per session: the geometric scenario's campaign, its calibration and bundle."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def calibrated_cell(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    from robocal.serve.bundle import write_bundle
    from robocal.sim.twin import load_scenario, simulate
    from robocal.workflows import geometric

    root = tmp_path_factory.mktemp("iso_cell")
    simulate(load_scenario("geometric"), root / "campaign")
    geometric.run(root / "campaign", "kr16_2", root / "cal", report=False)
    bundle = write_bundle(root / "bundle", "kr16_2", root / "cal" / "calibration.json")
    return {"root": root, "calibration": root / "cal" / "calibration.json", "bundle": Path(bundle)}
