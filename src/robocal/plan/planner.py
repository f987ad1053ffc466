"""``plan_poses``: choose the calibration poses before the tracker is switched on.

Steps: draw candidates in the joint ranges -> refuse what the cell does not allow (counted by reason,
:mod:`robocal.plan.constraints`) -> the identification Jacobian of every accepted candidate from the
calibration model (:meth:`CalibrationModel.residuals_and_jacobian`, whitened by the tracker noise) -> the
identifiable parameter set (:func:`robocal.identification.identifiability.analyse`, same priority order and
rank tolerance as the calibration) -> exchange for the D-, A- or I-optimal design
(:mod:`robocal.plan.design`; a robot with a linear axis, a track or a column, has its axis errors along the
travel in the model too, Legendre orders up to :data:`robocal.identification.axes.ORDER`: the design spreads the
poses along the travel to determine them, :func:`axis_blocks`) -> predictions: Cramér-Rao standard errors
``σ²(JᵀWJ)⁻¹``, the predicted error map over the validation region, and the number of poses needed for a
stated accuracy.

All randomness comes from ``config.seed`` through named child streams of one ``numpy.random.SeedSequence``:
the same robot, settings and seed give the same plan, byte for byte.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.identification.identifiability import PRIORITY, ParameterSpec, analyse
from robocal.identification.model import CalibrationModel, FitData
from robocal.kinematics.chain import build_chain
from robocal.kinematics.transforms import matrix_to_rotvec
from robocal.plan.config import PlanConfig
from robocal.plan.constraints import REASONS, Screened, sample_configurations, sampling_limits, screen
from robocal.plan.design import criterion_value, exchange, information, observability
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
_IDENT_SUBSET = 2000  # candidates whose stacked Jacobian decides the identifiable set and the column scale
_N_RANDOM = 20  # random designs averaged for the baseline


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
    """The axis error terms a plan designs for (:mod:`robocal.identification.axes`): every component of every
    linear axis up to :data:`~robocal.identification.axes.ORDER`, no bending (a property of the load, not of the
    travel); none for a robot without a linear axis."""
    from robocal.identification.axes import ORDER, AxisSettings, axis_terms

    return axis_terms(robot, AxisSettings(), ORDER, False) if robot.has_prismatic else []


def axis_blocks(
    model: CalibrationModel, x0: np.ndarray, q: np.ndarray, visible: np.ndarray, cfg: PlanConfig, terms: list[Any]
) -> np.ndarray:
    """Whitened identification Jacobian of the axis error terms, per candidate and target, as
    :func:`jacobian_blocks`: ``(C, K · r_t, T)``; the carriage element's column times the term's feature."""
    import copy

    from robocal.identification.axes import features
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


def build_problem(
    robot: RobotDescription | str | Mapping[str, Any],
    config: PlanConfig | Mapping[str, Any] | None = None,
    axis_terms: bool = True,
) -> Problem:
    """Candidates, constraints, Jacobian blocks, identifiable set and region for ``plan_poses`` (``axis_terms``:
    a linear axis's errors along its travel in the model, :func:`axis_terms_of`)."""
    cfg = config if isinstance(config, PlanConfig) else PlanConfig.from_mapping(config)
    robot = as_robot(robot)
    t0 = time.perf_counter()
    chain = build_chain(robot)
    limits = sampling_limits(robot, cfg.ranges_deg)
    q = sample_configurations(limits, cfg.n_candidates, rng_stream(cfg.seed, "candidates"))
    if robot.has_prismatic:  # a prismatic joint's value in mm: 1e-6 mm
        q = np.where(robot.prismatic, np.round(q, 6), np.deg2rad(np.round(np.rad2deg(q), 6)))
    else:
        q = np.deg2rad(np.round(np.rad2deg(q), 6))  # what plan.csv will say, 1e-6 deg
    if robot.coupling is not None:  # drawn as the controller reports them (its limits), planned as the kinematics
        q = robot.to_kinematic(q)
    cand = screen(robot, chain, q, cfg)
    if cand.n == 0:
        raise _nothing_left(cand, "candidate")
    t1 = time.perf_counter()

    model, x0 = _model(robot, cfg)
    Jb = jacobian_blocks(model, x0, cand.q, cand.visible, cfg)
    terms = axis_terms_of(robot) if axis_terms else []
    all_names, all_units = model.names, model.units
    if terms:  # the axis errors along the travel, after the calibration's parameters
        Jb = np.concatenate([Jb, axis_blocks(model, x0, cand.q, cand.visible, cfg, terms)], axis=2)
        all_names = (*all_names, *(t.name for t in terms))
        all_units = (*all_units, *(t.unit for t in terms))
    n_all = len(all_names)
    t2 = time.perf_counter()
    sub_rng = rng_stream(cfg.seed, "identifiability")
    sub = np.sort(sub_rng.choice(cand.n, size=min(_IDENT_SUBSET, cand.n), replace=False))
    Js = Jb[sub].reshape(-1, n_all)
    Js = Js[np.any(Js != 0.0, axis=1)]
    # the calibration's parameters, then the axis errors along the travel as candidates after them
    kinds = (*model.kinds, *(["axis"] * len(terms)))
    spec = ParameterSpec(all_names, kinds, all_units, tuple(cfg.fixed), "plan.fixed", priority=(*PRIORITY, ("axis",)))
    order = spec.keep_order()
    ident = analyse(Js, all_names, order, rtol=cfg.rank_tol)
    kept = np.sort(ident.kept)
    rms = np.sqrt(np.mean(Js[:, kept] ** 2, axis=0))
    scale = 1.0 / np.where(rms > 0, rms, 1.0)
    F = np.ascontiguousarray(Jb[:, :, kept] * scale)

    # the region the plan is made for (region.kind), from its own stream
    qv = region_configurations(robot, chain, cfg, limits)
    # position error of the first target (the tool point) at each region configuration: mm per scaled parameter
    tv = np.zeros(len(qv), dtype=int)
    pv, _ = model.predict(x0, qv, tv)
    _, Jv = model.residuals_and_jacobian(x0, FitData(q=qv, p_mm=pv, target_index=tv))
    Gv = Jv[: 3 * len(qv)].reshape(len(qv), 3, model.n)
    if terms:
        vcfg = replace(cfg, orientation=False, targets=cfg.targets[:1])
        Ga = axis_blocks(model, x0, qv, np.ones((len(qv), 1), dtype=bool), vcfg, terms) * cfg.noise_mm
        Gv = np.concatenate([Gv, Ga], axis=2)
    G = Gv[:, :, kept] * scale
    L = np.einsum("vip,viq->pq", G, G) / len(qv)
    t3 = time.perf_counter()
    units = tuple("deg" if all_units[i] == "rad" else all_units[i] for i in kept)
    return Problem(
        robot=robot,
        config=cfg,
        cand=cand,
        F=F,
        scale=scale,
        names=tuple(all_names[i] for i in kept),
        units=units,
        eliminated=[e.to_dict() for e in ident.eliminated],
        region_q=qv,
        region_xyz=pv,
        G=G,
        L=L,
        rows_per_pose_min=cfg.tracker.min_targets_visible * (6 if cfg.orientation else 3),
        timings={"candidates_s": t1 - t0, "jacobian_s": t2 - t1, "identifiability_region_s": t3 - t2},
    )


def predict(problem: Problem, idx: np.ndarray, rng: np.random.Generator | None = None) -> dict[str, Any]:
    """Cramér-Rao predictions for the design ``idx``: criteria, indices, standard errors, the region's errors.

    ``region_rms_mm`` is the predicted RMS 3-D position error of the calibrated model over the region (the
    square root of the I-criterion); ``region_mean_measured_mm`` adds the tracker noise, i.e. what a
    held-out measurement is expected to show on average (E|e|, e ~ N(0, Σ_v + σ²I), by sampling).
    """
    pr = problem
    M = information(pr.F, idx)
    out: dict[str, Any] = {
        "D_logdet": -criterion_value(M, "D"),
        "A_trace": criterion_value(M, "A"),
        "I_mean_var_mm2": criterion_value(M, "I", pr.L),
    }
    rows = pr.F[idx].reshape(-1, pr.p)
    rows = rows[np.any(rows != 0.0, axis=1)]
    out["observability"] = observability(rows)
    out["n_rows"] = int(rows.shape[0])
    if not np.isfinite(out["A_trace"]):
        return out
    cov_s = np.linalg.inv(M)
    cov = cov_s * np.outer(pr.scale, pr.scale)
    se = np.sqrt(np.diag(cov))
    se_disp = np.where(np.array(pr.units) == "deg", np.rad2deg(se), se)
    out["stderr"] = {n: float(v) for n, v in zip(pr.names, se_disp, strict=True)}
    Sv = np.einsum("vip,pq,vjq->vij", pr.G, cov_s, pr.G)  # (V, 3, 3) mm²
    var = np.trace(Sv, axis1=1, axis2=2)
    out["region_sigma_mm"] = np.sqrt(var)
    out["region_rms_mm"] = float(np.sqrt(var.mean()))
    out["region_max_mm"] = float(np.sqrt(var.max()))
    if rng is not None:
        z = rng.standard_normal((256, 3))
        Ch = np.linalg.cholesky(Sv + (problem.config.noise_mm**2) * np.eye(3))
        e = np.linalg.norm(np.einsum("vij,sj->vsi", Ch, z), axis=-1)
        out["region_mean_measured_mm"] = float(e.mean())
    return out


def _curve_grid(n: int, n_min: int, n_cand: int) -> list[int]:
    hi = min(max(4 * n, 120), n_cand)
    grid = np.unique(np.round(np.geomspace(n_min, hi, 10)).astype(int))
    return sorted({int(v) for v in grid if n_min <= v <= n_cand} | ({n} if n <= n_cand else set()))


def region_rms(problem: Problem, idx: np.ndarray) -> float | None:
    """Predicted RMS 3-D error of the calibrated model over the region (mm), or None when M is singular."""
    M = information(problem.F, idx)
    s, _ = np.linalg.slogdet(M)
    if s <= 0:
        return None
    try:
        cov_s = np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return None
    v = float(np.sum(cov_s * problem.L))
    return float(np.sqrt(v)) if v > 0 else None


def poses_needed_curve(
    problem: Problem, idx: np.ndarray, rng: np.random.Generator, n_sub: int = 5000, n_random: int = 5
) -> list[dict[str, Any]]:
    """Predicted RMS error over the region against the number of poses, planned and random.

    Each size is planned by the same exchange and criterion, warm-started from the previous size, over a
    random subset of ``n_sub`` accepted candidates plus the plan (so the curve is quick; with fewer choices
    it can only be slightly pessimistic). Random: the median of ``n_random`` draws from all accepted candidates.
    """
    pr = problem
    cfg = pr.config
    C = pr.cand.n
    sub = np.unique(np.concatenate([rng.choice(C, size=min(n_sub, C), replace=False), idx]))
    Fs = pr.F[sub]
    n = len(idx)
    rows = []
    prev = np.searchsorted(sub, idx)
    for N in _curve_grid(n, pr.n_min, len(sub)):  # a size is planned over the subset: at most its size
        if N == n:
            e_idx = idx
            prev = np.searchsorted(sub, idx)
        else:
            init = prev[:N] if len(prev) >= N else prev
            e = exchange(
                Fs, N, cfg.criterion, rng, L=pr.L, init=init, max_exchanges=cfg.max_exchanges, active_set=cfg.active_set
            )
            prev = e.idx
            e_idx = sub[e.idx]
        rr = [region_rms(pr, np.sort(rng.choice(C, size=N, replace=False))) for _ in range(n_random)]
        rr_ok = [r for r in rr if r is not None]
        rows.append(
            {
                "n_poses": N,
                "planned_region_rms_mm": region_rms(pr, e_idx),
                "random_region_rms_mm": float(np.median(rr_ok)) if rr_ok else None,
                "random_singular": n_random - len(rr_ok),
            }
        )
    return rows


@dataclass
class PlanResult:
    """A planned pose set with the predictions made before measuring (see :func:`plan_poses`)."""

    problem: Problem
    idx: np.ndarray
    q: np.ndarray  # (n, N) rad, the planned poses
    visible: np.ndarray  # (n, K)
    prediction: dict[str, Any]
    random_baseline: dict[str, Any]
    curve: list[dict[str, Any]]
    n_needed: int | None
    exchange: dict[str, Any]
    orientation_spread: dict[str, float]
    timings: dict[str, float]

    @property
    def pose_ids(self) -> list[str]:
        return [f"plan{k:04d}" for k in range(len(self.idx))]

    def to_dict(self) -> dict[str, Any]:
        """Everything ``plan.json`` holds; no timings, so the same seed writes the same bytes."""
        pr = self.problem
        cfg = pr.config
        pred = {k: v for k, v in self.prediction.items() if k != "region_sigma_mm"}
        return {
            "robot": pr.robot.name,
            "n_poses": len(self.idx),
            "criterion": cfg.criterion,
            "seed": cfg.seed,
            "candidates": {
                "sampled": pr.cand.n_sampled,
                "accepted": pr.cand.n,
                "refused": pr.cand.refused,
                "failing": pr.cand.failing,
            },
            "identifiable": {
                "names": list(pr.names),
                "units": list(pr.units),
                "n": pr.p,
                "eliminated": pr.eliminated,
                "column_scale": {n: float(s) for n, s in zip(pr.names, pr.scale, strict=True)},
                "n_poses_min": pr.n_min,
            },
            "planned": pred,
            "random_baseline": self.random_baseline,
            "accuracy_mm": cfg.accuracy_mm,
            "n_needed_for_accuracy": self.n_needed,
            "curve": self.curve,
            "exchange": self.exchange,
            "orientation_spread": self.orientation_spread,
            "region": {
                "kind": cfg.region.kind,
                "optimal_for": cfg.region.describe(cfg.joint_margin_deg),
                "tool_point_min_mm": [round(float(v), 3) for v in pr.region_xyz.min(axis=0)],
                "tool_point_max_mm": [round(float(v), 3) for v in pr.region_xyz.max(axis=0)],
                "n": len(pr.region_q),
                "predicted_rms_mm": self.prediction.get("region_rms_mm"),
                "predicted_max_mm": self.prediction.get("region_max_mm"),
            },
            "targets_visible": {t.name: int(self.visible[:, k].sum()) for k, t in enumerate(cfg.targets)},
        }


def _spread(R: np.ndarray) -> dict[str, float]:
    """Spread of the tool orientations: angles (deg) from the chordal mean rotation; tool-z cone half-angle."""
    U, _, Vt = np.linalg.svd(R.sum(0))
    Rm = U @ np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))]) @ Vt
    ang = np.rad2deg(np.linalg.norm(matrix_to_rotvec(np.swapaxes(R, 1, 2) @ Rm), axis=1))
    z = R[:, :, 2]
    zm = z.mean(0)
    zm /= max(np.linalg.norm(zm), 1e-12)
    zang = np.rad2deg(np.arccos(np.clip(z @ zm, -1, 1)))
    return {
        "rms_deg": float(np.sqrt(np.mean(ang**2))),
        "max_deg": float(ang.max()),
        "tool_z_max_deg": float(zang.max()),
    }


