"""A campaign and a robot of one's own through the pipeline (issue 30, items 1 and 8), fast: no DVC run.

* A temperature log that is not a warm-up (an air-temperature log) makes the thermal chain skip, saying why and
  naming the user's campaign, and the stages after it (screen, validate) skip too; errors name the user's file,
  not the interim copy.
* ``robot_file=<path>`` gives every stage that robot description; a bad robot override or a missing file is one
  line that says what to do.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pandas as pd
import pytest
import yaml

from robocal.errors import ConfigError, DataError
from robocal.pipeline import ROBOT_FILE, apply_robot_file, compose

REPO = Path(__file__).resolve().parents[2]
STAGES = REPO / "stages"


def _stage(name: str) -> ModuleType:
    import importlib.util

    if str(STAGES) not in sys.path:
        sys.path.insert(0, str(STAGES))
    spec = importlib.util.spec_from_file_location(f"_own_{name}", STAGES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run(name: str, root: Path, argv: list[str] | None = None) -> int:
    mod = _stage(name)
    common = sys.modules["common"]
    try:
        common.run(mod.STAGE, mod.compute, argv=argv or [], root=root)
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0


def _campaign(tmp: Path, n_poses: int = 12, orientation: bool = False) -> Path:
    """A small twin campaign of the KR16-2 (geometric scenario) with an air-temperature log: one reading per
    pose, 10 s apart, so one temperature state, not a warm-up."""
    from robocal.sim.twin import load_scenario, simulate

    sc = load_scenario("geometric")
    sc.update(n_poses=n_poses, n_validation_poses=4, orientation=orientation)
    d = tmp / "my-cell"
    simulate(sc, d, seed=3)
    poses = pd.read_csv(d / "poses.csv")
    stamps = sorted(set(poses["timestamp"]))
    pd.DataFrame({"timestamp": stamps, "T_j1_C": [21.5 + 0.01 * k for k in range(len(stamps))]}).to_csv(
        d / "temperatures.csv", index=False
    )
    return d


def _params(root: Path, **over: Any) -> dict[str, Any]:
    params = compose(REPO, [f"{k}={v}" for k, v in over.items()])
    params["tracking"] = {"enabled": False}
    (root / "params.yaml").write_text(yaml.safe_dump(params))
    return params


# ------------------------------------------------------------------------ item 1: a log that is not a warm-up


def test_a_temperature_log_that_is_not_a_warm_up_skips_the_thermal_chain(tmp_path: Path) -> None:
    camp = _campaign(tmp_path)
    root = tmp_path / "repo"
    root.mkdir()
    _params(root, **{"data.campaign": str(camp)})
    assert _run("prepare", root) == 0
    assert json.loads((root / "data/interim/prepare.json").read_text())["has_temperatures"] is True
    for name, out in (("thermal_fit", "thermal"), ("screen", "screen"), ("validate", "validate")):
        assert _run(name, root) == 0, name  # today: thermal_fit fails, "1 temperature state(s)"
        result = json.loads((root / "reports" / out / "result.json").read_text())
        assert result["status"] == "skipped", name
        metrics = json.loads((root / f"reports/metrics/{name}.json").read_text())
        assert metrics == {name: "skipped"}
    reason = json.loads((root / "reports/thermal/result.json").read_text())["reason"]
    assert "not a warm-up" in reason and "1 temperature state(s)" in reason
    assert str(camp) in reason and "data/interim" not in reason  # the user's campaign, not the interim copy
    for out in ("screen", "validate"):
        assert "thermal_fit skipped" in json.loads((root / "reports" / out / "result.json").read_text())["reason"]
    assert _run("compliance_fit", root) == 0  # no payload: skipped, independent of the thermal chain
    assert json.loads((root / "reports/compliance/result.json").read_text())["status"] == "skipped"


def test_a_campaign_measured_over_several_days_is_not_a_warm_up(tmp_path: Path) -> None:
    """Pauses split the rows into temperature states, but each state measures other poses (the UR10's series A:
    thermal_fit failed, "temperature state 1 shares only 0 pose/target pairs with the reference state")."""
    camp = _campaign(tmp_path, n_poses=18)
    poses = pd.read_csv(camp / "poses.csv")
    t = pd.to_datetime(poses["timestamp"])
    day = (pd.Series(range(len(poses))) * 3 // len(poses)).to_numpy()  # three blocks, other poses in each
    poses["timestamp"] = (t + pd.to_timedelta(day, unit="D")).dt.strftime("%Y-%m-%dT%H:%M:%SZ")
    poses.to_csv(camp / "poses.csv", index=False)
    stamps = sorted(set(poses["timestamp"]))
    pd.DataFrame({"timestamp": stamps, "T_j1_C": [21.5] * len(stamps)}).to_csv(camp / "temperatures.csv", index=False)
    root = tmp_path / "repo"
    root.mkdir()
    _params(root, **{"data.campaign": str(camp)})
    assert _run("prepare", root) == 0
    assert _run("thermal_fit", root) == 0  # before: exit 255 from the state identification
    result = json.loads((root / "reports/thermal/result.json").read_text())
    assert result["status"] == "skipped"
    assert "not a warm-up" in result["reason"] and "measure again" in result["reason"], result["reason"]


def test_a_skip_does_not_outlive_a_later_run_of_the_same_folder(tmp_path: Path) -> None:
    """The skipped result is what the later stages read: a stale one must not stop them after a real run."""
    _stage("screen")
    common = sys.modules["common"]
    root = tmp_path
    (root / "params.yaml").write_text(yaml.safe_dump({"a": {}, "tracking": {"enabled": False}}))
    stage = common.Stage("s", ("a",), "reports/s", "reports/metrics/s.json")
    common.run(stage, lambda ctx: ctx.skip("nothing to do"), argv=[], root=root)
    assert (root / "reports/s/result.json").is_file()
    common.run(stage, lambda ctx: {"x": 1}, argv=[], root=root)
    assert not (root / "reports/s/result.json").exists()


def test_errors_name_the_users_file_not_the_interim_copy(tmp_path: Path) -> None:
    _stage("prepare")
    common = sys.modules["common"]
    camp = tmp_path / "cell7"
    camp.mkdir()
    (camp / "poses.csv").write_text("pose_id\n")
    (camp / "temperatures.csv").write_text("timestamp\n")
    interim = tmp_path / "data" / "interim"
    interim.mkdir(parents=True)
    (interim / "prepare.json").write_text(json.dumps({"source": str(camp)}))
    err = DataError("bad value", file="data/interim/poses.parquet", row=7, column="q2_deg")
    assert common.user_message(err, tmp_path) == f"file {camp / 'poses.csv'}, row 7, column 'q2_deg': bad value"
    err = DataError("no states", file=str(interim / "temperatures.parquet"), row=3)
    assert common.user_message(err, tmp_path) == f"file {camp / 'temperatures.csv'}, row 3: no states"
    err = DataError("no validation rows", file="data/interim", column="split")
    assert common.user_message(err, tmp_path) == f"file {camp}, column 'split': no validation rows"


def test_the_interim_copy_reads_back_the_campaign_bit_for_bit(tmp_path: Path) -> None:
    """Degrees -> radians -> degrees is not the identity in the last bit for ~5 % of real angles: the copy the
    pipeline's stages read must be the campaign the CLI reads, or the two can answer differently."""
    import numpy as np

    from robocal.data.contract import degrees_read_back, read_campaign
    from robocal.robot import load_robot

    rng = np.random.default_rng(0)
    deg = np.round(rng.uniform(-170, 170, 20000), 7)  # as a file holds them
    q = np.radians(deg)
    assert np.any(np.radians(np.degrees(q)) != q)  # the plain round trip is not exact
    assert np.array_equal(np.radians(degrees_read_back(q)), q)
    # normalising a quaternion twice is not normalising it once, in the last bit: reading is idempotent
    from robocal.data.contract import unit_quaternions

    quat = rng.normal(size=(20000, 4))
    unit = unit_quaternions(quat)
    assert np.array_equal(unit_quaternions(unit), unit)
    assert np.any(unit / np.linalg.norm(unit, axis=1)[:, None] != unit)  # the plain division is not
    camp_dir = _campaign(tmp_path, orientation=True)
    robot = load_robot("kr16_2")
    camp = read_campaign(camp_dir, robot)
    assert camp.quat is not None
    (tmp_path / "copy").mkdir()
    camp.to_frame().to_parquet(tmp_path / "copy" / "poses.parquet", index=False)
    again = read_campaign(tmp_path / "copy", robot)
    assert np.array_equal(again.q, camp.q) and np.array_equal(again.timestamp_s, camp.timestamp_s)
    assert again.quat is not None and np.array_equal(again.quat, camp.quat)


