"""Joint angles in radians are caught (issue 23, item 1): at the data door when every joint column lies inside
+-2 pi while the robot's limits span far more, and by the calibration when the nominal model cannot start
(a calibration corrects millimetres, not a tenth of the cell), naming the columns."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import robocal
from robocal.cli import main
from robocal.data import read_campaign
from robocal.errors import DataError

QCOLS = [f"q{j}_deg" for j in range(1, 7)]


def _to_radians(src: Path, dst: Path, keep: list[str] | None = None) -> Path:
    df = pd.read_csv(src / "poses.csv", dtype={c: float for c in QCOLS})
    if keep is not None:
        df = df[df["pose_id"].isin(keep)]
    for c in QCOLS:
        df[c] = np.radians(df[c])
    dst.mkdir(parents=True)
    df.to_csv(dst / "poses.csv", index=False)
    return dst


@pytest.fixture()
def abb(shared_dir: Path) -> Path:
    d = shared_dir / "data" / "abb-irb120"
    if not (d / "poses.csv").is_file():
        pytest.skip(f"{d} has no poses.csv")
    return d


def test_a_twin_campaign_in_radians_is_refused_naming_the_column_and_nothing_else_is(tmp_path):
    robot = robocal.load_robot("kr16_2")
    sc = robocal.load_scenario("geometric")
    sc.update(n_poses=12, n_validation_poses=0)
    robocal.simulate(sc, tmp_path / "deg", seed=4)
    read_campaign(tmp_path / "deg", robot)  # in degrees: fine
    rad = _to_radians(tmp_path / "deg", tmp_path / "rad")
    with pytest.raises(DataError) as exc:
        read_campaign(rad, robot)
    err = exc.value
    assert err.column in QCOLS and err.row is not None and Path(str(err.file)).name == "poses.csv"
    assert (
        "look like radians" in str(err) and f"'{err.column}'" in str(err) and "12 distinct configurations" in str(err)
    )
    # no false alarm: a drift test near zero, the real campaigns and the twin's other campaigns
    _a_campaign_standing_still_near_zero_is_not_taken_for_radians(tmp_path)
    shared = Path(__file__).resolve().parents[2].parent / "shared"
    _real_and_twin_campaigns_in_degrees_still_load(shared, tmp_path)


def test_the_real_abb_data_in_radians_is_refused_by_calibrate(abb, tmp_path, capsys):
    rad = _to_radians(abb, tmp_path / "rad")
    code = main(["calibrate", str(rad), "--robot", str(abb / "robot.yaml"), "--out", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err.strip()
    # the largest |value| is q6 of pose v08 (2.889 rad = 165.5 deg), file row 117
    assert err.startswith(f"robocal calibrate: error: file {rad / 'poses.csv'}, row 117, column 'q6_deg'"), err
    assert "look like radians" in err and "180/pi" in err
    assert not (tmp_path / "o" / "summary.json").exists()


def _real_and_twin_campaigns_in_degrees_still_load(shared_dir: Path, tmp_path: Path) -> None:
    for name in ("abb-irb120", "ur10-ipa"):
        d = shared_dir / "data" / name
        if (d / "poses.csv").is_file():
            assert read_campaign(d, robocal.load_robot(d / "robot.yaml")).n_rows > 100
    for scenario in ("thermal", "heavy_load"):  # the twin's other campaigns (geometric: above)
        sc = robocal.load_scenario(scenario)
        robocal.simulate(sc, tmp_path / scenario, seed=1)
        read_campaign(tmp_path / scenario, robocal.load_robot(sc["robot"]))


def _a_campaign_standing_still_near_zero_is_not_taken_for_radians(tmp_path: Path) -> None:
    """A drift test repeating a few configurations near zero: repeated configurations count once."""
    robot = robocal.load_robot("kr16_2")
    rows = []
    for k in range(40):
        q = [0.5, -3.0, 2.0, 0.0, 4.0, -1.0] if k % 2 else [1.0, -2.0, 3.0, 0.5, 5.0, 0.0]
        t = pd.Timestamp("2026-01-05T07:00:00Z") + pd.Timedelta(minutes=5 * k)
        rows.append({"pose_id": f"p{k % 2}", "timestamp": t.isoformat(), **dict(zip(QCOLS, q, strict=True)),
                     "x_mm": 1500.0 + 0.01 * k, "y_mm": 300.0, "z_mm": 900.0})  # fmt: skip
    (tmp_path / "still").mkdir()
    pd.DataFrame(rows).to_csv(tmp_path / "still" / "poses.csv", index=False)
    assert read_campaign(tmp_path / "still", robot).n_rows == 40


def test_a_fit_that_cannot_start_is_failed_with_the_reason(abb, tmp_path):
    """Six configurations in radians pass the door (too few to call it); the nominal model then misses by more
    than a tenth of the cell, and read as radians it fits: the calibration is failed and says so. The wrong robot
    (the UR10's description for the IRB 120's data) cannot start either."""
    from robocal.workflows import geometric

    rad = _to_radians(abb, tmp_path / "rad6", keep=[f"c{i:02d}" for i in range(6)])
    s = geometric.run(rad, abb / "robot.yaml", tmp_path / "o1", report=False)
    assert s["status"] == "failed"
    text = s["problems"][0]
    assert text.startswith("the fit cannot start: the nominal model misses the measurements by")
    assert "q1_deg..q6_deg" in text and "look like radians" in text, text
    # the same six configurations in degrees start from a few millimetres: no such problem
    deg = tmp_path / "deg6"
    deg.mkdir()
    df = pd.read_csv(abb / "poses.csv", dtype=str, keep_default_na=False)
    df[df["pose_id"].isin([f"c{i:02d}" for i in range(6)])].to_csv(deg / "poses.csv", index=False)
    s = geometric.run(deg, abb / "robot.yaml", tmp_path / "o2", report=False)
    assert s["start_rms_position_mm"] < 20 and not any("cannot start" in p for p in s["problems"])
    ur10 = abb.parent / "ur10-ipa" / "robot.yaml"
    if ur10.is_file():
        s = geometric.run(abb, ur10, tmp_path / "o3", report=False)
        assert s["status"] == "failed" and s["problems"][0].startswith("the fit cannot start")
        assert "Check the joint angles' unit (degrees), the robot (--robot) and the targets" in s["problems"][0]
