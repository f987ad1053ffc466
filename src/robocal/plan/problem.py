"""The planning problem: the candidates, their identification Jacobian blocks from the calibration model (with
a linear axis's terms along the travel, :func:`axis_blocks`) and the plan's named random streams
(:func:`rng_stream`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.identification.model import CalibrationModel, FitData
from robocal.plan.config import PlanConfig
from robocal.plan.constraints import REASONS, Screened
from robocal.robot import RobotDescription, load_robot, robot_from_dict

#: the settings that relax each refusal reason (named in the error when nothing is left)
RELAX = {
    "joint_limits": "joint_margin_deg",
    "singularity": "singularity.min_sigma",
    "wrist": "singularity.min_wrist_deg",
    "volume": "volume",
    "self_collision": "collision.radius_mm",
    "tracker_range": "tracker.min_range_mm / tracker.max_range_mm / tracker.position_mm",
    "line_of_sight": "tracker.acceptance_half_angle_deg",
}


def rng_stream(seed: int, name: str) -> np.random.Generator:
    """A named child stream of the plan's seed (independent of the order streams are used in)."""
    key = tuple(int(b) for b in name.encode())
    return np.random.default_rng(np.random.SeedSequence(entropy=int(seed), spawn_key=key))


@dataclass
class Problem:
    """What the design works on: accepted candidates, their Jacobian blocks, the region, the parameter set.

    F : (C, r, p) whitened, column-scaled blocks; scale : (p,) column scale ``s`` (physical = s · scaled);
    names / units : identifiable parameters; G : (V, 3, p) scaled position Jacobians of the region;
    L : (p, p) ``mean GᵀG``; region_q : (V, n) rad; region_xyz : (V, 3) tool point (base frame, mm).
    """

    robot: RobotDescription
    config: PlanConfig
    cand: Screened
    F: np.ndarray
    scale: np.ndarray
    names: tuple[str, ...]
    units: tuple[str, ...]
    eliminated: list[dict[str, Any]]
    region_q: np.ndarray
    region_xyz: np.ndarray
    G: np.ndarray
    L: np.ndarray
    rows_per_pose_min: int
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def p(self) -> int:
        return int(self.F.shape[-1])

    @property
    def n_min(self) -> int:
        """Fewest poses with more measured coordinates than identifiable parameters (one degree of freedom)."""
        return int(math.floor(self.p / self.rows_per_pose_min) + 1)


def _model(robot: RobotDescription, cfg: PlanConfig) -> tuple[CalibrationModel, np.ndarray]:
    names = tuple(t.name for t in cfg.targets)
    model = CalibrationModel(robot, names, orientation=cfg.orientation)
    x0 = model.zeros()
    tools = np.array([t.position_mm for t in cfg.targets])
    x0[model.n_chain : model.n_chain + 3 * len(names)] = tools.ravel()
    return model, x0


def jacobian_blocks(
    model: CalibrationModel, x0: np.ndarray, q: np.ndarray, visible: np.ndarray, cfg: PlanConfig, chunk: int = 20000
) -> np.ndarray:
    """Whitened identification Jacobian per candidate and target: ``(C, K · r_t, n_params)``, zero rows for
    targets the tracker does not see (``r_t`` = 3, or 6 with orientation)."""
    C = q.shape[0]
    K = len(cfg.targets)
    rt = 6 if cfg.orientation else 3
    out = np.zeros((C, K * rt, model.n))
    w_pos = 1.0 / cfg.noise_mm
    w_rot = 1.0 / np.deg2rad(cfg.noise_deg)
    for s in range(0, C, chunk):
        qc = q[s : s + chunk]
        m = qc.shape[0]
        for k in range(K):
            ti = np.full(m, k, dtype=int)
            p, R = model.predict(x0, qc, ti)
            data = FitData(q=qc, p_mm=p, target_index=ti, R_meas=R if cfg.orientation else None)
            _, J = model.residuals_and_jacobian(x0, data)
            blk = out[s : s + m, k * rt : (k + 1) * rt]
            blk[:, :3] = J[: 3 * m].reshape(m, 3, model.n) * w_pos
            if cfg.orientation:
                blk[:, 3:] = J[3 * m :].reshape(m, 3, model.n) * w_rot
            blk *= visible[s : s + m, k][:, None, None]
    return out


def axis_terms_of(robot: RobotDescription) -> list[Any]:
    """The axis error terms a plan designs for (:mod:`robocal.calibration.axes`): every component of every
    linear axis up to :data:`~robocal.calibration.axes.ORDER`, no bending (a property of the load, not of the
    travel); none for a robot without a linear axis."""
    from robocal.calibration.axes import ORDER, AxisSettings, axis_terms

    return axis_terms(robot, AxisSettings(), ORDER, False) if robot.has_prismatic else []


def axis_blocks(
    model: CalibrationModel, x0: np.ndarray, q: np.ndarray, visible: np.ndarray, cfg: PlanConfig, terms: list[Any]
) -> np.ndarray:
    """Whitened identification Jacobian of the axis error terms, per candidate and target, as
    :func:`jacobian_blocks`: ``(C, K · r_t, T)``; the carriage element's column times the term's feature."""
    import copy

    from robocal.calibration.axes import features
    from robocal.identification.model import with_base
    from robocal.kinematics.axes import augment

    C, n = q.shape
    K = len(cfg.targets)
    rt = 6 if cfg.orientation else 3
    out = np.zeros((C, K * rt, len(terms)))
    if not terms:
        return out
    joints = sorted({t.joint for t in terms})
    aug = copy.copy(model)
    aug.chain = augment(model.chain, joints)
    aug.full_chain = with_base(aug.chain)
    F = features(model.robot, q, np.zeros(C), terms)
    cols = [n + 6 * t.axis_pos + t.slot for t in terms]
    qa = np.concatenate([q, np.zeros((C, 6 * len(joints)))], axis=1)
    for k in range(K):
        ti = np.full(C, k, dtype=int)
        p, R = model.predict(x0, q, ti)
        J_q, W_q = aug.joint_jacobians(
            x0, FitData(q=qa, p_mm=p, target_index=ti, R_meas=R if cfg.orientation else None)
        )
        blk = out[:, k * rt : (k + 1) * rt]
        blk[:, :3] = J_q[:, :, cols] * F[:, None, :] / cfg.noise_mm
        if cfg.orientation and W_q is not None:
            blk[:, 3:] = W_q[:, :, cols] * F[:, None, :] / np.deg2rad(cfg.noise_deg)
        blk *= visible[:, k][:, None, None]
    return out


def _nothing_left(screened: Screened, what: str) -> ConfigError:
    worst = max(REASONS, key=lambda r: screened.refused[r])
    counts = {r: c for r, c in screened.refused.items() if c}
    return ConfigError(
        f"no {what} satisfies the constraints: all {screened.n_sampled} sampled configurations were refused "
        f"({counts}); most by '{worst}': relax the '{RELAX[worst]}' plan setting"
    )


def as_robot(robot: RobotDescription | str | Mapping[str, Any]) -> RobotDescription:
    """A description from itself, a name / YAML path, or a mapping (the pipeline's ``robot`` section)."""
    if isinstance(robot, RobotDescription):
        return robot
    if isinstance(robot, Mapping):
        return robot_from_dict(dict(robot), source="params: robot")
    return load_robot(robot)