def plan_poses(
    robot: RobotDescription | str | Mapping[str, Any],
    config: PlanConfig | Mapping[str, Any] | None = None,
    curve: bool = True,
) -> PlanResult:
    """Plan ``config.n_poses`` calibration poses for ``robot``.

    Parameters
    ----------
    robot : RobotDescription or str
        A description or a robot name / YAML path (``conf/robot/<name>.yaml``).
    config : PlanConfig or mapping, optional
        Settings (``conf/plan/default.yaml``); a mapping is validated (errors name the setting).
    curve : bool
        Also compute the poses-needed curve (a design per grid size).

    Raises
    ------
    ConfigError
        Unknown robot, a bad setting, ``n_poses`` below the identifiable minimum or above the feasible
        candidates, constraints that leave no candidate.
    """
    cfg = config if isinstance(config, PlanConfig) else PlanConfig.from_mapping(config)
    t0 = time.perf_counter()
    pr = build_problem(robot, cfg)
    n = cfg.n_poses
    if n < pr.n_min:
        raise ConfigError(
            f"The 'n_poses' plan setting must be at least {pr.n_min} for {pr.robot.name}: {pr.p} parameters are "
            f"identifiable and a pose measures at least {pr.rows_per_pose_min} coordinates. Got {n} instead."
        )
    if n > pr.cand.n:
        raise ConfigError(
            f"The 'n_poses' plan setting ({n}) exceeds the {pr.cand.n} candidates that satisfy the constraints "
            f"(of {pr.cand.n_sampled} sampled): raise 'n_candidates' or relax the constraints"
        )
    t1 = time.perf_counter()
    start_rng = rng_stream(cfg.seed, "start")
    ex = exchange(pr.F, n, "D", start_rng, max_exchanges=cfg.max_exchanges, active_set=cfg.active_set)
    if cfg.criterion != "D":
        ex = exchange(
            pr.F,
            n,
            cfg.criterion,
            start_rng,
            L=pr.L,
            init=ex.idx,
            max_exchanges=cfg.max_exchanges,
            active_set=cfg.active_set,
        )
    t2 = time.perf_counter()
    idx = ex.idx
    pred = predict(pr, idx, rng_stream(cfg.seed, "predict"))

    brng = rng_stream(cfg.seed, "random")
    base: list[dict[str, Any]] = []
    for _ in range(_N_RANDOM):
        base.append(predict(pr, np.sort(brng.choice(pr.cand.n, size=n, replace=False))))
    finite = [b for b in base if "region_rms_mm" in b]
    random_baseline: dict[str, Any] = {
        "n_designs": _N_RANDOM,
        "n_singular": _N_RANDOM - len(finite),
        "D_logdet_mean": float(np.mean([b["D_logdet"] for b in base])),
    }
    if finite:
        random_baseline.update(
            A_trace_mean=float(np.mean([b["A_trace"] for b in finite])),
            I_mean_var_mm2_mean=float(np.mean([b["I_mean_var_mm2"] for b in finite])),
            region_rms_mm_mean=float(np.mean([b["region_rms_mm"] for b in finite])),
            observability_mean={
                k: float(np.mean([b["observability"][k] for b in finite])) for k in finite[0]["observability"]
            },
            stderr_mean={k: float(np.mean([b["stderr"][k] for b in finite])) for k in pr.names},
        )

    rows: list[dict[str, Any]] = []
    n_needed = None
    if curve:
        rows = poses_needed_curve(pr, idx, rng_stream(cfg.seed, "curve"))
        ok = [
            r["n_poses"]
            for r in rows
            if r["planned_region_rms_mm"] is not None and r["planned_region_rms_mm"] <= cfg.accuracy_mm
        ]
        n_needed = min(ok) if ok else None
    t3 = time.perf_counter()
    timings = {
        **pr.timings,
        "setup_s": t1 - t0,
        "exchange_s": t2 - t1,
        "predictions_and_curve_s": t3 - t2,
        "total_s": t3 - t0,
    }
    spread = _spread(pr.cand.flange_R[idx])
    spread["min_required_deg"] = cfg.min_orientation_spread_deg
    spread["satisfied"] = bool(spread["rms_deg"] >= cfg.min_orientation_spread_deg)
    return PlanResult(
        problem=pr,
        idx=idx,
        q=pr.cand.q[idx],
        visible=pr.cand.visible[idx],
        prediction=pred,
        random_baseline=random_baseline,
        curve=rows,
        n_needed=n_needed,
        exchange={
            "criterion": cfg.criterion,
            "n_exchanges": ex.n_exchanges,
            "n_rounds": ex.n_rounds,
            "converged": ex.converged,
        },
        orientation_spread=spread,
        timings=timings,
    )


def random_poses(problem: Problem, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` distinct accepted candidates drawn uniformly: the random baseline under the same constraints."""
    return np.sort(rng.choice(problem.cand.n, size=n, replace=False))
