"""Discovered effects as a product: the extended model written as a calibration, and its joint-level effects
evaluated for any commanded configuration (offline compensation and the online service).

A joint-level effect ``dq_j = S(q, payload, torque, current, direction) · c`` is added to the commanded joint
angles, exactly as the discovery fitted it (``q_true = q_cmd + dq``) and as the compensation's
``joint_offset`` hook expects. Signals:

* ``angle``: ``sin(h q_j), cos(h q_j)`` of the commanded angle (gear transmission error); with
  ``held_outside_deg`` (the calibration visited less than one period of the harmonic) held at its values at the
  visited range's ends outside it (:func:`robocal.discovery.physics.held_harmonic_signal`);
* ``gravity``: the gravity torque of joint ``j`` from the robot description's masses and the payload;
* ``torque`` / ``current``: the torque or motor current the controller reports (given with the target);
* ``direction``: the approach direction ``±1`` of joint ``j`` (backlash; given with the target);
* ``transmission``: the gear transmission error, a Fourier series of the commanded angle, zero outside the angles
  the calibration visited (``harmonics``, ``visited_deg``, ``taper_deg``; :mod:`robocal.discovery.physics`);
* ``weight``: the compliance under the arm's own weight without link masses (``basis``, ``scale``);
* ``layer``: the residual layer, a kernel ridge on all joint angles, zero outside the calibrated region
  (``centres_rad``, ``length_rad``, ``inside_rad``).

Parameter drifts (thermal, drift) need the temperatures or the time of the moment: they are written under
``not_compensated`` with the reason, never applied silently.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.discovery.model import Accepted, Fit
from robocal.identification.calibrate import CalibrationConfig, CalibrationResult, calibration_record
from robocal.identification.identifiability import Eliminated, Identifiability
from robocal.robot import RobotDescription

if TYPE_CHECKING:
    from robocal.compensation.effects import Signals

SIGNALS = ("angle", "gravity", "torque", "current", "direction", "dictionary", "transmission", "weight", "layer")


def signal_kind(acc: Accepted) -> str | None:
    """The signal of a joint-level effect (one of :data:`SIGNALS`), None for parameter or structure effects."""
    c = acc.cand
    if c.shape != "joint":
        return None
    if c.effect == "gear":
        return "angle"
    if c.effect in ("transmission", "weight", "layer"):
        return c.effect
    if c.effect == "backlash":
        return "direction"
    if c.effect == "compliance":
        return str(c.extra.get("source", "gravity"))
    if c.effect == "proposed":
        from robocal.discovery.dictionary import Term

        ok = all(
            Term(tuple((f["kind"], f["index"], f["harmonic"]) for f in t["factors"])).from_joints_only
            for t in c.extra["terms"]
        )
        return "dictionary" if ok else None
    raise ValueError(f"unknown joint-level effect {c.effect!r}")


def effect_records(fit: Fit) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The accepted effects of a discovery fit as JSON records: ``(joint_level, not_compensated)``."""
    model = fit.model
    joint_level: list[dict[str, Any]] = []
    other: list[dict[str, Any]] = []
    for acc, sl in zip(model.accepted, model.slices, strict=True):
        c = acc.cand
        kind = signal_kind(acc)
        if kind is None:
            if c.shape == "structure":
                continue  # lives in the geometry (beta), already in the calibration
            if c.effect == "proposed":
                why = "a proposed equation with a term the commanded joints do not give (temperature, time, torque)"
            elif c.effect in ("drift", "air", "regap"):
                why = "a measurement-side effect (the tracker's frame moving): it corrects the figures, never the robot"
            elif c.effect == "scale":
                why = "a measurement-side effect (the tracker's length scale): it corrects the figures, never the robot"
            else:
                why = (
                    "a parameter drift with "
                    + ("the temperatures" if c.effect == "thermal" else "time")
                    + ": it needs the state of the moment, not the commanded joints; "
                    "use the thermal pipeline's model for online compensation"
                )
            other.append({"key": c.key, "effect": c.effect, "reason": why})
            continue
        assert c.joint is not None
        rec_terms: dict[str, Any] = {"terms": c.extra["terms"]} if kind == "dictionary" else {}
        if kind == "angle" and c.extra.get("held_outside_deg") is not None:
            rec_terms = {"held_outside_deg": list(c.extra["held_outside_deg"])}
        elif kind == "transmission":
            rec_terms = {k: c.extra[k] for k in ("harmonics", "visited_deg", "taper_deg", "centre")}
        elif kind == "weight":
            rec_terms = {k: c.extra[k] for k in ("basis", "scale", "prior_deg")}
        elif kind == "layer":
            rec_terms = {k: c.extra[k] for k in ("centres_rad", "length_rad", "inside_rad")}
        joint_level.append(
            {
                **rec_terms,
                "key": c.key,
                "effect": c.effect,
                "joint": int(c.joint),
                "harmonic": None if c.harmonic is None else int(c.harmonic),
                "signal": kind,
                "coefficients": [float(v) for v in fit.theta[sl]],
                "coefficient_names": list(c.coef_names),
                "units": list(c.coef_units),
            }
        )
    return joint_level, other


