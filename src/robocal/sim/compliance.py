"""Twin effect ``compliance``: joint deflection under payload, with motor currents that include friction.

Modelled on Mao et al. (2021) (``../shared/papers/mao2021-joint-deformation.zh.md``): each reducer is a
linear torsion spring, ``dq_j = c_j · tau_j`` (eq. 20-21), where ``tau_j`` is the torque the reducer carries.

- Torques: the *true* gravity load torque (:func:`robocal.kinematics.gravity.gravity_torques`, sign convention
  there) computed with the twin's true link masses, which differ from the robot description's estimates by
  ``mass_error_sd`` (relative, 1 sigma, drawn per link), plus static friction left from the approach:
  ``tau_f = -dir_j (coulomb_j + viscous_j · approach_speed)`` (Coulomb + viscous at the sampling speed,
  opposite to the approach direction ``dir_j``). With ``friction_in_reducer`` (the paper's eq. 19-20) the
  reducer carries gravity + friction; otherwise gravity only (the friction sits on the motor side).
- Reported columns: motor currents ``i{j}_A = (tau_gravity + tau_f) / K_j`` + noise (the drive supplies the
  friction either way), ``K_j`` the joint torque per motor ampere (torque constant × gear ratio, sign included);
  optionally the drive's torque estimate ``tau{j}_Nm = K_nominal_j · i_j`` with ``K_nominal`` off by
  ``torque_constant_error_sd``; the approach directions ``dir{j}`` (unless another effect wrote them).
- Plan (:meth:`ComplianceEffect.plan`): the same calibration poses measured at every load of
  ``calibration_loads_kg`` (the paper: unloaded, then 210 kg), and the validation poses at every load of
  ``validation_loads_kg`` (table 4: 0, 43, 128, 210 kg). With ``iso_cube`` the validation poses are the five
  points of an ISO 9283 cube (P1 the centre, P2..P5 on the diagonal plane at 10 % of the diagonal from the
  corners), reached by inverse kinematics of the nominal robot for target 1 from ``seed_q_deg``.

Truth (``truth["effects"]["compliance"]``): ``c_rad_per_Nm`` and ``c_rad_per_A`` (= c·K, what a current-based fit
should find when the reducer carries the friction), ``K_Nm_per_A``, true and nominal link masses, friction.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from robocal.compensation import ActualRobot, compensate
from robocal.errors import ConfigError
from robocal.kinematics.gravity import gravity_torques
from robocal.sim.effects import Rows, TwinContext, register_effect


def iso9283_cube_points(center_mm: np.ndarray, side_mm: float, inset: float = 0.1) -> np.ndarray:
    """The five ISO 9283 test points ``(5, 3)`` mm: P1 the cube centre, P2..P5 on the diagonal plane.

    The plane holds the cube corners ``(-,-,-), (-,+,-), (+,+,+), (+,-,+)`` (relative to the centre);
    P2..P5 lie on its diagonals at ``inset`` × the plane diagonal from those corners.
    """
    c = np.asarray(center_mm, dtype=float)
    h = float(side_mm) / 2.0
    corners = np.array([[-h, -h, -h], [-h, h, -h], [h, h, h], [h, -h, h]])
    # the plane diagonal runs corner to opposite corner (length 2 |corner|): inset of it from the corner
    pts = c + corners * (1.0 - 2.0 * inset)
    return np.vstack([c, pts])


def spring_torque_shape(
    q_rad: np.ndarray, vertical_deg: float, h_m: float = 0.55, r_m: float = 0.45, l0_m: float = 0.05
) -> np.ndarray:
    """The torque per unit stiffness of a tension spring from a point ``h_m`` above the joint axis on the base to
    a point ``r_m`` out on the arm (rest length ``l0_m``), the arm at ``q - vertical`` from the upright:
    ``(l - l0) h r sin(phi) / l``, ``l = sqrt(h² + r² - 2 h r cos(phi))``; a heavy robot's counterbalance."""
    phi = np.asarray(q_rad, dtype=float) - np.deg2rad(vertical_deg)
    length = np.sqrt(h_m * h_m + r_m * r_m - 2.0 * h_m * r_m * np.cos(phi))
    return np.asarray((length - l0_m) * h_m * r_m * np.sin(phi) / length)


