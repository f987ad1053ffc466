"""The data door (docs/data-contract.md): every rule, each with a bad file built in tmp_path.

Every error must name the file, the row (header = row 1, first data row = row 2) and the column, and what
was expected. The good-path tests check units, defaults, the temperature join, the split and the round trip.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from robocal.data import Campaign, SplitConfig, read_campaign
from robocal.errors import ConfigError, DataError

START = pd.Timestamp("2026-01-05T07:00:00Z")
N_POSES = 6
TARGETS = ("T1", "T2")


def iso(t: pd.Timestamp) -> str:
    return t.strftime("%Y-%m-%dT%H:%M:%SZ")


def good_poses(robot, *, n_poses: int = N_POSES, targets=TARGETS, seed: int = 0) -> pd.DataFrame:
    """A valid poses table: every pose measured on every target, 10 s apart, 1.5-3 m from the tracker."""
    rng = np.random.default_rng(seed)
    lim = np.degrees(robot.q_limits)
    rows = []
    k = 0
    for i in range(n_poses):
        q = lim[:, 0] + (0.1 + 0.8 * rng.random(robot.n_joints)) * (lim[:, 1] - lim[:, 0])
        for t in targets:
            row = {"pose_id": f"p{i:02d}", "timestamp": iso(START + pd.Timedelta(seconds=10 * k)), "target": t}
            row.update({f"q{j + 1}_deg": round(float(q[j]), 6) for j in range(robot.n_joints)})
            p = rng.uniform(-1500.0, 1500.0, 3) + np.array([0.0, 0.0, 2000.0])
            row.update({"x_mm": round(p[0], 6), "y_mm": round(p[1], 6), "z_mm": round(p[2], 6)})
            row["payload_kg"] = 0.0
            rows.append(row)
            k += 1
    return pd.DataFrame(rows)


def good_temperatures(robot, *, n: int = 12, step_s: float = 60.0, start_offset_s: float = -30.0) -> pd.DataFrame:
    """A temperature log starting before the first pose, one reading a minute, one column per sensor."""
    ts = [START + pd.Timedelta(seconds=start_offset_s + step_s * i) for i in range(n)]
    d: dict[str, object] = {"timestamp": [iso(t) for t in ts]}
    for s, name in enumerate(robot.sensor_names):
        d[name] = [round(20.0 + s + 0.1 * i, 3) for i in range(n)]
    return pd.DataFrame(d)


def write(folder: Path, df: pd.DataFrame, stem: str = "poses", fmt: str = "csv") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{stem}.{fmt}"
    if fmt == "csv":
        df.to_csv(path, index=False)
    else:
        df.to_parquet(path, index=False)
    return path


def as_text(df: pd.DataFrame) -> pd.DataFrame:
    """Object columns, so that any cell can be set to a bad string."""
    return df.astype(object)


def expect_error(folder: Path, robot, *, file: Path, row: int | None, column: str | None, match: str = "", **kw):
    """Read ``folder`` and check the DataError names the file, row and column (in the message, too)."""
    with pytest.raises(DataError) as ei:
        read_campaign(folder, robot, **kw)
    err = ei.value
    msg = str(err)
    assert err.file is not None and Path(err.file).name == file.name, msg
    assert file.name in msg, msg
    assert err.row == row, msg
    if row is not None:
        assert f"row {row}" in msg, msg
    assert err.column == column, msg
    if column is not None:
        assert repr(column) in msg, msg
    if match:
        assert match in msg, msg
    return err


# ------------------------------------------------------------------------------------------ the rules


def test_missing_required_columns_are_all_named(tmp_path, kr16):
    df = good_poses(kr16).drop(columns=["q3_deg", "y_mm"])
    f = write(tmp_path, df)
    err = expect_error(tmp_path, kr16, file=f, row=1, column="q3_deg", match="missing required column")
    assert "'q3_deg'" in err.reason and "'y_mm'" in err.reason


@pytest.mark.parametrize("column", ["q2_deg", "x_mm", "z_mm", "timestamp", "pose_id"])
@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_missing_value_in_a_required_column(tmp_path, kr16, column, fmt):
    df = as_text(good_poses(kr16))
    df.loc[4, column] = None  # data row 4 (0-based) = file row 6
    f = write(tmp_path, df, fmt=fmt)
    expect_error(tmp_path, kr16, file=f, row=6, column=column)


def test_nan_text_in_a_numeric_column(tmp_path, kr16):
    df = as_text(good_poses(kr16))
    df.loc[2, "y_mm"] = "NaN"
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=4, column="y_mm", match="non-finite")


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_non_numeric_cell(tmp_path, kr16, fmt):
    df = as_text(good_poses(kr16))
    df.loc[7, "q4_deg"] = "12,5"  # a decimal comma: must not be read as 12 or 125
    df["q4_deg"] = df["q4_deg"].astype(str)  # Parquet needs one type per column: a text column
    f = write(tmp_path, df, fmt=fmt)
    expect_error(tmp_path, kr16, file=f, row=9, column="q4_deg", match="'12,5'")


def test_bad_timestamp(tmp_path, kr16):
    df = as_text(good_poses(kr16))
    df.loc[3, "timestamp"] = "yesterday"
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=5, column="timestamp", match="ISO 8601")


@pytest.mark.parametrize(("column", "value"), [("q2_deg", 35.5), ("q2_deg", -155.01), ("q6_deg", 351.0)])
def test_joint_angle_outside_limits(tmp_path, kr16, column, value):
    # KR16-2 limits (Guo table 3): q2 in [-155, 35], q6 in [-350, 350]
    df = good_poses(kr16)
    pid = df.loc[5, "pose_id"]
    df.loc[df.pose_id == pid, column] = value  # both targets of that pose, so only the limit rule fires
    f = write(tmp_path, df)
    first = int(np.flatnonzero(df.pose_id == pid)[0]) + 2
    expect_error(tmp_path, kr16, file=f, row=first, column=column, match="outside the limits")


def test_joint_angle_on_the_limit_is_accepted(tmp_path, kr16):
    df = good_poses(kr16)
    df.loc[df.pose_id == "p01", "q2_deg"] = 35.0
    write(tmp_path, df)
    camp = read_campaign(tmp_path, kr16)
    assert np.isclose(camp.q[2, 1], np.radians(35.0))


def test_duplicated_pose_target_timestamp(tmp_path, kr16):
    df = good_poses(kr16)
    df = pd.concat([df, df.iloc[[3]]], ignore_index=True)  # row 5 again as the last row
    f = write(tmp_path, df)
    err = expect_error(tmp_path, kr16, file=f, row=len(df) + 1, column="pose_id", match="duplicated")
    assert "first seen at row 5" in err.reason


def test_same_pose_on_another_target_or_time_is_not_a_duplicate(tmp_path, kr16):
    df = good_poses(kr16)
    again = df.iloc[[0, 1]].copy()
    again.loc[:, "timestamp"] = [iso(START + pd.Timedelta(hours=2, seconds=s)) for s in (0, 10)]
    write(tmp_path, pd.concat([df, again], ignore_index=True))
    camp = read_campaign(tmp_path, kr16)
    assert camp.n_rows == len(df) + 2


@pytest.mark.parametrize("equal", [False, True])
def test_non_monotonic_temperature_timestamps(tmp_path, kr16, equal):
    write(tmp_path, good_poses(kr16))
    t = good_temperatures(kr16)
    t.loc[5, "timestamp"] = t.loc[4, "timestamp"] if equal else t.loc[2, "timestamp"]
    f = write(tmp_path, t, stem="temperatures")
    expect_error(tmp_path, kr16, file=f, row=7, column="timestamp", match="increase strictly")


def _with_quaternions(df: pd.DataFrame, seed: int = 1) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(len(df), 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    out = df.copy()
    for k, c in enumerate(("qw", "qx", "qy", "qz")):
        out[c] = q[:, k]
    return out


def test_quaternion_norm_far_from_one(tmp_path, kr16):
    df = _with_quaternions(good_poses(kr16))
    df.loc[6, ["qw", "qx", "qy", "qz"]] *= 1.01
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=8, column="qw", match="quaternion norm")


def test_quaternion_rounding_is_accepted_and_normalised(tmp_path, kr16):
    df = _with_quaternions(good_poses(kr16))
    df.loc[6, ["qw", "qx", "qy", "qz"]] *= 1.0005  # within the default 1e-3 (4-5 printed digits)
    write(tmp_path, df)
    camp = read_campaign(tmp_path, kr16)
    assert camp.quat is not None
    np.testing.assert_allclose(np.linalg.norm(camp.quat, axis=1), 1.0, atol=1e-12)


def test_partial_quaternion(tmp_path, kr16):
    df = _with_quaternions(good_poses(kr16)).drop(columns=["qz"])
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=1, column="qz")


def test_orientation_on_some_rows_only_is_refused_saying_what_to_do(tmp_path, kr16):
    # a 6-DoF probe's rows with a point reflector's (no orientation): before, "missing or non-finite value in a
    # required column" for an optional column
    df = _with_quaternions(good_poses(kr16))
    df.loc[[3, 9], ["qw", "qx", "qy", "qz"]] = np.nan
    f = write(tmp_path, df)
    err = expect_error(tmp_path, kr16, file=f, row=5, column="qw", match="every row or of none")
    assert "2 row(s)" in err.reason


def test_orientation_columns_empty_in_every_row_are_positions_only(tmp_path, kr16):
    df = good_poses(kr16)
    for c in ("qw", "qx", "qy", "qz"):
        df[c] = np.nan
    write(tmp_path, df)
    assert read_campaign(tmp_path, kr16).quat is None


def test_positions_in_metres(tmp_path, kr16):
    df = good_poses(kr16)
    df[["x_mm", "y_mm", "z_mm"]] /= 1000.0
    f = write(tmp_path, df)
    err = expect_error(tmp_path, kr16, file=f, row=2, column=_largest(df, 0), match="metres")
    assert "millimetres" in err.reason


def _largest(df: pd.DataFrame, i: int) -> str:
    return str(df.loc[i, ["x_mm", "y_mm", "z_mm"]].astype(float).abs().idxmax())


def test_one_row_in_metres_among_millimetres(tmp_path, kr16):
    df = good_poses(kr16)
    df.loc[9, ["x_mm", "y_mm", "z_mm"]] /= 1000.0
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=11, column=_largest(df, 9), match="metres")


@pytest.mark.parametrize("value", ["train", "valid", ""])
def test_bad_split_value(tmp_path, kr16, value):
    df = as_text(good_poses(kr16))
    df["split"] = "calibration"
    df.loc[8, "split"] = value
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=10, column="split", match="split must be one of")


@pytest.mark.parametrize("fmt", ["tau{}_Nm", "i{}_A", "dir{}"])
def test_partial_joint_blocks(tmp_path, kr16, fmt):
    df = good_poses(kr16)
    for j in range(5):  # joints 1..5, joint 6 missing
        df[fmt.format(j + 1)] = 1.0
    f = write(tmp_path, df)
    err = expect_error(tmp_path, kr16, file=f, row=1, column=fmt.format(6))
    assert "all 6 joints" in err.reason


@pytest.mark.parametrize("value", [0, 2, 0.5])
def test_direction_not_plus_or_minus_one(tmp_path, kr16, value):
    df = good_poses(kr16)
    for j in range(6):
        df[f"dir{j + 1}"] = 1.0
    df.loc[4, "dir3"] = value
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=6, column="dir3", match="-1 or +1")


def test_same_pose_id_with_different_joints(tmp_path, kr16):
    df = good_poses(kr16)
    df.loc[7, "q5_deg"] += 0.01  # pose p03, target T2: 0.01 deg off its T1 row (row 8)
    f = write(tmp_path, df)
    err = expect_error(tmp_path, kr16, file=f, row=9, column="q5_deg", match="measured before (row 8)")
    assert "'p03'" in err.reason


def test_same_pose_id_rounding_is_accepted(tmp_path, kr16):
    df = good_poses(kr16)
    df.loc[7, "q5_deg"] += 5e-4  # below the 1e-3 deg rounding slack (4 printed decimals)
    write(tmp_path, df)
    assert read_campaign(tmp_path, kr16).n_rows == len(df)


def test_stale_temperature_reading(tmp_path, kr16):
    poses = good_poses(kr16)
    write(tmp_path, poses)
    t = good_temperatures(kr16, n=3, step_s=40.0, start_offset_s=0.0)  # readings at 0, 40, 80 s; poses 0..110 s
    f = write(tmp_path, t, stem="temperatures")
    # a tolerance of 25 s: the pose at 30 s (data row 3 -> file row 5) is 30 s after the reading at 0 s
    err = expect_error(
        tmp_path,
        kr16,
        file=tmp_path / "poses.csv",
        row=5,
        column="timestamp",
        match="tolerance 25 s",
        temperature_tolerance_s=25.0,
    )
    assert "30 s old" in err.reason  # the poses file is named (the stale row is a pose), not temperatures.csv
    assert f.name not in str(err)
    # the default tolerance (900 s) accepts the same files
    assert read_campaign(tmp_path, kr16).has_temperatures


def test_pose_before_first_temperature(tmp_path, kr16):
    write(tmp_path, good_poses(kr16))
    write(tmp_path, good_temperatures(kr16, start_offset_s=25.0), stem="temperatures")  # first reading at 25 s
    expect_error(
        tmp_path, kr16, file=tmp_path / "poses.csv", row=2, column="timestamp", match="before the first temperature"
    )


def test_unknown_sensor(tmp_path, kr16):
    write(tmp_path, good_poses(kr16))
    t = good_temperatures(kr16)
    t["T_j9_C"] = 21.0
    f = write(tmp_path, t, stem="temperatures")
    err = expect_error(tmp_path, kr16, file=f, row=1, column="T_j9_C")
    assert "T_j1_C" in err.reason  # the robot's own sensors are listed


def test_temperature_file_without_sensor_column(tmp_path, kr16):
    write(tmp_path, good_poses(kr16))
    f = write(tmp_path, good_temperatures(kr16)[["timestamp"]], stem="temperatures")
    expect_error(tmp_path, kr16, file=f, row=1, column=None, match="T_<sensor>_C")


def test_missing_temperature_value(tmp_path, kr16):
    write(tmp_path, good_poses(kr16))
    t = as_text(good_temperatures(kr16))
    t.loc[3, "T_l4_C"] = ""
    f = write(tmp_path, t, stem="temperatures")
    expect_error(tmp_path, kr16, file=f, row=5, column="T_l4_C")


@pytest.mark.parametrize("stem", ["poses", "temperatures"])
def test_both_csv_and_parquet(tmp_path, kr16, stem):
    poses, temps = good_poses(kr16), good_temperatures(kr16)
    write(tmp_path, poses)
    write(tmp_path, temps, stem="temperatures")
    write(tmp_path, poses if stem == "poses" else temps, stem=stem, fmt="parquet")
    with pytest.raises(DataError) as ei:
        read_campaign(tmp_path, kr16)
    msg = str(ei.value)
    # a folder-level ambiguity: no row or column, but both files are named
    assert f"{stem}.csv" in msg and f"{stem}.parquet" in msg and str(tmp_path) in msg


def test_missing_folder_and_missing_poses_file(tmp_path, kr16):
    with pytest.raises(DataError, match="does not exist"):
        read_campaign(tmp_path / "nowhere", kr16)
    with pytest.raises(DataError, match=r"no poses\.csv or poses\.parquet"):
        read_campaign(tmp_path, kr16)


def test_header_only_and_duplicated_columns(tmp_path, kr16):
    df = good_poses(kr16)
    f = write(tmp_path, df.iloc[:0])
    expect_error(tmp_path, kr16, file=f, row=None, column=None, match="no rows")
    cols = [*list(df.columns), "x_mm"]
    text = ",".join(cols) + "\n" + "\n".join(",".join(map(str, [*r, r[-4]])) for r in df.itertuples(index=False))
    f.write_text(text + "\n")
    expect_error(tmp_path, kr16, file=f, row=1, column="x_mm", match="duplicated column")


def test_more_joint_columns_than_the_robot(tmp_path, kr16):
    df = good_poses(kr16)
    df["q7_deg"] = 0.0
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=1, column="q7_deg", match="6 joints")


def test_missing_pose_id_target_and_negative_payload(tmp_path, kr16):
    df = as_text(good_poses(kr16))
    df.loc[1, "target"] = " "
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=3, column="target", match="missing target")
    df = good_poses(kr16)
    df.loc[10, "payload_kg"] = -2.0
    write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=12, column="payload_kg", match="negative payload")


# ------------------------------------------------------------------------------------- the good path


def _rich(robot, seed: int = 0) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Poses with every optional block and two extra columns, and a temperature log."""
    df = _with_quaternions(good_poses(robot, seed=seed), seed=seed)
    rng = np.random.default_rng(seed + 10)
    for j in range(robot.n_joints):
        df[f"tau{j + 1}_Nm"] = np.round(rng.normal(0, 50, len(df)), 4)
        df[f"i{j + 1}_A"] = np.round(rng.normal(0, 3, len(df)), 4)
        df[f"dir{j + 1}"] = rng.choice([-1, 1], len(df))
    df["payload_kg"] = np.where(np.arange(len(df)) % 3 == 0, 10.0, 0.0)
    df["operator"] = "jdoe"
    df["comment"] = [f"note {i}" for i in range(len(df))]
    df["split"] = np.where(df.pose_id.isin(["p01", "p04"]), "validation", "calibration")
    return df, good_temperatures(robot)


