"""The contract's column table (robocal.data.columns) is the one the reader, Campaign.to_frame and the twin use."""

from __future__ import annotations

from pathlib import Path

from robocal.data import read_campaign
from robocal.data.columns import POSE_COLUMNS, known_columns, required_columns
from robocal.sim.twin import load_scenario, simulate


def test_the_twin_writes_what_the_reader_knows_in_the_tables_order(tmp_path: Path, kr16) -> None:
    """A twin campaign with every optional group the twin reports (orientation, payload, currents, torques,
    approach directions, stations) comes out in the table's order, with no column the reader would take for an
    extra one, and to_frame gives the same columns back."""
    sc = load_scenario("geometric")
    sc.update(
        n_poses=4,
        n_validation_poses=2,
        orientation=True,
        payload_kg=5.0,
        stations={"S2": {"xyz_mm": [2000.0, -1000.0, 0.0], "rpy_deg": [0.0, 0.0, 40.0]}},
        effects={
            "backlash": {"joints": {1: 0.02}},
            "compliance": {
                "c_rad_per_Nm": [0.0, 2e-6, 2e-6, 0.0, 0.0, 0.0],
                "torque_constant_Nm_per_A": [10.0] * 6,
                "report_torques": True,
            },
        },
    )
    simulate(sc, tmp_path, seed=1, robot=kr16)
    header = (tmp_path / "poses.csv").read_text().splitlines()[0].split(",")
    n = kr16.n_joints
    table_order = [c for g in POSE_COLUMNS for c in g.columns(n)]
    assert header == [c for c in table_order if c in header]
    assert set(required_columns(n)) <= set(header) and set(header) <= known_columns(n)
    for key in ("quat", "payload", "tau", "current", "direction", "station"):  # the optional groups written
        group = next(g for g in POSE_COLUMNS if g.key == key)
        assert set(group.columns(n)) <= set(header), key
    camp = read_campaign(tmp_path, kr16)
    assert not camp.extra  # the reader knows every column the twin writes
    assert list(camp.to_frame().columns) == header