def _counterbalance(cfg: Mapping[str, Any] | None, q: np.ndarray, tau_g: np.ndarray, n: int) -> dict[str, Any]:
    """``counterbalance: {joint, share, vertical_deg}``: a spring on ``joint`` (1-based) whose stiffness cancels
    ``share`` of that joint's gravity torque over the campaign (least squares), added to ``tau_g`` in place; its
    truth record (empty without one). ``vertical_deg`` (the joint's angle with the arm upright, where the spring's
    torque vanishes): by default the whole degree at which the spring's shape cancels the most of that torque
    (mounted as a designer would; the robots' descriptions put the upright at different angles)."""
    if not cfg:
        return {}
    j = int(cfg.get("joint", 2)) - 1
    if not 0 <= j < n:
        raise ConfigError(f"compliance effect: counterbalance joint {j + 1} is not one of the robot's 1..{n}")
    tau = tau_g[:, j]

    def left(v: float) -> float:
        f = spring_torque_shape(q[:, j], v)
        return float(np.sum((tau - f * (f @ tau) / max(float(f @ f), 1e-300)) ** 2))

    vertical = float(cfg["vertical_deg"]) if "vertical_deg" in cfg else min(range(-180, 180), key=left)
    f = spring_torque_shape(q[:, j], vertical)
    k = -float(cfg.get("share", 0.85)) * float(f @ tau) / max(float(f @ f), 1e-300)
    rms_before = float(np.sqrt(np.mean(tau_g[:, j] ** 2)))
    tau_g[:, j] += k * f
    return {"joint": j + 1, "stiffness_Nm": k, "share": float(cfg.get("share", 0.85)), "vertical_deg": vertical,
            "gravity_rms_Nm": rms_before, "net_rms_Nm": float(np.sqrt(np.mean(tau_g[:, j] ** 2)))}  # fmt: skip


def _per_joint(cfg: Mapping[str, Any], key: str, n: int, default: float | None = None) -> np.ndarray:
    if key not in cfg:
        if default is None:
            raise ConfigError(f"compliance effect: missing setting {key!r} (a list of {n} numbers)")
        return np.full(n, float(default))
    v = np.asarray(cfg[key], dtype=float)
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"The '{key}' setting of the compliance effect must be {n} numbers. Got {cfg[key]!r}.")
    return v


