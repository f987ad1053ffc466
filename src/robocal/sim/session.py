"""Twin effect ``second_session``: the same robot measured again months later, from another tracker placement,
with its tool re-seated and the cell warmer (issue 33 item 5).

A plant calibrates once and runs for months; what it lives with is the next session. The effect splits the plan:
the last ``share`` of the calibration poses and of the validation poses are measured in a second session
``after_days`` after the first, from the tracker station ``station`` (``tracker: {xyz_mm, rpy_deg}``), with

* the tool **re-seated**: every target sits ``tool_shift_mm`` (flange axes) from where it sat in the first session
  (a tool taken off and put back, a reflector nest re-glued);
* the cell **warmer**: the air temperature of each session (``air_C``: ``[first, second]``, with a slow wander of
  ``air_walk_C`` RMS within each) is logged in the column ``column`` (``air_T_C``, declared in ``signals.yaml``
  as ambient), and the robot follows it: every length of the robot and its tool grows by
  ``expansion_ppm_per_C`` (steel ~11.5, aluminium ~23) per degree above ``T0_C`` — a uniform expansion about the
  robot's base. The tracker measures in true lengths (its own air compensation is not in question here).

Rows are re-ordered so that the first session's come first (its calibration poses, then its validation poses),
then the second's; the ``station`` column says which session each row belongs to (``S1``, ``station``).

Truth: ``truth["effects"]["second_session"]`` with the tool shift, the expansion, each session's air temperature
and the rows of each; ``truth["stations_T_base"]`` the two tracker placements.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields, replace
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.kinematics.transforms import homogeneous, matrix_from_rpy
from robocal.sim.effects import Rows, TwinContext, register_effect

DAY_S = 86400.0


def _number(cfg: Mapping[str, Any], key: str, default: float, lo: float = 0.0) -> float:
    v = cfg.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) or v < lo:
        raise ConfigError(f"The '{key}' setting of the second_session effect must be a number >= {lo}. Got {v!r}.")
    return float(v)


def _vector(cfg: Mapping[str, Any], key: str, default: list[float], n: int) -> np.ndarray:
    v = np.asarray(cfg.get(key, default), dtype=float)
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"The '{key}' setting of the second_session effect must be {n} numbers. Got {v.tolist()}.")
    return v


@register_effect("second_session")
class SecondSessionEffect:
    """A second measurement session months later: another tracker placement, the tool re-seated, a warmer cell
    (see the module docstring)."""

    name = "second_session"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)
        self.share = _number(self.cfg, "share", 0.5)
        if not 0.0 < self.share < 1.0:
            raise ConfigError(f"The 'share' setting of the second_session effect must be in (0, 1). Got {self.share}.")
        self.after_days = _number(self.cfg, "after_days", 120.0)
        self.station = str(self.cfg.get("station", "S2"))
        if self.station == "S1":
            raise ConfigError("The 'station' setting of the second_session effect must not be S1 (the first session's)")
        tr = dict(self.cfg.get("tracker") or {})
        self.T2 = homogeneous(
            matrix_from_rpy(np.deg2rad(_vector(tr, "rpy_deg", [0.8, -0.4, -40.0], 3))),
            _vector(tr, "xyz_mm", [-1800.0, 2600.0, -420.0], 3),
        )
        self.tool_shift_mm = _vector(self.cfg, "tool_shift_mm", [0.12, -0.08, 0.18], 3)
        self.air_C = _vector(self.cfg, "air_C", [20.0, 24.0], 2)
        self.air_walk_C = _number(self.cfg, "air_walk_C", 0.3)
        self.ppm_per_C = _number(self.cfg, "expansion_ppm_per_C", 11.5)
        self.T0_C = _number(self.cfg, "T0_C", 20.0, lo=-273.15)
        self.column = str(self.cfg.get("column", "air_T_C"))
        self.second: np.ndarray | None = None  # (m,) bool after plan()

    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        """The last ``share`` of each split's poses move to the second session; rows re-ordered by session, the
        second session's clock ``after_days`` later."""
        if rows.station is not None:
            raise ConfigError("The second_session effect cannot be combined with another effect that sets stations")
        m = len(rows.pose_id)
        pid = np.asarray(rows.pose_id).astype(str)
        split = np.asarray(rows.split).astype(str)
        second = np.zeros(m, dtype=bool)
        for s in ("calibration", "validation"):
            poses = list(dict.fromkeys(pid[split == s]))
            k = round(self.share * len(poses))
            second |= np.isin(pid, poses[len(poses) - k :]) & (split == s)
        order = np.concatenate(
            [np.flatnonzero(~second & (split == "calibration")), np.flatnonzero(~second & (split != "calibration")),
             np.flatnonzero(second & (split == "calibration")), np.flatnonzero(second & (split != "calibration"))]
        )  # fmt: skip
        moved: dict[str, Any] = {}
        for f in fields(rows):
            v = getattr(rows, f.name)
            if isinstance(v, np.ndarray) and v.shape[:1] == (m,):
                moved[f.name] = v[order]
            elif f.name == "columns":
                moved[f.name] = {k: np.asarray(c)[order] for k, c in v.items()}
            elif f.name == "axis_error" and v:
                moved[f.name] = {k: np.asarray(c)[order] for k, c in v.items()}
        rows = replace(rows, **moved)
        self.second = second[order]
        interval = float(np.median(np.diff(rows.t_s))) if m > 1 else 10.0
        n1 = int((~self.second).sum())
        t = np.arange(m) * interval
        t[n1:] = self.after_days * DAY_S + np.arange(m - n1) * interval
        rows.t_s = t
        return rows

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        second = self.second
        assert second is not None and len(second) == len(rows.pose_id), "plan() first"
        m = len(second)
        rows.station = np.where(second, self.station, "S1").astype(object)
        T1 = np.asarray(ctx.truth["tracker_T_base"], dtype=float)
        ctx.truth["stations_T_base"] = {"S1": T1.tolist(), self.station: self.T2.tolist()}
        shift = np.zeros((m, 3))
        shift[second] = self.tool_shift_mm
        rows.dtool_mm = shift if rows.dtool_mm is None else rows.dtool_mm + shift
        rng = ctx.rng_factory("second_session")
        air = np.where(second, self.air_C[1], self.air_C[0]).astype(float)
        for sel in (~second, second):
            n = int(sel.sum())
            if n > 1 and self.air_walk_C > 0:
                w = np.cumsum(rng.normal(size=n))
                w -= w.mean()
                air[sel] += w * (self.air_walk_C / max(float(np.std(w)), 1e-12))
        air = np.round(air, 2)  # what the logger writes, 0.01 °C
        rows.columns[self.column] = air
        scale = self.ppm_per_C * 1e-6 * (air - self.T0_C)
        rows.base_scale = scale if rows.base_scale is None else rows.base_scale + scale
        ctx.truth.setdefault("signals", {})[self.column] = {
            "unit": "degC",
            "location": "ambient",
            "description": "air temperature of the cell",
        }
        ctx.truth.setdefault("effects", {})[self.name] = {
            "station": self.station,
            "after_days": self.after_days,
            "tool_shift_mm": self.tool_shift_mm.tolist(),
            "expansion_ppm_per_C": self.ppm_per_C,
            "T0_C": self.T0_C,
            "column": self.column,
            "air_C_mean": {"S1": float(air[~second].mean()), self.station: float(air[second].mean())},
            "rows": {"S1": int((~second).sum()), self.station: int(second.sum())},
        }


__all__ = ["SecondSessionEffect"]
