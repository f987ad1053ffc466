"""``plan_poses``: choose the calibration poses before the tracker is switched on.

Steps: draw candidates in the joint ranges -> refuse what the cell does not allow (counted by reason,
:mod:`robocal.plan.constraints`) -> the identification Jacobian of every accepted candidate from the
calibration model (:meth:`CalibrationModel.residuals_and_jacobian`, whitened by the tracker noise) -> the
identifiable parameter set (:func:`robocal.identification.identifiability.analyse`, same priority order and
rank tolerance as the calibration) -> exchange for the D-, A- or I-optimal design
(:mod:`robocal.plan.design`; a robot with a linear axis, a track or a column, has its axis errors along the
travel in the model too, Legendre orders up to :data:`robocal.calibration.axes.ORDER`: the design spreads the
poses along the travel to determine them, :func:`axis_blocks`) -> predictions: Cramér-Rao standard errors
``σ²(JᵀWJ)⁻¹``, the predicted error map over the validation region, and the number of poses needed for a
stated accuracy.

All randomness comes from ``config.seed`` through named child streams of one ``numpy.random.SeedSequence``:
the same robot, settings and seed give the same plan, byte for byte.

The problem and its Jacobian blocks are built by :mod:`robocal.plan.problem`, the validation region by
:mod:`robocal.plan.region`, the predictions by :mod:`robocal.plan.prediction` (issue 32); their names are
importable from here as before.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.identification.identifiability import PRIORITY, ParameterSpec, analyse
from robocal.identification.model import FitData
from robocal.kinematics.chain import build_chain
from robocal.kinematics.transforms import matrix_to_rotvec
from robocal.plan.config import PlanConfig
from robocal.plan.constraints import sample_configurations, sampling_limits, screen
from robocal.plan.design import exchange
from robocal.plan.prediction import poses_needed_curve, predict, region_rms
from robocal.plan.problem import (
    RELAX,
    Problem,
    _model,
    _nothing_left,
    as_robot,
    axis_blocks,
    axis_terms_of,
    jacobian_blocks,
    rng_stream,
)
from robocal.plan.region import cell_from_scenario, region_configurations
from robocal.robot import RobotDescription

_IDENT_SUBSET = 2000  # candidates whose stacked Jacobian decides the identifiable set and the column scale
_N_RANDOM = 20  # random designs averaged for the baseline


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


__all__ = [
    "RELAX",
    "PlanResult",
    "Problem",
    "as_robot",
    "axis_blocks",
    "axis_terms_of",
    "build_problem",
    "cell_from_scenario",
    "jacobian_blocks",
    "plan_poses",
    "poses_needed_curve",
    "predict",
    "random_poses",
    "region_configurations",
    "region_rms",
    "rng_stream",
]