def _assert_same_campaign(a: Campaign, b: Campaign, *, atol_deg: float = 0.0) -> None:
    np.testing.assert_array_equal(a.pose_id, b.pose_id)
    np.testing.assert_array_equal(a.target, b.target)
    assert a.target_names == b.target_names
    np.testing.assert_array_equal(a.target_index, b.target_index)
    np.testing.assert_allclose(a.timestamp_s, b.timestamp_s, rtol=0, atol=1e-6)  # µs: ISO text carries no more
    assert pd.Timestamp(a.t0) == pd.Timestamp(b.t0)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=np.radians(atol_deg) + 1e-15)
    np.testing.assert_allclose(a.p_mm, b.p_mm, rtol=1e-15, atol=0)
    for name in ("quat", "tau_Nm", "current_A", "direction", "temperatures"):
        va, vb = getattr(a, name), getattr(b, name)
        assert (va is None) == (vb is None), name
        if va is not None:
            np.testing.assert_allclose(va, vb, rtol=1e-15, atol=1e-15, err_msg=name)
    np.testing.assert_array_equal(a.payload_kg, b.payload_kg)
    np.testing.assert_array_equal(a.split, b.split)
    assert a.sensor_names == b.sensor_names
    assert set(a.extra) == set(b.extra)
    for k in a.extra:
        np.testing.assert_array_equal(a.extra[k].astype(str), b.extra[k].astype(str), err_msg=k)
    np.testing.assert_array_equal(a.row_number, b.row_number)


