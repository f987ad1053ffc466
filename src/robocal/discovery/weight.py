"""The compliance under the arm's own weight (and its payload's) as a candidate of the cross-validated selection
(:func:`robocal.discovery.grow.physics_candidates`): the deflection of each joint's reducer under the gravity torque,
without the link masses (the mass-moment combinations the poses tell apart, :func:`robocal.discovery.physics
.weight_basis`) or with them (the described torque, corrected by those combinations), beside physical shapes that
hold over the whole workspace: links shaped like the arm's, the payload carried at the flange (its mass given with
every row, ``payload_kg``), and a shoulder's counterbalance.

A campaign of several payloads gets the payload's own columns (:func:`robocal.compensation.signals.with_payload`:
its centre of mass and the stiffness under it fitted; each target's payload then given to the service)."""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.data.campaign import Campaign
from robocal.discovery.candidates import Candidate
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.scoring import Variant
from robocal.robot import RobotDescription


def weight_candidates(
    campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, rows: np.ndarray, q: np.ndarray
) -> list[tuple[Candidate, list[Variant]]]:
    """The ``weight:j<j>`` candidates of every joint with a gravity torque (none with logged torques or currents:
    the library's compliance takes those); signals for every campaign row, bases from the fitted ``rows``."""
    from robocal.compensation.signals import with_payload
    from robocal.discovery.physics import (
        BALANCER_HARMONICS,
        balancer_columns,
        bounded_columns,
        weight_basis,
        workspace_sample,
    )
    from robocal.kinematics.gravity import described_mass_moments, generic_mass_moments, gravity_regressor

    # link masses in the description do not stop it: the library's ``compliance`` from those masses competes with
    # it (a vendor's URDF with link inertials but no tool mass: compliance j2, j3 from the given masses 0.137 mm
    # held out, the same poses without the inertials, this weight model, 0.059)
    has_load_signal = campaign.tau_Nm is not None or campaign.current_A is not None
    if "weight" not in cfg.effects or has_load_signal:
        return []
    out: list[tuple[Candidate, list[Variant]]] = []
    n = robot.n_joints
    Y = gravity_regressor(robot, q)
    # the torque of links shaped like the arm's (uniform rods): one combination of physical shape over the
    # whole workspace, beside the ones the poses tell apart (on a heavy robot in 17 configurations those alone
    # matched its true torque to only 40-60 %, and gear harmonics stood in for the rest)
    qw = workspace_sample(robot)
    Yw = gravity_regressor(robot, qw)
    pi0 = described_mass_moments(robot, qw, Yw) if robot.has_dynamics else generic_mass_moments(robot)
    # the payload, for an arm whose masses are unknown (with them the library's compliance carries its torque
    # exactly: the twin's KR16 at 0 and 16 kg named weight j2 in its place, a heavy arm's 0.077 mm became 0.085)
    pay = np.broadcast_to(np.asarray(campaign.payload_kg, dtype=float), (len(q),))
    pay = pay if not robot.has_dynamics else np.zeros(len(q))
    payload = bool(np.ptp(pay[rows]) > 1e-6)
    shapes = [pi0]  # physical torques: the links' (and the payload's), beside the combinations the poses tell
    if payload:  # rows of several payloads: the payload's own columns (newcomer pass 14: 100-200 kg, 2.52 mm)
        Y, Yw = with_payload(Y, pay), with_payload(Yw, float(np.max(pay[rows])))
        e_pay = np.zeros(len(pi0) + 4)
        e_pay[len(pi0)] = 1.0  # the payload's own torque, its mass at the flange (each row's kg)
        shapes = [np.concatenate([pi0, np.zeros(4)]), e_pay]
    elif float(np.max(pay[rows])) > 0:  # one payload on every row: its torque's own shape (a mass at the flange)
        e_pay = np.zeros(len(pi0))
        e_pay[len(pi0) - 4] = 1.0
        shapes = [pi0, e_pay]
    split = not robot.has_dynamics and (float(np.max(pay[rows], initial=0.0)) > 0 or _rods_m(pi0) > SPLIT_REACH_M)
    shoulder, B, centre = balancer_columns(robot, q, rows, Y, qw, offered=cfg.counterbalance != "off")
    for j in range(n):
        V, scale = weight_basis(Y[rows, j, :])
        if V.shape[1] == 0:
            continue
        for shape in reversed(_own_and_beyond(shapes, j) if split else shapes):
            s0 = float(np.sqrt(np.mean((Y[rows, j, :] @ shape) ** 2)))
            if s0 > 1e-9 * float(np.max(scale)):  # a torque, not the rounding of one the shape does not exert
                V, scale = np.column_stack([shape, V]), np.concatenate([[s0], scale])
        keep = bounded_columns(Y[rows, j, :] @ V, Yw[:, j, :] @ V)
        if not keep.any():
            continue
        V, scale = V[:, keep], scale[keep]
        S, r = Y[:, j, :] @ V / scale, V.shape[1]
        bal: dict[str, Any] = {}
        if j == shoulder:  # a counterbalance's columns after the torque's
            S = np.column_stack([S, B])
            bal = {"balancer_harmonics": list(BALANCER_HARMONICS), "balancer_centre": centre.tolist()}
        r_all = S.shape[1]
        cand = Candidate(
            f"weight:j{j + 1}", "weight", j + 1, None,
            cause=f"torsional elasticity of the joint-{j + 1} reducer under the arm's own weight "
            + ("(the torque of the description's link masses and the mass-moment combinations the poses tell "
               "apart, which correct them)" if robot.has_dynamics else
               "(link masses unknown: the mass-moment combinations the poses tell apart)"),
            signal=f"gravity-torque regressor of joint {j + 1} ({r} combinations)", shape="joint", S=S,
            coef_names=tuple(f"w{k + 1}" for k in range(r_all)), coef_units=("rad",) * r_all,
            extra={"basis": V.tolist(), "scale": scale.tolist(), "prior_deg": cfg.compliance_prior_deg, **bal,
                   **({"payload_columns": True} if payload else {})},
        )  # fmt: skip
        tau = float(np.deg2rad(cfg.compliance_prior_deg)) / np.sqrt(r)
        label = f"prior {cfg.compliance_prior_deg}° RMS" + (", with a counterbalance" if r_all > r else "")
        out.append((cand, [Variant(np.arange(r_all), tau, label)]))
    return out


