"""The signals of stored joint-level effects, evaluated at commanded joints: what the compensation (the service,
the program filter, ``compensation.csv``) and the discovery's fit both compute from an effect's record.

* :func:`transmission_signal`: a Fourier series of one joint's angle (:func:`fourier_signal`) weighted by the
  coverage of the angles the calibration visited (:func:`coverage_weight`): the gear transmission error;
* :func:`weight_signal`: the load torque of the arm's own weight per mass-moment combination
  (:func:`robocal.kinematics.gravity.gravity_regressor`): compliance without known masses;
* :func:`layer_signal`: the residual layer's gated kernel features (:func:`layer_features`, :func:`layer_gate`);
* :func:`evaluate_factor`: one factor of a proposed equation's term.

How they are fitted (visited intervals, the weight basis, the layer's centres) is the discovery's
(:mod:`robocal.discovery.physics`); the records they read are written by :mod:`robocal.discovery.effects`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.kinematics.gravity import gravity_regressor
from robocal.robot import RobotDescription

REV_DEG = 360.0

#: a factor of a term: ("sin" | "cos", joint 1-based, harmonic) or (signal kind, index 1-based or 0, 0)
Factor = tuple[str, int, int]


def coverage_weight(q_rad: np.ndarray, intervals: list[list[float]], taper_deg: float) -> np.ndarray:
    """``w (m,)`` in [0, 1]: 1 on the visited intervals, a raised cosine to 0 over ``taper_deg`` outside."""
    a = np.mod(np.rad2deg(np.asarray(q_rad, dtype=float)), REV_DEG)
    if not intervals:
        return np.zeros(a.shape)
    iv = np.asarray(intervals, dtype=float)
    lo, hi = iv[:, 0], iv[:, 1]  # (K,) every interval at once: the service evaluates this per Newton step
    A = a[..., None]
    inside = np.where(lo <= hi, (A >= lo) & (A <= hi), (A >= lo) | (A <= hi))  # lo > hi: wraps through 0
    d = np.minimum(np.mod(lo - A, REV_DEG), np.mod(A - hi, REV_DEG))
    dist = np.where(inside, 0.0, d).min(axis=-1)
    if taper_deg <= 0:
        return (dist == 0).astype(float)
    t = np.clip(dist / taper_deg, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * t))


def fourier_signal(q_rad: np.ndarray, harmonics: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
    """``S (m, 2H)``: ``[sin(h q) ..., cos(h q) ...]`` for the harmonics ``h`` (times ``weight`` when given)."""
    q = np.asarray(q_rad, dtype=float)
    h = np.asarray(harmonics, dtype=int)
    if len(h) and np.array_equal(h, np.arange(h[0], h[0] + len(h))):
        # consecutive harmonics: e^{i h q} by repeated multiplication (one sin/cos per pose; the service and
        # compensation.csv evaluate tens of harmonics per Newton step), exact to ~len(h) ulp
        from robocal.kinematics import compiled

        z = np.exp(1j * q)
        z0 = np.exp(1j * h[0] * q)
        if compiled.AVAILABLE:  # the same recurrence, compiled (a Python loop over tens of harmonics otherwise)
            Z = compiled.harmonics(z, z0, len(h))
        else:
            Z = np.empty((len(q), len(h)), dtype=complex)
            Z[:, 0] = z0
            for k in range(1, len(h)):
                Z[:, k] = Z[:, k - 1] * z
        S = np.concatenate([Z.imag, Z.real], axis=1)
    else:
        S = np.concatenate([np.sin(h[None, :] * q[:, None]), np.cos(h[None, :] * q[:, None])], axis=1)
    return S if weight is None else S * np.asarray(weight, dtype=float)[:, None]


def held_harmonic_signal(q_rad: np.ndarray, harmonic: int, held_deg: list[float] | None) -> np.ndarray:
    """``S (m, 2)``: ``sin(h q), cos(h q)`` of a joint's angle on the arc ``held_deg = [lo, hi]`` (deg) its
    calibration visited, and held outside it at the value of the nearer end: over the first and the last quarter
    of the arc never visited the value at ``hi`` and at ``lo``, and linearly from one to the other over its middle
    half (continuous and periodic, as the service needs). ``held_deg`` None: the harmonic everywhere.

    A harmonic whose period the visited angles do not cover is a smooth trend there (a proxy fitted jointly with
    the geometry), not an identified periodic error: continuing its curve beyond the visited angles extrapolates
    the trend, and dropping it to zero leaves the geometry fitted with it inconsistent. Held at its edge values,
    the model outside the visited angles is the one the calibration saw at its nearest edge."""
    q = np.asarray(q_rad, dtype=float)
    h = int(harmonic)
    if held_deg is None:
        return np.column_stack([np.sin(h * q), np.cos(h * q)])
    lo, hi = np.deg2rad(float(held_deg[0])), np.deg2rad(float(held_deg[1]))
    span = hi - lo
    two_pi = 2.0 * np.pi
    d = np.mod(q - lo, two_pi)  # angle from lo around the circle
    f = np.clip(2.0 * (d - span) / max(two_pi - span, 1e-12) - 0.5, 0.0, 1.0)[:, None]  # 0 near hi, 1 near lo
    inside = (d <= span)[:, None]
    edge_hi = np.array([np.sin(h * hi), np.cos(h * hi)])
    edge_lo = np.array([np.sin(h * lo), np.cos(h * lo)])
    return np.where(inside, np.column_stack([np.sin(h * q), np.cos(h * q)]), (1.0 - f) * edge_hi + f * edge_lo)


def transmission_signal(q_rad: np.ndarray, record: dict[str, Any]) -> np.ndarray:
    """The transmission-error signal of a stored effect (``harmonics``, ``visited_deg``, ``taper_deg``, and the
    ``centre`` subtracted: the signal's mean over the calibration poses, whose constant part the geometry's
    joint offset carries)."""
    w = coverage_weight(q_rad, record["visited_deg"], float(record["taper_deg"]))
    S = fourier_signal(q_rad, np.asarray(record["harmonics"], dtype=int), w)
    return S - np.asarray(record.get("centre", 0.0), dtype=float)


def with_payload(Y: np.ndarray, payload_kg: Any) -> np.ndarray:
    """The gravity regressor ``Y (m, n, 4 b)`` with a carried payload's columns after it: the last body's four (a
    mass at its frame's origin, its first mass moments) times each row's payload (kg) — a payload of known mass
    whose centre of mass, and the stiffness under it, the fit finds (``(m, n, 4 b + 4)``)."""
    p = np.broadcast_to(np.asarray(0.0 if payload_kg is None else payload_kg, dtype=float), (Y.shape[0],))
    return np.concatenate([Y, p[:, None, None] * Y[:, :, -4:]], axis=2)


def weight_signal(
    robot: RobotDescription,
    q: np.ndarray,
    record: dict[str, Any],
    Y: np.ndarray | None = None,
    payload_kg: Any = None,
) -> np.ndarray:
    """The compliance-under-own-weight signal of a stored effect (``basis``, ``scale``); ``Y``: the
    :func:`gravity_regressor` at ``q`` when already computed (one for every joint's effect); ``payload_kg`` each
    row's payload, for an effect fitted on rows of several payloads (``payload_columns``: :func:`with_payload`)."""
    j = int(record["joint"]) - 1
    Y = gravity_regressor(robot, q) if Y is None else Y
    if record.get("payload_columns"):
        Y = with_payload(Y, payload_kg)
    Yj = Y[:, j, :]
    S = Yj @ np.asarray(record["basis"], dtype=float) / np.asarray(record["scale"], dtype=float)
    if record.get("balancer_harmonics"):
        S = np.column_stack([S, balancer_signal(np.asarray(q, dtype=float)[:, j], record)])
    return S


def balancer_signal(q_rad: np.ndarray, record: dict[str, Any]) -> np.ndarray:
    """The counterbalance's part of a weight effect (``balancer_harmonics``, ``balancer_centre``): a spring or
    hydro-pneumatic cylinder between the base and the upper arm of a heavy robot exerts a torque that depends on
    the shoulder's own angle alone, ``sin/cos(h q)`` less their mean over the calibration poses (the constant part
    is the geometry's joint offset); as :func:`transmission_signal` with its window open."""
    h = np.asarray(record["balancer_harmonics"], dtype=int)
    return fourier_signal(q_rad, h) - np.asarray(record["balancer_centre"], dtype=float)


def layer_features(q_rad: np.ndarray, centres: np.ndarray, length_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian kernel features ``exp(-|q - c|² / (2 l²))`` ``(m, D)`` and each pose's distance to its nearest
    centre ``(m,)`` rad."""
    q = np.atleast_2d(np.asarray(q_rad, dtype=float))
    c = np.asarray(centres, dtype=float)
    d2 = np.zeros((len(q), len(c)))
    for j in range(q.shape[1]):  # joint by joint, each element on its own: a row's value whatever rows are read
        d2 += (q[:, j, None] - c[None, :, j]) ** 2
    d = np.sqrt(d2)
    return np.exp(-d2 / (2.0 * length_rad**2)), d.min(axis=1)


def layer_gate(dist_rad: np.ndarray, inside_rad: float, length_rad: float) -> np.ndarray:
    """1 within ``inside_rad`` of a centre (the calibrated region), a raised cosine to 0 one length scale
    further: outside the calibrated region the layer is not applied (the parametric model alone)."""
    t = np.clip((np.asarray(dist_rad, dtype=float) - inside_rad) / length_rad, 0.0, 1.0)
    return np.asarray(0.5 * (1.0 + np.cos(np.pi * t)))


def layer_signal(q_rad: np.ndarray, record: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The residual layer's gated features ``(m, D)`` of a stored effect and the gate ``(m,)`` (1 = inside the
    calibrated region, 0 = outside: parametric correction only)."""
    ell = float(record["length_rad"])
    F, d = layer_features(q_rad, np.asarray(record["centres_rad"], dtype=float), ell)
    g = layer_gate(d, float(record["inside_rad"]), ell)
    return F * g[:, None], g


def factor_label(f: Factor) -> str:
    kind, i, h = f
    if kind in ("sin", "cos"):
        return f"{kind}({'' if h == 1 else h}q{i})"
    return {
        "gravity": f"tau_g{i}",
        "tau": f"tau{i}",
        "current": f"i{i}",
        "temperature": f"T_PC{i}",
        "dtemperature": f"dT_PC{i}/dt",
        "time": "t_h",
    }[kind]


def evaluate_factor(
    f: Factor,
    q: np.ndarray,
    grav: np.ndarray | None = None,
    tau: np.ndarray | None = None,
    current: np.ndarray | None = None,
) -> np.ndarray:
    """One factor at joints ``q (m, n)`` rad (gravity torques, torques, currents given where needed)."""
    kind, i, h = f
    if kind == "sin":
        return np.sin(h * q[:, i - 1])
    if kind == "cos":
        return np.cos(h * q[:, i - 1])
    arr = {"gravity": grav, "tau": tau, "current": current}.get(kind)
    if arr is None:
        raise ValueError(f"the term factor {factor_label(f)} needs a signal that was not given")
    return np.asarray(arr)[:, i - 1]