def test_csv_and_parquet_give_the_same_campaign(tmp_path, kr16):
    poses, temps = _rich(kr16)
    write(tmp_path / "csv", poses)
    write(tmp_path / "csv", temps, stem="temperatures")
    # Parquet as a user would write it: real timestamps and numbers, not text
    pq = poses.copy()
    pq["timestamp"] = pd.to_datetime(pq["timestamp"], utc=True)
    tq = temps.copy()
    tq["timestamp"] = pd.to_datetime(tq["timestamp"], utc=True)
    write(tmp_path / "pq", pq, fmt="parquet")
    write(tmp_path / "pq", tq, stem="temperatures", fmt="parquet")
    a = read_campaign(tmp_path / "csv", kr16)
    b = read_campaign(tmp_path / "pq", kr16)
    assert a.poses_file.endswith("poses.csv") and b.poses_file.endswith("poses.parquet")
    _assert_same_campaign(a, b)
    pd.testing.assert_frame_equal(a.temperature_log, b.temperature_log)


def test_units_are_converted_once(tmp_path, kr16):
    df = good_poses(kr16)
    write(tmp_path, df)
    camp = read_campaign(tmp_path, kr16)
    q_deg = df[[f"q{j + 1}_deg" for j in range(6)]].to_numpy()
    np.testing.assert_allclose(camp.q, q_deg * np.pi / 180.0, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(camp.p_mm, df[["x_mm", "y_mm", "z_mm"]].to_numpy())  # mm stay mm
    np.testing.assert_array_equal(camp.timestamp_s, 10.0 * np.arange(len(df)))  # seconds since the first pose
    assert pd.Timestamp(camp.t0) == START


def test_defaults_target_t1_payload_zero_and_extras_kept(tmp_path, kr16):
    df = good_poses(kr16, targets=("X",)).drop(columns=["target", "payload_kg"])
    df["operator"] = "jdoe"
    df["humidity_pct"] = 41.5
    write(tmp_path, df)
    camp = read_campaign(tmp_path, kr16)
    assert camp.target_names == ("T1",) and set(camp.target) == {"T1"}
    np.testing.assert_array_equal(camp.target_index, 0)
    np.testing.assert_array_equal(camp.payload_kg, 0.0)
    assert not camp.has_payload and not camp.has_orientation and not camp.has_temperatures
    assert not camp.has_torques and not camp.has_currents and not camp.has_directions
    assert set(camp.extra) == {"operator", "humidity_pct"}
    assert list(camp.extra["operator"]) == ["jdoe"] * len(df)
    np.testing.assert_array_equal(camp.extra["humidity_pct"].astype(float), 41.5)


def test_temperatures_join_the_nearest_earlier_reading(tmp_path, kr16):
    write(tmp_path, good_poses(kr16))  # poses at 0, 10, ..., 110 s
    t = good_temperatures(kr16, n=4, step_s=40.0, start_offset_s=0.0)  # readings at 0, 40, 80, 120 s
    write(tmp_path, t, stem="temperatures")
    camp = read_campaign(tmp_path, kr16)
    assert camp.sensor_names == tuple(kr16.sensor_names)
    # reading k covers poses in [40k, 40k + 40): a reading at the pose's own time counts as earlier
    expect_k = np.array([0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2])
    vals = t[list(kr16.sensor_names)].to_numpy(dtype=float)
    np.testing.assert_array_equal(camp.temperatures, vals[expect_k])
    assert camp.temperature_log is not None
    np.testing.assert_array_equal(camp.temperature_log["t_s"], [0.0, 40.0, 80.0, 120.0])


def _hashes(folder: Path) -> dict[str, tuple[str, float]]:
    return {
        p.name: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime)
        for p in sorted(folder.iterdir())
        if p.is_file()
    }


