"""The tracker registered to the robot base by axis circles, as ISO 9283 testers do it: no calibration involved.

``base_circles.csv`` (beside the test's ``poses.csv``; every problem a :class:`robocal.errors.DataError` naming
file, row and column):

``axis``            int   1 or 2: the joint turned while the others stand still;
``q1_deg`` ..       deg   the joint angles of the row (one per joint of the robot);
``x_mm`` ..         mm    the reflector's position, tracker frame (``y_mm``, ``z_mm``).

At least 5 rows per axis, over at least 20 deg of the turning joint. The reflector traces a circle about the
turning axis: a plane fit gives the axis direction (the normal, signed by the right-hand rule of the joint's
rotation), a circle fit in that plane a point of it (the centre).

The base frame is then the one in which the measured axes sit where the robot description's nominal axes sit
(for the KR16-2: z along axis 1, x along the common perpendicular from axis 1 to axis 2 at q1 = 0, origin on
axis 1 ``d1`` below that perpendicular): the same construction on both pairs of lines -- the nominal lines from the
nominal model at the measured rows' joint angles -- and ``base_T_tracker = A_nominal A_measured^-1``.

This is the base frame the robot's own axes define. Any error of the robot that only moves its axes 1 and 2
relative to a frame fixed elsewhere (e.g. the mounting plate: a tilt or offset of axis 1, the zero of joint 1)
cannot be seen by any measurement of the robot's motion: it is part of where the base is, not of the robot's
error.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from robocal.errors import DataError
from robocal.kinematics.transforms import inv_transform

FILE = "base_circles.csv"
MIN_ROWS = 5
MIN_SPAN_DEG = 20.0


@dataclass(frozen=True)
class Circle:
    """A fitted circle: centre (3,), unit normal (3,) along the turning axis (right-hand rule), radius, the rms of
    the points' distances from the fitted circle (mm), number of points and the span of the turning joint (deg)."""

    centre: np.ndarray
    normal: np.ndarray
    radius_mm: float
    rms_mm: float
    n: int
    span_deg: float


def fit_circle(p: np.ndarray, angle: np.ndarray) -> Circle:
    """Circle through the points ``p`` (k, 3) traced while a joint turned through ``angle`` (k,) rad: plane by
    SVD, centre by the algebraic (Kasa) fit in the plane, normal signed so that the joint turns positively about
    it."""
    c0 = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c0)
    e1, e2, n = vt
    u, v = (p - c0) @ e1, (p - c0) @ e2
    A = np.column_stack([2 * u, 2 * v, np.ones(len(u))])
    sol = np.linalg.lstsq(A, u**2 + v**2, rcond=None)[0]
    centre = c0 + sol[0] * e1 + sol[1] * e2
    r = float(np.sqrt(sol[2] + sol[0] ** 2 + sol[1] ** 2))
    order = np.argsort(angle, kind="stable")
    rel = p[order] - centre
    if float(np.cross(rel[:-1], rel[1:]).sum(axis=0) @ n) < 0:
        n = -n
    off_plane = (p - centre) @ n
    in_plane = np.linalg.norm((p - centre) - off_plane[:, None] * n, axis=1) - r
    rms = float(np.sqrt(np.mean(off_plane**2 + in_plane**2)))
    span = float(np.rad2deg(angle.max() - angle.min()))
    return Circle(centre, n, r, rms, len(p), span)


def axis_frame(c1: np.ndarray, u1: np.ndarray, c2: np.ndarray, u2: np.ndarray, offset: bool) -> np.ndarray:
    """The frame two joint axes define (4, 4): z along axis 1 (point c1, direction u1); with ``offset`` (axis 2
    passes beside axis 1) x along the common perpendicular from axis 1 to axis 2 and the origin at its foot on
    axis 1; without (they intersect) x along u2 x u1 and the origin at the point of axis 1 nearest axis 2."""
    z = u1 / np.linalg.norm(u1)
    u2 = u2 / np.linalg.norm(u2)
    # the nearest points of the two lines: c1 + s z and c2 + t u2
    s, t = np.linalg.lstsq(np.column_stack([z, -u2]), c2 - c1, rcond=None)[0]
    f1, f2 = c1 + s * z, c2 + t * u2
    x = (f2 - f1) if offset else np.cross(u2, z)
    x = x - (x @ z) * z
    x = x / np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = f1
    return T


@dataclass(frozen=True)
class CircleRegistration:
    """``tracker_T_base`` from the axis circles, with what a certificate states about it."""

    tracker_T_base: np.ndarray
    circles: dict[int, Circle]
    file: str

    def info(self) -> dict[str, Any]:
        return {
            f"axis{a}": {
                "points": c.n,
                "span_deg": round(c.span_deg, 3),
                "radius_mm": round(c.radius_mm, 3),
                "fit_rms_mm": round(c.rms_mm, 4),
            }
            for a, c in self.circles.items()
        }


