"""The digital twin: writes measurement campaigns in the data contract, with a truth file.

A scenario (a mapping, e.g. ``conf/scenario/geometric.yaml``) says which robot, how many poses (or which:
``poses_deg`` / ``validation_poses_deg``, a list or a ``plan.csv`` path, see :func:`given_poses`),
the size of the geometric errors, where the tracker stands, which targets sit on the tool, the
tracker noise and which optional effects act. The true robot is the nominal one plus random
joint-level errors; effects add joint-angle offsets (compliance, gear errors, backlash) or make the
kinematic parameters drift (thermal). Every random number comes from ``numpy.random.default_rng(seed)``
through named child streams, and files are written with fixed formatting: the same scenario and seed
write the same bytes.

Effects are registered in :data:`EFFECTS` (name -> class); each implements :class:`Effect`.

The twin's parts (issue 32): :mod:`robocal.sim.effects` (the rows, the effect registry, gear, transmission and
backlash), :mod:`robocal.sim.scenario` (scenarios, their poses and settings), :mod:`robocal.sim.campaign_files`
(the files written); their names are importable from here as before.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.kinematics.chain import Chain, build_chain, propagate
from robocal.kinematics.transforms import matrix_to_quat, rotvec_to_matrix
from robocal.robot import RobotDescription, load_robot
from robocal.sim.campaign_files import _write_campaign
from robocal.sim.effects import (
    EFFECT_MODULES,
    EFFECTS,
    BacklashEffect,
    Effect,
    GearEffect,
    Rows,
    TransmissionEffect,
    TwinContext,
    load_effect_modules,
    register_effect,
)
from robocal.sim.scenario import GrossErrors, ScenarioConfig, given_poses, load_scenario, rng_factory, sample_poses


def simulate(
    scenario: Mapping[str, Any] | ScenarioConfig,
    out_dir: str | Path,
    seed: int | None = None,
    robot: RobotDescription | None = None,
) -> dict[str, Any]:
    """Write ``poses.csv`` (+ ``temperatures.csv``), ``truth.json`` and ``scenario.yaml`` into ``out_dir``.

    ``scenario`` : a scenario mapping (:func:`load_scenario`) or its :class:`ScenarioConfig`; ``seed`` replaces
    the scenario's; ``robot`` replaces the one it names. Returns the truth mapping.
    """
    if isinstance(scenario, ScenarioConfig):
        cfg = scenario if seed is None else replace(scenario, seed=int(seed))
    else:
        cfg = ScenarioConfig.from_mapping(scenario, seed)
    robot = robot or load_robot(cfg.robot)
    chain = build_chain(robot)
    rng = rng_factory(cfg.seed)
    g = rng("geometry")  # the true geometric errors
    eta = np.array(
        [g.normal(0, cfg.length_error_mm if k == "length" else cfg.angle_error_rad) for k in chain.param_kind]
    )
    tool_R = rotvec_to_matrix(rng("tool_rot").normal(0, 0.3, (len(cfg.target_names), 3)))
    rows = _plan(cfg, robot, chain.n_params, rng("poses"))
    truth = _truth(cfg, robot, chain, eta, tool_R)
    ctx = TwinContext(robot=robot, chain=chain, eta_true=eta, rng_factory=rng, truth=truth)
    rows = _apply_effects(cfg, rows, ctx)

    p, R = _true_points(cfg, chain, rows, eta, tool_R)
    if rows.fixed_points is not None:  # rows measuring a reflector on the part (a positioner), not the tool
        on_part = ~np.isnan(rows.fixed_points[:, 0])
        p[on_part] = rows.fixed_points[on_part]
    station_of = _stations(cfg, truth, rows, p, R)
    if rows.tracker_scale is not None:  # about the tracker head: the point in its station's frame
        p = p * (1.0 + rows.tracker_scale)[:, None]
    if rows.dp_tracker_mm is not None:
        p = p + rows.dp_tracker_mm
    noise = rng("noise")
    p_meas = p + noise.normal(0, cfg.noise_mm, p.shape)
    m = len(rows.pose_id)
    sigma_o = np.deg2rad(cfg.noise_deg)
    quat = matrix_to_quat(rotvec_to_matrix(noise.normal(0, sigma_o, (m, 3))) @ R) if cfg.orientation else None
    _gross_errors(cfg.gross_errors, truth, rows, p_meas, rng("gross"), list(cfg.target_names))
    _write_campaign(Path(out_dir), cfg, rows, p_meas, quat, station_of, ctx.temperature_log, truth, robot)
    return truth


def _plan(cfg: ScenarioConfig, robot: RobotDescription, n_params: int, rng: np.random.Generator) -> Rows:
    """The measurement plan: the calibration and validation poses, each measured on every target in turn."""
    n_cal, n_val = cfg.n_poses, cfg.n_validation_poses
    frac = cfg.joint_range_fraction
    q_cal = given_poses(cfg.poses_deg, robot, "poses_deg")
    q_val = given_poses(cfg.validation_poses_deg, robot, "validation_poses_deg")
    if q_cal is None and q_val is None:
        q_all = sample_poses(robot, n_cal + n_val, rng, frac, cfg.joint_ranges_deg)
    else:
        # a given pose list (e.g. robocal plan's plan.csv) replaces that split's part of the random draw; the
        # draw itself is the random design's, so the other split keeps the same poses (planned vs random
        # calibrations are validated on the same poses)
        drawn = sample_poses(robot, n_cal + n_val, rng, frac, cfg.joint_ranges_deg)
        q_cal = drawn[:n_cal] if q_cal is None else q_cal
        q_val = drawn[n_cal:] if q_val is None else q_val
        n_cal, n_val = len(q_cal), len(q_val)
        q_all = np.concatenate([q_cal, q_val])
    if robot.has_prismatic:  # a prismatic joint reports mm (1e-6 mm)
        q_all = np.where(robot.prismatic, np.round(q_all, 6), np.deg2rad(np.round(np.rad2deg(q_all), 6)))
    else:
        q_all = np.deg2rad(np.round(np.rad2deg(q_all), 6))  # what the controller reports, 1e-6 deg
    if robot.coupling is not None:  # drawn (or given) as the controller reports them, inside its limits
        q_all = robot.to_kinematic(q_all)
    K = len(cfg.target_names)
    pid = np.repeat(np.array([f"p{k:04d}" for k in range(n_cal + n_val)], dtype=object), K)
    m = len(pid)
    return Rows(
        pose_id=pid,
        split=np.repeat(np.array(["calibration"] * n_cal + ["validation"] * n_val, dtype=object), K),
        target_index=np.tile(np.arange(K), n_cal + n_val),
        q_cmd=np.repeat(q_all, K, axis=0),
        t_s=np.arange(m) * cfg.interval_s,
        payload_kg=np.full(m, cfg.payload_kg),
        dq=np.zeros((m, robot.n_joints)),
        deta=np.zeros((m, n_params)),
    )


def _truth(
    cfg: ScenarioConfig, robot: RobotDescription, chain: Chain, eta: np.ndarray, tool_R: np.ndarray
) -> dict[str, Any]:
    """The truth file's start: the true errors, tracker frame and tools (effects add theirs)."""
    names, kinds = chain.param_names, chain.param_kind
    return {
        "scenario": cfg.name,
        "seed": cfg.seed,
        "robot": robot.name,
        "kinematic_errors": {name: float(v) for name, v in zip(names, eta, strict=True)},
        "kinematic_units": {name: ("mm" if k == "length" else "rad") for name, k in zip(names, kinds, strict=True)},
        "tracker_T_base": cfg.tracker_T_base.tolist(),
        "tools_mm": {t: cfg.tools_mm[k].tolist() for k, t in enumerate(cfg.target_names)},
        "tool_rotations": {t: tool_R[k].tolist() for k, t in enumerate(cfg.target_names)},
        "noise_mm": cfg.noise_mm,
    }


