"""Twin effect ``linear_axis``: a track's or a column's own errors along its travel (issue 34).

Config (one mapping per axis, or a list of them)::

    linear_axis:
      joint: 1                        # the prismatic joint (1-based)
      legendre:                       # component -> {order: coefficient}: mm (straightness, positioning) or
        straightness_y: {2: 0.25}     #   µrad (pitch, yaw, roll), Legendre polynomials of the travel in [-1, 1]
        pitch: {1: 40.0, 2: -25.0}
      bending_urad_per_kNm:           # a column bending under the arm's weight: rotation about the carriage's
        x: [30.0, 15.0]               #   x (y) of (k0 + k1 u) µrad per kN·m of the carried moment about x (y)
        y: [30.0, 15.0]

The carriage frame, the components and the moment are those of :mod:`robocal.kinematics.axes` (the identification
fits the same functions, :mod:`robocal.calibration.axes`). The errors act on the true points through the
augmented chain (``rows.axis_error``); the truth holds every coefficient by the identification's term names
(``axis_errors``: ``track:straightness_y_P2`` in mm, ``column:pitch_P1`` in rad, ``column:bending_x`` /
``column:bending_x_ext`` in rad per kN·m).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.kinematics.axes import COMPONENTS, carried_moment, legendre, travel_coordinate
from robocal.sim.effects import Rows, TwinContext, register_effect


@register_effect("linear_axis")
class LinearAxisEffect:
    """A linear axis's straightness, positioning, pitch, yaw, roll and bending (module docstring)."""

    name = "linear_axis"

    def __init__(self, cfg: Mapping[str, Any] | list[Any]) -> None:
        self.axes = list(cfg) if isinstance(cfg, list) else [dict(cfg)]

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        return rows

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        robot = ctx.robot
        truth = ctx.truth.setdefault("axis_errors", {})
        rows.axis_error = dict(rows.axis_error or {})
        for cfg in self.axes:
            j = int(cfg.get("joint", 0)) - 1
            if not 0 <= j < robot.n_joints or not robot.prismatic[j]:
                raise ConfigError(
                    f"The 'joint' setting of the linear_axis effect must name a prismatic joint; got {j + 1}"
                )
            role = robot.role(j)
            u = travel_coordinate(rows.q_cmd[:, j], robot.q_limits[j])
            E = rows.axis_error.get(j, np.zeros((len(u), 6)))
            for comp, terms in dict(cfg.get("legendre") or {}).items():
                if comp not in COMPONENTS:
                    raise ConfigError(f"linear_axis.legendre: unknown component {comp!r}; known: {list(COMPONENTS)}")
                c = COMPONENTS.index(comp)
                scale = 1.0 if c < 3 else 1e-6  # mm, or µrad -> rad
                for order, value in dict(terms).items():
                    k = int(order)
                    E[:, c] += scale * float(value) * legendre(u, k)
                    truth[f"{role}:{comp}_P{k}"] = scale * float(value)
            bend = cfg.get("bending_urad_per_kNm")
            if bend:
                M = carried_moment(robot, rows.q_cmd, j, rows.payload_kg) / 1000.0  # kN·m, carriage frame
                for axis, comp in ((0, "x"), (1, "y")):
                    k0, k1 = (float(v) * 1e-6 for v in bend.get(comp, (0.0, 0.0)))
                    E[:, 3 + axis] += (k0 + k1 * u) * M[:, axis]
                    truth[f"{role}:bending_{comp}"] = k0
                    truth[f"{role}:bending_{comp}_ext"] = k1
            rows.axis_error[j] = E
