"""ISO columns: bad or inconsistent values get the data contract's errors (file, row, column); the command line."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from robocal.errors import DataError
from robocal.iso9283.run import run_iso9283
from robocal.iso9283.settings import IsoSettings
from robocal.iso9283.twin import simulate_iso


@pytest.fixture(scope="module")
def small_test(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("iso_small") / "test"
    simulate_iso(IsoSettings.load({"test": {"cycles": 3}}), out, "geometric")
    return out


def _broken(small_test: Path, tmp_path: Path, edit) -> Path:  # type: ignore[no-untyped-def]
    df = pd.read_csv(small_test / "poses.csv", dtype=str, keep_default_na=False)
    df = edit(df)
    d = tmp_path / "broken"
    d.mkdir()
    df.to_csv(d / "poses.csv", index=False)
    return d


@pytest.mark.parametrize(
    ("edit", "row", "column", "message"),
    [
        (lambda df: df.drop(columns=["cycle"]), 1, "cycle", "missing ISO 9283 column"),
        (lambda df: df.assign(cycle=df["cycle"].where(df.index != 4, "1.5")), 6, "cycle", "whole number >= 1"),
        (lambda df: df.assign(cycle=df["cycle"].where(df.index != 2, "0")), 4, "cycle", "whole number >= 1"),
        (lambda df: df.assign(cmd_y_mm=df["cmd_y_mm"].where(df.index != 6, "x")), 8, "cmd_y_mm", "expected a number"),
        (lambda df: df.assign(iso_pose=df["iso_pose"].where(df.index != 3, "")), 5, "iso_pose", "missing iso_pose"),
        # row 17 (index 15) is P1 of cycle 2 (15 visits per cycle): commanded elsewhere than P1 in row 2
        (
            lambda df: df.assign(cmd_z_mm=df["cmd_z_mm"].where(df.index != 15, "1001.0")),
            17,
            "cmd_z_mm",
            "one test pose has one commanded target",
        ),
        # the second row claims to be the first row's pose, approach and cycle
        (
            lambda df: df.assign(
                iso_pose=df["iso_pose"].where(df.index != 1, "P1"),
                cmd_x_mm=df["cmd_x_mm"].where(df.index != 1, df["cmd_x_mm"][0]),
                cmd_y_mm=df["cmd_y_mm"].where(df.index != 1, df["cmd_y_mm"][0]),
                cmd_z_mm=df["cmd_z_mm"].where(df.index != 1, df["cmd_z_mm"][0]),
            ),
            3,
            "cycle",
            "one row per pose, approach and cycle",
        ),
    ],
)
def test_bad_iso_columns_name_file_row_and_column(  # type: ignore[no-untyped-def]
    calibrated_cell, small_test, tmp_path, edit, row, column, message
) -> None:
    d = _broken(small_test, tmp_path, edit)
    with pytest.raises(DataError, match=message) as err:
        run_iso9283(d, "kr16_2", calibrated_cell["calibration"], tmp_path / "out", report=False)
    assert err.value.file is not None and err.value.file.endswith("poses.csv")
    assert (err.value.row, err.value.column) == (row, column)


def test_commanded_quaternion_must_be_complete(calibrated_cell, small_test, tmp_path) -> None:  # type: ignore[no-untyped-def]
    d = _broken(small_test, tmp_path, lambda df: df.assign(cmd_qw="1.0", cmd_qx="0.0"))
    with pytest.raises(DataError, match="give all four or none") as err:
        run_iso9283(d, "kr16_2", calibrated_cell["calibration"], tmp_path / "out", report=False)
    assert err.value.column == "cmd_qy"


def test_cli_simulate_and_certify(calibrated_cell, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from robocal.cli import main

    test = tmp_path / "test"
    assert main(["simulate", "iso9283", "--out", str(test), "test.cycles=4", "noise_mm=0.02"]) == 0
    assert "4 cycles x 3 approaches x 5 poses" in capsys.readouterr().out
    assert json.loads((test / "truth.json").read_text())["noise_mm"] == 0.02  # a scenario override
    out = tmp_path / "cert"
    rc = main(
        ["iso9283", str(test), "--robot", "kr16_2", "--calibration", str(calibrated_cell["calibration"]),
         "--out", str(out), "certificate.serial=KR-0042", "certificate.cell=line 3"]
    )  # fmt: skip
    assert rc == 0
    printed = capsys.readouterr().out
    assert "P1: 4 cycles" in printed and "predicted after" in printed
    html = (out / "report.html").read_text()
    for text in ("KR-0042", "line 3", "PREDICTED", "vAP_p", "Definitions", "RP_l"):
        assert text in html
    assert main(["simulate", "geometric", "--out", str(tmp_path / "g"), "--bundle", "x"]) == 2  # iso9283 only


def test_program_is_what_the_twin_runs(small_test: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from robocal.cli import main

    rc = main(["iso9283", "--program", str(tmp_path), "--robot", "kr16_2", "test.cycles=3", "test.tcp_mm=[35,-20,120]"])
    assert rc == 0 and "3 cycles x 3 approaches x 5 poses" in capsys.readouterr().out
    prog = pd.read_csv(tmp_path / "iso_program.csv")
    twin = pd.read_csv(small_test / "poses.csv")
    q = [f"q{j}_deg" for j in range(1, 7)]
    assert list(prog["iso_pose"]) == list(twin["iso_pose"]) and list(prog["approach"]) == list(twin["approach"])
    assert (prog[q].to_numpy() == twin[q].to_numpy()).all()  # the same visits, the same joint targets
    back = prog[["cmd_x_mm", "cmd_y_mm", "cmd_z_mm"]].to_numpy() - prog[["pre_x_mm", "pre_y_mm", "pre_z_mm"]].to_numpy()
    first = prog["approach"] == "-x"
    # approached moving along -x: the pre-position is 100 mm further along +x
    assert abs(back[first.to_numpy()] - [-100.0, 0.0, 0.0]).max() < 1e-5


def test_a_coupled_robots_program_gives_the_controllers_joints(tmp_path: Path) -> None:
    """A FANUC-coupled robot (J3 reported relative to J2): iso_program.csv's joints are the controller's, so that
    the controller's J3 taken back to the kinematic one reaches each commanded point (the kinematic J3 was written:
    read back through the data reader, P1 landed 199 mm off). The seed is the controller's too: KUKA's usual
    [0, -90, 90, 0, 60, 0] kinematic is [0, -90, 0, 0, 60, 0] as a FANUC controller states it."""
    import numpy as np
    import yaml

    from robocal.iso9283.program import write_program
    from robocal.kinematics.chain import build_chain, fk
    from robocal.robot import find_robot, robot_from_dict

    data = yaml.safe_load(find_robot("kr16_2").read_text())
    robot = robot_from_dict({**(data.get("robot") or data), "coupling": "fanuc_j2j3"}, source="test")
    from robocal.iso9283.settings import IsoSettings

    st = IsoSettings.from_mapping(
        {"test": {"cycles": 2, "tcp_mm": [35, -20, 120]}, "twin": {"seed_q_deg": [0, -90, 0, 0, 60, 0]}}
    )
    prog = pd.read_csv(write_program(tmp_path, robot, st))
    q_rep = np.deg2rad(prog[[f"q{j}_deg" for j in range(1, 7)]].to_numpy())
    T = fk(build_chain(robot), robot.to_kinematic(q_rep))
    tcp = T[:, :3, 3] + np.einsum("mij,j->mi", T[:, :3, :3], np.array([35.0, -20.0, 120.0]))
    # the joints are written to 1e-6 deg: ~1e-5 mm at the tool of a 1.6 m arm
    assert np.abs(tcp - prog[["cmd_x_mm", "cmd_y_mm", "cmd_z_mm"]].to_numpy()).max() < 1e-3
    assert np.abs(q_rep[:, 2] - robot.to_kinematic(q_rep)[:, 2]).max() > 0.1  # the coupling really moved J3
