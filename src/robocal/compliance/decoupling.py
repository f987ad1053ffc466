"""POE decoupling (Mao et al. 2021, eq. 25-26): calibrated errors -> link lengths / offsets a controller accepts.

The SR210 layout of fig. 3 / eq. 25 (base frame at the height of axis 2, all axes in the x-z plane at q = 0):
axis points ``p2 = (L1, 0, 0)``, ``p3 = (L1, 0, L2)``, ``p4 = (L1, 0, L2 + L3)``, ``p5 = p6 = (L1 + L4, 0, L2 + L3)``,
flange ``(L1 + L4 + L5, 0, L2 + L3)``; twists ``xi = [v; w]`` with ``v = -w x p``. The paper's decoupling matrix
``B`` maps ``dL = [dL1..dL4]`` to the twist errors ``dxi`` (eq. 26); :func:`decoupling_matrix` computes it as
``d xi / d L`` (exact: the twists are linear in ``L``).

robocal's chain calibrates "local POE" errors (six per link, :mod:`robocal.kinematics.chain`), which span the same
error space as the twist errors; a controller accepts only ``L`` and zero offsets. :func:`controller_parameters`
therefore finds the controller parameters (``dL1..dL4``, joint zero offsets, with the base frame and tool refitted)
whose kinematics reproduce the calibrated kinematics best (least squares over the calibration poses) and reports
what they cannot express (the RMS difference, mm). ``dL5`` is redundant with the tool z offset, ``dtheta1`` with the
base rotation and ``dtheta6`` with the tool x/y offset (position-only data): they are held at 0, as in the paper's
table 1.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from robocal.calibration.result import CalibrationResult
from robocal.errors import ConfigError
from robocal.identification.model import CalibrationModel, FitData
from robocal.metrics import ErrorStats
from robocal.optimizers.least_squares import least_squares
from robocal.robot import RobotDescription

_W = np.array([[0, 0, 1], [0, -1, 0], [0, -1, 0], [1, 0, 0], [0, -1, 0], [1, 0, 0]], dtype=float)
CONTROLLER_FIXED = ("L5", "theta1", "theta6")


def layout_lengths(robot: RobotDescription, tol_mm: float = 1e-6) -> np.ndarray:
    """``L1..L5`` (mm) of a robot with the Mao fig. 3 layout; ConfigError naming the mismatch otherwise."""
    if robot.convention != "poe" or robot.n_joints != 6 or robot.poe_w is None or robot.poe_p_mm is None:
        raise ConfigError(f"robot {robot.name!r}: decoupling needs a 6-axis POE robot with the Mao fig. 3 layout")
    assert robot.poe_flange0 is not None
    if np.abs(robot.poe_w - _W).max() > 1e-9:
        raise ConfigError(f"robot {robot.name!r}: joint axes differ from the Mao fig. 3 layout {_W.tolist()}")
    p = robot.poe_p_mm
    f = robot.poe_flange0[:3, 3]
    L = np.array([p[1, 0], p[2, 2], p[3, 2] - p[2, 2], p[4, 0] - p[1, 0], f[0] - p[4, 0]])
    ref = layout_points(L)
    # points on an axis may slide along it: compare the components across the axis only
    for i in range(6):
        d = p[i] - ref[i]
        d = d - np.dot(d, robot.poe_w[i]) * robot.poe_w[i]
        if np.linalg.norm(d) > tol_mm:
            raise ConfigError(f"robot {robot.name!r}: axis {i + 1} does not pass where the Mao layout puts it")
    return L


def layout_points(L: np.ndarray) -> np.ndarray:
    """Axis points ``(6, 3)`` and (row 6) the flange origin, ``(7, 3)`` mm, of the Mao layout for ``L``."""
    L1, L2, L3, L4, L5 = L
    h = L2 + L3
    return np.array(
        [[0, 0, 0], [L1, 0, 0], [L1, 0, L2], [L1, 0, h], [L1 + L4, 0, h], [L1 + L4, 0, h], [L1 + L4 + L5, 0, h]],
        dtype=float,
    )


def with_lengths(robot: RobotDescription, L: np.ndarray, theta_offset: np.ndarray | None = None) -> RobotDescription:
    """The robot with link lengths ``L`` (and joint zero offsets, rad)."""
    pts = layout_points(np.asarray(L, dtype=float))
    assert robot.poe_flange0 is not None
    f = robot.poe_flange0.copy()
    f[:3, 3] = pts[6]
    th = robot.theta_offset if theta_offset is None else np.asarray(theta_offset, dtype=float)
    return replace(robot, poe_p_mm=pts[:6], poe_flange0=f, theta_offset=th)


def twists(robot: RobotDescription) -> np.ndarray:
    """Joint twists ``(n, 6)`` as ``[v; w]``, ``v = -w x p`` (mm, unitless)."""
    assert robot.poe_w is not None and robot.poe_p_mm is not None
    v = -np.cross(robot.poe_w, robot.poe_p_mm)
    return np.concatenate([v, robot.poe_w], axis=1)


def decoupling_matrix(robot: RobotDescription) -> np.ndarray:
    """The paper's ``B`` (eq. 26): ``d xi (6n,) = B (6n, 4) · dL1..dL4``, by exact differences of :func:`twists`."""
    L = layout_lengths(robot)
    base = twists(with_lengths(robot, L)).ravel()
    B = np.zeros((base.size, 4))
    for k in range(4):
        d = np.zeros(5)
        d[k] = 1.0
        B[:, k] = twists(with_lengths(robot, L + d)).ravel() - base
    return B


