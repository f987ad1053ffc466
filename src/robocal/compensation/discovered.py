"""The joint-level effects a discovery wrote into a calibration (``effects`` records of ``calibration.json``),
evaluated for any commanded configuration: a joint-space effect of :mod:`robocal.compensation.effects`, so the
service, the program filter and ``compensation.csv`` apply them through the one compensation path.

A joint-level effect ``dq_j = S(q, payload, torque, current, direction) · c`` is added to the commanded joint
angles, exactly as the discovery fitted it (``q_true = q_cmd + dq``). Signals (:data:`SIGNALS`):

* ``angle``: ``sin(h q_j), cos(h q_j)`` of the commanded angle (gear transmission error); with
  ``held_outside_deg`` (the calibration visited less than one period of the harmonic) held at its values at the
  visited range's ends outside it (:func:`robocal.compensation.signals.held_harmonic_signal`);
* ``gravity``: the gravity torque of joint ``j`` from the robot description's masses and the payload;
* ``torque`` / ``current``: the torque or motor current the controller reports (given with the target);
* ``direction``: the approach direction ``±1`` of joint ``j`` (backlash; given with the target);
* ``dictionary``: a proposed equation's terms (products of factors of the commanded joints and gravity torques);
* ``transmission``: the gear transmission error, a Fourier series of the commanded angle, zero outside the angles
  the calibration visited (``harmonics``, ``visited_deg``, ``taper_deg``);
* ``weight``: the compliance under the arm's own weight without link masses (``basis``, ``scale``);
* ``layer``: the residual layer, a kernel ridge on all joint angles, zero outside the calibrated region
  (``centres_rad``, ``length_rad``, ``inside_rad``).

The records are written by :mod:`robocal.discovery.effects`; their signals are :mod:`robocal.compensation.signals`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.compensation.signals import (
    evaluate_factor,
    held_harmonic_signal,
    layer_signal,
    transmission_signal,
    weight_signal,
    with_payload,
)
from robocal.kinematics import compiled
from robocal.kinematics.gravity import gravity_regressor, gravity_torques, regressor_arrays
from robocal.robot import RobotDescription

if TYPE_CHECKING:
    from robocal.compensation.effects import Signals

SIGNALS = ("angle", "gravity", "torque", "current", "direction", "dictionary", "transmission", "weight", "layer",
           "logged", "logged_frame")  # fmt: skip


def joint_offsets(
    effects: list[dict[str, Any]],
    robot: RobotDescription,
    q: np.ndarray,
    payload_kg: np.ndarray | float | None = None,
    tau_Nm: np.ndarray | None = None,
    current_A: np.ndarray | None = None,
    direction: np.ndarray | None = None,
    logged: Mapping[str, np.ndarray] | None = None,
) -> np.ndarray:
    """Joint deflection ``dq (m, n)`` rad of the effects at commanded joints ``q (m, n)`` rad (an effect of the
    base or the tool, ``logged_frame``, moves no joint: :func:`frame_transforms`).

    Raises ValueError naming the missing signal when an effect needs torques, currents, directions or a logged
    signal that are not given.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    m, n = q.shape
    dq = np.zeros((m, n))
    grav = None
    Yg: np.ndarray | None = None
    for e in effects:
        kind = e["signal"]
        if kind == "logged_frame":
            continue
        j = int(e["joint"]) - 1
        c = np.asarray(e["coefficients"], dtype=float)
        if kind == "logged":
            S = logged_values(e, logged, m)[:, None]
        elif kind == "angle":
            S = held_harmonic_signal(q[:, j], int(e["harmonic"]), e.get("held_outside_deg"))
        elif kind == "transmission":
            S = transmission_signal(q[:, j], e)
        elif kind == "weight":
            if Yg is None:  # one regressor for every joint's weight effect
                Yg = gravity_regressor(robot, q)
            S = weight_signal(robot, q, e, Yg, payload_kg)
        elif kind == "layer":
            S = layer_signal(q, e)[0]
        elif kind == "dictionary":
            if grav is None and any(f["kind"] == "gravity" for t in e["terms"] for f in t["factors"]):
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
    layer = [e for e in effects if e.get("signal") == "layer"]
    if not layer:
        return None
    return layer_signal(np.atleast_2d(np.asarray(q, dtype=float)), layer[0])[1]