def _apply_effects(cfg: ScenarioConfig, rows: Rows, ctx: TwinContext) -> Rows:
    """The scenario's effects (:data:`EFFECTS`): each may change the plan, then each acts on the rows."""
    effects: list[Effect] = []
    if cfg.effects:
        load_effect_modules()
    for name, ecfg in cfg.effects.items():
        if ecfg in (None, False):
            continue
        if name not in EFFECTS:
            raise ConfigError(f"unknown twin effect {name!r}; known effects: {sorted(EFFECTS)}")
        effects.append(EFFECTS[name](ecfg if isinstance(ecfg, Mapping) else {}))
    for eff in effects:
        rows = eff.plan(rows, ctx)
    for eff in effects:
        eff.apply(rows, ctx)
    return rows


def _true_points(
    cfg: ScenarioConfig, chain: Chain, rows: Rows, eta: np.ndarray, tool_R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """True target points (m, 3) and orientations (m, 3, 3) in the tracker frame, grouped by identical drift."""
    m = len(rows.pose_id)
    q_true = rows.q_cmd + rows.dq
    if rows.axis_error:  # the carriages' errors: pseudo joints of the augmented chain (robocal.kinematics.axes)
        from robocal.kinematics.axes import augment

        joints = sorted(rows.axis_error)
        chain = augment(chain, joints)
        q_true = np.concatenate([q_true, *(rows.axis_error[j] for j in joints)], axis=1)
    p = np.zeros((m, 3))
    R = np.zeros((m, 3, 3))
    keys, inv = np.unique(np.round(rows.deta, 15), axis=0, return_inverse=True)
    inv = inv.ravel()
    for g_i in range(len(keys)):
        sel = inv == g_i
        st = propagate(chain, q_true[sel], eta + rows.deta[np.flatnonzero(sel)[0]], cfg.tracker_T_base)
        t = cfg.tools_mm[rows.target_index[sel]]
        if rows.dtool_mm is not None:
            t = t + rows.dtool_mm[sel]
        p[sel] = st.o + st.x * t[:, 0:1] + st.y * t[:, 1:2] + st.z * t[:, 2:3]
        R[sel] = st.R @ tool_R[rows.target_index[sel]]
    if rows.base_scale is not None:  # the robot grown about its base's origin (thermal expansion): T S T^-1
        T = cfg.tracker_T_base
        t0 = T[:3, 3]
        p = t0 + (p - t0) * (1.0 + rows.base_scale)[:, None]
    if rows.base_rotvec is not None:  # the base turned about its own origin (a compliant stand): T R(w) T^-1
        T = cfg.tracker_T_base
        Rt, t0 = T[:3, :3], T[:3, 3]
        Rw = rotvec_to_matrix(rows.base_rotvec)
        pb = (p - t0) @ Rt  # base frame
        p = np.einsum("ij,mj->mi", Rt, np.einsum("mij,mj->mi", Rw, pb)) + t0
        R = Rt @ Rw @ Rt.T @ R
    return p, R


def _stations(
    cfg: ScenarioConfig, truth: dict[str, Any], rows: Rows, p: np.ndarray, R: np.ndarray
) -> np.ndarray | None:
    """``stations: {S2: {xyz_mm, rpy_deg}, ...}``: more tracker placements besides ``tracker`` (station S1).
    Pose number k (in plan order) is measured from station ``k mod S`` — or from the station an effect gave the
    row (``rows.station``, the placements in ``truth["stations_T_base"]``: :mod:`robocal.sim.session`); ``p`` and
    ``R`` are moved into that station's frame in place. Returns the station of every row, or None without extra
    stations."""
    T_base = cfg.tracker_T_base
    if rows.station is not None:  # an effect measured the rows from its own stations (robocal.sim.session)
        if cfg.stations:
            raise ConfigError("The 'stations' scenario setting cannot be combined with an effect that sets stations")
        placed = dict(truth["stations_T_base"])
        names = list(placed)
        Ts = [np.asarray(placed[nm], dtype=float) for nm in names]
        st = np.array([names.index(str(s)) for s in rows.station])
    elif not cfg.stations:
        return None
    else:
        names = ["S1", *cfg.stations]
        Ts = [T_base, *cfg.stations.values()]
        poses = list(dict.fromkeys(map(str, rows.pose_id)))
        k_of = {pid: k for k, pid in enumerate(poses)}
        st = np.array([k_of[str(pid)] % len(names) for pid in rows.pose_id])
    inv_base = np.linalg.inv(T_base)
    for s in range(1, len(names)):
        sel = st == s
        D = Ts[s] @ inv_base
        p[sel] = p[sel] @ D[:3, :3].T + D[:3, 3]
        R[sel] = D[:3, :3] @ R[sel]
    truth["stations_T_base"] = {nm: T.tolist() for nm, T in zip(names, Ts, strict=True)}
    return np.array(names, dtype=object)[st]


def _gross_errors(
    cfg: GrossErrors, truth: dict[str, Any], rows: Rows, p_meas: np.ndarray, rng: np.random.Generator, tnames: list
) -> None:
    """``n`` calibration rows displaced in a random direction by a magnitude uniform in ``[min_mm, max_mm]`` (a
    beam break, a bumped reflector). Listed in the truth."""
    n = cfg.n
    if n <= 0:
        return
    lo, hi = cfg.min_mm, cfg.max_mm
    cal = np.flatnonzero(np.asarray(rows.split) == "calibration")
    if n > len(cal):
        raise ConfigError(f"The 'gross_errors.n' scenario setting asks for {n} rows; the campaign has {len(cal)}")
    pick = np.sort(rng.choice(cal, size=n, replace=False))
    out = []
    for i in pick:
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        mag = rng.uniform(lo, hi)
        p_meas[i] += mag * u
        out.append(
            {
                "row": int(i) + 2,
                "pose_id": str(rows.pose_id[i]),
                "target": tnames[int(rows.target_index[i])],
                "magnitude_mm": float(mag),
            }
        )
    truth["gross_errors"] = out


__all__ = [
    "EFFECTS",
    "EFFECT_MODULES",
    "BacklashEffect",
    "Effect",
    "GearEffect",
    "GrossErrors",
    "Rows",
    "ScenarioConfig",
    "TransmissionEffect",
    "TwinContext",
    "given_poses",
    "load_effect_modules",
    "load_scenario",
    "register_effect",
    "rng_factory",
    "sample_poses",
    "simulate",
]
