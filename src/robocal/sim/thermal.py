"""Twin effect ``thermal``: a robot warming up, its kinematic parameters drifting with its temperatures.

Modelled on the experiment of Guo et al. (2026), section 3.3: the robot starts cold (at ambient temperature),
runs a warm-up program, and the pose set is measured every 30 min until thermal steady state (~150 min);
another day a second warm-up from cold is measured for validation.

- Temperatures: every sensor follows a first-order heating curve
  ``T_k(t) = T_amb + rise_k (1 - exp(-h / tau_k))``, ``h`` the time since the warm-up started; the log
  (``temperatures.csv``) samples them every ``log_interval_s`` with sensor noise.
- Parameter drift (eq. 28 in kind): lengths by linear expansion ``d_eta = c (T_j - T0)`` of one sensor
  (``c = lambda L`` in mm/°C), angles by polynomials of the sensors in ``T - T0`` (coefficients in deg/°C^k);
  every row gets the drift of its own (true, noise-free) temperatures in ``rows.deta``.
- Plan: the calibration poses are measured at ``states_min`` of the first warm-up (0 = cold, measured before
  the program starts), the validation poses at ``validation_states_min`` of the second; pose ids repeat across
  states (same joints), as the data contract says.

Truth: ``truth["effects"]["thermal"]["model"]`` is the drift model in the format of
:class:`robocal.thermal.model.ThermalModel` (reference ``T0`` for every sensor), plus the heating curves and
the tool-point drift per axis of each calibration state.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.kinematics.chain import propagate
from robocal.sim.effects import Rows, TwinContext, register_effect

DEFAULT_STATES_MIN = (0, 30, 60, 90, 120, 150, 180)


def _monomial(key: str, sensors: list[str]) -> dict[str, int]:
    """``"T_j4_C^2*T_l4_C"`` -> ``{"T_j4_C": 2, "T_l4_C": 1}`` (sensors must be known)."""
    out: dict[str, int] = {}
    for factor in str(key).replace(" ", "").split("*"):
        name, _, power = factor.partition("^")
        if name not in sensors:
            raise ConfigError(f"thermal effect: drift term {key!r} names the sensor {name!r}; known: {sensors}")
        try:
            k = int(power) if power else 1
        except ValueError:
            raise ConfigError(f"thermal effect: drift term {key!r} has a bad power {power!r}") from None
        if k < 1:
            raise ConfigError(f"thermal effect: drift term {key!r} must have powers >= 1")
        out[name] = out.get(name, 0) + k
    return out


@register_effect("thermal")
class ThermalEffect:
    """Warm-up with temperature-dependent kinematic parameters (see the module docstring).

    Config keys: ``T0_C`` (reference of the drift model; default the robot's ``T0_C``), ``ambient_C``
    ``[day 1, day 2]``, ``states_min``, ``validation_states_min``, ``day_gap_h``, ``log_interval_s``,
    ``sensor_noise_C``, ``heating`` ``{sensor: {rise_C, tau_min}}``, ``drift`` ``{parameter: {sensor,
    coef_mm_per_C} | {terms_deg: {monomial: coef}}}``.
    """

    name = "thermal"

    def __init__(self, cfg: Mapping[str, Any]) -> None:
        self.cfg = dict(cfg)
        self._state: np.ndarray | None = None

    # ---------------------------------------------------------------------------------------- helpers
    def _setup(self, ctx: TwinContext) -> None:
        robot = ctx.robot
        sensors = list(robot.sensor_names)
        if not sensors:
            raise ConfigError(f"thermal effect: robot {robot.name!r} has no temperature sensors")
        heat = dict(self.cfg.get("heating") or {})
        unknown = sorted(set(heat) - set(sensors))
        if unknown:
            raise ConfigError(f"thermal effect: heating names unknown sensor(s) {unknown}; robot sensors: {sensors}")
        self.sensors = sensors
        self.rise = np.array([float(dict(heat.get(s, {})).get("rise_C", 0.0)) for s in sensors])
        self.tau_s = np.array([float(dict(heat.get(s, {})).get("tau_min", 45.0)) * 60.0 for s in sensors])
        if np.any(self.tau_s <= 0):
            raise ConfigError("thermal effect: every heating tau_min must be > 0")
        t0 = self.cfg.get("T0_C", robot.T0_C)
        self.T0 = float(24.3 if t0 is None else t0)
        raw = self.cfg.get("ambient_C", [self.T0, self.T0])
        amb = [float(raw)] * 2 if isinstance(raw, int | float) else [float(v) for v in raw]
        if len(amb) != 2:
            raise ConfigError("thermal effect: ambient_C must be one value or [day 1, day 2]")
        self.ambient = amb
        self.noise_C = float(self.cfg.get("sensor_noise_C", 0.05))
        chain = ctx.chain
        kinds = chain.param_kind
        self.params: list[dict[str, Any]] = []
        for pname, spec in dict(self.cfg.get("drift") or {}).items():
            if pname not in chain.param_names:
                raise ConfigError(f"thermal effect: drift names {pname!r}, not a parameter of {chain.param_names}")
            spec = dict(spec)
            k = chain.param_names.index(pname)
            if "sensor" in spec:
                s = str(spec["sensor"])
                if s not in sensors:
                    raise ConfigError(f"thermal effect: drift of {pname!r} names unknown sensor {s!r}")
                self.params.append(
                    {
                        "name": pname,
                        "index": k,
                        "kind": kinds[k],
                        "form": "expansion",
                        "sensors": [s],
                        "terms": [[1]],
                        "coefficients": [float(spec["coef_mm_per_C"])],
                    }
                )
            elif "terms_deg" in spec:
                monos = [_monomial(key, sensors) for key in spec["terms_deg"]]
                used = [s for s in sensors if any(s in m for m in monos)]
                terms = [[m.get(s, 0) for s in used] for m in monos]
                f = np.deg2rad(1.0) if kinds[k] == "angle" else 1.0
                coefs = [float(v) * f for v in dict(spec["terms_deg"]).values()]
                self.params.append(
                    {
                        "name": pname,
                        "index": k,
                        "kind": kinds[k],
                        "form": "polynomial",
                        "sensors": used,
                        "terms": terms,
                        "coefficients": coefs,
                    }
                )
            else:
                raise ConfigError(f"thermal effect: drift of {pname!r} needs 'sensor' + 'coef_mm_per_C' or 'terms_deg'")

    def temperatures(self, h_s: np.ndarray, day: int) -> np.ndarray:
        """True temperatures ``(m, s)`` after ``h_s`` seconds of warm-up (``h <= 0``: cold) on day 0 or 1."""
        h = np.maximum(np.asarray(h_s, dtype=float), 0.0)[:, None]
        return self.ambient[day] + self.rise[None, :] * (1.0 - np.exp(-h / self.tau_s[None, :]))

    def drift(self, T: np.ndarray, n_params: int) -> np.ndarray:
        """Parameter drift ``(m, P)`` at true temperatures ``(m, s)``."""
        out = np.zeros((T.shape[0], n_params))
        for p in self.params:
            idx = [self.sensors.index(s) for s in p["sensors"]]
            x = T[:, idx] - self.T0
            val = np.zeros(T.shape[0])
            for c, e in zip(p["coefficients"], p["terms"], strict=True):
                val += c * np.prod(x ** np.asarray(e, dtype=float)[None, :], axis=1)
            out[:, p["index"]] = val
        return out

    # ------------------------------------------------------------------------------------------ effect
    def plan(self, rows: Rows, ctx: TwinContext) -> Rows:
        self._setup(ctx)
        interval = float(rows.t_s[1] - rows.t_s[0]) if len(rows.t_s) > 1 else 10.0
        states = [float(v) for v in self.cfg.get("states_min", DEFAULT_STATES_MIN)]
        vstates = [float(v) for v in self.cfg.get("validation_states_min", states)]
        if not states or states[0] != 0 or sorted(states) != states:
            raise ConfigError("thermal effect: states_min must start with 0 (the cold state) and increase")
        gap_s = float(self.cfg.get("day_gap_h", 20.0)) * 3600.0
        blocks: list[tuple[np.ndarray, int, float, int]] = []  # (row indices, day, warm-up start, state number)
        t_list, day_list, h_list, state_list = [], [], [], []
        sel_sets = [np.flatnonzero(rows.split == "calibration"), np.flatnonzero(rows.split == "validation")]
        self.warm_start_s = []
        t_cursor = 0.0
        for day, (sel, st) in enumerate(zip(sel_sets, (states, vstates), strict=True)):
            if len(sel) == 0:
                self.warm_start_s.append(np.nan)
                continue
            n = len(sel)
            start = t_cursor + n * interval  # the cold set is measured first, then the program starts
            self.warm_start_s.append(start)
            for k, smin in enumerate(st):
                t0 = start - n * interval if smin == 0 else start + smin * 60.0
                t = t0 + np.arange(n) * interval
                blocks.append((sel, day, start, k))
                t_list.append(t)
                day_list.append(np.full(n, day))
                h_list.append(t - start)
                state_list.append(np.full(n, k))
            t_cursor = start + st[-1] * 60.0 + n * interval + gap_s
        idx = np.concatenate([b[0] for b in blocks])
        m = len(idx)
        P = rows.deta.shape[1]
        new = Rows(
            pose_id=rows.pose_id[idx],
            split=rows.split[idx],
            target_index=rows.target_index[idx],
            q_cmd=rows.q_cmd[idx],
            t_s=np.concatenate(t_list),
            payload_kg=rows.payload_kg[idx],
            dq=np.zeros((m, rows.dq.shape[1])),
            deta=np.zeros((m, P)),
            columns={k: v[idx] for k, v in rows.columns.items()},
        )
        self._day = np.concatenate(day_list)
        self._h = np.concatenate(h_list)
        self._state = np.concatenate(state_list)
        self._states = (states, vstates)
        return new

    def apply(self, rows: Rows, ctx: TwinContext) -> None:
        assert self._state is not None, "plan() must run before apply()"
        P = ctx.chain.n_params
        T_true = np.zeros((len(rows.t_s), len(self.sensors)))
        for day in (0, 1):
            sel = self._day == day
            if sel.any():
                T_true[sel] = self.temperatures(self._h[sel], day)
        rows.deta += self.drift(T_true, P)

        # the temperature log: each day from 2 min before its first row to 2 min after its last
        rng = ctx.rng_factory("thermal_sensors")
        dt = float(self.cfg.get("log_interval_s", 60.0))
        t_log, T_log = [], []
        for day in (0, 1):
            sel = self._day == day
            if not sel.any():
                continue
            t = np.arange(rows.t_s[sel].min() - 120.0, rows.t_s[sel].max() + 120.0 + dt, dt)
            t_log.append(t)
            T_log.append(self.temperatures(t - self.warm_start_s[day], day))
        tt = np.concatenate(t_log)
        TT = np.concatenate(T_log)
        TT = TT + rng.normal(0.0, self.noise_C, TT.shape)
        ctx.temperature_log = {"t_s": tt, **{s: TT[:, k] for k, s in enumerate(self.sensors)}}

        # truth: the drift model in ThermalModel format, heating curves, tool-point drift per state
        truth_params = []
        for p in self.params:
            truth_params.append(
                {
                    "name": p["name"],
                    "kind": p["kind"],
                    "form": p["form"],
                    "sensors": p["sensors"],
                    "terms": p["terms"],
                    "coefficients": p["coefficients"],
                    "stderr": [0.0] * len(p["coefficients"]),
                    "intercept": 0.0,
                    "nominal": float(ctx.chain.nominal[list(ctx.chain.param).index(p["index"])])
                    if p["form"] == "expansion"
                    else 0.0,
                }
            )
        s = len(self.sensors)
        model = {
            "format": "robocal.thermal_model/1",
            "robot": ctx.robot.name,
            "param_names": list(ctx.chain.param_names),
            "sensors": list(self.sensors),
            "T_ref_C": [self.T0] * s,
            "fitted_range_C": [[self.T0, self.T0 + float(r)] for r in self.rise],
            "parameters": truth_params,
            "info": {"source": "twin truth"},
        }
        drift_rows = self._tool_drift(rows, ctx, T_true)
        ctx.truth.setdefault("effects", {})["thermal"] = {
            "model": model,
            "T0_C": self.T0,
            "ambient_C": self.ambient,
            "heating": {
                sname: {"rise_C": float(self.rise[k]), "tau_min": float(self.tau_s[k] / 60.0)}
                for k, sname in enumerate(self.sensors)
            },
            "states_min": {"calibration": self._states[0], "validation": self._states[1]},
            "warm_up_start_s": [float(v) for v in self.warm_start_s],
            "sensor_noise_C": self.noise_C,
            "tool_drift": drift_rows,
        }

    def _tool_drift(self, rows: Rows, ctx: TwinContext, T_true: np.ndarray) -> list[dict[str, float]]:
        """Mean |drift| per base-frame axis and mean 3-D drift of the tool point per calibration state (mm)."""
        tools = np.array([ctx.truth["tools_mm"][t] for t in ctx.truth["tools_mm"]])
        out: list[dict[str, float]] = []
        cal = self._day == 0
        if not cal.any():
            return out
        cold = cal & (self._state == 0)
        q = rows.q_cmd[cold]
        t = tools[rows.target_index[cold]]

        def point(deta: np.ndarray) -> np.ndarray:
            st = propagate(ctx.chain, q, ctx.eta_true + deta)
            return st.o + st.x * t[:, 0:1] + st.y * t[:, 1:2] + st.z * t[:, 2:3]

        p0 = point(rows.deta[cold].mean(axis=0))
        for k, smin in enumerate(self._states[0]):
            sel = cal & (self._state == k)
            d = point(rows.deta[sel].mean(axis=0)) - p0
            out.append(
                {
                    "state_min": float(smin),
                    "mean_abs_x_mm": float(np.mean(np.abs(d[:, 0]))),
                    "mean_abs_y_mm": float(np.mean(np.abs(d[:, 1]))),
                    "mean_abs_z_mm": float(np.mean(np.abs(d[:, 2]))),
                    "mean_3d_mm": float(np.mean(np.linalg.norm(d, axis=1))),
                    "max_3d_mm": float(np.max(np.linalg.norm(d, axis=1))),
                }
            )
        return out
