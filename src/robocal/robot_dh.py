"""Standard (distal) Denavit-Hartenberg descriptions, as robot data sheets give them (``convention: dh`` in a robot
file), read as the same chain in a convention robocal calibrates (:func:`dh_description`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.errors import ConfigError

#: the convention string of a robot file in standard Denavit-Hartenberg
DH = "dh"


def _number(j: dict[str, Any], key: str, where: str, default: float | None) -> float:
    """``j[key]`` as a float (``default`` when absent; absent without one: an error naming the key)."""
    if key not in j:
        if default is None:
            raise ConfigError(f"{where}: missing key {key!r} (convention dh: a_mm, alpha_deg, d_mm per joint)")
        return default
    try:
        return float(j[key])
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: key {key!r} must be a number, got {j[key]!r}") from None


def dh_matrix(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    """Standard DH link transform ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` (mm, rad)."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])


def dh_description(data: dict[str, Any], source: str, mdh: str, poe: str) -> dict[str, Any]:
    """A description in standard Denavit-Hartenberg (``convention: dh``; each joint ``a_mm``, ``alpha_deg``,
    ``d_mm``, ``theta_offset_deg``: link i is ``Rz(q_i + theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``, the base frame
    the frame of axis 1, the flange frame n) as the same chain in a convention robocal calibrates.

    The product regroups as MD-H (Craig) rows ``Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(q_i + theta_i) Tz(d_i)`` (``Tx Rx``
    commute) followed by ``Tx(a_n) Rx(alpha_n)``; when that last transform is the identity (most arms: the
    flange on axis n) the description is that MD-H table, with the Hayati ``beta`` of joint i free where axes i
    and i + 1 are parallel (``alpha_i = 0``; a joint's own ``beta_free`` wins). Otherwise it is the POE
    description of the chain at q = 0 (axis i: the z axis of DH frame i - 1). The same flange pose for every q.
    ``mdh``, ``poe``: the convention names of :mod:`robocal.robot`, which reads the result."""
    joints = data["joints"]
    dyn = data.get("dynamics")
    if dyn is not None and (not isinstance(dyn, dict) or dyn.get("links")):
        raise ConfigError(f"{source}: convention dh with 'dynamics.links': give link masses with an MD-H "
                          "description (their centres of mass are in its link frames); gravity alone may be stated "
                          "(dynamics: {gravity_mps2: [gx, gy, gz]}, in the base frame: DH's is axis 1's)")  # fmt: skip
    rows = []
    for i, j in enumerate(joints, start=1):
        where = f"{source}: joints[{i}]"
        if not isinstance(j, dict):
            raise ConfigError(f"{where} must be a mapping")
        rows.append([_number(j, k, where, 0.0 if k == "theta_offset_deg" else None)
                     for k in ("a_mm", "alpha_deg", "d_mm", "theta_offset_deg")])  # fmt: skip
    dh_keys = ("a_mm", "alpha_deg", "d_mm", "theta_offset_deg", "beta_deg", "beta_free")
    rest = [{k: v for k, v in j.items() if k not in dh_keys} for j in joints]
    out = {k: v for k, v in data.items() if k not in ("convention", "joints")}
    out["description_convention"] = f"{DH} (standard Denavit-Hartenberg), read by robocal.robot.dh_description"
    n = len(rows)
    if rows[-1][0] == 0.0 and rows[-1][1] == 0.0:
        mdh_rows = []
        for i, j in enumerate(rest):
            a_prev, al_prev = (0.0, 0.0) if i == 0 else (rows[i - 1][0], rows[i - 1][1])
            free = bool(joints[i].get("beta_free", i + 1 < n and rows[i][1] == 0.0))
            mdh_rows.append({**j, "a_mm": a_prev, "alpha_deg": al_prev, "d_mm": rows[i][2],
                        "theta_offset_deg": rows[i][3], "beta_deg": 0.0, "beta_free": free})  # fmt: skip
        return {**out, "convention": mdh, "joints": mdh_rows}
    if any(str(j.get("type", "revolute")) == "prismatic" for j in joints):
        raise ConfigError(f"{source}: convention dh with a prismatic joint and a_mm or alpha_deg on the last joint: "
                          "write it as MD-H")  # fmt: skip
    T, twists = np.eye(4), []
    for a, al, d, th in rows:
        twists.append({"w": T[:3, 2].tolist(), "p_mm": T[:3, 3].tolist()})
        T = T @ dh_matrix(a, np.deg2rad(al), d, np.deg2rad(th))
    chain0 = {"twists": twists, "flange_at_zero_mm": T[:3, 3].tolist(), "flange_R_at_zero": T[:3, :3].tolist()}
    return {**out, "convention": poe, "joints": rest, "poe": chain0}


__all__ = ["DH", "dh_description", "dh_matrix"]
