"""Discovered effects as a product: the extended model written as a calibration (geometry plus its
joint-level effects as ``effects`` records, :func:`extended_calibration`); offline compensation with it is the
one entry point :func:`robocal.compensation.correct.correct` (``robocal.compensate``).

The records are evaluated for any commanded configuration by :mod:`robocal.compensation.discovered` (the one
compensation path the service, the program filter and ``compensation.csv`` share). Parameter drifts (thermal,
drift) need the temperatures or the time of the moment, and measurement-side effects (the tracker's frame or
scale) correct the figures, never the robot: they are written under ``effects_not_compensated`` with the reason,
never applied silently.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.record import calibration_record
from robocal.calibration.result import CalibrationResult
from robocal.discovery.model import Accepted, Fit
from robocal.identification.identifiability import Eliminated, Identifiability
from robocal.robot import RobotDescription

if TYPE_CHECKING:
    pass


def signal_kind(acc: Accepted) -> str | None:
    """The signal of a joint-level effect (one of :data:`robocal.compensation.discovered.SIGNALS`), None for
    parameter or structure effects."""
    c = acc.cand
    if c.shape != "joint":
        return None
    if c.effect == "gear":
        return "angle"
    if c.effect in ("transmission", "weight", "layer"):
        return c.effect
    if c.effect == "backlash":
        return "direction"
    if c.effect == "compliance":
        return str(c.extra.get("source", "gravity"))
    if c.effect == "signal":
        return "logged" if c.extra.get("side", "robot") == "robot" else None
    if c.effect == "proposed":
        from robocal.discovery.dictionary import Term

        ok = all(
            Term(tuple((f["kind"], f["index"], f["harmonic"]) for f in t["factors"])).from_joints_only
            for t in c.extra["terms"]
        )
        return "dictionary" if ok else None
    raise ValueError(f"unknown joint-level effect {c.effect!r}")


#: why an effect of these families is not compensated (the families not listed: effect_records says)
_NOT_COMPENSATED = {
    "session": "a tool re-seated between sessions: the session's own, like its tracker frame; a new session "
    "re-measures its tool",
    "axis": "an external axis's own error along its travel (robocal.discovery.axes): not a joint-level effect; "
    "written under the calibration's 'axes' and compensated there (robocal.compensation.axes: the service, "
    "the program filter, the discovery's compensation.csv)",
}


def effect_records(fit: Fit) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The accepted effects of a discovery fit as JSON records: ``(joint_level, not_compensated)``."""
    model = fit.model
    joint_level: list[dict[str, Any]] = []
    other: list[dict[str, Any]] = []
    for acc, sl in zip(model.accepted, model.slices, strict=True):
        c = acc.cand
        kind = signal_kind(acc)
        if c.shape == "frame" and c.extra.get("side", "robot") == "robot":
            # the base or the tool following a logged signal: the service and compensation.csv take the signal's
            # value with each target and correct the pose the robot must reach (robocal.compensation.discovered)
            joint_level.append(
                {
                    "key": c.key,
                    "effect": c.effect,
                    "joint": None,
                    "harmonic": None,
                    "signal": "logged_frame",
                    "frame": c.extra["frame"],
                    **({"axis_joint": int(c.extra["axis_joint"])} if "axis_joint" in c.extra else {}),
                    "column": c.extra["column"],
                    "centre": float(c.extra["centre"]),
                    **({"range": list(c.extra["range"])} if "range" in c.extra else {}),
                    "coefficients": [float(v) for v in fit.theta[sl]],
                    "coefficient_names": list(c.coef_names),
                    "units": list(c.coef_units),
                }
            )
            continue
        if kind is None:
            if c.shape == "structure":
                continue  # lives in the geometry (beta), already in the calibration
            if c.effect == "proposed":
                why = "a proposed equation with a term the commanded joints do not give (temperature, time, torque)"
            elif c.effect in ("drift", "air", "regap"):
                why = "a measurement-side effect (the tracker's frame moving): it corrects the figures, never the robot"
            elif c.effect == "signal":
                what = "the tracker's scale follows" if c.shape == "tracker" else "declared on the tracker:"
                why = (f"a measurement-side effect ({what} the logged signal {c.extra['column']}): it corrects the "
                       "figures, never the robot")  # fmt: skip
            elif c.effect == "misfit":
                why = "a systematic misfit of the rows under a condition: it corrects the figures, never the robot"
            elif c.effect == "scale":
                why = "a measurement-side effect (the tracker's length scale): it corrects the figures, never the robot"
            else:
                why = (
                    "a parameter drift with "
                    + ("the temperatures" if c.effect == "thermal" else "time")
                    + ": it needs the state of the moment, not the commanded joints; "
                    "use the thermal pipeline's model for online compensation"
                )
            why = _NOT_COMPENSATED.get(c.effect, why)
            other.append({"key": c.key, "effect": c.effect, "reason": why})
            continue
        assert c.joint is not None
        rec_terms: dict[str, Any] = {"terms": c.extra["terms"]} if kind == "dictionary" else {}
        if kind == "angle" and c.extra.get("held_outside_deg") is not None:
            rec_terms = {"held_outside_deg": list(c.extra["held_outside_deg"])}
        elif kind == "transmission":
            rec_terms = {k: c.extra[k] for k in ("harmonics", "visited_deg", "taper_deg", "centre", "window")
                         if k in c.extra}  # fmt: skip
        elif kind == "weight":
            rec_terms = {k: c.extra[k] for k in ("basis", "scale", "prior_deg", "balancer_harmonics",
                                                  "balancer_centre", "payload_columns") if k in c.extra}  # fmt: skip
        elif kind == "layer":
            rec_terms = {k: c.extra[k] for k in ("centres_rad", "length_rad", "inside_rad")}
        elif kind == "logged":
            rec_terms = {"column": c.extra["column"], "centre": float(c.extra["centre"]),
                         **({"range": list(c.extra["range"])} if "range" in c.extra else {})}  # fmt: skip
        joint_level.append(
            {
                **rec_terms,
                "key": c.key,
                "effect": c.effect,
                "joint": int(c.joint),
                "harmonic": None if c.harmonic is None else int(c.harmonic),
                "signal": kind,
                "coefficients": [float(v) for v in fit.theta[sl]],
                "coefficient_names": list(c.coef_names),
                "units": list(c.coef_units),
            }
        )
    return joint_level, other