#: an arm whose links beyond the base (the rods' lengths, m) reach further than this, or that carries a payload, has
#: its links' weight split per joint (:func:`_own_and_beyond`): on a long or loaded arm the upper arm's share of the
#: shoulder's torque is what a gear harmonic otherwise stands in for (a 165 kg-class arm in 18 configurations
#: 0.259 -> 0.158 mm held out, one with 120 kg 0.114 -> 0.031); on the real UR10 (1.5 m) and IRB 120 (0.7 m), no
#: payload, the extra column only moved the path (UR10 series A 0.0699 -> 0.0779 mm, a thermal drift and two
#: tracker scales then named together; IRB 120 0.1389 -> 0.1469)
SPLIT_REACH_M = 2.0


def _rods_m(pi0: np.ndarray) -> float:
    """The summed length (m) of the links beyond the first (the rods' masses, 1 kg per m)."""
    return float(np.sum(pi0[4::4]))


def _own_and_beyond(shapes: list[np.ndarray], j: int) -> list[np.ndarray]:
    """The links' shape (``shapes[0]``, uniform rods) split for joint ``j`` (0-based) into the link it turns first
    and the links beyond it, each its own column: without the masses their ratio is unknown, and one rod-shaped
    combination left a heavy arm's shoulder to a gear harmonic (newcomer pass 15: 120 kg at the flange, weight j2
    0.121 deg of a true 0.213, gear j2 h1 0.31 deg held outside the visited range, 0.114 mm held out, 0.756 at a
    pose 3 deg past it). The payload's shapes follow as they were."""
    pi0, n4 = shapes[0], 4 * (j + 1)
    own, beyond = np.zeros_like(pi0), np.zeros_like(pi0)
    own[4 * j : n4] = pi0[4 * j : n4]
    beyond[n4:] = pi0[n4:]
    return [own, beyond, *shapes[1:]]


__all__ = ["weight_candidates"]
