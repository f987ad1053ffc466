"""A URDF's ``<inertial>`` elements as the robot description's dynamics (:func:`robocal.cell.urdf.robot_dict_from_urdf`;
split from it by role)."""

from __future__ import annotations

from typing import Any

import numpy as np

#: URDF joint types that turn
REVOLUTE = ("revolute", "continuous")
#: URDF joint types robocal models as joints (that move)
ACTUATED = (*REVOLUTE, "prismatic")


def origin_mm(T: np.ndarray | None) -> np.ndarray:
    """A URDF origin ``(4, 4)`` (metres) in millimetres (identity when absent)."""
    out = np.eye(4) if T is None else np.array(T, dtype=float)
    out[:3, 3] *= 1000.0
    return out


def body_inertials(urdf: Any, joints: list[Any], twists: list[dict[str, Any]]) -> tuple[Any, str]:
    """The description's ``dynamics.links`` from the URDF's ``<inertial>`` elements: each moving body (the links
    from one actuated joint to the next on the path, with the links fixed to them off the path) as one mass and
    centre of mass, in body ``i``'s frame (:mod:`robocal.kinematics.gravity`: the POE axis frame at q = 0).
    None, and why, when the file has no usable masses: a moving body without mass, or the placeholder pattern of
    equal masses all at their link origins (a file written without dynamics), which would give a wrong torque
    shape where robocal's mass-free weight model does better. The second value says what was done."""
    from robocal.kinematics.chain import poe_axis_frames

    children: dict[str, list[Any]] = {}
    for j in urdf.joint_map.values():
        children.setdefault(j.parent, []).append(j)
    on_path = {j.name for j in joints}
    mass: list[float] = []
    moment: list[np.ndarray] = []
    per_link: list[tuple[float, np.ndarray]] = []  # (mass, centre in its link frame, mm) of every link used

    def add(link: str, T: np.ndarray) -> None:
        inertial = getattr(urdf.link_map[link], "inertial", None)
        m = float(getattr(inertial, "mass", 0.0) or 0.0) if inertial is not None else 0.0
        c_local = origin_mm(getattr(inertial, "origin", None))[:3, 3] if inertial is not None else np.zeros(3)
        if m > 0 and mass:
            mass[-1] += m
            moment[-1] = moment[-1] + m * (T[:3, :3] @ c_local + T[:3, 3])
        per_link.append((m, c_local))
        for jf in children.get(link, []):  # the links fixed to it off the path belong to the same body
            if jf.name not in on_path and jf.type == "fixed":
                add(jf.child, T @ origin_mm(jf.origin))

    T = np.eye(4)
    for j in joints:
        T = T @ j.origin
        if j.type in ACTUATED:
            mass.append(0.0)
            moment.append(np.zeros(3))
        if mass:
            add(j.child, T)
    if not mass or min(mass) <= 0.0:
        return None, "not used: a moving body has no <inertial> mass (the weight is modelled without masses)"
    ms = np.array([m for m, _ in per_link if m > 0])
    if len(ms) > 1 and np.ptp(ms) == 0.0 and all(not np.any(c) for m, c in per_link if m > 0):
        return None, ("not used: every link's <inertial> is the same mass at its link origin, a placeholder (the "
                      "weight is modelled without masses)")  # fmt: skip
    frames = poe_axis_frames(np.array([t["w"] for t in twists]), np.array([t["p_mm"] for t in twists]))
    links = []
    for m, mom, F in zip(mass, moment, frames, strict=True):
        c = F[:3, :3].T @ (mom / m - F[:3, 3])
        links.append({"mass_kg": float(m), "com_mm": [float(v) for v in c]})
    return links, "used: the <inertial> masses and centres of the links each joint moves"


__all__ = ["ACTUATED", "REVOLUTE", "body_inertials", "origin_mm"]
