"""A calibration is applied only to the robot it was made for (issue 23, item 3): ``calibration.json`` records
its robot (name, joint count, nominal table) and ``robocal serve --make-bundle`` and ``robocal urdf`` refuse
another one with an error naming both robots."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
import yaml

import robocal
from robocal.calibration.load import load_calibration
from robocal.cli import main
from robocal.errors import ConfigError
from robocal.io import write_json
from robocal.robot import SHIPPED_ROBOT_DIR, robot_from_dict


@pytest.fixture(scope="module")
def abb_calibration(tmp_path_factory) -> Path:
    """calibration.json of an IRB 120 (a small twin campaign)."""
    tmp = tmp_path_factory.mktemp("abbcal")
    robot = robocal.load_robot("abb_irb120")
    sc = robocal.load_scenario("geometric")
    sc.update(n_poses=30, n_validation_poses=0)
    robocal.simulate(sc, tmp / "camp", seed=2, robot=robot)
    cal = robocal.calibrate(robocal.read_campaign(tmp / "camp", robot), robot)
    write_json(tmp / "calibration.json", cal.to_dict())
    return tmp / "calibration.json"


def _raw(name: str) -> dict:
    return yaml.safe_load((SHIPPED_ROBOT_DIR / f"{name}.yaml").read_text())


def test_calibration_json_records_its_robot(abb_calibration):
    data = json.loads(abb_calibration.read_text())
    nominal = data["nominal"]
    assert data["robot"] == "abb_irb120" and nominal["n_joints"] == 6 and nominal["convention"] == data["convention"]
    assert nominal["mdh"]["d_mm"][0] == pytest.approx(290.0)  # the IRB 120's first link height
    assert load_calibration(data, robocal.load_robot("abb_irb120")).model.robot.name == "abb_irb120"


def test_make_bundle_refuses_another_robot_naming_both(abb_calibration, tmp_path, capsys):
    out = tmp_path / "B"
    code = main(["serve", "--make-bundle", str(out), "--robot", "kr16_2", "--calibration", str(abb_calibration)])
    assert code == 2
    err = capsys.readouterr().err
    assert "made for robot 'abb_irb120', not for 'kr16_2'" in err and str(abb_calibration) in err, err
    assert not (out / "manifest.json").exists()  # nothing written
    # the right robot still makes a bundle
    assert (
        main(["serve", "--make-bundle", str(out), "--robot", "abb_irb120", "--calibration", str(abb_calibration)]) == 0
    )


def test_urdf_refuses_another_robot_naming_both(abb_calibration, tmp_path, capsys):
    code = main(["urdf", "--robot", "kr16_2", "--calibration", str(abb_calibration), "--out", str(tmp_path / "u")])
    assert code == 2
    err = capsys.readouterr().err
    assert "made for robot 'abb_irb120', not for 'kr16_2'" in err and "nominal" in err, err
    assert not (tmp_path / "u").exists()


def test_same_name_but_another_nominal_table_or_joint_count_is_refused(abb_calibration):
    data = json.loads(abb_calibration.read_text())
    other = _raw("abb_irb120")
    other["joints"][0]["d_mm"] = 300.0  # the same name, another first link
    with pytest.raises(ConfigError, match=r"nominal d_mm of joint 1 is 290, 'abb_irb120' has 300"):
        load_calibration(data, robot_from_dict(other))
    five = copy.deepcopy(_raw("abb_irb120"))
    five["joints"] = five["joints"][:5]
    five["n_joints"] = 5
    five.pop("poe", None)
    five.pop("dynamics", None)
    with pytest.raises(ConfigError, match=r"it has 6 joints, 'abb_irb120' has 5"):
        load_calibration(data, robot_from_dict(five))


def test_an_older_calibration_without_the_nominal_record_is_checked_by_name_and_joints(abb_calibration):
    data = json.loads(abb_calibration.read_text())
    del data["nominal"]
    with pytest.raises(ConfigError, match=r"made for robot 'abb_irb120', not for 'kr16_2'"):
        load_calibration(data, robocal.load_robot("kr16_2"))
    load_calibration(data, robocal.load_robot("abb_irb120"))


def test_a_urdf_robots_calibration_bundles_by_reference_and_refuses_another(tmp_path):
    from robocal.serve.bundle import load_bundle, write_bundle

    ref = f"{Path(__file__).resolve().parent / 'cell' / 'data' / 'ur5_robot.urdf'}#base_link:tool0"
    robot = robocal.load_robot(ref)
    sc = robocal.load_scenario("geometric")
    sc.update(n_poses=30, n_validation_poses=0)
    robocal.simulate(sc, tmp_path / "camp", seed=7, robot=robot)
    write_json(tmp_path / "c.json", robocal.calibrate(robocal.read_campaign(tmp_path / "camp", robot), robot).to_dict())
    b = write_bundle(tmp_path / "B", ref, tmp_path / "c.json")
    assert json.loads((b / "manifest.json").read_text())["robot"] == ref and load_bundle(b).robot.name == "ur5"
    with pytest.raises(ConfigError, match=r"made for robot 'ur5', not for 'kr16_2'.*its convention is 'poe'"):
        write_bundle(tmp_path / "B2", "kr16_2", tmp_path / "c.json")
