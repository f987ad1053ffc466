"""Every logged signal is a candidate driver: the extra numeric columns of a campaign as causes of effects.

A numeric column of ``poses.csv`` the data contract does not name (:mod:`robocal.logged_signals`: an
inclinometer, an accelerometer, an external axis position, a load cell, a time counter) is first screened:

* a column that does not vary or is not numeric is not used (said, with the reason);
* a column with a few missing readings (a sensor sampled more slowly than the poses, dropped samples: at most
  :data:`MAX_MISSING_SHARE` of the rows) has them filled (:func:`fill_gaps`), by linear interpolation in time or
  by its regression on the joint-angle basis, whichever predicts the column's own readings better left out one at
  a time (a tilt that follows the arm's weight is a function of the pose, a slow drift one of time); the rows
  filled, the way and its error are reported. Before, one empty cell dropped the signal;
* a column that is a function of the joints — a commanded pose logged beside the joints, a copy of a joint — is
  recognised by regressing it on a joint-angle basis (the angles, their first two harmonics and the nominal
  flange pose) and not used: R² of at least :data:`FUNCTION_R2` (it carries nothing the joints do not, and an
  effect driven by it would be a joint-angle effect under another name). A sensor reads its cause with its own
  noise: an inclinometer under a stand tilting with the arm's weight follows the pose to R² ~0.9996 (a commanded
  value logged beside the joints to 1 - 1e-7 and closer), and a *declared* sensor is offered whatever its R²
  (said: "mostly a function of the pose");
* a column that is a function of the measurement itself (the tracker's own distance, angles or coordinates) is
  recognised by regressing it on the measured position (linear, quadratic and spherical terms) and not used: an
  effect driven by it would fit the measurement with itself (a declared sensor is offered, as above);
* a column equal to an earlier usable one (|r| >= :data:`COPY_R`) is a copy and not used twice;
* a column whose name says it logs a commanded pose or set point (``goal_roll_rad``, ``cmd_x_mm``:
  :func:`commanded_column`) is a function of the joints even where the regression cannot show it (angles that wrap,
  roll and yaw undefined at pitch +-90 deg) and is not used unless declared;
* a column whose name says it is the instrument's stated uncertainty of its reading (``std_x_mm``, ``u_mm``,
  ``sigma_z``: :func:`uncertainty_column`) is a noise figure, not a cause, and is not used unless declared.

Each remaining signal ``s`` (centred on the calibration rows) is offered as the cause of

* ``signal:<col>:base_rot`` / ``base_trans``: the robot base rotating / moving with the signal (``rx, ry, rz`` rad
  or ``tx, ty, tz`` mm per unit of the signal, in the robot's base axes; on every tracker station);
* ``signal:<col>:tool_rot`` / ``tool_trans``: the tool (every target alike) rotating / moving on the flange
  (flange axes);
* ``signal:<col>:carriage_rot``: on an arm a linear axis carries, the axis's carriage rotating about its own
  origin, which travels with the axis (base axes: :func:`offered_frames`);
* ``signal:<col>:j<j>``: a joint offset ``dq_j = c · s`` (rad per unit);
* ``signal:<col>:scale``: the tracker's length scale following the signal (ppm per unit, measurement side).

The frame effects are ``frame`` candidates (first order, like the parameter drifts: ``dp = G c s`` with ``G`` the
model's Jacobian of the base or tool frame, :func:`frame_columns`); the joint offsets are ordinary joint effects.
They join the library, so they pass the same false-discovery control (the F-test with its Bonferroni threshold
over the whole library, the BIC, the excess share and the pose-grouped cross-validation; the cross-validated
selection's own test for the leftovers).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from robocal.data.columns import known_columns
from robocal.data.contract import Campaign
from robocal.logged_signals import SignalDeclaration, merged
from robocal.robot import RobotDescription

#: R² (or |r|) at or above which a column is a function of the joints, of the measurement, or a copy of another
#: column: a logged sensor carries its own noise and its own cause, so it never reaches this on a joint basis of
#: ~40 functions over a few hundred rows (a random column's R² is about 40 / rows), while a commanded value
#: logged beside the joints, rounded to 1e-6, is at 1 - 1e-9.
#: (was 0.999: a declared inclinometer under a stand tilting 3 mrad with the arm's weight, 0.005 mrad of sensor noise
#: and 0.05 mrad of wander, reaches 0.9996 and was not used; the UR10's commanded goal_x/y/z_mm reach 1 - 2e-7 to
#: 1 - 3e-8 and its goal_pitch_rad 1 - 5e-6)
FUNCTION_R2 = 0.99999
#: |r| at or above which a column is a copy of an earlier usable one
COPY_R = 0.999
#: a column missing more than this share of its rows' readings is not used (its gaps are not filled)
MAX_MISSING_SHARE = 0.5
#: the basis must have at most this share of the rows to judge R² (else the lower harmonics only)
BASIS_MAX_SHARE = 0.5
#: the frame effects a signal may drive, with their coefficient names and units (per unit of the signal)
FRAMES = {
    "base_rot": (("rx", "ry", "rz"), "rad"),
    "base_trans": (("tx", "ty", "tz"), "mm"),
    "tool_rot": (("rx", "ry", "rz"), "rad"),
    "tool_trans": (("tx", "ty", "tz"), "mm"),
    "carriage_rot": (("rx", "ry", "rz"), "rad"),
}
FRAME_WORDS = {
    "base_rot": "the robot base rotates with {s} (a compliant stand or floor tilting, an axis carrying the base)",
    "base_trans": "the robot base moves with {s} (a stand or a carrying axis deflecting)",
    "tool_rot": "the tool rotates on the flange with {s} (a compliant tool or gripper, a loose mount)",
    "tool_trans": "the tool moves on the flange with {s} (a compliant tool, its thermal growth)",
    "carriage_rot": "the carriage of the linear axis carrying the arm rotates with {s} about its own origin, which "
    "travels with the axis (a rail's or a column's pitch, a carriage rocking under the arm; base axes)",
}


@dataclass(frozen=True)
class LoggedSignal:
    """A usable logged signal: its column, values for every campaign row, centre (calibration-row mean), the
    declaration (``None``: undeclared, named as found)."""

    name: str
    values: np.ndarray
    centre: float
    declaration: SignalDeclaration | None
    filled: dict[str, Any] | None = None  # missing readings filled (fill_gaps): how many, which way, its error

    @property
    def unit(self) -> str:
        return self.declaration.unit if self.declaration is not None else ""

    @property
    def side(self) -> str:
        return "measurement" if self.declaration is not None and self.declaration.measurement_side else "robot"

    def to_dict(self) -> dict[str, Any]:
        d = self.declaration
        return {
            "column": self.name,
            "declared": d is not None,
            "unit": self.unit or None,
            "location": None if d is None else (d.location or None),
            "description": None if d is None else (d.description or None),
            "side": self.side,
            "centre": self.centre,
            "std": float(np.std(self.values)),
            **({"filled": self.filled} if self.filled else {}),
        }


def _r2(y: np.ndarray, B: np.ndarray) -> float:
    """R² of the least-squares fit of ``y`` on the columns of ``B`` (which hold a constant)."""
    yc = y - y.mean()
    ss = float(yc @ yc)
    if ss <= 0:
        return 1.0
    coef, *_ = np.linalg.lstsq(B, y, rcond=1e-12)
    e = y - B @ coef
    return float(1.0 - (e @ e) / ss)


def fill_gaps(
    x: np.ndarray, t_s: np.ndarray, B: np.ndarray, along: dict[str, np.ndarray] | None = None
) -> tuple[np.ndarray, dict[str, Any]]:
    """A logged column's missing readings (NaN) filled, and how: by linear interpolation in time between the
    readings (the first and last held beyond them), or by the column's least-squares fit on the joint-angle basis
    ``B`` (rows x functions), or by that fit with its leftover interpolated in time, whichever predicts the
    readings better when each is left out in turn (the interpolation from its neighbours in time, the fit by its
    leave-one-out residual ``e / (1 - h)``, the leftover's interpolation from its neighbours); or by interpolation
    along a coordinate of ``along`` (a linear axis's position: a rail's pitch follows where the carriage is, and
    the poses jump along the rail in time — newcomer pass 17: 0.0055 deg filled from the pose and time, 0.0020
    along the track). Returns the
    filled column and ``{"rows", "way", "loo_rms"}`` (the chosen way's leave-one-out RMS error, in the column's
    unit, beside which its spread ``std`` says how good a fill it is)."""
    ok = np.isfinite(x)
    t = np.asarray(t_s, dtype=float)
    miss = ~ok
    rms_time, fill_time = _by_time(t[ok], x[ok], t[miss])
    best = (rms_time, fill_time, "linear interpolation in time between the readings")
    for name, coord in (along or {}).items():
        c = np.asarray(coord, dtype=float)
        rms_c, fill_c = _along(c[ok], x[ok], c[miss])
        if rms_c < best[0]:
            best = (rms_c, fill_c, f"linear interpolation along {name} between the readings")
    if B.shape[1] < 0.5 * ok.sum():
        Bk = B[ok]
        coef, *_ = np.linalg.lstsq(Bk, x[ok], rcond=1e-12)
        e = x[ok] - Bk @ coef
        Q, _ = np.linalg.qr(Bk)
        h = np.clip(np.sum(Q**2, axis=1), 0.0, 1.0 - 1e-9)
        rms_joint = float(np.sqrt(np.mean((e / (1.0 - h)) ** 2)))
        if rms_joint < best[0]:
            best = (rms_joint, B[miss] @ coef, "regression on the joint-angle basis (the column follows the pose)")
        # the pose's part and, between the readings in time, what it leaves (a stand that tilts with the arm's
        # weight and wanders slowly): the leftover's own leave-one-out interpolation
        rms_both, fill_e = _by_time(t[ok], e, t[miss], e / (1.0 - h))
        if rms_both < best[0]:
            best = (rms_both, B[miss] @ coef + fill_e, "regression on the joint-angle basis, its leftover "
                    "interpolated in time between the readings")  # fmt: skip
    rms, fill, way = best
    out = x.copy()
    out[miss] = fill
    return out, {"rows": int(miss.sum()), "way": way, "loo_rms": float(f"{rms:.3g}")}


def _by_time(
    t: np.ndarray, x: np.ndarray, t_new: np.ndarray, x_self: np.ndarray | None = None
) -> tuple[float, np.ndarray]:
    """Linear interpolation in time of readings ``x`` at times ``t`` (held beyond the first and the last): the RMS
    error of each reading (``x_self``, default ``x``: a fit's leftover left out is its leave-one-out residual)
    predicted from its neighbours in time, and the values at ``t_new``."""
    o = np.argsort(t, kind="stable")
    ts, xs = t[o], x[o]
    own = xs if x_self is None else x_self[o]
    pred = np.empty_like(xs)
    if len(xs) > 2:
        dt = ts[2:] - ts[:-2]
        w = np.divide(ts[1:-1] - ts[:-2], dt, out=np.full(len(dt), 0.5), where=dt > 0)
        pred[1:-1] = xs[:-2] + w * (xs[2:] - xs[:-2])
    pred[0], pred[-1] = (xs[1], xs[-2]) if len(xs) > 1 else (xs[0], xs[0])
    return float(np.sqrt(np.mean((own - pred) ** 2))), np.interp(t_new, ts, xs)


def _along(c: np.ndarray, x: np.ndarray, c_new: np.ndarray) -> tuple[float, np.ndarray]:
    """Linear interpolation of readings ``x`` along a coordinate ``c`` (held beyond its ends), as :func:`_by_time`,
    the readings at one value of it (a pose's reflectors, read once) averaged and left out together: each row's
    error predicted from the neighbouring values only (from its own pose's other row the error was ~0, five times
    too good). Infinite with fewer than three values."""
    u, inv = np.unique(c, return_inverse=True)
    if len(u) < 3:
        return float("inf"), np.zeros(len(c_new))
    ux = np.bincount(inv, weights=x) / np.bincount(inv)
    pred = np.empty_like(ux)
    w = (u[1:-1] - u[:-2]) / (u[2:] - u[:-2])
    pred[1:-1] = ux[:-2] + w * (ux[2:] - ux[:-2])
    pred[0], pred[-1] = ux[1], ux[-2]
    return float(np.sqrt(np.mean((x - pred[inv]) ** 2))), np.interp(c_new, u, ux)


def joint_basis(campaign: Campaign, robot: RobotDescription) -> np.ndarray:
    """The joint-angle basis of the screening (rows x functions): 1, the angles, sin / cos of 1 and 2 times each
    angle and the nominal flange pose (position and rotation entries) — so that a copy of a joint, a commanded
    Cartesian pose (flange or tool point in any fixed frame) and smooth functions of single joints are held;
    fewer harmonics when the rows are few."""
    from robocal.kinematics.chain import build_chain, fk

    q = campaign.q
    m = len(q)
    T = fk(build_chain(robot), q)
    cols = [np.ones(m), *q.T, *T[:, :3, 3].T, *T[:, :3, :3].reshape(m, 9).T]
    for h in (1, 2):
        more = [f(h * q[:, j]) for j in range(q.shape[1]) for f in (np.sin, np.cos)]
        if len(cols) + len(more) > BASIS_MAX_SHARE * m:
            break
        cols += more
    return np.column_stack(cols)


def axis_positions(campaign: Campaign, robot: RobotDescription) -> dict[str, np.ndarray]:
    """The linear axes' positions (mm) by joint name: the coordinates a logged column's gaps may be interpolated
    along (:func:`fill_gaps`)."""
    return {robot.joint_names[j]: campaign.q[:, j] for j in range(robot.n_joints) if robot.prismatic[j]}


def fill_basis(campaign: Campaign, robot: RobotDescription, B: np.ndarray) -> np.ndarray:
    """The basis a logged column's gaps are filled from (:func:`fill_gaps`): the joint-angle basis ``B``
    (:func:`joint_basis`) and, for a linear axis carrying the arm (a lifting column, a track), its position times
    the nominal flange position: a column bending under the arm's weight tilts by the arm's moment times the
    height (newcomer pass 9: from the joint basis alone, a lifting column's tilt was filled to 0.45 mrad of its
    3 mrad, ~1.4 mm at the tool)."""
    from robocal.kinematics.chain import build_chain, fk

    axes = [j for j in range(robot.n_joints) if robot.prismatic[j]]
    if not axes:
        return B
    p = fk(build_chain(robot), campaign.q)[:, :3, 3]
    p = (p - p.mean(axis=0)) / np.maximum(p.std(axis=0), 1e-9)
    more = []
    for j in axes:
        s = campaign.q[:, j]
        s = (s - s.mean()) / max(float(s.std()), 1e-9)
        more += [s * p[:, k] for k in range(3)]
    if B.shape[1] + len(more) > BASIS_MAX_SHARE * len(B):
        return B
    return np.column_stack([B, *more])


def measurement_basis(campaign: Campaign) -> np.ndarray:
    """The measured-position basis of the screening: 1, x, y, z, their squares and products, the distance, the
    azimuth (sin, cos) and the elevation of the measured point (tracker frame)."""
    p = campaign.p_mm
    x, y, z = p.T
    r = np.linalg.norm(p, axis=1)
    az = np.arctan2(y, x)
    el = np.arcsin(np.clip(z / np.maximum(r, 1e-9), -1, 1))
    return np.column_stack([np.ones(len(p)), x, y, z, x * x, y * y, z * z, x * y, x * z, y * z, r, np.sin(az),
                            np.cos(az), el])  # fmt: skip


#: names of the columns in which a tracker or total station states the uncertainty of its own reading (a standard
#: deviation per coordinate or angle, an expanded uncertainty): ``std_x_mm``, ``u_mm``, ``sigma_z``, ``x_std``
_UNCERTAINTY = re.compile(r"^(std|u|sigma|unc|uncertainty)(_|$)|_(std|sigma|unc|uncertainty)(_|$)", re.IGNORECASE)


#: names of the columns that log what the controller was commanded (``goal_x_mm``, ``cmd_roll_rad``,
#: ``setpoint_z``, ``commanded_a``): the joints' own target, not a cause
_COMMANDED = re.compile(r"^(goal|cmd|command|commanded|setpoint|set_point|nominal)(_|$)", re.IGNORECASE)


def commanded_column(name: str) -> bool:
    """Whether a column's name says it logs a commanded pose or set point (:data:`_COMMANDED`)."""
    return bool(_COMMANDED.search(name))


def uncertainty_column(name: str) -> bool:
    """Whether a column's name says it is the measurement's own stated uncertainty (:data:`_UNCERTAINTY`)."""
    return bool(_UNCERTAINTY.search(name))


def _function_of(
    x: np.ndarray, Bj: np.ndarray, Bm: np.ndarray, declared: bool
) -> tuple[str | None, float | None, str | None]:
    """Whether a column's readings ``x`` are a function of the joints (basis ``Bj``) or of the measured position
    (``Bm``) to R² >= :data:`FUNCTION_R2`: ``(why not used, its R², None)`` for an undeclared column, ``(None,
    None, note)`` for a declared one (offered, the note saying so), ``(None, None, None)`` otherwise."""
    for B, what in ((Bj, "joint"), (Bm, "measurement")):
        r2 = _r2(x, B) if B.shape[1] < len(x) else float("nan")
        if not r2 >= FUNCTION_R2:
            continue
        if declared:
            basis = "on a joint-angle basis" if what == "joint" else "on the measured position"
            return None, None, f"mostly a function of the pose (R² = 1 - {1 - r2:.1e} {basis}); offered: declared"
        if what == "joint":
            why = ("a function of the joint angles (a commanded pose or joint logged beside the joints): "
                   f"R² = {r2:.6f} on a joint-angle basis")  # fmt: skip
        else:
            why = f"a function of the measured position (the tracker's own reading): R² = {r2:.6f}"
        return why, r2, None
    return None, None, None


def screen(campaign: Campaign, robot: RobotDescription) -> tuple[list[LoggedSignal], list[dict[str, Any]]]:
    """The campaign's usable logged signals and the extra columns not used, each with the reason."""
    decl = merged(robot.signals, campaign.signal_declarations)
    known = known_columns(campaign.n_joints)
    has_val = bool(np.any(campaign.split == "validation"))
    cal = campaign.split == "calibration" if has_val else np.ones(campaign.n_rows, dtype=bool)
    used: list[LoggedSignal] = []
    skipped: list[dict[str, Any]] = []
    Bj: np.ndarray | None = None
    Bf: np.ndarray | None = None  # the fill basis (fill_basis)
    Bm: np.ndarray | None = None
    for name, raw in campaign.extra.items():
        if name in known:
            continue
        d = decl.get(name)

        def skip(why: str, r2: float | None = None, name: str = name, d: SignalDeclaration | None = d) -> None:
            skipped.append({"column": name, "declared": d is not None, "reason": why,
                            **({} if r2 is None else {"r2": r2})})  # fmt: skip

        if d is not None and not d.use:
            skip("declared not to be used (use: false)")
            continue
        x = _numeric(raw)
        if x is None:
            skip("not numeric")
            continue
        ok = np.isfinite(x)  # the R² tests below judge the column's own readings, not the filled ones
        bad = np.flatnonzero(~ok)
        filled = None
        if Bj is None:
            Bj, Bm = joint_basis(campaign, robot), measurement_basis(campaign)
            Bf = fill_basis(campaign, robot, Bj)
        assert Bm is not None and Bf is not None
        if len(bad):
            rows = campaign.row_number[bad[:5]].tolist()
            more = " ..." if len(bad) > 5 else ""
            if len(bad) > MAX_MISSING_SHARE * len(x) or not np.any(np.isfinite(x[cal])):
                skip(f"missing or non-finite values in {len(bad)} row(s) (file rows {rows}{more}): more than "
                     f"{MAX_MISSING_SHARE:.0%} of the rows, not filled")  # fmt: skip
                continue
            x, filled = fill_gaps(x, campaign.timestamp_s, Bf, axis_positions(campaign, robot))
            filled["file_rows"] = campaign.row_number[bad[:20]].tolist()  # the first 20 (``rows``: how many)
        if float(np.std(x[cal])) <= 1e-12 * max(1.0, float(np.abs(x).max())):
            skip("does not vary over the calibration rows")
            continue
        why, r2, pose_note = _function_of(x[ok], Bj[ok], Bm[ok], declared=d is not None)
        if why is not None:
            skip(why, r2)
            continue
        if d is None and commanded_column(name):
            skip("a commanded pose or set point (its name): a function of the joints the controller was sent, which "
                 "the joint-angle test cannot always show (a roll-pitch-yaw angle wraps at +-180 deg and is "
                 "undefined at pitch +-90 deg); declare it in signals.yaml to offer it anyway")  # fmt: skip
            continue
        if d is None and uncertainty_column(name):
            skip("the instrument's stated uncertainty of the measurement (a noise figure, not a cause of an error): "
                 "declare it in signals.yaml to offer it anyway")  # fmt: skip
            continue
        copy = next((s for s in used if abs(float(np.corrcoef(s.values, x)[0, 1])) >= COPY_R), None)
        if copy is not None:
            skip(f"a copy of the logged signal {copy.name} (|r| >= {COPY_R})")
            continue
        if pose_note is not None:
            filled = {**(filled or {}), "note": pose_note}
        used.append(LoggedSignal(name, x, float(x[cal].mean()), d, filled))
    return used, skipped


def record(campaign: Campaign, robot: RobotDescription) -> dict[str, Any] | None:
    """``discovery.json``'s ``logged_signals``: the signals offered (with their declarations) and the extra columns
    not used with the reason; None when the campaign has no extra column."""
    decl = merged(robot.signals, campaign.signal_declarations)
    absent = sorted(k for k in decl if k not in campaign.extra)  # declared for the robot, not logged here
    if not any(c not in known_columns(campaign.n_joints) for c in campaign.extra):
        return {"used": [], "not_used": [], "declared_not_in_campaign": absent} if absent else None
    used, skipped = screen(campaign, robot)
    return {"used": [s.to_dict() for s in used], "not_used": skipped,
            **({"declared_not_in_campaign": absent} if absent else {})}  # fmt: skip


def _group_columns(names: tuple[str, ...], suffix: str, kind: str) -> list[int]:
    """Columns of the base model whose name is the base's or a station's (``kind == "base"``) or any target's
    (``kind == "tool"``) parameter with this suffix."""
    if kind == "base":
        return [i for i, n in enumerate(names) if n == f"base_{suffix}" or (n.startswith("station_")
                and n.endswith(f"_{suffix}"))]  # fmt: skip
    return [i for i, n in enumerate(names) if n.startswith("tool_") and n.endswith(f"_{suffix}")]


def offered_frames(
    campaign: Campaign, robot: RobotDescription
) -> list[tuple[str, tuple[tuple[str, ...], str], dict[str, Any]]]:
    """The frame effects a signal is offered as the cause of, each with its coefficients' names and unit and what
    its candidate carries: the four of :data:`FRAMES` and, on an arm carried by a linear axis that moves in the
    campaign, its carriage's rotation about the carriage's origin (``axis_joint``, 1-based; ``pivot_mm`` every
    row's origin in the base frame). A fixed base's tilt cannot follow a pivot travelling metres along a rail: a
    carriage inclinometer on a 5 m track came out at 0.75 of its gain with a translation of -44.6 mm per degree
    beside it (newcomer pass 17)."""
    from robocal.kinematics.axes import carriage_origin, carrying_axis

    out: list[tuple[str, tuple[tuple[str, ...], str], dict[str, Any]]] = [
        (f, FRAMES[f], {}) for f in FRAMES if f != "carriage_rot"
    ]
    j = carrying_axis(robot)
    if j is not None and float(np.ptp(campaign.q[:, j])) > 1.0:  # mm: a carriage that travels
        carried = {"axis_joint": j + 1, "pivot_mm": carriage_origin(robot, campaign.q, j)}
        out.append(("carriage_rot", FRAMES["carriage_rot"], carried))
    return out


def frame_columns(
    frame: str,
    Jx: np.ndarray,
    names: tuple[str, ...],
    tools_mm: np.ndarray,
    target_index: np.ndarray,
    pivot_mm: np.ndarray | None = None,
) -> np.ndarray:
    """``(m, d, 3)``: the first-order change of the residuals per unit of each coefficient of a frame effect.

    Jx : (m, d, nb) the base model's Jacobian per row (position rows first, then orientation when ``d == 6``);
    names : its parameter names; tools_mm : (K, 3) the targets' offsets in the flange frame; target_index : (m,).
    Base effects sum the base's and every station's own column (each row lives in one station's frame); tool
    translations sum every target's (each row measures one target); a tool rotation ``w`` moves target ``t`` by
    ``R_flange (w x t)`` and turns it by ``R_flange w``. A carriage's rotation ``w`` about its origin ``c``
    (``pivot_mm (m, 3)``, base frame) is the base's rotation ``w`` and its translation ``c x w``: ``w x (p - c)``.
    """
    m, d, _ = Jx.shape
    if frame == "carriage_rot":
        if pivot_mm is None:
            raise ValueError("a carriage's rotation needs its origin on every row (pivot_mm)")
        rot, trans = (frame_columns(f, Jx, names, tools_mm, target_index) for f in ("base_rot", "base_trans"))
        c = np.asarray(pivot_mm, dtype=float)
        cx = np.zeros((m, 3, 3))  # [c]x
        cx[:, 0, 1], cx[:, 0, 2], cx[:, 1, 2] = -c[:, 2], c[:, 1], -c[:, 0]
        cx[:, 1, 0], cx[:, 2, 0], cx[:, 2, 1] = c[:, 2], -c[:, 1], c[:, 0]
        return rot + np.einsum("mdk,mkj->mdj", trans, cx)
    if frame in ("base_rot", "base_trans"):
        sfx = ("rx", "ry", "rz") if frame == "base_rot" else ("tx", "ty", "tz")
        return np.stack([Jx[:, :, _group_columns(names, s, "base")].sum(axis=2) for s in sfx], axis=2)
    Rf = np.stack([Jx[:, :3, _group_columns(names, s, "tool")].sum(axis=2) for s in ("x", "y", "z")], axis=2)
    out = np.zeros((m, d, 3))
    if frame == "tool_trans":
        out[:, :3, :] = Rf
        return out
    t = np.asarray(tools_mm, dtype=float)[target_index]  # (m, 3)
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1.0
        out[:, :3, i] = np.einsum("mab,mb->ma", Rf, np.cross(e, t))
        if d == 6:
            out[:, 3:, i] = Rf[:, :, i]
    return out


def _numeric(raw: Any) -> np.ndarray | None:
    """A logged column as numbers, its empty cells NaN (a gap in a numeric column is read as text: it was reported
    "not numeric" instead of where its values are missing); None when some filled cell is not a number."""
    try:
        return np.asarray(raw, dtype=float)
    except (TypeError, ValueError):
        pass
    import pandas as pd

    col = pd.Series(raw, dtype=object)
    blank = col.isna() | col.astype(str).str.strip().eq("")
    num = pd.to_numeric(col.where(~blank), errors="coerce")
    if not bool((~blank).any()) or bool(num[~blank].isna().any()):
        return None
    return np.asarray(num, dtype=float)


def frame_rows(
    cand: Any, Jx: np.ndarray, base: Any, x: np.ndarray, target_index: np.ndarray, rows: np.ndarray
) -> np.ndarray:
    """``(m, d, 3)`` regressor of a frame candidate on campaign rows ``rows`` (its signal times
    :func:`frame_columns`) at the base model ``base`` with parameters ``x``."""
    pivot = cand.extra.get("pivot_mm")
    G = frame_columns(cand.extra["frame"], Jx, base.names, base.tools(x), target_index,
                      None if pivot is None else np.asarray(pivot)[rows])  # fmt: skip
    return G * cand.S[rows, 0][:, None, None]


def filled_columns(
    campaign: Campaign, robot: RobotDescription, columns: Any
) -> tuple[dict[str, np.ndarray], dict[str, tuple[np.ndarray, dict[str, Any]]]]:
    """The logged ``columns`` over every row of ``campaign``, their empty cells filled as the search filled them
    (:func:`fill_gaps` on the same basis, :func:`screen`), and per column with gaps ``(mask of the empty rows,
    how they were filled)``: the product (``compensation.csv``) corrects a pose whose reading was empty with the
    value its effects were fitted with, and says so (it read the empty cell as text and stopped the run)."""
    values: dict[str, np.ndarray] = {}
    gaps: dict[str, tuple[np.ndarray, dict[str, Any]]] = {}
    Bf: np.ndarray | None = None
    for c in sorted(columns):
        x = _numeric(campaign.extra[c])
        if x is None:
            raise ValueError(f"the logged column {c!r} of {campaign.source} is not numeric")
        miss = ~np.isfinite(x)
        if np.any(miss):
            Bf = fill_basis(campaign, robot, joint_basis(campaign, robot)) if Bf is None else Bf
            x, how = fill_gaps(x, campaign.timestamp_s, Bf, axis_positions(campaign, robot))
            gaps[c] = (miss, how)
        values[c] = x
    return values, gaps


def signal_gaps(cal: Any, fit: Any) -> dict[str, np.ndarray]:
    """Per logged column an effect of ``fit`` follows, the rows of ``cal`` (the calibration rows) whose reading was
    empty (filled by :func:`fill_gaps`): a mask over ``cal``'s rows."""
    out: dict[str, np.ndarray] = {}
    for a in fit.model.accepted:
        members = a.cand.extra.get("members") or (a.cand,)
        for c in members:
            name = c.extra.get("column") if c.effect == "signal" else None
            if name and name not in out and name in cal.extra:
                raw = pd.to_numeric(pd.Series(np.asarray(cal.extra[name])), errors="coerce").to_numpy(dtype=float)
                if np.any(~np.isfinite(raw)):
                    out[name] = ~np.isfinite(raw)
    return out
