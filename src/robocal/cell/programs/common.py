"""What the KRL and RAPID readers share: targets with their place in the text, frames, configurations, errors.

A reader returns a :class:`Program`: the files' bytes, and every motion target with the exact character span
of its value in its file, its tool and base (work object) frames, its configuration data and where it is used.
A writer replaces only those spans; every other byte of every file is copied as it is.

Configuration data (KUKA Status/Turn, ABB confdata) are computed from the robot model's geometry with one set
of rules (:func:`arm_configuration`), the same when reading and when writing:

* shoulder: the wrist centre (the point of axis 5 nearest to axis 4) lies behind axis 1 (KUKA Status bit 0,
  "overhead"; ABB cfx 4);
* elbow: joint 3 is bent positively past the stretched arm (the sign of ``((o3 - o2) x (wc - o3)) · u3``; KUKA
  Status bit 1; ABB cfx 2 is its negation);
* wrist: axis 5 negative (KUKA Status bit 2, ABB cfx 1);
* KUKA Turn bit i: axis i+1 negative; ABB cf1, cf4, cf6: the quadrant ``floor(q / 90 deg)`` of axes 1, 4, 6.

Limits: these rules match the vendors' definitions for 6-axis arms with a spherical wrist whose joint zero and
sign conventions are those of the robot model; they were not checked against a controller, so a program
taught on a real cell must be read with a robot description that uses the controller's axis conventions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from robocal.errors import RobocalError
from robocal.kinematics.transforms import matrix_from_rpy, rpy_from_matrix


class ProgramError(RobocalError, ValueError):
    """A robot program that cannot be filtered; the message names the file and the line."""

    def __init__(self, message: str, file: str | Path | None = None, line: int | None = None) -> None:
        self.file = None if file is None else str(file)
        self.line = line
        self.reason = message
        where = []
        if file is not None:
            where.append(f"{file}")
        if line is not None:
            where.append(f"line {line}")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)


@dataclass
class Target:
    """One motion target of a program.

    name : str (declared name, or ``"<inline>"``); kind : ``"pose"`` (Cartesian, in the base frame) or ``"axis"``;
    file : Path; line : int (1-based: the declared name, or the inline value); span : (start, end) character
    offsets of the value text;
    T_base_tcp : (4, 4) mm, pose targets; q_deg : (n,) axis targets; config : dialect-specific configuration
    (KUKA ``{"S": int, "T": int}``, ABB ``{"cf": [cf1, cf4, cf6, cfx]}``); tool : (4, 4) flange_T_tcp;
    base : (4, 4) robot base -> target frame; used_at : [(file, line)] of the motions using it;
    data : what the writer needs to re-render the value.
    """

    name: str
    kind: str
    file: Path
    line: int
    span: tuple[int, int]
    T_base_tcp: np.ndarray | None = None
    q_deg: np.ndarray | None = None
    config: dict[str, Any] = field(default_factory=dict)
    tool: np.ndarray | None = None
    base: np.ndarray | None = None
    tool_name: str = ""
    base_name: str = ""
    used_at: list[tuple[str, int]] = field(default_factory=list)
    data: dict[str, Any] = field(default_factory=dict)


@dataclass
class Program:
    """A parsed program: ``texts`` {path: text (latin-1 decoded, so bytes round-trip)}, the targets in motion
    order (a target used twice appears once, at its first use), the dialect (``"krl"`` or ``"rapid"``)."""

    dialect: str
    texts: dict[Path, str]
    targets: list[Target]
    main: Path


def format_number(v: float, nd: int) -> str:
    """``v`` with at most ``nd`` decimals, trailing zeros dropped, never ``-0`` (how targets are written back)."""
    s = f"{v:.{nd}f}"
    if "." in s:
        s = s.rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def reuse_target(
    targets: dict[str, Target],
    key: str,
    tool: np.ndarray,
    base: np.ndarray,
    frames: str,
    file: Path,
    line: int,
) -> bool:
    """A target named again: record the use and return True when it is known (with the same tool and base:
    one corrected value cannot suit two frames, an error naming both uses); False when it is new."""
    t = targets.get(key)
    if t is None:
        return False
    assert t.tool is not None and t.base is not None
    if not (np.allclose(t.tool, tool) and np.allclose(t.base, base)):
        raise ProgramError(
            f"target {t.name!r} is used with {frames} here and with {t.tool_name}/{t.base_name} at line "
            f"{t.used_at[0][1]}: one value cannot suit both",
            file,
            line,
        )
    t.used_at.append((str(file), line))
    return True


def read_text(path: Path) -> str:
    """The file as text with every byte kept (latin-1 maps bytes 0-255 one to one)."""
    return path.read_bytes().decode("latin-1")


def blank_to_line_end(text: str, out: list[str], i: int) -> int:
    """Blank ``out[i:]`` up to the end of the line (a comment; ``\\r`` kept so line ends stay); returns the
    index of the newline (or ``len(text)``), where the scan goes on."""
    j = text.find("\n", i)
    j = len(text) if j < 0 else j
    for k in range(i, j):
        if text[k] != "\r":
            out[k] = " "
    return j


def line_of(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


def apply_edits(text: str, edits: list[tuple[int, int, str]]) -> str:
    """Replace the spans ``(start, end, new)`` (non-overlapping) of ``text``; everything else is kept."""
    out, last = [], 0
    for s, e, new in sorted(edits):
        if s < last:
            raise ValueError("overlapping edits")
        out.append(text[last:s])
        out.append(new)
        last = e
    out.append(text[last:])
    return "".join(out)


# --------------------------------------------------------------------------------------------- frames


def rot_zyx_deg(a: float, b: float, c: float) -> np.ndarray:
    """KUKA A, B, C (deg): ``R = Rz(A) Ry(B) Rx(C)``."""
    return np.asarray(matrix_from_rpy(np.deg2rad([c, b, a])))


def abc_deg(R: np.ndarray, near: tuple[float, float, float] | None = None) -> tuple[float, float, float]:
    """KUKA A, B, C (deg) of a rotation, accurate near B = +-90 deg.

    A rotation has two ZYX representations, ``(A, B, C)`` and ``(A + 180, 180 - B, C + 180)`` (each angle
    modulo 360), and a one-parameter family at B = +-90 (only A - C, resp. A + C, is defined). Without ``near``
    the principal one (B in [-90, 90], A and C in (-180, 180]); with ``near`` (the A, B, C the program had) the
    exact representation nearest to it (angles compared modulo 360, written in (-180, 180]): the nearer branch,
    and at B = +-90 the split of A -+ C nearest to the original's. Near B = 90 a small tilt of the tool moves A
    and C by the tilt's direction, whatever the representation; the nearer branch keeps that move within 90 deg
    (a tool-down ``{A 0, B 90, C 0}`` tilted by 0.04 deg towards 10 deg is written ``{A 10, B 90.04, C 10}``,
    not ``{A -170, B 89.96, C -170}``).
    """
    roll, pitch, yaw = rpy_from_matrix(R)
    abc = (math.degrees(yaw), math.degrees(pitch), math.degrees(roll))
    if near is None:
        return abc
    a0, b0, c0 = (float(v) for v in near)
    a, b, c = abc
    cands = [(a, b, c), (a + 180.0, 180.0 - b, c + 180.0)]
    R = np.asarray(R, dtype=float)
    if math.hypot(R[0, 0], R[1, 0]) <= 1e-10:  # gimbal lock: only A - C (B = 90) or A + C (B = -90) is defined
        s = 1.0 if b > 0 else -1.0
        d = a - s * c  # the defined combination
        d0 = a0 - s * c0
        d = d0 + _wrap180(d - d0)
        da = 0.5 * (d - d0)  # the change of A - s C shared between A and C, nearest to the original
        cands = [(a0 + da, b, c0 - s * da)]
    best = min(cands, key=lambda v: _wrap180(v[0] - a0) ** 2 + _wrap180(v[1] - b0) ** 2 + _wrap180(v[2] - c0) ** 2)
    return _norm180(best[0]), _norm180(best[1]), _norm180(best[2])


def _wrap180(d: float) -> float:
    """``d`` (deg) modulo 360 into [-180, 180)."""
    return (d + 180.0) % 360.0 - 180.0


def _norm180(d: float) -> float:
    """``d`` (deg) modulo 360 into (-180, 180] (the range the controller shows)."""
    w = _wrap180(d)
    return 180.0 if w == -180.0 else w


# --------------------------------------------------------------------------------------------- configuration


def arm_configuration(cc: Any, q: np.ndarray) -> dict[str, np.ndarray]:
    """Shoulder (wrist centre behind axis 1), elbow (joint 3 bent positively) and wrist (axis 5 < 0) flags
    ``(m,)`` bool of joints ``q`` (m, n) rad on the compiled nominal chain ``cc`` (6-axis arms)."""
    from robocal.kinematics.ik import forward
    from robocal.kinematics.transforms import rotvec_to_matrix

    q = np.atleast_2d(q)
    _, _, U, O = forward(cc, q, np.eye(4), record=True)
    assert U is not None and O is not None
    u1, u3 = U[:, :, 0], U[:, :, 2]
    o1, o2, o3 = O[:, :, 0], O[:, :, 1], O[:, :, 2]
    wc = wrist_centre(U, O)
    # "forward" of axis 1: base x turned by q1 about axis 1
    fwd = np.einsum("mij,j->mi", rotvec_to_matrix(u1 * q[:, 0:1]), np.array([1.0, 0.0, 0.0]))
    shoulder = np.einsum("mi,mi->m", wc - o1, fwd) < 0
    elbow = np.einsum("mi,mi->m", np.cross(o3 - o2, wc - o3), u3) > 0
    wrist = q[:, 4] < 0
    return {"shoulder": shoulder, "elbow": elbow, "wrist": wrist}


def elbow_angle(cc: Any, q: np.ndarray) -> np.ndarray:
    """Signed angle (m,) rad of the forearm (axis 3 -> wrist centre) from the stretched arm (axis 2 -> axis 3),
    about axis 3: its sign is the elbow flag of :func:`arm_configuration`; near 0 the arm is stretched (a
    singularity, where the configuration flips)."""
    from robocal.kinematics.ik import forward

    q = np.atleast_2d(q)
    _, _, U, O = forward(cc, q, np.eye(4), record=True)
    assert U is not None and O is not None
    wc = wrist_centre(U, O)
    a, b, u3 = O[:, :, 2] - O[:, :, 1], wc - O[:, :, 2], U[:, :, 2]
    a = a - np.einsum("mi,mi->m", a, u3)[:, None] * u3
    b = b - np.einsum("mi,mi->m", b, u3)[:, None] * u3
    return np.arctan2(np.einsum("mi,mi->m", np.cross(a, b), u3), np.einsum("mi,mi->m", a, b))


def wrist_centre(U: np.ndarray, O: np.ndarray) -> np.ndarray:
    """The point of axis 5 nearest to axis 4, (m, 3), from joint axes and origins (m, 3, n)."""
    u4, u5, o4, o5 = U[:, :, 3], U[:, :, 4], O[:, :, 3], O[:, :, 4]
    w = o5 - o4
    b = np.einsum("mi,mi->m", u4, u5)
    d = np.einsum("mi,mi->m", u4, w)
    e = np.einsum("mi,mi->m", u5, w)
    t5 = (b * d - e) / np.maximum(1.0 - b**2, 1e-12)
    return o5 + t5[:, None] * u5


def kuka_status_turn(cc: Any, q: np.ndarray, status_high: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """KUKA Status (bits 0-2 from the arm configuration, higher bits ``status_high`` kept) and Turn of joints
    ``q`` (m, n) rad."""
    c = arm_configuration(cc, q)
    s = c["shoulder"].astype(int) + 2 * c["elbow"].astype(int) + 4 * c["wrist"].astype(int) + (status_high & ~7)
    t = np.zeros(len(q), dtype=int)
    for j in range(q.shape[1]):
        t += (q[:, j] < 0).astype(int) << j
    return s, t


def abb_confdata(cc: Any, q: np.ndarray) -> np.ndarray:
    """ABB confdata ``[cf1, cf4, cf6, cfx]`` (m, 4) int of joints ``q`` (m, n) rad."""
    c = arm_configuration(cc, q)
    quad = np.floor(q[:, [0, 3, 5]] / (np.pi / 2)).astype(int)
    cfx = 4 * c["shoulder"].astype(int) + 2 * (~c["elbow"]).astype(int) + c["wrist"].astype(int)
    return np.column_stack([quad, cfx])


#: an angle within this of a configuration boundary (a quadrant boundary of ABB cf1/cf4/cf6, the sign of a
#: KUKA Turn bit or of axis 5) matches the configurations on both sides, as the controller accepts them: a
#: target on the boundary (``[0,0,1,0]`` above the y = 0 plane: axis 4 at 0 or -0.0, or -1e-16 from the
#: inverse kinematics) states either neighbour. 0.001 deg: far above the inverse kinematics' and the written
#: text's rounding (1e-4 mm over 300 mm is 2e-5 deg), far below any difference between taught poses.
BOUNDARY_TOL_DEG = 1e-3


def _quadrant_ok(q: np.ndarray, quad: np.ndarray, tol: float) -> np.ndarray:
    """``q`` (m, k) rad lies in quadrant ``quad`` (k,) (``[quad, quad + 1] * 90 deg``) within ``tol`` rad."""
    lo = quad[None, :] * (np.pi / 2)
    return (q >= lo - tol) & (q <= lo + np.pi / 2 + tol)


def _sign_ok(q: np.ndarray, negative: np.ndarray, tol: float) -> np.ndarray:
    """``q`` (m, k) rad has the stated sign (``negative`` (k,) bool) within ``tol`` rad (0 matches both)."""
    return np.where(negative[None, :], q <= tol, q >= -tol)


def config_matches(dialect: str, cc: Any, q: np.ndarray, config: dict[str, Any]) -> np.ndarray:
    """Which joints ``q`` (m, n) rad have the target's configuration (all True when it states none). Angles
    within :data:`BOUNDARY_TOL_DEG` of a quadrant or sign boundary match both neighbours."""
    m = len(q)
    tol = math.radians(BOUNDARY_TOL_DEG)
    if dialect == "krl":
        ok = np.ones(m, dtype=bool)
        c = arm_configuration(cc, q)
        if config.get("S") is not None:
            s = int(config["S"])
            ok &= c["shoulder"] == bool(s & 1)
            ok &= c["elbow"] == bool(s & 2)
            ok &= _sign_ok(q[:, 4:5], np.array([bool(s & 4)]), tol)[:, 0]
        if config.get("T") is not None:
            t = int(config["T"])
            neg = np.array([bool((t >> j) & 1) for j in range(q.shape[1])])
            ok &= _sign_ok(q, neg, tol).all(axis=1)
        return ok
    cf = config.get("cf")
    if cf is None:
        return np.ones(m, dtype=bool)
    cfa = np.asarray(cf, dtype=int)
    c = arm_configuration(cc, q)
    ok_q = np.asarray(_quadrant_ok(q[:, [0, 3, 5]], cfa[:3], tol).all(axis=1), dtype=bool)
    ok_q = ok_q & (c["shoulder"] == bool(cfa[3] & 4)) & (c["elbow"] == (not cfa[3] & 2))
    return ok_q & _sign_ok(q[:, 4:5], np.array([bool(cfa[3] & 1)]), tol)[:, 0]


def written_config(dialect: str, cc: Any, q: np.ndarray, config: dict[str, Any]) -> dict[str, Any]:
    """The configuration data to write with the joints ``q`` (n,) rad: computed from ``q``
    (:func:`kuka_status_turn`, :func:`abb_confdata`), except that a quadrant or sign the target stated and
    that ``q`` still matches within :data:`BOUNDARY_TOL_DEG` is kept as written (a target on a boundary stays
    as taught instead of flipping to the other neighbour)."""
    tol = math.radians(BOUNDARY_TOL_DEG)
    q2 = np.asarray(q, dtype=float)[None, :]
    if dialect == "krl":
        st, tt = kuka_status_turn(cc, q2, int(config.get("S") or 0))
        s, t = int(st[0]), int(tt[0])
        if config.get("S") is not None and _sign_ok(q2[:, 4:5], np.array([bool(config["S"] & 4)]), tol)[0, 0]:
            s = (s & ~4) | (int(config["S"]) & 4)
        if config.get("T") is not None:
            t0 = int(config["T"])
            for j in range(q2.shape[1]):
                if _sign_ok(q2[:, j : j + 1], np.array([bool((t0 >> j) & 1)]), tol)[0, 0]:
                    t = (t & ~(1 << j)) | (t0 & (1 << j))
        return {"S": s, "T": t}
    cf = [int(v) for v in abb_confdata(cc, q2)[0]]
    if config.get("cf") is not None:
        cf0 = [int(v) for v in config["cf"]]
        for i, j in enumerate((0, 3, 5)):
            if _quadrant_ok(q2[:, j : j + 1], np.array([cf0[i]]), tol)[0, 0]:
                cf[i] = cf0[i]
        if _sign_ok(q2[:, 4:5], np.array([bool(cf0[3] & 1)]), tol)[0, 0]:
            cf[3] = (cf[3] & ~1) | (cf0[3] & 1)
    return {"cf": cf}


def config_seeds(
    dialect: str, config: dict[str, Any], limits: np.ndarray, rng: np.random.Generator, k: int
) -> np.ndarray:
    """``k`` random joint seeds (k, n) rad inside ``limits`` (n, 2) rad that agree with the signs and quadrants
    the configuration states (the remaining joints uniform)."""
    n = len(limits)
    lo, hi = limits[:, 0].copy(), limits[:, 1].copy()
    if dialect == "krl" and config.get("T") is not None:
        t = int(config["T"])
        for j in range(n):
            if (t >> j) & 1:
                hi[j] = min(hi[j], 0.0)
            else:
                lo[j] = max(lo[j], 0.0)
    elif dialect == "rapid" and config.get("cf") is not None:
        cf = [int(v) for v in config["cf"]]
        for j, qd in zip((0, 3, 5), cf[:3], strict=True):
            lo[j] = max(lo[j], qd * np.pi / 2)
            hi[j] = min(hi[j], (qd + 1) * np.pi / 2)
        if cf[3] & 1:
            hi[4] = min(hi[4], 0.0)
        else:
            lo[4] = max(lo[4], 0.0)
    bad = lo >= hi
    lo[bad], hi[bad] = limits[bad, 0], limits[bad, 1]
    # keep away from the wrist singularity (axis 5 = 0) and the limits
    span = hi - lo
    return lo + span * (0.05 + 0.9 * rng.random((k, n)))
