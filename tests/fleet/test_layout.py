"""The fleet layout: read, checked, and every bad input named by its path."""

from __future__ import annotations

import shutil

import pytest

from robocal.errors import ConfigError
from robocal.fleet.layout import check_serial, folder_sha256, read_fleet, read_robot_folder


def test_reads_the_twin_fleet(twin_fleet):
    fleet = read_fleet(twin_fleet)
    assert [r.serial for r in fleet.robots] == ["R0001", "R0002", "R0003"]
    assert fleet.n_campaigns == 9
    r = fleet.robots[0]
    assert r.robot == "kr16_2"
    assert [c.name for c in r.campaigns] == ["2026-01-05", "2026-04-06", "2026-07-06"]
    assert len({c.sha256 for c in r.campaigns}) == 3  # different data, different hashes
    assert read_fleet(twin_fleet, ["R0002"]).robots[0].serial == "R0002"


def test_hash_follows_the_content(fleet_copy):
    c = read_fleet(fleet_copy).robots[0].campaigns[0]
    h = folder_sha256(c.path)
    (c.path / "notes.txt").write_text("tracker re-levelled")
    assert folder_sha256(c.path) != h


@pytest.mark.parametrize("serial", ["", "-R1", "R 1", "R/1", "x" * 65, "é1"])
def test_bad_serials(serial):
    with pytest.raises(ConfigError, match="serial number"):
        check_serial(serial, "here")


def test_bad_inputs_name_the_path(fleet_copy, tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        read_fleet(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="no robot folder"):
        read_fleet(tmp_path / "empty")
    r = fleet_copy / "R0001"
    # serial not matching the folder
    (r / "robot.yaml").write_text("serial: R0009\nrobot: kr16_2\n")
    with pytest.raises(ConfigError, match=r"R0001/robot.yaml.*does not match"):
        read_robot_folder(r)
    # unknown robot description
    (r / "robot.yaml").write_text("serial: R0001\nrobot: kr99\n")
    with pytest.raises(ConfigError, match=r"R0001/robot.yaml: unknown robot 'kr99'"):
        read_robot_folder(r)
    (r / "robot.yaml").write_text("serial: R0001\nrobot: missing.yaml\n")
    with pytest.raises(ConfigError, match=r"missing\.yaml does not exist"):
        read_robot_folder(r)
    # a robot description as a YAML file in the robot folder is fine
    from robocal.robot import SHIPPED_ROBOT_DIR

    shutil.copyfile(SHIPPED_ROBOT_DIR / "kr16_2.yaml", r / "description.yaml")
    (r / "robot.yaml").write_text("serial: R0001\nrobot: description.yaml\n")
    assert read_robot_folder(r).robot.endswith("description.yaml")
    # a mistyped campaign folder is an error, not a silently dropped campaign
    (r / "2026-13-01").mkdir()
    with pytest.raises(ConfigError, match="2026-13-01: not a valid date"):
        read_robot_folder(r)
    (r / "2026-13-01").rename(r / "jan2026")
    with pytest.raises(ConfigError, match="jan2026: not a campaign folder"):
        read_robot_folder(r)
    (r / "jan2026").rename(r / "2026-09-01")
    with pytest.raises(ConfigError, match="2026-09-01: campaign folder without poses"):
        read_robot_folder(r)
    # no robot.yaml
    (r / "robot.yaml").unlink()
    with pytest.raises(ConfigError, match=r"no robot\.yaml"):
        read_robot_folder(r)
