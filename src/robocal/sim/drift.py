"""Twin effects ``drift`` (the tracker or the robot base moves slowly during the campaign) and ``scale`` (the
tracker's length scale is off, and may change with time).

A tracker on a tripod settles, a floor creeps as it warms: the measured points shift in the tracker frame by
``dp(t) = v · h + a · h²`` with ``h`` hours since the campaign start (``rate_mm_per_h`` = v,
``accel_mm_per_h2`` = a, tracker-frame mm). The shift is written to ``rows.dp_tracker_mm`` and added to the
true positions before the tracker noise. Nothing is reported in the data: only the timestamps carry it.

Truth: ``truth["effects"]["drift"] = {"rate_mm_per_h": [...], "accel_mm_per_h2": [...], "max_shift_mm": ...}``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.sim.effects import Rows, TwinContext, register_effect


def _vec3(cfg: Mapping[str, Any], key: str) -> np.ndarray:
    v = np.asarray(cfg.get(key, [0.0, 0.0, 0.0]), dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"The '{key}' setting of the drift effect must be [x, y, z] in mm. Got {cfg.get(key)!r}.")
    return v


@register_effect("drift")
class DriftEffect:
    """Slow tracker/base drift over time (see the module docstring). Config: ``rate_mm_per_h``,
    ``accel_mm_per_h2`` (tracker-frame [x, y, z])."""

    name = "drift"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        return rows

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        v = _vec3(self.cfg, "rate_mm_per_h")
        a = _vec3(self.cfg, "accel_mm_per_h2")
        h = (np.asarray(rows.t_s, dtype=float) - float(np.min(rows.t_s)))[:, None] / 3600.0
        dp = v[None, :] * h + a[None, :] * h**2
        rows.dp_tracker_mm = dp if rows.dp_tracker_mm is None else rows.dp_tracker_mm + dp
        ctx.truth.setdefault("effects", {})["drift"] = {
            "rate_mm_per_h": v.tolist(),
            "accel_mm_per_h2": a.tolist(),
            "max_shift_mm": float(np.max(np.linalg.norm(dp, axis=1))) if len(dp) else 0.0,
        }


@register_effect("scale")
class ScaleEffect:
    """The tracker's length scale is off: every measured point is scaled about the tracker head by ``1 + s(t)``,
    ``s = (ppm + ppm_per_h · h) · 1e-6`` with ``h`` hours since the campaign start (a wrong or stale weather
    station: the air's refractive index sets the laser's wavelength). Config: ``ppm``, ``ppm_per_h``.

    Truth: ``truth["effects"]["scale"] = {"ppm": ..., "ppm_per_h": ..., "max_abs_ppm": ...}``. A constant
    scale is a uniform scale of the robot's lengths (no calibration can tell them apart without a reference
    length); a scale that changes with time is a measurement-side effect discovery can find.
    """

    name = "scale"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        return rows

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        vals = {}
        for key in ("ppm", "ppm_per_h"):
            v = self.cfg.get(key, 0.0)
            if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
                raise ConfigError(f"The '{key}' setting of the scale effect must be a number. Got {v!r}.")
            vals[key] = float(v)
        h = (np.asarray(rows.t_s, dtype=float) - float(np.min(rows.t_s))) / 3600.0
        s = (vals["ppm"] + vals["ppm_per_h"] * h) * 1e-6
        rows.tracker_scale = s if rows.tracker_scale is None else rows.tracker_scale + s
        ctx.truth.setdefault("effects", {})["scale"] = {**vals, "max_abs_ppm": float(np.max(np.abs(s))) * 1e6}


__all__ = ["DriftEffect", "ScaleEffect"]