def _columns(path: Path, n_joints: int) -> dict[str, np.ndarray]:
    import pandas as pd

    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False)
    except Exception as exc:  # pandas' parser errors name no row; say the file
        raise DataError(f"cannot read as CSV: {exc}", file=str(path)) from None
    need = ["axis", *[f"q{j + 1}_deg" for j in range(n_joints)], "x_mm", "y_mm", "z_mm"]
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise DataError(
            f"missing column(s) {missing}; has {list(df.columns)}", file=str(path), row=1, column=missing[0]
        )
    out: dict[str, np.ndarray] = {}
    for col in need:
        vals = np.full(len(df), np.nan)
        for i, v in enumerate(df[col]):
            try:
                vals[i] = float(str(v).strip())
            except ValueError:
                raise DataError(f"expected a number, got {v!r}", file=str(path), row=i + 2, column=col) from None
            if not np.isfinite(vals[i]):
                raise DataError("missing or non-finite value", file=str(path), row=i + 2, column=col)
        out[col] = vals
    bad = np.flatnonzero(~np.isin(out["axis"], (1.0, 2.0)))
    if bad.size:
        raise DataError(
            f"axis must be 1 or 2, got {df['axis'].iloc[bad[0]]!r}", file=str(path), row=int(bad[0]) + 2, column="axis"
        )
    return out


def register_by_circles(path: str | Path, robot: Any) -> CircleRegistration:
    """``tracker_T_base`` of the tracker that measured ``path`` (``base_circles.csv``, see the module docstring)."""
    from robocal.kinematics.chain import build_chain, propagate

    path = Path(path)
    n = robot.n_joints
    cols = _columns(path, n)
    q = np.deg2rad(np.column_stack([cols[f"q{j + 1}_deg"] for j in range(n)]))
    p = np.column_stack([cols["x_mm"], cols["y_mm"], cols["z_mm"]])
    chain = build_chain(robot)
    measured: dict[int, Circle] = {}
    nominal: dict[int, Circle] = {}
    for a in (1, 2):
        rows = np.flatnonzero(cols["axis"] == a)
        if len(rows) < MIN_ROWS:
            raise DataError(
                f"axis {a} has {len(rows)} row(s); a circle needs at least {MIN_ROWS}", file=str(path), column="axis"
            )
        ang = q[rows, a - 1]
        others = np.delete(q[rows], a - 1, axis=1)
        moved = np.flatnonzero(np.abs(others - others[0]).max(axis=1) > 1e-6)
        if moved.size:
            raise DataError(
                f"axis {a}: only joint {a} may turn while its circle is measured; this row's other joints differ "
                "from the first row's",
                file=str(path),
                row=int(rows[moved[0]]) + 2,
                column="q1_deg" if a != 1 else "q2_deg",
            )
        if np.rad2deg(ang.max() - ang.min()) < MIN_SPAN_DEG:
            raise DataError(
                f"axis {a} turns through {np.rad2deg(ang.max() - ang.min()):.3g} deg; a circle needs at least "
                f"{MIN_SPAN_DEG:g}",
                file=str(path),
                column=f"q{a}_deg",
            )
        measured[a] = fit_circle(p[rows], ang)
        # the nominal line: the flange origin of the nominal model traces the nominal circle at the same angles
        s = propagate(chain, q[rows], np.zeros(chain.n_params))
        nominal[a] = fit_circle(s.o + s.z * 100.0 + s.x * 50.0, ang)  # any point off the axis traces a circle of it
    # axis 2 beside axis 1 (an offset, e.g. the KR16-2's 260 mm) or through it: decided on the nominal lines
    nz = nominal[1].normal
    w = np.cross(nz, nominal[2].normal)
    dist = (
        abs(float((nominal[2].centre - nominal[1].centre) @ w / np.linalg.norm(w))) if np.linalg.norm(w) > 1e-9 else 0
    )
    offset = dist > 1.0
    A_nom = axis_frame(nominal[1].centre, nominal[1].normal, nominal[2].centre, nominal[2].normal, offset)
    A_meas = axis_frame(measured[1].centre, measured[1].normal, measured[2].centre, measured[2].normal, offset)
    tracker_T_base = A_meas @ inv_transform(A_nom)
    return CircleRegistration(tracker_T_base, measured, str(path))


__all__ = ["FILE", "Circle", "CircleRegistration", "axis_frame", "fit_circle", "register_by_circles"]
