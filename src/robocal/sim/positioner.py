"""Twin effect ``positioner``: reflectors on a part that a turntable (or a two-axis positioner) carries, issue 34.

The robot description declares the positioner (``positioner:`` in robot.yaml, :class:`robocal.robot.Positioner`):
its axes and the reflectors on the part (``targets``, which must be scenario targets: their ``[x, y, z]`` are
their coordinates on the part, in the last axis' frame at angle 0). The arm's poses measure the other targets
(the tool's); the part's reflectors are measured at ``angles`` positioner angles (random over 90 % of each axis'
limits; ``validation_angles`` more for the validation split), with the arm parked at its first pose. Config::

    positioner:
      angles: 12                      # calibration angles (each axis drawn independently)
      validation_angles: 6
      errors: {P1_tx: 0.8, P1_ty: -0.5, P1_rx: 0.05, P1_ry: -0.03}   # the true axis errors: mm, deg
                                      #   (robocal.kinematics.positioner.parameter_names, angles in deg)

The positioner's angles are written as ``pos<j>_deg`` on every row (0 on the arm's rows). The truth holds the
errors by parameter name (mm, rad) under ``positioner.parameters`` and the part points under
``positioner.part_points_mm``. One tracker station; positions only.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.kinematics.positioner import parameter_names, part_points
from robocal.sim.effects import Rows, TwinContext, register_effect


@register_effect("positioner")
class PositionerEffect:
    """Rows measuring the part on the positioner (module docstring)."""

    name = "positioner"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)
        unknown = sorted(set(self.cfg) - {"angles", "validation_angles", "errors"})
        if unknown:
            raise ConfigError(f"positioner effect: unknown setting(s) {unknown}; known: angles, validation_angles, "
                              "errors")  # fmt: skip
        self.angles: np.ndarray | None = None

    def _positioner(self, ctx: TwinContext) -> Any:
        pos = ctx.robot.positioner
        if pos is None:
            raise ConfigError(f"the positioner effect needs a robot with a 'positioner' block; {ctx.robot.name!r} has "
                              "none")  # fmt: skip
        names = list(ctx.truth["tools_mm"])
        missing = [t for t in pos.targets if t not in names]
        if missing:
            raise ConfigError(f"the positioner's targets {missing} are not scenario targets ({names})")
        return pos

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        pos = self._positioner(ctx)
        names = list(ctx.truth["tools_mm"])
        part = np.array([names.index(t) for t in pos.targets])
        arm = ~np.isin(rows.target_index, part)
        n_cal, n_val = int(self.cfg.get("angles", 12)), int(self.cfg.get("validation_angles", 6))
        rng = ctx.rng_factory("positioner")
        lim = pos.q_limits
        mid, half = lim.mean(axis=1), 0.45 * (lim[:, 1] - lim[:, 0])
        ang = mid + half * rng.uniform(-1.0, 1.0, (n_cal + n_val, pos.n_axes))
        ang = np.deg2rad(np.round(np.rad2deg(ang), 6))  # as the controller reports them
        K = len(part)
        k = n_cal + n_val
        m_arm = int(arm.sum())
        dt = float(rows.t_s[1] - rows.t_s[0]) if len(rows.t_s) > 1 else 10.0
        t0 = float(rows.t_s[arm][-1]) if m_arm else 0.0
        q_park = rows.q_cmd[arm][0] if m_arm else rows.q_cmd[0]
        new = Rows(
            pose_id=np.concatenate([rows.pose_id[arm], np.repeat([f"t{i:04d}" for i in range(k)], K).astype(object)]),
            split=np.concatenate(
                [rows.split[arm], np.repeat(np.array(["calibration"] * n_cal + ["validation"] * n_val), K)]
            ).astype(object),
            target_index=np.concatenate([rows.target_index[arm], np.tile(part, k)]),
            q_cmd=np.concatenate([rows.q_cmd[arm], np.tile(q_park, (k * K, 1))]),
            t_s=np.concatenate([rows.t_s[arm], t0 + dt * np.arange(1, k * K + 1)]),
            payload_kg=np.concatenate([rows.payload_kg[arm], np.full(k * K, rows.payload_kg[0])]),
            dq=np.concatenate([rows.dq[arm], np.zeros((k * K, rows.dq.shape[1]))]),
            deta=np.concatenate([rows.deta[arm], np.zeros((k * K, rows.deta.shape[1]))]),
            columns={c: v[arm] for c, v in rows.columns.items()},
        )
        q_pos = np.concatenate([np.zeros((m_arm, pos.n_axes)), np.repeat(ang, K, axis=0)])
        for j, col in enumerate(pos.columns):
            new.columns[col] = np.rad2deg(q_pos[:, j])
        self.angles = q_pos
        return new

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        pos = self._positioner(ctx)
        assert self.angles is not None
        names = parameter_names(pos)
        errors = dict(self.cfg.get("errors") or {})
        unknown = sorted(set(errors) - set(names))
        if unknown:
            raise ConfigError(f"positioner.errors: unknown parameter(s) {unknown}; known: {list(names)}")
        params = np.array([float(errors.get(n, 0.0)) for n in names])
        params = np.where([n.endswith(("_tx", "_ty")) for n in names], params, np.deg2rad(params))
        tools = ctx.truth["tools_mm"]
        target_names = list(tools)
        T = np.asarray(ctx.truth["tracker_T_base"], dtype=float)
        fixed = np.full((len(rows.pose_id), 3), np.nan)
        for t in pos.targets:
            sel = rows.target_index == target_names.index(t)
            pb = part_points(pos, self.angles[sel], params, np.asarray(tools[t], dtype=float))
            fixed[sel] = pb @ T[:3, :3].T + T[:3, 3]
        rows.fixed_points = fixed
        ctx.truth["positioner"] = {
            "parameters": {n: float(v) for n, v in zip(names, params, strict=True)},
            "part_points_mm": {t: list(tools[t]) for t in pos.targets},
        }
