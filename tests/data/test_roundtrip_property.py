"""Property test of the data door: any valid campaign survives read -> to_frame -> write -> read.

Random campaigns (pose ids measured again later, several targets, optional orientation / torque / current /
direction blocks, extra columns, a user split) in CSV or Parquet. Needs hypothesis (a dev dependency).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from robocal.data import read_campaign
from robocal.robot import load_robot

hypothesis = pytest.importorskip("hypothesis")
st = pytest.importorskip("hypothesis.strategies")

ROBOT = load_robot("kr16_2")
START = pd.Timestamp("2026-01-05T07:00:00Z")


@st.composite
def campaigns(draw):
    n = ROBOT.n_joints
    lim = np.degrees(ROBOT.q_limits)
    n_poses = draw(st.integers(1, 6))
    targets = draw(st.lists(st.sampled_from(["T1", "T2", "SMR_3"]), min_size=1, max_size=3, unique=True))
    repeats = draw(st.integers(1, 2))
    q = [
        [draw(st.floats(float(lim[j, 0]), float(lim[j, 1]), allow_nan=False)) for j in range(n)] for _ in range(n_poses)
    ]
    coord = st.floats(-5000.0, 5000.0, allow_nan=False, allow_infinity=False)
    rows = []
    t = 0.0
    for _ in range(repeats):
        for i in range(n_poses):
            for tg in targets:
                t += draw(st.floats(0.001, 3600.0))  # strictly later: no duplicated (pose, target, time)
                p = [draw(coord), draw(coord), draw(st.floats(20.0, 5000.0))]  # >= 20 mm from the tracker
                rows.append({"pose_id": f"P{i}", "t": t, "target": tg, "q": q[i], "p": p})
    m = len(rows)
    d: dict[str, object] = {
        "pose_id": [r["pose_id"] for r in rows],
        # millisecond timestamps: ISO text and Parquet both carry them exactly
        "timestamp": [START + pd.Timedelta(milliseconds=round(1000 * r["t"])) for r in rows],
        "target": [r["target"] for r in rows],
    }
    for j in range(n):
        d[f"q{j + 1}_deg"] = [r["q"][j] for r in rows]
    for k, c in enumerate(("x_mm", "y_mm", "z_mm")):
        d[c] = [r["p"][k] for r in rows]
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if draw(st.booleans()):
        quat = rng.normal(size=(m, 4))
        quat /= np.linalg.norm(quat, axis=1, keepdims=True)
        for k, c in enumerate(("qw", "qx", "qy", "qz")):
            d[c] = quat[:, k]
    if draw(st.booleans()):
        d["payload_kg"] = rng.uniform(0, 16, m)
    for fmt, gen in (("tau{}_Nm", lambda: rng.normal(0, 80, m)), ("i{}_A", lambda: rng.normal(0, 4, m))):
        if draw(st.booleans()):
            for j in range(n):
                d[fmt.format(j + 1)] = gen()
    if draw(st.booleans()):
        for j in range(n):
            d[f"dir{j + 1}"] = rng.choice([-1.0, 1.0], m)
    if draw(st.booleans()):
        d["split"] = rng.choice(["calibration", "validation"], m)
    if draw(st.booleans()):
        d["note"] = [f"n{k}" for k in range(m)]
    df = pd.DataFrame(d)
    df["timestamp"] = pd.to_datetime(df["timestamp"], utc=True)
    return df


def _write(folder: Path, df: pd.DataFrame, fmt: str) -> None:
    folder.mkdir()
    if fmt == "csv":
        out = df.copy()
        out["timestamp"] = out["timestamp"].dt.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        out.to_csv(folder / "poses.csv", index=False)
    else:
        df.to_parquet(folder / "poses.parquet", index=False)


@hypothesis.settings(max_examples=25, deadline=None)
@hypothesis.given(
    df=campaigns(), fmt_in=st.sampled_from(["csv", "parquet"]), fmt_out=st.sampled_from(["csv", "parquet"])
)
def test_read_to_frame_write_read_round_trip(df, fmt_in, fmt_out):
    with tempfile.TemporaryDirectory() as d:
        _write(Path(d) / "a", df, fmt_in)
        a = read_campaign(Path(d) / "a", ROBOT)
        # the door read what was written (units converted once: deg -> rad, mm kept)
        np.testing.assert_allclose(a.q, np.radians(df[[f"q{j + 1}_deg" for j in range(6)]].to_numpy()), atol=1e-15)
        np.testing.assert_allclose(a.p_mm, df[["x_mm", "y_mm", "z_mm"]].to_numpy(), rtol=1e-15, atol=1e-12)
        frame = a.to_frame()
        _write(Path(d) / "b", frame, fmt_out)
        b = read_campaign(Path(d) / "b", ROBOT)
    np.testing.assert_array_equal(a.pose_id, b.pose_id)
    np.testing.assert_array_equal(a.target, b.target)
    assert a.target_names == b.target_names
    # deg -> rad -> deg may move the last bit of a double: 1e-12 deg is far below any encoder
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=np.radians(1e-12))
    np.testing.assert_allclose(a.p_mm, b.p_mm, rtol=1e-15, atol=1e-12)
    np.testing.assert_allclose(a.timestamp_s, b.timestamp_s, rtol=0, atol=1e-6)  # µs, the text format's resolution
    for name in ("quat", "tau_Nm", "current_A", "direction"):
        va, vb = getattr(a, name), getattr(b, name)
        assert (va is None) == (vb is None), name
        if va is not None:
            np.testing.assert_allclose(va, vb, rtol=1e-15, atol=1e-15, err_msg=name)
    np.testing.assert_allclose(a.payload_kg, b.payload_kg, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(a.split, b.split)
    assert set(a.extra) == set(b.extra)
    for k in a.extra:
        np.testing.assert_array_equal(a.extra[k].astype(str), b.extra[k].astype(str))
