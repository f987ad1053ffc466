"""The UR10's other IPA series as robocal campaigns: held-out series of the robot in ../shared/data/ur10-ipa.

    git clone https://github.com/christianlandgraf/ipa-robot-accuracy IPA   # commit 507fba6 (MIT licence)
    python benchmarks/ipa_series.py --repo IPA --series C D --out /tmp/ipa
    python benchmarks/real_robots.py --data /tmp/ipa/ur10-C --data /tmp/ipa/ur10-D

Series B is ``../shared/data/ur10-ipa`` (this script, given ``B``, writes the same rows, joints, positions,
orientations, ``u_mm`` and split as that folder: checked to 5e-7). Series C is 2 773 random poses from the same
tracker placement, with joint-1 angles B never visits; series D (March 2021, 632 poses on ISO cubes) is from another
tracker placement; series A (July 2020, 11 910 grid poses) has no per-point standard deviations. Each is written as
in ``../shared/data/ur10-ipa/README.md``: the T-Mac orientation from upstream's intrinsic XYZ Euler angles, scalar
first with ``qw >= 0``; ``u_mm`` = 2 x the RMS of the three per-axis standard deviations; synthetic timestamps 10 s
apart in file order (upstream's were rounded away by a spreadsheet); the air temperature as ``T_air_C``; a 70/30
split by joint configuration (joints within 1e-4 rad), seed 20211018; upstream's LICENSE.md beside the data.
The robot description is ``../shared/data/ur10-ipa/robot.yaml``.
"""

from __future__ import annotations

import argparse
import io
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

HERE = Path(__file__).resolve().parent
UR10 = HERE.parent.parent / "shared" / "data" / "ur10-ipa"
FILES = {
    "A": "Series_A/measurements_grid.csv",
    "B": "Series_B/measurements_joint_configurations.csv",
    "C": "Series_C/measurements_random_poses.csv",
    "D": "Series_D/measurements_iso_cubes.csv",
}
JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]


def configurations(q: np.ndarray, tol_rad: float = 1e-4) -> np.ndarray:
    """``(m,)`` configuration index of each row: rows whose joints all agree within ``tol_rad`` share one."""
    out = np.full(len(q), -1)
    reps: list[int] = []
    for i in range(len(q)):
        for k, r in enumerate(reps):
            if np.abs(q[i] - q[r]).max() <= tol_rad:
                out[i] = k
                break
        else:
            out[i] = len(reps)
            reps.append(i)
    return out


def convert(repo: Path, series: str, out: Path, val_frac: float = 0.3, seed: int = 20211018) -> pd.DataFrame:
    raw = subprocess.run(["git", "-C", str(repo), "show", f"HEAD:{FILES[series]}"], capture_output=True, check=True)
    df = pd.read_csv(io.BytesIO(raw.stdout), sep=";", decimal=",")
    m = len(df)
    q = df[JOINTS].to_numpy(float)
    xyzw = Rotation.from_euler("XYZ", df[["measurement_rx", "measurement_ry", "measurement_rz"]].to_numpy(float),
                               degrees=True).as_quat()  # fmt: skip
    wxyz = np.column_stack([xyzw[:, 3], xyzw[:, :3]])
    wxyz *= np.where(wxyz[:, :1] < 0, -1.0, 1.0)
    cfg = configurations(q)
    nc = int(cfg.max()) + 1
    val = np.zeros(nc, dtype=bool)
    val[np.random.default_rng(seed).permutation(nc)[: round(val_frac * nc)]] = True
    ts = (pd.Timestamp("2020-11-01T00:00:00Z") + pd.to_timedelta(np.arange(m) * 10, unit="s")).strftime(
        "%Y-%m-%dT%H:%M:%SZ"
    )
    poses = pd.DataFrame(
        {
            "pose_id": [f"{series}{i + 1:05d}" for i in range(m)],
            "timestamp": ts,
            "target": "TMAC",
            **{f"q{j + 1}_deg": np.rad2deg(q[:, j]) for j in range(6)},
            "x_mm": df["measurement_x"],
            "y_mm": df["measurement_y"],
            "z_mm": df["measurement_z"],
            "qw": wxyz[:, 0],
            "qx": wxyz[:, 1],
            "qy": wxyz[:, 2],
            "qz": wxyz[:, 3],
            "payload_kg": 0.0,
            "split": np.where(val[cfg], "validation", "calibration"),
            "config_id": [f"{series}{c:04d}" for c in cfg],
        }
    )
    if "measurement_std_x" in df:
        s = df[["measurement_std_x", "measurement_std_y", "measurement_std_z"]].to_numpy(float)
        poses["u_mm"] = 2.0 * np.sqrt((s**2).mean(axis=1))
    out.mkdir(parents=True, exist_ok=True)
    poses.to_csv(out / "poses.csv", index=False, float_format="%.9g")
    pd.DataFrame({"timestamp": ts, "T_air_C": df["measurement_temperature"]}).to_csv(
        out / "temperatures.csv", index=False
    )
    shutil.copy(UR10 / "robot.yaml", out / "robot.yaml")
    shutil.copy(repo / "LICENSE.md" if (repo / "LICENSE.md").exists() else UR10 / "LICENSE.md", out / "LICENSE.md")
    return poses


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repo", type=Path, required=True, help="a clone of christianlandgraf/ipa-robot-accuracy")
    ap.add_argument("--series", nargs="+", choices=sorted(FILES), default=["C", "D"])
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    for s in args.series:
        d = convert(args.repo, s, args.out / f"ur10-{s}")
        counts = d["split"].value_counts().to_dict()
        print(f"series {s}: {len(d)} rows, {d['config_id'].nunique()} configurations, {counts} -> {args.out}/ur10-{s}")


if __name__ == "__main__":
    main()