def test_raw_files_are_never_modified(tmp_path, kr16):
    poses, temps = _rich(kr16)
    write(tmp_path, poses)
    write(tmp_path, temps, stem="temperatures")
    before = _hashes(tmp_path)
    read_campaign(tmp_path, kr16)
    assert _hashes(tmp_path) == before
    # nor on the error path
    with pytest.raises(DataError):
        read_campaign(tmp_path, kr16, temperature_tolerance_s=1.0)
    assert _hashes(tmp_path) == before


def test_split_by_config_keeps_poses_together_and_is_seeded(tmp_path, kr16):
    df = good_poses(kr16, n_poses=40, targets=("T1", "T2", "T3"))
    write(tmp_path, df)
    cfg = SplitConfig(method="random", validation_fraction=0.25, seed=7)
    a = read_campaign(tmp_path, kr16, split=cfg)
    assert not a.split_from_file
    val_ids = set(a.pose_id[a.split == "validation"])
    assert len(val_ids) == 10  # 25 % of 40 pose ids, by id, not by row
    for pid in set(a.pose_id):
        assert len(set(a.split[a.pose_id == pid])) == 1, pid  # all targets of a pose on one side
    b = read_campaign(tmp_path, kr16, split={"method": "random", "validation_fraction": 0.25, "seed": 7})
    np.testing.assert_array_equal(a.split, b.split)  # same seed, same split (mapping or dataclass)
    others = [read_campaign(tmp_path, kr16, split=SplitConfig(validation_fraction=0.25, seed=s)) for s in (8, 9)]
    assert any(set(o.pose_id[o.split == "validation"]) != val_ids for o in others)
    none = read_campaign(tmp_path, kr16, split={"method": "none"})
    assert set(none.split) == {"calibration"}
    default = read_campaign(tmp_path, kr16)  # 20 %, seed 0
    assert len(set(default.pose_id[default.split == "validation"])) == 8