@register_effect("compliance")
class ComplianceEffect:
    """Joint compliance under payload (see the module docstring for the config keys)."""

    name = "compliance"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)

    # ------------------------------------------------------------------------------------------- plan
    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        cfg = self.cfg
        cal_loads = [float(v) for v in cfg.get("calibration_loads_kg", [0.0])]
        val_loads = [float(v) for v in cfg.get("validation_loads_kg", cal_loads)]
        if not cal_loads or min(cal_loads + val_loads) < 0:
            raise ConfigError("compliance effect: calibration_loads_kg must be non-empty and loads >= 0")
        q_cmd = rows.q_cmd
        pid, split, tidx = rows.pose_id, rows.split, rows.target_index
        cube = cfg.get("iso_cube")
        if cube:
            q_cube = self._cube_joints(dict(cube), ctx)
            K = int(tidx.max()) + 1 if len(tidx) else 1
            keep = split == "calibration"
            pid = np.concatenate([pid[keep], np.repeat(np.array([f"iso_P{k + 1}" for k in range(5)], object), K)])
            split = np.concatenate([split[keep], np.full(5 * K, "validation", dtype=object)])
            tidx = np.concatenate([tidx[keep], np.tile(np.arange(K), 5)])
            q_cmd = np.concatenate([q_cmd[keep], np.repeat(q_cube, K, axis=0)])
        blocks: list[tuple[np.ndarray, float]] = []
        cal = np.flatnonzero(split == "calibration")
        val = np.flatnonzero(split == "validation")
        blocks += [(cal, load) for load in cal_loads]
        blocks += [(val, load) for load in val_loads]
        idx = np.concatenate([b[0] for b in blocks])
        load = np.concatenate([np.full(len(b[0]), b[1]) for b in blocks])
        m = len(idx)
        interval = float(rows.t_s[1] - rows.t_s[0]) if len(rows.t_s) > 1 else 10.0
        n = rows.dq.shape[1]
        return Rows(
            pose_id=pid[idx],
            split=split[idx],
            target_index=tidx[idx],
            q_cmd=q_cmd[idx],
            t_s=np.arange(m) * interval,
            payload_kg=load,
            dq=np.zeros((m, n)),
            deta=np.zeros((m, rows.deta.shape[1])),
            columns={},
        )

    def _cube_joints(self, cube: Mapping[str, Any], ctx: TwinContext) -> np.ndarray:
        robot = ctx.robot
        n = robot.n_joints
        center = np.asarray(cube.get("center_mm", [0.0, 0.0, 0.0]), dtype=float)
        side = float(cube.get("side_mm", 500.0))
        seed = np.deg2rad(np.asarray(cube.get("seed_q_deg", [0.0] * n), dtype=float))
        if center.shape != (3,) or seed.shape != (n,) or not side > 0:
            raise ConfigError("compliance effect: iso_cube needs center_mm [x, y, z], side_mm > 0, seed_q_deg (n)")
        pts = iso9283_cube_points(center, side)
        tool = np.asarray(next(iter(ctx.truth["tools_mm"].values())), dtype=float)
        nominal = ActualRobot(ctx.chain, np.zeros(ctx.chain.n_params), np.eye(4), tool, np.eye(3))
        # inverse kinematics from a seed (a large move, not a small correction): no stall rule
        comp = compensate(nominal, np.tile(seed, (5, 1)), pts, max_iter=60, tol_mm=1e-6, stall=False)
        if not comp.converged.all():
            raise ConfigError(
                f"compliance effect: the ISO cube (centre {center.tolist()}, side {side}) is out of reach"
            )
        q = np.deg2rad(np.round(np.rad2deg(comp.q), 6))
        lim = robot.q_limits
        bad = (q < lim[:, 0]) | (q > lim[:, 1])
        if bad.any():
            k, j = (int(v[0]) for v in np.nonzero(bad))
            raise ConfigError(
                f"compliance effect: ISO cube point P{k + 1} needs joint {j + 1} at {np.rad2deg(q[k, j]):.1f} deg, "
                "outside its limits; move iso_cube.center_mm or change seed_q_deg"
            )
        return q

    # ------------------------------------------------------------------------------------------ apply
    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        cfg = self.cfg
        robot = ctx.robot
        n = robot.n_joints
        if not robot.has_dynamics:
            raise ConfigError(f"compliance effect: robot {robot.name!r} has no dynamics (link masses)")
        assert robot.link_mass_kg is not None
        c = _per_joint(cfg, "c_rad_per_Nm", n)
        K = _per_joint(cfg, "torque_constant_Nm_per_A", n)
        if np.any(K == 0):
            raise ConfigError("The 'torque_constant_Nm_per_A' setting of the compliance effect must be non-zero")
        coulomb = _per_joint(cfg, "coulomb_Nm", n, 0.0)
        viscous = _per_joint(cfg, "viscous_Nm_s_per_deg", n, 0.0)
        speed = float(cfg.get("approach_speed_deg_s", 0.0))
        noise_A = float(cfg.get("current_noise_A", 0.0))
        in_reducer = bool(cfg.get("friction_in_reducer", True))
        rng = ctx.rng_factory("compliance")
        mass_true = robot.link_mass_kg * (1.0 + rng.normal(0.0, float(cfg.get("mass_error_sd", 0.0)), n))
        mass_true = np.maximum(mass_true, 0.0)

        # approach directions: another effect's (backlash) if present, else one per pose id and load block
        m = len(rows.pose_id)
        if all(f"dir{j + 1}" in rows.columns for j in range(n)):
            dirs = np.column_stack([rows.columns[f"dir{j + 1}"] for j in range(n)]).astype(float)
        else:
            key = np.array([f"{p}@{w:g}" for p, w in zip(rows.pose_id, rows.payload_kg, strict=True)])
            _, inv = np.unique(key, return_inverse=True)
            dirs = rng.choice(np.array([-1.0, 1.0]), size=(int(inv.max()) + 1, n))[inv.ravel()]
            if bool(cfg.get("report_directions", True)):
                for j in range(n):
                    rows.columns[f"dir{j + 1}"] = dirs[:, j]

        tau_g = gravity_torques(robot, rows.q_cmd, rows.payload_kg, chain=ctx.chain, link_mass_kg=mass_true)
        balancer = _counterbalance(cfg.get("counterbalance"), rows.q_cmd, tau_g, n)
        tau_f = -dirs * (coulomb + viscous * speed)
        tau_drive = tau_g + tau_f
        tau_reducer = tau_drive if in_reducer else tau_g
        rows.dq += c * tau_reducer
        cur = tau_drive / K + rng.normal(0.0, noise_A, (m, n))
        if bool(cfg.get("report_currents", True)):
            for j in range(n):
                rows.columns[f"i{j + 1}_A"] = cur[:, j]
        K_nom = K * (1.0 + rng.normal(0.0, float(cfg.get("torque_constant_error_sd", 0.0)), n))
        if bool(cfg.get("report_torques", False)):
            for j in range(n):
                rows.columns[f"tau{j + 1}_Nm"] = cur[:, j] * K_nom[j]
        ctx.truth.setdefault("effects", {})["compliance"] = {
            "c_rad_per_Nm": c.tolist(),
            "c_rad_per_A": (c * K).tolist(),
            "K_Nm_per_A": K.tolist(),
            "K_nominal_Nm_per_A": K_nom.tolist(),
            "link_mass_true_kg": mass_true.tolist(),
            "link_mass_nominal_kg": robot.link_mass_kg.tolist(),
            "coulomb_Nm": coulomb.tolist(),
            "viscous_Nm_s_per_deg": viscous.tolist(),
            "approach_speed_deg_s": speed,
            "friction_in_reducer": in_reducer,
            "current_noise_A": noise_A,
            "deflection_rms_deg": np.rad2deg(np.sqrt(np.mean((c * tau_reducer) ** 2, axis=0))).tolist(),
            **({"counterbalance": balancer} if balancer else {}),
        }


__all__ = ["ComplianceEffect", "iso9283_cube_points"]