# ------------------------------------------------------------------------ item 8: a robot file by path


def _my_robot(tmp: Path) -> Path:
    data = yaml.safe_load((REPO / "conf/robot/kr16_2.yaml").read_text())
    data["name"] = "kr16-cell7"
    path = tmp / "descriptions" / "cell7.yaml"
    path.parent.mkdir(parents=True)
    path.write_text(yaml.safe_dump(data))
    return path


def test_robot_file_gives_every_stage_that_robot(tmp_path: Path) -> None:
    assert compose(REPO)[ROBOT_FILE] is None  # default: the robot group
    camp = _campaign(tmp_path)
    root = tmp_path / "repo"
    root.mkdir()
    robot = _my_robot(tmp_path)
    _params(root, **{"data.campaign": str(camp), ROBOT_FILE: str(robot), "robot": "abb_irb120"})
    assert _run("prepare", root) == 0
    assert json.loads((root / "data/interim/prepare.json").read_text())["robot"] == "kr16-cell7"
    # relative to the repository root, and the twin's scenario follows the robot's name
    cfg = {"robot": {"name": "kr16_2"}, "scenario": {"robot": "kr16_2"}, ROBOT_FILE: "../descriptions/cell7.yaml"}
    cfg = apply_robot_file(cfg, root)
    assert cfg["robot"]["name"] == "kr16-cell7" and cfg["scenario"]["robot"] == "kr16-cell7"
    assert apply_robot_file({"robot": {"name": "a"}, ROBOT_FILE: None}, root)["robot"] == {"name": "a"}


