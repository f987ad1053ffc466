"""Where the plan's poses may lie: the cell a scenario describes (:func:`cell_from_scenario`) and the validation
region's joint configurations (:func:`region_configurations`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.plan.config import PlanConfig
from robocal.plan.constraints import Screened, sample_configurations, sampling_limits, screen
from robocal.plan.problem import _nothing_left, rng_stream
from robocal.robot import RobotDescription


def cell_from_scenario(scenario: Mapping[str, Any]) -> dict[str, Any]:
    """Plan settings describing the twin's cell of a scenario: tracker position in the robot base frame (from
    ``tracker.xyz_mm`` / ``rpy_deg``, the base in the tracker frame), the targets (normal along flange z), the
    noise, orientation (6-DoF probe), the joint ranges and the number of calibration poses."""
    from robocal.kinematics.transforms import homogeneous, inv_transform, matrix_from_rpy

    tr = dict(scenario.get("tracker") or {})
    T = homogeneous(
        matrix_from_rpy(np.deg2rad(np.asarray(tr.get("rpy_deg", [0.3, -0.5, 135.0]), dtype=float))),
        np.asarray(tr.get("xyz_mm", [2500.0, 1200.0, -350.0]), dtype=float),
    )
    out: dict[str, Any] = {"tracker": {"position_mm": inv_transform(T)[:3, 3].tolist()}}
    targets = scenario.get("targets") or {"T1": [0.0, 0.0, 120.0]}
    out["targets"] = {str(k): {"position_mm": list(v), "normal": [0.0, 0.0, 1.0]} for k, v in targets.items()}
    for src, dst in (("noise_mm", "noise_mm"), ("orientation", "orientation"), ("n_poses", "n_poses")):
        if scenario.get(src) is not None:
            out[dst] = scenario[src]
    if scenario.get("orientation") and scenario.get("noise_deg") is not None:
        out["noise_deg"] = scenario["noise_deg"]
    if scenario.get("joint_ranges_deg") is not None:
        out["ranges_deg"] = scenario["joint_ranges_deg"]
    return out


def _working_range_config(cfg: PlanConfig) -> PlanConfig:
    """``cfg`` with only the robot's own checks left (joint margin, self-collision): no tracker, volume or
    singularity check (the robot works where the tracker cannot see)."""
    from dataclasses import replace

    from robocal.plan.config import SingularityConfig, TrackerConfig, VolumeConfig

    return replace(
        cfg,
        tracker=TrackerConfig(acceptance_half_angle_deg=180.0, min_range_mm=0.0, max_range_mm=1e12),
        volume=VolumeConfig(),
        singularity=SingularityConfig(min_sigma=0.0, min_wrist_deg=0.0),
    )


def _region_poses(robot: RobotDescription, poses: str | tuple[tuple[float, ...], ...]) -> np.ndarray:
    """The ``region.poses`` configurations (rad): a list in degrees or a CSV file with ``q1_deg ..`` columns."""
    n = robot.n_joints
    where = "region.poses"
    if isinstance(poses, str):
        import pandas as pd

        from robocal.errors import DataError

        path = poses
        try:
            df = pd.read_csv(path)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{where}: cannot read the CSV file {path!r}: {exc}") from exc
        cols = [f"q{j + 1}_deg" for j in range(n)]
        missing = [c for c in cols if c not in df.columns]
        if missing:
            raise DataError(f"{path}: region poses need the columns {cols}; missing {missing}")
        q = df[cols].to_numpy(dtype=float)
        bad = np.argwhere(~np.isfinite(q))
        if len(bad):
            r, c = bad[0]
            raise DataError(f"{path}: row {int(r) + 2}, column {cols[c]}: not a number ({df[cols[c]].iloc[r]!r})")
        where = path
    else:
        rows = [tuple(r) for r in poses]
        wrong = [k for k, r in enumerate(rows) if len(r) != n]
        if wrong:
            raise ConfigError(
                f"region.poses[{wrong[0]}]: must give {n} joint angles in degrees; got {len(rows[wrong[0]])}"
            )
        q = np.asarray(rows, dtype=float).reshape(-1, n)
    if len(q) == 0:
        raise ConfigError(f"{where}: no poses")
    lim = np.rad2deg(robot.q_limits)
    out = np.argwhere((q < lim[:, 0] - 1e-9) | (q > lim[:, 1] + 1e-9))
    if len(out):
        r, j = out[0]
        raise ConfigError(
            f"{where}: pose {int(r)}: q{j + 1} = {q[r, j]:g} deg is outside the joint limits "
            f"[{lim[j, 0]:g}, {lim[j, 1]:g}] of {robot.name}"
        )
    return np.deg2rad(q)


def region_configurations(robot: RobotDescription, chain: Any, cfg: PlanConfig, limits: np.ndarray) -> np.ndarray:
    """``region.n`` configurations (rad) of the region the plan is made for (:class:`RegionConfig`), drawn from
    the plan's ``region`` stream (the given ones for ``poses``). ``limits``: the candidates' joint ranges."""
    reg = cfg.region
    if reg.kind == "poses":
        assert reg.poses is not None
        return _region_poses(robot, reg.poses)
    if reg.kind == "cell":
        checks = cfg
        lim = sampling_limits(robot, reg.ranges_deg) if reg.ranges_deg is not None else limits
    else:
        checks = _working_range_config(cfg)
        lim = sampling_limits(robot, reg.ranges_deg if reg.kind == "joints" else None)
    box = None
    if reg.kind == "box":
        assert reg.min_mm is not None and reg.max_mm is not None
        box = np.asarray(reg.min_mm), np.asarray(reg.max_mm)
    rrng = rng_stream(cfg.seed, "region")
    got: list[np.ndarray] = []
    drawn = 0
    last: Screened | None = None
    cap = (1000 if box is not None else 200) * reg.n  # a small box is hit by few configurations
    while sum(len(g) for g in got) < reg.n and drawn < cap:
        batch = max(4 * reg.n, 2000)
        last = screen(robot, chain, sample_configurations(lim, batch, rrng), checks)
        drawn += batch
        q = last.q
        if box is not None:
            xyz = last.targets_mm[:, 0]
            q = q[np.all((xyz >= box[0]) & (xyz <= box[1]), axis=1)]
        got.append(q)
    qv = np.concatenate(got)[: reg.n] if got else np.zeros((0, robot.n_joints))
    if len(qv) == 0:
        assert last is not None
        if box is not None:
            raise ConfigError(
                f"region.min_mm / region.max_mm: the tool point of {robot.name} reaches no point of the box in "
                f"{drawn} configurations drawn in its working range; move or enlarge the box"
            )
        raise _nothing_left(last, f"configuration of the region ({reg.describe(cfg.joint_margin_deg)})")
    return qv
