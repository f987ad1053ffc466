"""A robot described in standard Denavit-Hartenberg (``convention: dh``), as data sheets give it."""

from __future__ import annotations

import numpy as np
import pytest

from robocal.errors import ConfigError
from robocal.kinematics.chain import build_chain, fk
from robocal.robot import MDH, POE, robot_from_dict
from robocal.robot_dh import dh_matrix

# UR10 (CB3), UR's own standard DH table (the comment of ../shared/data/ur10-ipa/robot.yaml)
UR10_DH = [(0, 90, 127.3), (-612, 0, 0), (-572.3, 0, 0), (0, 90, 163.941), (0, -90, 115.7), (0, 0, 92.2)]
UR10_MDH = [(0, 0, 127.3), (0, 90, 0), (-612, 0, 0), (-572.3, 0, 163.941), (0, 90, 115.7), (0, -90, 92.2)]


def _robot(rows, convention, **extra):
    joints = [{"name": f"j{i + 1}", "a_mm": a, "alpha_deg": al, "d_mm": d, "q_min_deg": -360, "q_max_deg": 360,
               **extra.get(i, {})} for i, (a, al, d) in enumerate(rows)]  # fmt: skip
    return robot_from_dict({"name": "r", "convention": convention, "joints": joints}, "test.yaml")


def _direct(rows, q):
    """The DH product itself, per configuration."""
    out = []
    for qq in q:
        T = np.eye(4)
        for (a, al, d), qi in zip(rows, qq, strict=True):
            T = T @ dh_matrix(a, np.deg2rad(al), d, qi)
        out.append(T)
    return np.array(out)


def test_the_ur10s_standard_dh_table_reads_as_its_md_h_file():
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, size=(50, 6))
    dh = _robot(UR10_DH, "dh")
    assert dh.convention == MDH
    # Hayati beta where consecutive axes are parallel: axes 2, 3, 4 (joints 2 and 3), as the file has it
    assert dh.beta_free.tolist() == [False, True, True, False, False, False]
    mdh = _robot(UR10_MDH, MDH)
    assert fk(build_chain(dh), q) == pytest.approx(fk(build_chain(mdh), q), abs=1e-9)
    assert fk(build_chain(dh), q) == pytest.approx(_direct(UR10_DH, q), abs=1e-9)


def test_a_flange_off_the_last_axis_reads_as_poe_with_the_same_chain():
    rows = [*UR10_DH[:5], (35.0, 90, 92.2)]  # the last link with a and alpha: no MD-H table without a flange frame
    dh = _robot(rows, "dh")
    assert dh.convention == POE
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, size=(50, 6))
    assert fk(build_chain(dh), q) == pytest.approx(_direct(rows, q), abs=1e-9)


def test_a_dh_joint_without_its_table_is_named():
    with pytest.raises(ConfigError, match=r"joints\[2\]: missing key 'alpha_deg'"):
        robot_from_dict({"convention": "dh", "joints": [
            {"a_mm": 0, "alpha_deg": 90, "d_mm": 100, "q_min_deg": -1, "q_max_deg": 1},
            {"a_mm": 0, "d_mm": 100, "q_min_deg": -1, "q_max_deg": 1}]}, "test.yaml")  # fmt: skip


def test_a_description_in_other_units_is_refused_not_misread():
    rows = [{"a_mm": 0, "alpha_deg": 0, "d_mm": 0.4, "q_min_deg": -3, "q_max_deg": 3}]
    with pytest.raises(ConfigError, match="units must be"):
        robot_from_dict({"units": {"length": "m", "angle": "rad"}, "joints": rows}, "test.yaml")
    assert robot_from_dict({"units": {"length": "mm", "angle": "deg"}, "joints": rows}, "t.yaml").d_mm[0] == 0.4


def test_a_dh_track_states_its_gravity_and_is_not_taken_for_a_column() -> None:
    """A DH table's base frame is axis 1's: for a floor track its z runs along the travel, and the default gravity
    (-z) made the track a lifting column with the arm's weight along the rails. Gravity alone may be stated in a DH
    description; masses still may not (their centres are in MD-H link frames)."""
    import pytest as _pytest

    from robocal.errors import ConfigError
    from robocal.robot import robot_from_dict

    joints = [
        {"name": "E1", "type": "prismatic", "a_mm": 0.0, "alpha_deg": 90.0, "d_mm": 0.0, "theta_offset_deg": 90.0,
         "q_min_mm": 0.0, "q_max_mm": 4000.0},
        {"name": "J1", "a_mm": 50.0, "alpha_deg": -90.0, "d_mm": 478.0, "q_min_deg": -180.0, "q_max_deg": 180.0},
        {"name": "J2", "a_mm": 425.0, "alpha_deg": 0.0, "d_mm": 50.0, "q_min_deg": -130.0, "q_max_deg": 147.5},
        {"name": "J3", "a_mm": 0.0, "alpha_deg": 0.0, "d_mm": 0.0, "q_min_deg": -145.0, "q_max_deg": 145.0},
    ]  # fmt: skip
    base = {"name": "track", "convention": "dh", "joints": joints}
    assert robot_from_dict(base, source="t").role(0) == "column"  # gravity -z: along the travel
    track = robot_from_dict({**base, "dynamics": {"gravity_mps2": [0.0, -9.81, 0.0]}}, source="t")
    assert track.role(0) == "E1" and list(track.gravity) == [0.0, -9.81, 0.0] and not track.has_dynamics
    with _pytest.raises(ConfigError, match=r"dynamics\.links"):
        robot_from_dict({**base, "dynamics": {"links": [{"mass_kg": 1.0, "com_mm": [0, 0, 0]}] * 4}}, source="t")