LAYER_NOTE = "outside the calibrated region: the residual layer is not applied (parametric correction only)"


def request_fields(effects: list[dict[str, Any]]) -> set[str]:
    """The per-target fields of a request the effect records read besides the joints: ``tau_Nm``, ``current_A``,
    ``dir``, and ``signal:<column>`` for an effect driven by a logged signal. (What a joint-space effect *needs*,
    among :data:`robocal.compensation.effects.SIGNALS`, is :attr:`DiscoveredEffects.needs`.)"""
    names = {"torque": "tau_Nm", "current": "current_A", "direction": "dir"}
    out = {names[e["signal"]] for e in effects if e["signal"] in names}
    return out | {f"signal:{e['column']}" for e in effects if e["signal"] in ("logged", "logged_frame")}


def logged_values(e: Mapping[str, Any], logged: Mapping[str, np.ndarray] | None, m: int) -> np.ndarray:
    """The centred values ``(m,)`` of the logged signal an effect record follows; a ValueError naming the effect
    and the signal when it is not given (or not one value per target)."""
    col = str(e["column"])
    if logged is None or col not in logged:
        raise ValueError(f"the effect {e['key']} needs the logged signal '{col}' with each target (its value at the "
                         "moment, as in the campaign's column)")  # fmt: skip
    v = np.broadcast_to(np.asarray(logged[col], dtype=float), (m,))
    if not np.all(np.isfinite(v)):
        raise ValueError(f"the effect {e['key']} needs a finite value of the logged signal '{col}' for every target")
    return v - float(e["centre"])