def extended_calibration(fit: Fit, robot: RobotDescription, summary_fit: dict[str, Any]) -> dict[str, Any]:
    """The discovered model written as a calibration (the geometric format of
    :func:`~robocal.calibration.record.calibration_record`, so every reader of ``calibration.json`` takes
    it) with its joint-level effects under ``effects`` and the rest under ``effects_not_compensated``."""
    model = fit.model
    base = model.base
    nb = model.nb
    x = fit.theta[:nb].copy()
    free_b = np.array([i for i in fit.free if i < nb], dtype=int)
    identified = np.zeros(base.n, dtype=bool)
    identified[free_b] = True
    pos = [int(np.flatnonzero(fit.free == i)[0]) for i in free_b]
    cov = fit.cov[np.ix_(pos, pos)]
    stderr = np.full(base.n, np.nan)
    stderr[free_b] = np.sqrt(np.diag(cov))
    elim = tuple(
        Eliminated(n, (), 0.0, "not identifiable in the extended model") for n in fit.eliminated if n in base.names
    )
    Jb = fit.jacobian_columns(pos)
    Jn = Jb / np.maximum(np.linalg.norm(Jb, axis=0), 1e-300)
    ident = Identifiability(
        kept=free_b,
        eliminated=elim,
        rank=len(free_b),
        singular_values=np.linalg.svd(Jn, compute_uv=False),
        names=base.names,
    )
    out = calibration_record(
        base, x, identified, stderr, cov, ident, (), summary_fit, CalibrationConfig(noise_mm=fit.sigma)
    )
    joint_level, other = effect_records(fit)
    out["effects"] = joint_level
    out["effects_not_compensated"] = other
    if not np.array_equal(base.robot.beta_free, robot.beta_free):
        out["beta_free"] = [bool(v) for v in base.robot.beta_free]
    out["source"] = "robocal discover: geometry and every named effect, fitted jointly"
    return out


def compensate_targets(
    cal: CalibrationResult,
    q_target: np.ndarray,
    target: str | None = None,
    payload_kg: np.ndarray | float = 0.0,
    tau_Nm: np.ndarray | None = None,
    current_A: np.ndarray | None = None,
    direction: np.ndarray | None = None,
    logged: Mapping[str, np.ndarray] | None = None,
    **newton: Any,
) -> tuple[Any, np.ndarray]:
    """Deprecated (was ``robocal.compensate``): use :func:`robocal.compensation.correct.correct` (``robocal.compensate``
    now), which returns one :class:`~robocal.compensation.correct.Corrected` with the command as ``command_T``.

    Kept as a thin wrapper for outside callers: ``(corrected, command_T)`` of
    ``correct(cal, q_target, target=target, signals=Signals(payload_kg, tau_Nm, current_A, direction, logged))``."""
    import warnings

    from robocal.compensation.correct import correct
    from robocal.compensation.effects import Signals

    warnings.warn(
        "robocal.discovery.effects.compensate_targets is deprecated; use robocal.compensate "
        "(robocal.compensation.correct.correct), which returns one Corrected with command_T",
        DeprecationWarning,
        stacklevel=2,
    )
    m = len(q_target)
    sig = Signals(np.broadcast_to(np.asarray(payload_kg, dtype=float), (m,)), tau_Nm, current_A, direction, logged)
    c = correct(cal, q_target, target=target, signals=sig, **newton)
    assert c.command_T is not None
    return c, c.command_T