def controller_parameters(result: CalibrationResult, q: np.ndarray, target_index: np.ndarray) -> dict[str, Any]:
    """Controller parameters (``L``, zero offsets) closest to the calibrated kinematics at the poses ``q``.

    Returns nominal and calibrated ``L`` (mm), ``dL``, zero offsets ``dtheta`` (deg), the base / tool refitted
    with them, and ``rms_mm`` / ``max_mm``: how far the controller model stays from the calibrated model.
    """
    robot = result.model.robot
    L0 = layout_lengths(robot)
    gm = result.model
    p_cal, _ = gm.predict(result.x, q, target_index)
    n = robot.n_joints
    names = [f"L{k + 1}" for k in range(5)] + [f"theta{j + 1}" for j in range(n)]
    free_ctrl = [i for i, nm in enumerate(names) if nm not in CONTROLLER_FIXED]
    nb = gm.n_chain - gm.chain.n_params  # base parameters
    base_tool = list(range(gm.chain.n_params, gm.chain.n_params + nb + 3 * len(gm.target_names)))
    z = np.zeros(5 + n)
    y = np.zeros(gm.n)
    y[base_tool] = result.x[base_tool]
    y[[gm.index(f"theta{j + 1}") for j in range(n)]] = 0.0
    data = FitData(q=q, p_mm=p_cal, target_index=target_index)

    def build(zz: np.ndarray) -> CalibrationModel:
        rob = with_lengths(robot, L0 + zz[:5], robot.theta_offset + zz[5:])
        return CalibrationModel(rob, gm.target_names, T_ref=gm.T_ref)

    nbt = len(base_tool)

    def unpack(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        yy, zz = y.copy(), z.copy()
        yy[base_tool] = w[:nbt]
        zz[free_ctrl] = w[nbt:]
        return yy, zz

    def fun(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        yy, zz = unpack(w)
        mdl = build(zz)
        r, J = mdl.residuals_and_jacobian(yy, data)
        cols = [J[:, i] for i in base_tool]
        for i in free_ctrl:
            if i < 5:
                dz = np.zeros_like(zz)
                dz[i] = 1.0  # positions are affine in L for fixed joints: a unit difference is exact
                cols.append(build(zz + dz).residuals(yy, data) - r)
            else:
                cols.append(J[:, mdl.index(names[i])])
        return r, np.column_stack(cols)

    # Gauss-Newton by the identification's least-squares core (line search; a linear problem in L, so 1-2 steps)
    w0 = np.concatenate([y[base_tool], z[free_ctrl]])
    lm = least_squares(fun, w0, np.arange(len(w0)), 1.0, max_iter=8, ftol=1e-15, xtol=1e-12, method="gn")
    y, z = unpack(lm.x)
    r = build(z).residuals(y, data)
    e = ErrorStats.of(r.reshape(-1, 3))
    return {
        "layout": "Mao 2021 fig. 3 (eq. 25)",
        "L_nominal_mm": L0.tolist(),
        "L_calibrated_mm": (L0 + z[:5]).tolist(),
        "dL_mm": z[:5].tolist(),
        "dtheta_deg": np.rad2deg(z[5:]).tolist(),
        "fixed": list(CONTROLLER_FIXED),
        **e.position(("rms", "max"), scheme="short"),
        "n_poses": len(q),
        "B": decoupling_matrix(robot).tolist(),
    }


__all__ = [
    "CONTROLLER_FIXED",
    "controller_parameters",
    "decoupling_matrix",
    "layout_lengths",
    "layout_points",
    "twists",
    "with_lengths",
]
