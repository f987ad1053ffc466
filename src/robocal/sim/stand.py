"""Twin effects ``compliant_stand`` (the robot's base sits on a compliant stand whose tilt a logged inclinometer
measures) and ``logged_channels`` (extra logged columns with no effect: the null twin of the logged-signal
discovery, :mod:`robocal.discovery.logged`).

``compliant_stand``: the stand tilts about the robot base's origin by ``theta = C · M + w(t)``: ``M`` the moment
of the arm's weight about the base (an effective mass ``arm_mass_kg`` plus the row's payload at the nominal
flange position, kN·m), ``C`` the stand's compliance (``compliance_mrad_per_kNm``), and ``w(t)`` a slow wander
of the floor or the stand (a random walk over the poses scaled to ``wander_mrad`` RMS per axis). A load at +x of
the base tilts it about +y, a load at +y about -x. An inclinometer on the base logs the tilt about the base x and
y axes with its own noise (``sensor_noise_mrad``) in the columns ``columns`` (default ``incl_x``, ``incl_y``,
mrad); with ``declare: true`` (default) the campaign gets a ``signals.yaml`` declaring them. The tilt is applied
to the true points (``rows.base_rotvec``); the truth holds the tilt gain (1: the inclinometer reads the tilt).

``logged_channels``: ``channels: {name: kind}`` with kind ``white`` (an independent reading per row), ``walk``
(a random walk over time, like a slowly changing sensor), ``joint<j>`` (the commanded joint ``j`` in degrees: a
function of the joints, which discovery must recognise and not use) or ``commanded_x`` (the commanded flange x,
mm). Nothing acts on the robot.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.kinematics.chain import fk
from robocal.sim.effects import Rows, TwinContext, register_effect

G = 9.81


def _num(cfg: Mapping[str, Any], key: str, default: float, effect: str) -> float:
    v = cfg.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) or v < 0:
        raise ConfigError(f"The '{key}' setting of the {effect} effect must be a number >= 0. Got {v!r}.")
    return float(v)


def _walk(rng: np.random.Generator, m: int, rms: float) -> np.ndarray:
    """A random walk over ``m`` rows, centred and scaled to ``rms``."""
    w = np.cumsum(rng.normal(size=m))
    w -= w.mean()
    s = float(np.std(w))
    return w * (rms / s) if s > 0 else w


def _flange_mm(rows: Rows, ctx: TwinContext) -> np.ndarray:
    """The nominal flange position (m, 3) mm in the base frame at the commanded joints."""
    return fk(ctx.chain, rows.q_cmd)[:, :3, 3]


@register_effect("compliant_stand")
class CompliantStandEffect:
    """A compliant stand with a logged inclinometer (see the module docstring)."""

    name = "compliant_stand"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        return rows

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        e = self.name
        C = _num(self.cfg, "compliance_mrad_per_kNm", 0.2, e)
        mass = _num(self.cfg, "arm_mass_kg", 30.0, e)
        wander = _num(self.cfg, "wander_mrad", 0.05, e)
        noise = _num(self.cfg, "sensor_noise_mrad", 0.002, e)
        names = list(self.cfg.get("columns", ["incl_x", "incl_y"]))
        if len(names) != 2:
            raise ConfigError(f"The 'columns' setting of the {e} effect must name two columns. Got {names!r}.")
        m = len(rows.pose_id)
        p = _flange_mm(rows, ctx)
        load_kN = (mass + rows.payload_kg) * G / 1000.0
        M = load_kN[:, None] * p[:, :2] / 1000.0  # kN·m: the load's lever along base x and y
        rng = ctx.rng_factory("compliant_stand")
        tilt = np.zeros((m, 3))  # mrad about the base x, y, z
        tilt[:, 0] = -C * M[:, 1] + _walk(rng, m, wander)
        tilt[:, 1] = C * M[:, 0] + _walk(rng, m, wander)
        rot = tilt * 1e-3
        rows.base_rotvec = rot if rows.base_rotvec is None else rows.base_rotvec + rot
        logged = tilt[:, :2] + rng.normal(0.0, noise, (m, 2))
        for k, nm in enumerate(names):
            rows.columns[nm] = logged[:, k]
        if self.cfg.get("declare", True):
            ctx.truth.setdefault("signals", {}).update(
                {nm: {"unit": "mrad", "location": "base", "description": f"inclinometer on the stand, tilt about "
                      f"the base {ax} axis"} for nm, ax in zip(names, "xy", strict=True)}
            )  # fmt: skip
        ctx.truth.setdefault("effects", {})[e] = {
            "columns": names,
            "gain": 1.0,  # rad of base tilt per rad the inclinometer reads (about x for the first column, y second)
            "compliance_mrad_per_kNm": C,
            "wander_mrad": wander,
            "sensor_noise_mrad": noise,
            "tilt_rms_mrad": [float(np.sqrt(np.mean(tilt[:, k] ** 2))) for k in range(2)],
        }


@register_effect("logged_channels")
class LoggedChannelsEffect:
    """Extra logged columns that drive nothing (see the module docstring)."""

    name = "logged_channels"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        return rows

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        channels = dict(self.cfg.get("channels") or {"noise_a": "white", "noise_b": "walk"})
        rng = ctx.rng_factory("logged_channels")
        m = len(rows.pose_id)
        n = rows.q_cmd.shape[1]
        order = np.argsort(rows.t_s, kind="stable")
        for name, kind in channels.items():
            if kind == "white":
                v = rng.normal(size=m)
            elif kind == "walk":
                v = np.empty(m)
                v[order] = _walk(rng, m, 1.0)
            elif isinstance(kind, str) and kind.startswith("joint") and kind[5:].isdigit() and 1 <= int(kind[5:]) <= n:
                v = np.rad2deg(rows.q_cmd[:, int(kind[5:]) - 1])
            elif kind == "commanded_x":
                v = _flange_mm(rows, ctx)[:, 0]
            else:
                raise ConfigError(f"The 'channels.{name}' setting of the logged_channels effect must be white, walk, "
                                  f"joint1..joint{n} or commanded_x. Got {kind!r}.")  # fmt: skip
            rows.columns[str(name)] = v
        ctx.truth.setdefault("effects", {})[self.name] = {"channels": {str(k): str(v) for k, v in channels.items()}}


__all__ = ["CompliantStandEffect", "LoggedChannelsEffect"]
