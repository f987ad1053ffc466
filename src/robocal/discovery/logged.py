"""Every logged signal is a candidate driver: the extra numeric columns of a campaign as causes of effects.

A numeric column of ``poses.csv`` the data contract does not name (:mod:`robocal.logged_signals`: an
inclinometer, an accelerometer, an external axis position, a load cell, a time counter) is first screened:

* a column that does not vary, holds missing values, or is not numeric is not used (said, with the reason);
* a column that is a function of the joints — a commanded pose logged beside the joints, a copy of a joint — is
  recognised by regressing it on a joint-angle basis (the angles, their first two harmonics and the nominal
  flange pose) and not used: R² of at least :data:`FUNCTION_R2` (it carries nothing the joints do not, and an
  effect driven by it would be a joint-angle effect under another name);
* a column that is a function of the measurement itself (the tracker's own distance, angles or coordinates) is
  recognised by regressing it on the measured position (linear, quadratic and spherical terms) and not used: an
  effect driven by it would fit the measurement with itself;
* a column equal to an earlier usable one (|r| >= :data:`FUNCTION_R2`) is a copy and not used twice;
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

from robocal.data.columns import known_columns
from robocal.data.contract import Campaign
from robocal.logged_signals import SignalDeclaration, merged
from robocal.robot import RobotDescription

#: R² (or |r|) at or above which a column is a function of the joints, of the measurement, or a copy of another
#: column: a logged sensor carries its own noise and its own cause, so it never reaches this on a joint basis of
#: ~40 functions over a few hundred rows (a random column's R² is about 40 / rows), while a commanded value
#: logged beside the joints, rounded to 1e-6, is at 1 - 1e-9.
FUNCTION_R2 = 0.999
#: the basis must have at most this share of the rows to judge R² (else the lower harmonics only)
BASIS_MAX_SHARE = 0.5
#: the frame effects a signal may drive, with their coefficient names and units (per unit of the signal)
FRAMES = {
    "base_rot": (("rx", "ry", "rz"), "rad"),
    "base_trans": (("tx", "ty", "tz"), "mm"),
    "tool_rot": (("rx", "ry", "rz"), "rad"),
    "tool_trans": (("tx", "ty", "tz"), "mm"),
}
FRAME_WORDS = {
    "base_rot": "the robot base rotates with {s} (a compliant stand or floor tilting, an axis carrying the base)",
    "base_trans": "the robot base moves with {s} (a stand or a carrying axis deflecting)",
    "tool_rot": "the tool rotates on the flange with {s} (a compliant tool or gripper, a loose mount)",
    "tool_trans": "the tool moves on the flange with {s} (a compliant tool, its thermal growth)",
}


@dataclass(frozen=True)
class LoggedSignal:
    """A usable logged signal: its column, values for every campaign row, centre (calibration-row mean), the
    declaration (``None``: undeclared, named as found)."""

    name: str
    values: np.ndarray
    centre: float
    declaration: SignalDeclaration | None

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


def screen(campaign: Campaign, robot: RobotDescription) -> tuple[list[LoggedSignal], list[dict[str, Any]]]:
    """The campaign's usable logged signals and the extra columns not used, each with the reason."""
    decl = merged(robot.signals, campaign.signal_declarations)
    known = known_columns(campaign.n_joints)
    has_val = bool(np.any(campaign.split == "validation"))
    cal = campaign.split == "calibration" if has_val else np.ones(campaign.n_rows, dtype=bool)
    used: list[LoggedSignal] = []
    skipped: list[dict[str, Any]] = []
    Bj: np.ndarray | None = None
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
        bad = np.flatnonzero(~np.isfinite(x))
        if len(bad):
            rows = campaign.row_number[bad[:5]].tolist()
            more = " ..." if len(bad) > 5 else ""
            skip(f"missing or non-finite values in {len(bad)} row(s) (file rows {rows}{more})")
            continue
        if float(np.std(x[cal])) <= 1e-12 * max(1.0, float(np.abs(x).max())):
            skip("does not vary over the calibration rows")
            continue
        if Bj is None:
            Bj, Bm = joint_basis(campaign, robot), measurement_basis(campaign)
        assert Bm is not None
        r2j = _r2(x, Bj) if Bj.shape[1] < campaign.n_rows else float("nan")
        if r2j >= FUNCTION_R2:
            skip("a function of the joint angles (a commanded pose or joint logged beside the joints): "
                 f"R² = {r2j:.6f} on a joint-angle basis", r2j)  # fmt: skip
            continue
        r2m = _r2(x, Bm) if Bm.shape[1] < campaign.n_rows else float("nan")
        if r2m >= FUNCTION_R2:
            skip(f"a function of the measured position (the tracker's own reading): R² = {r2m:.6f}", r2m)
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
        copy = next((s for s in used if abs(float(np.corrcoef(s.values, x)[0, 1])) >= FUNCTION_R2), None)
        if copy is not None:
            skip(f"a copy of the logged signal {copy.name} (|r| >= {FUNCTION_R2})")
            continue
        used.append(LoggedSignal(name, x, float(x[cal].mean()), d))
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


def frame_columns(
    frame: str, Jx: np.ndarray, names: tuple[str, ...], tools_mm: np.ndarray, target_index: np.ndarray
) -> np.ndarray:
    """``(m, d, 3)``: the first-order change of the residuals per unit of each coefficient of a frame effect.

    Jx : (m, d, nb) the base model's Jacobian per row (position rows first, then orientation when ``d == 6``);
    names : its parameter names; tools_mm : (K, 3) the targets' offsets in the flange frame; target_index : (m,).
    Base effects sum the base's and every station's own column (each row lives in one station's frame); tool
    translations sum every target's (each row measures one target); a tool rotation ``w`` moves target ``t`` by
    ``R_flange (w x t)`` and turns it by ``R_flange w``."""
    m, d, _ = Jx.shape
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
    G = frame_columns(cand.extra["frame"], Jx, base.names, base.tools(x), target_index)
    return G * cand.S[rows, 0][:, None, None]
