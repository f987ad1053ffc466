"""A robot of your own (issue 23, item 7): one lookup order for a robot reference, used everywhere a robot is
looked up by name: a path, then ``conf/robot/<name>.yaml`` of the current project (the working directory or a
parent with ``conf/robot/``), then the robots shipped with the package."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

import robocal
from robocal.cli import main
from robocal.errors import ConfigError
from robocal.robot import SHIPPED_ROBOT_DIR, load_robot


def _project(tmp_path: Path, name: str, based_on: str = "abb_irb120", **changes: object) -> Path:
    """A project folder with conf/robot/<name>.yaml (a packaged robot under another name) and a subfolder."""
    data = yaml.safe_load((SHIPPED_ROBOT_DIR / f"{based_on}.yaml").read_text())
    data.update(name=name, **changes)
    (tmp_path / "proj" / "conf" / "robot").mkdir(parents=True)
    (tmp_path / "proj" / "conf" / "robot" / f"{name}.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    (tmp_path / "proj" / "cells" / "c7").mkdir(parents=True)
    return tmp_path / "proj"


def test_load_robot_finds_the_projects_own_robot(tmp_path, monkeypatch):
    proj = _project(tmp_path, "cell7_irb120")
    monkeypatch.chdir(proj / "cells" / "c7")  # anywhere inside the project
    for load in (load_robot, robocal.load_robot):
        robot = load("cell7_irb120")
        assert robot.name == "cell7_irb120" and robot.n_joints == 6
        assert Path(robot.source).resolve() == (proj / "conf" / "robot" / "cell7_irb120.yaml").resolve()
    # the packaged robots are still found from there, and a path still wins
    assert load_robot("kr16_2").name == "kr16_2"
    assert load_robot(str(proj / "conf" / "robot" / "cell7_irb120.yaml")).name == "cell7_irb120"


def test_the_project_comes_before_the_package_and_errors_name_both(tmp_path, monkeypatch):
    proj = _project(tmp_path, "kr16_2", based_on="kr16_2", T0_C=31.5)  # the project's own kr16_2
    monkeypatch.chdir(proj)
    assert load_robot("kr16_2").T0_C == 31.5
    assert load_robot("kr16_2", conf_dir=SHIPPED_ROBOT_DIR).T0_C != 31.5  # an explicit folder: only that one
    with pytest.raises(ConfigError) as exc:
        load_robot("kr99")
    text = str(exc.value)
    assert "unknown robot 'kr99'" in text and str(proj / "conf" / "robot") in text and str(SHIPPED_ROBOT_DIR) in text
    assert "'abb_irb120'" in text and "'kr16_2'" in text


def test_calibrate_and_urdf_take_the_projects_robot(tmp_path, monkeypatch, shared_dir, capsys):
    abb = shared_dir / "data" / "abb-irb120"
    if not (abb / "poses.csv").is_file():
        pytest.skip(f"{abb} has no poses.csv")
    proj = _project(tmp_path, "cell7_irb120")
    monkeypatch.chdir(proj)
    out = tmp_path / "cal"
    code = main(["calibrate", str(abb), "--robot", "cell7_irb120", "--out", str(out), "--no-report"])
    assert code in (0, 1), capsys.readouterr().err
    cal = json.loads((out / "calibration.json").read_text())
    assert cal["robot"] == "cell7_irb120"
    assert main(["urdf", "--robot", "cell7_irb120", "--calibration", str(out / "calibration.json"),
                 "--out", str(tmp_path / "urdf")]) == 0  # fmt: skip
    # a bundle of the project's robot carries the description, so it loads outside the project too
    from robocal.serve.bundle import load_bundle, write_bundle

    b = write_bundle(tmp_path / "bundle", "cell7_irb120", out / "calibration.json")
    assert json.loads((b / "manifest.json").read_text())["robot"] == "robot.yaml"
    monkeypatch.chdir(tmp_path)
    assert load_bundle(b).robot.name == "cell7_irb120"


def test_a_fleet_robot_folder_may_name_the_projects_robot(tmp_path, monkeypatch):
    from robocal.fleet.layout import _robot_ref

    proj = _project(tmp_path, "cell7_irb120")
    monkeypatch.chdir(proj)
    ref, digest = _robot_ref(tmp_path, "cell7_irb120")
    assert Path(ref) == (proj / "conf" / "robot" / "cell7_irb120.yaml").resolve() and len(digest) == 64
    assert _robot_ref(tmp_path, "kr16_2")[0] == "kr16_2"  # a packaged robot stays a name
