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
      rail:                           # a rail laid in segments: the carriage's pitch (about its x) and yaw (y)
        segments: 4                   #   piecewise linear along the travel, a kink and a step at each joint,
        pitch_urad: 150.0             #   random (seeded), scaled to these RMS values
        yaw_urad: 60.0
      inclinometer:                   # a two-axis inclinometer on the carriage logs its pitch and yaw
        columns: [carriage_incl_x, carriage_incl_y]
        noise_urad: 2.0               #   the reading's own noise (mrad columns, declared location: carriage)
        declare: true

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
            if cfg.get("rail"):
                E[:, 3:5] += _rail(dict(cfg["rail"]), u, ctx.rng_factory(f"linear_axis_rail_{j + 1}"))
                truth[f"{role}:rail"] = dict(cfg["rail"])
            if cfg.get("inclinometer"):
                _inclinometer(dict(cfg["inclinometer"]), E, rows, ctx, role, j)
            rows.axis_error[j] = E


def _rail(cfg: dict[str, Any], u: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``(m, 2)`` rad: the pitch and yaw of a carriage on a rail of ``segments`` pieces over the travel ``u`` in
    [-1, 1], each piece linear with a kink and a step at its joints, scaled to ``pitch_urad`` / ``yaw_urad`` RMS."""
    n = int(cfg.get("segments", 4))
    if n < 1:
        raise ConfigError(f"linear_axis.rail.segments must be >= 1; got {n}")
    edges = np.linspace(-1.0, 1.0, n + 1)
    piece = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, n - 1)
    out = np.zeros((len(u), 2))
    for k, key in enumerate(("pitch_urad", "yaw_urad")):
        level, slope = rng.normal(size=n), rng.normal(size=n)
        v = level[piece] + slope[piece] * (u - edges[piece]) * n
        v -= v.mean()
        s = float(np.std(v))
        out[:, k] = v * (float(cfg.get(key, 0.0)) * 1e-6 / s if s > 0 else 0.0)
    return out


def _inclinometer(cfg: dict[str, Any], E: np.ndarray, rows: Rows, ctx: TwinContext, role: str, j: int) -> None:
    """Log the carriage's pitch and yaw (``E[:, 3:5]``, rad) in mrad with the reading's noise, and declare it."""
    names = list(cfg.get("columns", ["carriage_incl_x", "carriage_incl_y"]))
    if len(names) != 2:
        raise ConfigError(f"linear_axis.inclinometer.columns must name two columns; got {names!r}")
    rng = ctx.rng_factory(f"linear_axis_inclinometer_{j + 1}")
    noise = float(cfg.get("noise_urad", 2.0)) * 1e-3
    for k, nm in enumerate(names):
        rows.columns[nm] = E[:, 3 + k] * 1e3 + rng.normal(0.0, noise, len(E))
    if cfg.get("declare", True):
        ctx.truth.setdefault("signals", {}).update(
            {nm: {"unit": "mrad", "location": "carriage", "description": f"inclinometer on the {role}'s carriage, "
                  f"its rotation about the carriage {ax} axis"} for nm, ax in zip(names, "xy", strict=True)}
        )  # fmt: skip
    ctx.truth.setdefault("effects", {})["carriage_inclinometer"] = {
        "columns": names, "joint": j + 1, "gain": 1.0, "noise_mrad": noise,
        "tilt_rms_mrad": [float(np.sqrt(np.mean(E[:, 3 + k] ** 2)) * 1e3) for k in range(2)],
    }  # fmt: skip