def _rotation(w: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(m, 3, 3)`` of rotation vectors ``w (m, 3)``."""
    from robocal.kinematics.transforms import rotvec_to_matrix

    return np.asarray(rotvec_to_matrix(w))


def frame_transforms(
    effects: list[dict[str, Any]],
    logged: Mapping[str, np.ndarray] | None,
    m: int,
    q: np.ndarray | None = None,
    robot: RobotDescription | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The base and the tool as the logged signals move them (``logged_frame`` records), per target: ``(A (m, 4,
    4), D (m, 4, 4))`` with the real tool at ``A · base_T_flange(q) · D · flange_T_tool`` — ``A`` the base turned
    (rotation vector, base axes) and moved about its origin, and turned about the origin of the carriage of the
    linear axis carrying the arm (``carriage_rot``: base axes, the origin at the targets' joints ``q (m, n)`` of
    ``robot``), ``D`` the tool turned and moved on the flange (flange axes); None when no record is a frame
    effect."""
    frames = [e for e in effects if e["signal"] == "logged_frame"]
    if not frames:
        return None
    vec = {k: np.zeros((m, 3)) for k in ("base_rot", "base_trans", "tool_rot", "tool_trans", "carriage_rot")}
    for e in frames:
        vec[e["frame"]] += logged_values(e, logged, m)[:, None] * np.asarray(e["coefficients"], dtype=float)[None, :]
    carriage = next((e for e in frames if e["frame"] == "carriage_rot"), None)  # one carrying axis
    if carriage is not None and (q is None or robot is None):
        raise ValueError(f"the effect {carriage['key']} turns a carriage: its origin needs the targets' joints")
    A = np.tile(np.eye(4), (m, 1, 1))
    D = np.tile(np.eye(4), (m, 1, 1))
    A[:, :3, :3], A[:, :3, 3] = _rotation(vec["base_rot"]), vec["base_trans"]
    if carriage is not None:  # about the carriage's origin c: [R, c - R c], after the base's own
        from robocal.kinematics.axes import carriage_origin

        assert q is not None and robot is not None
        pivot = carriage_origin(robot, np.atleast_2d(q), int(carriage["axis_joint"]) - 1)
        C = np.tile(np.eye(4), (m, 1, 1))
        C[:, :3, :3] = Rc = _rotation(vec["carriage_rot"])
        C[:, :3, 3] = pivot - np.einsum("mij,mj->mi", Rc, pivot)
        A = A @ C
    D[:, :3, :3], D[:, :3, 3] = _rotation(vec["tool_rot"]), vec["tool_trans"]
    return A, D


def frame_desired(
    frames: tuple[np.ndarray, np.ndarray], tool_T: np.ndarray, p: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pose ``(p (m, 3), R (m, 3, 3))`` the calibrated robot's ``base_T_flange(q) · tool_T`` must reach so that
    the real tool, moved by the frames ``(A, D)`` of :func:`frame_transforms`, lands on the desired ``(p, R)``:
    ``A⁻¹ · P · tool_T⁻¹ · D⁻¹ · tool_T``."""
    A, D = frames
    m = len(p)
    P = np.tile(np.eye(4), (m, 1, 1))
    P[:, :3, :3], P[:, :3, 3] = R, p
    T = np.broadcast_to(np.asarray(tool_T, dtype=float), (m, 4, 4))
    out = np.linalg.inv(A) @ P @ np.linalg.inv(T) @ np.linalg.inv(D) @ T
    return out[:, :3, 3], out[:, :3, :3]


TWO_PI = 2.0 * np.pi


def balancer_record(e: dict[str, Any]) -> dict[str, Any]:
    """A weight record's counterbalance part (:func:`robocal.compensation.signals.balancer_signal`) as the
    transmission record of the same Fourier signal with its window open (what the service tabulates)."""
    r = len(e["scale"])
    return {"signal": "transmission", "joint": e["joint"], "harmonics": list(e["balancer_harmonics"]),
            "visited_deg": [[0.0, 360.0]], "taper_deg": 0.0, "centre": list(e["balancer_centre"]),
            "coefficients": list(np.asarray(e["coefficients"], dtype=float)[r:])}  # fmt: skip


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

#: angles per chunk of a table's evaluation (a multiple of 64: every row's products as in one evaluation)
TABLE_CHUNK = 1 << 14


@dataclass(frozen=True)
class DiscoveredEffects:
    """The joint-level effects a discovery wrote into a calibration (``effects`` records, evaluated by
    :func:`joint_offsets`): a joint-space effect of :mod:`robocal.compensation.effects`."""

    records: tuple[dict[str, Any], ...]
    robot: Any
    name: str = "discovered effects"

    @property
    def needs(self) -> frozenset[str]:
        return frozenset("direction" if k == "dir" else k for k in request_fields(list(self.records)))

    @property
    def keys(self) -> list[str]:
        return [str(e["key"]) for e in self.records]

    def offsets(self, q: np.ndarray, s: Signals) -> np.ndarray:
        tables, weights, rest = self._tables
        q = np.atleast_2d(np.asarray(q, dtype=float))
        fused = self._fused
        if fused is not None:  # every effect tabulated or a weight effect: one compiled call
            return compiled.joint_tables_and_weight(np.ascontiguousarray(q), *fused)
        dq = (
            joint_offsets(rest, self.robot, q, s.payload_kg, s.tau_Nm, s.current_A, s.direction, s.logged)
            if rest
            else np.zeros(q.shape)
        )
        if tables is not None:
            cols, grid, vals, start = tables
            dq[:, cols] += _interp_tables(q, cols, grid, vals, start)
        if weights is not None:
            wcols, P = weights
            Y = gravity_regressor(self.robot, q)
            if P.shape[1] > Y.shape[2]:  # fitted on rows of several payloads: each target's own
                Y = with_payload(Y, s.payload_kg)
            dq[:, wcols] += np.einsum("mjk,jk->mj", Y[:, wcols, :], P)
        return dq

    @cached_property
    def _fused(self) -> tuple[Any, ...] | None:
        """The arguments of :func:`robocal.kinematics.compiled.joint_tables_and_weight` after ``q`` when every
        record is in the tables or a weight effect (and numba is there), else None (the sum term by term)."""
        tables, weights, rest = self._tables
        layer = self._layer
        if layer is not None:
            rest = [e for e in rest if e["signal"] != "layer"]
        if rest or not compiled.AVAILABLE or (tables is None and weights is None and layer is None):
            return None
        if weights is not None and weights[1].shape[1] != 4 * self.robot.n_joints:
            return None  # a payload's columns (each target's own payload): the sum term by term
        n = self.robot.n_joints
        none_i, none_f = np.zeros(0, dtype=np.int64), np.zeros(0)
        cols, grid, vals, start = tables if tables is not None else (none_i, none_f, none_f, np.zeros(1, np.int64))
        wcols, P = weights if weights is not None else (none_i, np.zeros((0, 4 * n)))
        lay = layer if layer is not None else (none_i, np.zeros((0, n)), 1.0, 0.0, np.zeros((0, 0)))
        return (cols, grid, vals, start, TWO_PI, wcols, np.ascontiguousarray(P), *lay, *regressor_arrays(self.robot))

    @cached_property
    def _layer(self) -> tuple[np.ndarray, np.ndarray, float, float, np.ndarray] | None:
        """The residual layer's records as ``(joints, centres (D, n), length, inside, W (D, joints))`` when they
        share one kernel (the discovery fits every joint's layer on the same centres), else None (evaluated
        record by record)."""
        recs = [e for e in self.records if e["signal"] == "layer"]
        if not recs:
            return None
        centres = np.asarray(recs[0]["centres_rad"], dtype=float)
        ell, inside = float(recs[0]["length_rad"]), float(recs[0]["inside_rad"])
        if any(
            not np.array_equal(np.asarray(e["centres_rad"], dtype=float), centres)
            or float(e["length_rad"]) != ell
            or float(e["inside_rad"]) != inside
            for e in recs
        ):
            return None
        per_joint: dict[int, np.ndarray] = {}
        for e in recs:
            j = int(e["joint"]) - 1
            per_joint[j] = per_joint.get(j, 0.0) + np.asarray(e["coefficients"], dtype=float)
        js = sorted(per_joint)
        W = np.ascontiguousarray(np.stack([per_joint[j] for j in js], axis=1))
        return np.array(js, dtype=np.int64), np.ascontiguousarray(centres), ell, inside, W

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
        rest = [e for e in self.records if not _tabulated(e) and e["signal"] not in ("weight", "logged_frame")]
        per_joint: dict[int, np.ndarray] = {}
        for e in self.records:
            if e["signal"] == "weight":
                j = int(e["joint"]) - 1
                r = len(e["scale"])
                c = np.asarray(e["coefficients"], dtype=float)[:r] / np.asarray(e["scale"], dtype=float)
                per_joint[j] = per_joint.get(j, 0.0) + np.asarray(e["basis"], dtype=float) @ c
                if e.get("balancer_harmonics"):  # a counterbalance's part: of the shoulder's angle alone, tabulated
                    single.append(balancer_record(e))
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
            # in chunks of the grid: the signals of tens of harmonics over 2^18 angles are hundreds of MB at once
            v = np.concatenate([joint_offsets(recs, self.robot, Q[a : a + TABLE_CHUNK])[:, j]
                                for a in range(0, len(Q), TABLE_CHUNK)])  # fmt: skip
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
        layer = self._layer
        if layer is not None and compiled.AVAILABLE:
            _, centres, ell, inside, _ = layer
            cover = compiled.layer_gate(np.ascontiguousarray(np.atleast_2d(np.asarray(q, dtype=float))), centres, ell,
                                        inside)  # fmt: skip
        else:
            cover = layer_coverage(list(self.records), q)
        if cover is None:
            return [[] for _ in range(len(q))]
        return [[f"{LAYER_NOTE} (layer weight {c:.2f})"] if c < 1.0 else [] for c in cover]