def test_split_column_wins_over_config(tmp_path, kr16):
    df = good_poses(kr16)
    df["split"] = np.where(df.pose_id == "p02", "Validation", "calibration")  # case is forgiven
    write(tmp_path, df)
    camp = read_campaign(tmp_path, kr16, split=SplitConfig(validation_fraction=0.5, seed=3))
    assert camp.split_from_file
    assert set(camp.pose_id[camp.split == "validation"]) == {"p02"}


def test_bad_split_settings():
    with pytest.raises(ConfigError, match=r"split\.method"):
        SplitConfig(method="kfold")
    with pytest.raises(ConfigError, match="validation_fraction"):
        SplitConfig(validation_fraction=1.0)
    with pytest.raises(ConfigError, match="valdiation_fraction"):
        SplitConfig.from_mapping({"valdiation_fraction": 0.2})


def test_subset_calibration_validation(tmp_path, kr16):
    poses, temps = _rich(kr16)
    write(tmp_path, poses)
    write(tmp_path, temps, stem="temperatures")
    camp = read_campaign(tmp_path, kr16)
    cal, val = camp.calibration(), camp.validation()
    assert cal.n_rows + val.n_rows == camp.n_rows and val.n_rows == 4
    assert set(val.pose_id) == {"p01", "p04"} and set(cal.split) == {"calibration"}
    np.testing.assert_array_equal(val.row_number, np.flatnonzero(camp.split == "validation") + 2)
    assert val.target_names == camp.target_names  # kept, so target_index stays valid
    idx = np.array([5, 0, 3])
    sub = camp.subset(idx)
    for name in ("q", "p_mm", "quat", "tau_Nm", "current_A", "direction", "temperatures", "payload_kg", "pose_id"):
        np.testing.assert_array_equal(getattr(sub, name), getattr(camp, name)[idx], err_msg=name)
    np.testing.assert_array_equal(sub.extra["comment"], camp.extra["comment"][idx])
    with pytest.raises(ValueError, match="mask has shape"):
        camp.subset(np.ones(3, dtype=bool))


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_to_frame_round_trip(tmp_path, kr16, fmt):
    poses, temps = _rich(kr16)
    write(tmp_path / "a", poses)
    write(tmp_path / "a", temps, stem="temperatures")
    a = read_campaign(tmp_path / "a", kr16)
    frame = a.to_frame()
    write(tmp_path / "b", frame, fmt=fmt)
    write(tmp_path / "b", temps, stem="temperatures")
    b = read_campaign(tmp_path / "b", kr16)
    # deg -> rad -> deg may move the last bit; 1e-12 deg is far below any encoder
    _assert_same_campaign(a, b, atol_deg=1e-12)
    # and a subset survives the round trip too
    v = a.validation()
    write(tmp_path / "c", v.to_frame(), fmt=fmt)
    write(tmp_path / "c", temps, stem="temperatures")
    c = read_campaign(tmp_path / "c", kr16)
    np.testing.assert_allclose(c.q, v.q, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(c.pose_id, v.pose_id)
    np.testing.assert_array_equal(c.split, "validation")


def test_an_id_in_an_error_is_the_id_not_a_numpy_repr(tmp_path, kr16):
    """Issue 23 item 12: a pose id measured twice with other joints is named as 'p03', not np.str_('p03')."""
    df = as_text(good_poses(kr16, n_poses=6, targets=("T1", "T2")))
    df.loc[7, "q2_deg"] = str(float(df.loc[7, "q2_deg"]) + 1.0)  # pose p03, second target: other joint angle
    f = write(tmp_path, df)
    err = expect_error(tmp_path, kr16, file=f, row=9, column="q2_deg", match="pose_id 'p03' was measured before")
    assert "np.str_" not in str(err)


# ------------------------------------------------------------------------ CSV as a spreadsheet saves it


def _european(folder: Path, df: pd.DataFrame, stem: str, sep: str = ";", encoding: str = "cp1252") -> Path:
    """``df`` as Excel saves "CSV" where the decimal mark is a comma: ``sep`` between columns, decimal commas,
    the Windows code page."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{stem}.csv"
    df.to_csv(path, index=False, sep=sep, decimal=",", encoding=encoding)
    return path


@pytest.mark.parametrize(("sep", "encoding"), [(";", "cp1252"), ("\t", "utf-8-sig")])
def test_european_csv_gives_the_same_campaign(tmp_path, kr16, sep, encoding):
    """Semicolon (or tab) separated, decimal commas, Windows-1252 or UTF-8 with a byte order mark: the same
    campaign as the comma-separated file (issue 30, item 5: it was "missing required column(s) ... present:
    ['pose_id;timestamp;target;...']"). Raw files untouched."""
    poses, temps = _rich(kr16)
    poses["operator"] = "Jürgen"  # a non-ASCII extra: the code page must be read as such
    poses["humidity_pct"] = 41.5  # a numeric extra column is converted too
    poses.loc[0, "x_mm"] = 1234.5  # written below with a thousands point, as a "#.##0,0" cell format does
    write(tmp_path / "us", poses)
    write(tmp_path / "us", temps, stem="temperatures")
    eu = tmp_path / "eu"
    p = _european(eu, poses, "poses", sep, encoding)
    _european(eu, temps, "temperatures", sep, encoding)
    text = p.read_text(encoding=encoding)
    assert text.startswith(f"pose_id{sep}timestamp{sep}target{sep}q1_deg") and "1234,5" in text
    p.write_text(text.replace(f"{sep}1234,5{sep}", f"{sep}1.234,5{sep}", 1), encoding=encoding)
    before = _hashes(eu)
    a = read_campaign(tmp_path / "us", kr16)
    b = read_campaign(eu, kr16)
    _assert_same_campaign(a, b)
    pd.testing.assert_frame_equal(a.to_frame(), b.to_frame())
    pd.testing.assert_frame_equal(a.temperature_log, b.temperature_log)
    assert b.p_mm[0, 0] == 1234.5 and list(b.extra["operator"]) == ["Jürgen"] * len(poses)
    assert _hashes(eu) == before


def test_mixed_decimal_marks_are_one_clear_error(tmp_path, kr16):
    """Decimal commas and a decimal point in one file: which is meant cannot be told (1.234 may be a thousands
    point); the error names the file, both cells and how to fix it."""
    df = good_poses(kr16)
    p = _european(tmp_path, df, "poses")
    lines = p.read_text(encoding="cp1252").splitlines()
    cells = lines[3].split(";")
    y = lines[0].split(";").index("y_mm")
    cells[y] = cells[y].replace(",", ".")
    lines[3] = ";".join(cells)
    p.write_text("\n".join(lines) + "\n", encoding="cp1252")
    err = expect_error(tmp_path, kr16, file=p, row=4, column="y_mm", match="mixes decimal commas (row 2, column")
    assert f"(row 4, column 'y_mm': {cells[y]!r})" in err.reason and "semicolon-separated" in err.reason


def test_a_header_with_two_delimiters_is_one_clear_error(tmp_path, kr16):
    p = write(tmp_path, good_poses(kr16))
    text = p.read_text()
    header, rest = text.split("\n", 1)
    p.write_text(header.replace(",", ";", 3) + "\n" + rest)
    err = expect_error(tmp_path, kr16, file=p, row=1, column=None, match="the header row has both commas")
    assert "semicolons (4 columns)" in err.reason


def test_a_decimal_comma_in_a_comma_separated_file_is_named(tmp_path, kr16):
    """A comma-separated file has no decimal commas (a quoted "1,523" may be a thousands comma): the cell is
    reported as written, not guessed."""
    df = as_text(good_poses(kr16))
    df.loc[2, "z_mm"] = "1523,4"
    f = write(tmp_path, df)
    expect_error(tmp_path, kr16, file=f, row=4, column="z_mm", match="expected a number, got '1523,4'")


def test_rows_of_bare_separators_at_the_end_are_not_rows(tmp_path, kr16):
    """A spreadsheet saves the rows it once formatted as bare separators (",,,,"): refused as a missing pose_id
    before; now the table ends at its last filled row. Such a row inside the table is still refused."""
    df = good_poses(kr16)
    f = write(tmp_path, df)
    blank = "," * (len(df.columns) - 1)
    f.write_text(f.read_text() + "\n".join([blank] * 3) + "\n")
    camp = read_campaign(tmp_path, kr16)
    assert camp.n_rows == len(df)
    lines = f.read_text().splitlines()
    f.write_text("\n".join([*lines[:4], blank, *lines[4:]]) + "\n")
    expect_error(tmp_path, kr16, file=f, row=5, column="pose_id", match="missing")


def test_other_tables_in_the_folder_are_named_when_the_split_is_drawn(tmp_path, kr16):
    """A validation.csv beside a poses file without a split column was ignored without a word (the campaign drew
    its own split from the calibration poses): it is named as not read. With a split column: nothing to say."""
    df = good_poses(kr16)
    write(tmp_path, df)
    write(tmp_path, df, stem="validation")
    (tmp_path / "README.md").write_text("not a table")
    camp = read_campaign(tmp_path, kr16)
    assert camp.not_read == ("validation.csv",)
    note = camp.not_read_note()
    assert note is not None and "validation.csv in the campaign folder was not read" in note, note
    df["split"] = "calibration"
    write(tmp_path, df)
    assert read_campaign(tmp_path, kr16).not_read_note() is None


def test_poses_and_temperatures_in_other_time_zones_are_said(tmp_path, kr16):
    """Poses written in local time without a zone beside a temperature log in UTC were read as UTC silently: the
    thermal model was fitted to temperatures an hour off (0.050 mm where 0.029 was right; newcomer pass 8)."""

    poses = good_poses(kr16)
    write(tmp_path / "zoned", poses)
    write(tmp_path / "zoned", good_temperatures(kr16), stem="temperatures")
    assert read_campaign(tmp_path / "zoned", kr16).reading_notes() == []
    poses["timestamp"] = poses["timestamp"].str.rstrip("Z")  # the same instants, without their zone
    write(tmp_path / "naive", poses)
    write(tmp_path / "naive", good_temperatures(kr16), stem="temperatures")
    (note,) = read_campaign(tmp_path / "naive", kr16).reading_notes()
    assert "poses.csv gives its timestamps without a time zone" in note and "read as UTC" in note
    t = good_temperatures(kr16)
    t["timestamp"] = t["timestamp"].str.rstrip("Z")
    write(tmp_path / "naive", t, stem="temperatures")  # both without: one reading, nothing to say
    assert read_campaign(tmp_path / "naive", kr16).reading_notes() == []