def joint_offsets(
    effects: list[dict[str, Any]],
    robot: RobotDescription,
    q: np.ndarray,
    payload_kg: np.ndarray | float | None = None,
    tau_Nm: np.ndarray | None = None,
    current_A: np.ndarray | None = None,
    direction: np.ndarray | None = None,
) -> np.ndarray:
    """Joint deflection ``dq (m, n)`` rad of the effects at commanded joints ``q (m, n)`` rad.

    Raises ValueError naming the missing signal when an effect needs torques, currents or directions that are
    not given.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    m, n = q.shape
    dq = np.zeros((m, n))
    grav = None
    Yg: np.ndarray | None = None
    for e in effects:
        j = int(e["joint"]) - 1
        c = np.asarray(e["coefficients"], dtype=float)
        kind = e["signal"]
        if kind == "angle":
            from robocal.discovery.physics import held_harmonic_signal

            S = held_harmonic_signal(q[:, j], int(e["harmonic"]), e.get("held_outside_deg"))
        elif kind == "transmission":
            from robocal.discovery.physics import transmission_signal

            S = transmission_signal(q[:, j], e)
        elif kind == "weight":
            from robocal.discovery.physics import gravity_regressor, weight_signal

            if Yg is None:  # one regressor for every joint's weight effect
                Yg = gravity_regressor(robot, q)
            S = weight_signal(robot, q, e, Yg)
        elif kind == "layer":
            from robocal.discovery.physics import layer_signal

            S = layer_signal(q, e)[0]
        elif kind == "dictionary":
            from robocal.discovery.dictionary import evaluate_factor

            if grav is None and any(f["kind"] == "gravity" for t in e["terms"] for f in t["factors"]):
                from robocal.kinematics.gravity import gravity_torques

                pay = np.broadcast_to(np.asarray(0.0 if payload_kg is None else payload_kg, dtype=float), (m,))
                grav = gravity_torques(robot, q, pay)
            S = np.column_stack(
                [
                    np.prod(
                        [evaluate_factor((f["kind"], f["index"], f["harmonic"]), q, grav) for f in t["factors"]],
                        axis=0,
                    )
                    for t in e["terms"]
                ]
            )
        elif kind == "gravity":
            if grav is None:
                from robocal.kinematics.gravity import gravity_torques

                pay = np.broadcast_to(np.asarray(0.0 if payload_kg is None else payload_kg, dtype=float), (m,))
                grav = gravity_torques(robot, q, pay)
            S = grav[:, j : j + 1]
        elif kind in ("torque", "current", "direction"):
            arr = {"torque": tau_Nm, "current": current_A, "direction": direction}[kind]
            if arr is None:
                field = {"torque": "tau_Nm", "current": "current_A", "direction": "dir"}[kind]
                raise ValueError(
                    f"the effect {e['key']} needs '{field}' (the {kind} of joint {j + 1}) with each target"
                )
            S = np.asarray(arr, dtype=float).reshape(m, n)[:, j : j + 1]
        else:
            raise ValueError(f"unknown effect signal {kind!r} in {e.get('key')}; known: {SIGNALS}")
        dq[:, j] += S @ c
    return dq


def layer_coverage(effects: list[dict[str, Any]], q: np.ndarray) -> np.ndarray | None:
    """``(m,)`` in [0, 1]: how much of the residual layer applies at joints ``q (m, n)`` rad (1 inside the
    calibrated region, 0 outside: the parametric correction alone), or None when the effects have no layer."""
    from robocal.discovery.physics import layer_signal

    layer = [e for e in effects if e.get("signal") == "layer"]
    if not layer:
        return None
    return layer_signal(np.atleast_2d(np.asarray(q, dtype=float)), layer[0])[1]


LAYER_NOTE = "outside the calibrated region: the residual layer is not applied (parametric correction only)"


def needs(effects: list[dict[str, Any]]) -> set[str]:
    """The per-target signals the effects need besides the joints: ``tau_Nm``, ``current_A``, ``dir``."""
    names = {"torque": "tau_Nm", "current": "current_A", "direction": "dir"}
    return {names[e["signal"]] for e in effects if e["signal"] in names}


TWO_PI = 2.0 * np.pi


def _tabulated(e: dict[str, Any]) -> bool:
    """A record the service tabulates over one revolution of its joint: the transmission error and the gear
    harmonics (held or not: periodic in the joint's angle)."""
    return e["signal"] in ("transmission", "angle")


#: numeric list fields of the effect records (converted once by :class:`DiscoveredEffects`)
_ARRAY_FIELDS = ("coefficients", "basis", "scale", "centre", "centres_rad")


def _interp_tables(
    q: np.ndarray, cols: np.ndarray, grid: np.ndarray, vals: np.ndarray, start: np.ndarray
) -> np.ndarray:
    """Linear interpolation of the tables of :meth:`DiscoveredEffects._tables` at joints ``q`` (compiled when
    numba is there)."""
    from robocal.kinematics import compiled

    if compiled.AVAILABLE:
        return compiled.periodic_tables(q, cols, grid, vals, start, TWO_PI)
    out = np.empty((len(q), len(cols)))
    for t, j in enumerate(cols):
        g, v = grid[start[t] : start[t + 1]], vals[start[t] : start[t + 1]]
        x = np.mod(q[:, j], TWO_PI)
        i = np.minimum(np.searchsorted(g, x, side="right") - 1, len(g) - 2)  # x = 2 pi after rounding
        out[:, t] = v[i] + (x - g[i]) * ((v[i + 1] - v[i]) / (g[i + 1] - g[i]))
    return out


def _window_kinks(records: list[dict[str, Any]]) -> np.ndarray:
    """The angles (rad, in [0, 2 pi]) where a record's signal is not smooth: for a transmission record each visited
    interval's ends, the ends of its tapers, and half-way between neighbouring intervals (where the nearest one
    changes); for a held gear harmonic the visited range's ends and the ends of the blend over the middle half of
    the arc never visited. On the table's grid, linear interpolation is exact there."""
    out: list[float] = []
    for e in records:
        if e["signal"] == "angle" and e.get("held_outside_deg") is not None:
            lo, hi = (float(a) for a in e["held_outside_deg"])
            gap = 360.0 - (hi - lo)
            out += [lo, hi, hi + 0.25 * gap, hi + 0.75 * gap]
        if e["signal"] != "transmission":
            continue
        tp = float(e["taper_deg"])
        iv = sorted((float(lo), float(hi)) for lo, hi in e["visited_deg"])
        for k, (lo, hi) in enumerate(iv):
            lo_next = iv[(k + 1) % len(iv)][0]
            out += [lo, hi, lo - tp, hi + tp, hi + 0.5 * ((lo_next - hi) % 360.0)]
    return np.deg2rad(np.mod(out, 360.0))


#: A joint's single-angle effects are tabulated over one revolution in this many steps (4.8e-5 rad) ...
TABLE_SIZE = 1 << 17
#: ... when linear interpolation is within this (rad) of the exact sum: 1e-8 rad is 1e-5 mm at a metre's reach,
#: a tenth of the Newton solver's tolerance (a stiffer effect is evaluated exactly).
TABLE_TOL_RAD = 1e-8


@dataclass(frozen=True)
class DiscoveredEffects:
    """The joint-level effects a discovery wrote into a calibration (``effects`` records, evaluated by
    :func:`joint_offsets`): a joint-space effect of :mod:`robocal.compensation.effects`."""

    records: tuple[dict[str, Any], ...]
    robot: Any
    name: str = "discovered effects"

    @property
    def needs(self) -> frozenset[str]:
        return frozenset("direction" if k == "dir" else k for k in needs(list(self.records)))

    @property
    def keys(self) -> list[str]:
        return [str(e["key"]) for e in self.records]

    def offsets(self, q: np.ndarray, s: Signals) -> np.ndarray:
        tables, weights, rest = self._tables
        q = np.atleast_2d(np.asarray(q, dtype=float))
        dq = joint_offsets(rest, self.robot, q, s.payload_kg, s.tau_Nm, s.current_A, s.direction) if rest else (
            np.zeros(q.shape))  # fmt: skip
        if tables is not None:
            cols, grid, vals, start = tables
            dq[:, cols] += _interp_tables(q, cols, grid, vals, start)
        if weights is not None:
            from robocal.discovery.physics import gravity_regressor

            wcols, P = weights
            dq[:, wcols] += np.einsum("mjk,jk->mj", gravity_regressor(self.robot, q)[:, wcols, :], P)
        return dq

    @cached_property
    def _tables(
        self,
    ) -> tuple[tuple[np.ndarray, ...] | None, tuple[np.ndarray, np.ndarray] | None, list[dict[str, Any]]]:
        """The records in the form the service evaluates at every Newton step: ``(tables, weights, rest)``.

        tables: the effects of one joint's own angle (gear harmonics, transmission error: periodic in it), summed
        per joint and tabulated over one revolution (:data:`TABLE_SIZE` steps, plus the windows' kinks) for
        linear interpolation, as ``(joints, grids, values, starts)``; a joint whose table is not within
        :data:`TABLE_TOL_RAD` of the exact sum at every mid-point (the largest error of linear interpolation)
        stays exact. weights: the compliance under the arm's own weight of joint ``j`` is ``Y_j(q) @ pi_j``
        (``pi_j = basis (coefficients / scale)``: mass moments over stiffness), as ``(joints, rows pi_j)``.
        rest: the other records, their numeric lists as arrays."""
        single = [e for e in self.records if _tabulated(e)]
        rest = [e for e in self.records if not _tabulated(e) and e["signal"] != "weight"]
        per_joint: dict[int, np.ndarray] = {}
        for e in self.records:
            if e["signal"] == "weight":
                j = int(e["joint"]) - 1
                c = np.asarray(e["coefficients"], dtype=float) / np.asarray(e["scale"], dtype=float)
                per_joint[j] = per_joint.get(j, 0.0) + np.asarray(e["basis"], dtype=float) @ c
        weights = None
        if per_joint:
            wj = sorted(per_joint)
            weights = (np.array(wj, dtype=np.int64), np.stack([per_joint[j] for j in wj]))
        n = self.robot.n_joints
        uniform = np.linspace(0.0, TWO_PI, TABLE_SIZE + 1)  # both ends: the angle is taken modulo one revolution
        cols, grids, vals_all = [], [], []
        for j in sorted({int(e["joint"]) - 1 for e in single}):
            recs = [e for e in single if int(e["joint"]) - 1 == j]
            grid = np.unique(np.concatenate([uniform, _window_kinks(recs)]))
            mid = 0.5 * (grid[:-1] + grid[1:])
            Q = np.zeros((len(grid) + len(mid), n))
            Q[:, j] = np.concatenate([grid, mid])
            v = joint_offsets(recs, self.robot, Q)[:, j]
            vals, exact = v[: len(grid)], v[len(grid) :]
            if float(np.abs(0.5 * (vals[:-1] + vals[1:]) - exact).max()) <= TABLE_TOL_RAD:
                cols.append(j)
                grids.append(grid)
                vals_all.append(vals)
            else:
                rest += recs
        tables = None
        if cols:
            start = np.cumsum([0] + [len(g) for g in grids]).astype(np.int64)
            tables = (np.array(cols, dtype=np.int64), np.concatenate(grids), np.concatenate(vals_all), start)
        # the stored lists (coefficients, bases) as arrays once, not at every call
        rest = [{k: (np.asarray(v, dtype=float) if k in _ARRAY_FIELDS else v) for k, v in e.items()} for e in rest]
        return tables, weights, rest

    def notes(self, q: np.ndarray) -> list[list[str]]:
        """Per target: :data:`LAYER_NOTE` (with the layer's weight) where the residual layer is not fully
        applied (outside the calibrated region), else nothing."""
        cover = layer_coverage(list(self.records), q)
        if cover is None:
            return [[] for _ in range(len(q))]
        return [[f"{LAYER_NOTE} (layer weight {c:.2f})"] if c < 1.0 else [] for c in cover]


def extended_calibration(fit: Fit, robot: RobotDescription, summary_fit: dict[str, Any]) -> dict[str, Any]:
    """The discovered model written as a calibration (the geometric format of
    :func:`~robocal.identification.calibrate.calibration_record`, so every reader of ``calibration.json`` takes
    it) with its joint-level effects under ``effects`` and the rest under ``effects_not_compensated``."""
    model = fit.model
    base = model.base
    nb = model.nb
    x = fit.theta[:nb].copy()
    free_b = np.array([i for i in fit.free if i < nb], dtype=int)
    identified = np.zeros(base.n, dtype=bool)
    identified[free_b] = True
    pos = [int(np.flatnonzero(fit.free == i)[0]) for i in free_b]
    cov = fit.cov[np.ix_(pos, pos)]
    stderr = np.full(base.n, np.nan)
    stderr[free_b] = np.sqrt(np.diag(cov))
    elim = tuple(
        Eliminated(n, (), 0.0, "not identifiable in the extended model") for n in fit.eliminated if n in base.names
    )
    Jn = fit.J_w[:, pos] / np.maximum(np.linalg.norm(fit.J_w[:, pos], axis=0), 1e-300)
    ident = Identifiability(
        kept=free_b,
        eliminated=elim,
        rank=len(free_b),
        singular_values=np.linalg.svd(Jn, compute_uv=False),
        names=base.names,
    )
    out = calibration_record(
        base, x, identified, stderr, cov, ident, (), summary_fit, CalibrationConfig(noise_mm=fit.sigma)
    )
    joint_level, other = effect_records(fit)
    out["effects"] = joint_level
    out["effects_not_compensated"] = other
    if not np.array_equal(base.robot.beta_free, robot.beta_free):
        out["beta_free"] = [bool(v) for v in base.robot.beta_free]
    out["source"] = "robocal discover: geometry and every named effect, fitted jointly"
    return out


def compensate_targets(
    cal: CalibrationResult,
    q_target: np.ndarray,
    target: str | None = None,
    payload_kg: np.ndarray | float = 0.0,
    tau_Nm: np.ndarray | None = None,
    current_A: np.ndarray | None = None,
    direction: np.ndarray | None = None,
    **newton: Any,
) -> tuple[Any, np.ndarray]:
    """Offline compensation with a calibration and its discovered joint-level effects (robot base frame): the
    joints that put the real tool where the nominal controller expects it at ``q_target (m, n)`` rad.

    Returns the :class:`robocal.compensation.Compensation` (with the one safety policy's status per target) and
    the nominal Cartesian command ``(m, 4, 4)``
    (what the nominal controller must be sent so that its inverse kinematics yields the corrected joints).
    ``newton``: stopping rules of :func:`robocal.compensation.compensate` (``max_iter``, ``tol_mm``, ``tol_rad``)."""
    from robocal.compensation import ActualRobot, compensate, desired_poses, judge_compensation
    from robocal.compensation.effects import Signals, compose, joint_effects
    from robocal.kinematics.chain import fk

    model = cal.model
    k = 0 if target is None else model.target_names.index(target)
    tool = model.tools(cal.x)[k]
    tool_R = model.tool_rotations(cal.x)[k]
    m = len(q_target)
    pay = np.broadcast_to(np.asarray(payload_kg, dtype=float), (m,))
    records = cal.effects
    effects = joint_effects(None, DiscoveredEffects(records, model.robot) if records else None)
    try:
        offset = compose(effects, Signals(pay, tau_Nm, current_A, direction))
    except ValueError:  # a signal not given: the effect's own error names it when evaluated
        from robocal.compensation.effects import JointOffsets

        offset = JointOffsets(tuple(effects), Signals(pay, tau_Nm, current_A, direction))
    actual = ActualRobot(model.chain, cal.kinematic_errors, np.eye(4), tool, tool_R, offset)
    nominal = ActualRobot(model.chain, np.zeros(model.chain.n_params), np.eye(4), tool, tool_R)
    p_d, R_d = desired_poses(nominal, q_target)
    comp = compensate(actual, q_target, p_d, R_d, **newton)
    comp.status, comp.reasons = judge_compensation(
        actual, comp, p_d, None, model.robot.q_limits, model.robot.joint_names
    )
    T_tool = np.eye(4)
    T_tool[:3, :3], T_tool[:3, 3] = tool_R, tool
    return comp, fk(model.chain, comp.q) @ T_tool