def test_a_urdf_robot_file_is_read_as_robocal_discover_reads_it(tmp_path: Path) -> None:
    """``robot_file`` may name a URDF (``path.urdf`` or ``path.urdf#BASE:TIP``), as ``--robot`` does: a newcomer's
    pipeline stopped at its first stage on one ("a robot description must be a mapping", issue 33)."""
    from robocal.cell.urdf import robot_from_ref
    from robocal.robot import robot_from_dict

    urdf = REPO / "tests/cell/data/ur5_robot.urdf"
    for ref in (f"{urdf}#:tool0", f"{urdf}#base_link:tool0"):
        cfg = apply_robot_file({"robot": {"name": "kr16_2"}, "scenario": {"robot": "kr16_2"}, ROBOT_FILE: ref}, REPO)
        got, want = robot_from_dict(cfg["robot"], source=ref), robot_from_ref(ref)
        assert got.n_joints == want.n_joints == 6 and cfg["scenario"]["robot"] == got.name
        assert np.array_equal(got.poe_p_mm, want.poe_p_mm) and np.array_equal(got.poe_flange0, want.poe_flange0)


def test_a_missing_robot_file_is_one_line_naming_the_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    camp = _campaign(tmp_path)
    root = tmp_path / "repo"
    root.mkdir()
    _params(root, **{"data.campaign": str(camp), ROBOT_FILE: "../nowhere/robot.yaml"})
    assert _run("prepare", root) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("stage prepare: error:")
    assert "'robot_file'" in err and "nowhere/robot.yaml" in err and "not a file" in err
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\njoints: 3\n")
    with pytest.raises(ConfigError, match=r"robot_file .*bad\.yaml.*'joints'"):
        apply_robot_file({ROBOT_FILE: str(bad)}, root)


def test_a_robot_path_given_as_the_group_is_one_line_saying_robot_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(ConfigError) as info:
        compose(REPO, ["robot=../shared/data/ur10-ipa/robot.yaml"])
    msg = str(info.value)
    assert "\n" not in msg and "(conf/robot/: abb_irb120, kr16_2," in msg and "sr210)" in msg
    assert "robot_file=../shared/data/ur10-ipa/robot.yaml" in msg
    # a Hydra-mode stage run says the same in one line (not Hydra's "Could not find" report)
    assert _run("prepare", REPO, ["robot=../x.yaml"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "robot_file=../x.yaml" in err
    # `make params` (python -m robocal.pipeline params) too, and params.yaml is left alone
    proc = subprocess.run(
        [sys.executable, "-m", "robocal.pipeline", "check", "robot=../x.yaml", "--root", str(REPO)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "robot_file=../x.yaml" in proc.stderr
