"""Joint-space effects: the one place where what deflects the joints is composed for a correction.

A joint-space effect predicts ``dq (m, n)`` rad added to the commanded joints (``q_real = q_cmd + dq``) from the
commanded joints and the per-target :class:`Signals` (payload, reported torques or currents, approach
direction). The calibration's own joint-space corrections are the sum of the effects of a bundle or a
calibration (:func:`joint_effects`: compliance model, discovered joint-level effects, ...), composed by
:func:`compose` into one :class:`JointOffsets` that the Newton solver (:func:`robocal.kinematics.ik.solve`)
calls.

A new effect (a per-joint periodic gear error, a residual layer on the joint angles) is a class with a
``name``, the ``needs`` it has among :data:`SIGNALS` and ``offsets(q, signals) -> dq`` (the protocol
:class:`JointEffect`; optionally ``notes(q)``, per target, where it does not apply); listed once in
:meth:`robocal.serve.bundle.Bundle.joint_effects` it reaches the service and the program filter (both through
:func:`robocal.compensation.correct.correct_targets`, its notes with them); passed to the one entry point
:func:`robocal.compensation.correct.correct` it reaches every offline compensation; the safety policy counts it as
the calibration's own correction (:func:`robocal.compensation.correct.beyond_own`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

#: the per-target signals an effect may need besides the joints and the payload
SIGNALS = ("tau_Nm", "current_A", "direction")


#: the need of an effect driven by a logged signal (an extra column of the campaign) is ``signal:<column>``
LOGGED = "signal:"


@dataclass(frozen=True)
class Signals:
    """Per-target signals: ``payload_kg`` (m,); ``tau_Nm`` / ``current_A`` (m, n) as the controller reports
    them; ``direction`` (m, n) the approach direction (+-1) of each joint; ``logged`` the logged signals'
    values (column -> (m,)) an effect discovered on them needs (:mod:`robocal.discovery.logged`). None = not
    given."""

    payload_kg: np.ndarray
    tau_Nm: np.ndarray | None = None
    current_A: np.ndarray | None = None
    direction: np.ndarray | None = None
    logged: Mapping[str, np.ndarray] | None = None

    def rows(self, rows: np.ndarray) -> Signals:
        """The signals of the targets ``rows``."""
        return Signals(
            self.payload_kg[rows],
            None if self.tau_Nm is None else self.tau_Nm[rows],
            None if self.current_A is None else self.current_A[rows],
            None if self.direction is None else self.direction[rows],
            None if self.logged is None else {k: np.asarray(v)[rows] for k, v in self.logged.items()},
        )

    def given(self) -> set[str]:
        return {k for k in SIGNALS if getattr(self, k) is not None} | {LOGGED + k for k in (self.logged or {})}


class JointEffect(Protocol):
    """A joint-space effect: ``offsets(q (k, n), signals of those k targets) -> dq (k, n)`` rad."""

    @property
    def name(self) -> str: ...

    @property
    def needs(self) -> frozenset[str]: ...

    def offsets(self, q: np.ndarray, s: Signals) -> np.ndarray: ...


@dataclass(frozen=True)
class ComplianceEffect:
    """A compliance model (:class:`robocal.compliance.model.ComplianceModel`, or anything with its
    ``joint_offsets(q, payload_kg, current_A, tau_Nm)``): joint deflection under load."""

    model: Any
    name: str = "compliance"
    needs: frozenset[str] = frozenset()

    def offsets(self, q: np.ndarray, s: Signals) -> np.ndarray:
        return np.asarray(self.model.joint_offsets(q, s.payload_kg, s.current_A, s.tau_Nm), dtype=float)


def joint_effects(compliance: Any = None, *effects: JointEffect | None) -> list[JointEffect]:
    """The joint-space effects in the order they are summed: the compliance model (a model with
    ``joint_offsets``, wrapped in :class:`ComplianceEffect`), then ``effects`` (None entries skipped): the
    discovered joint-level effects (:class:`robocal.compensation.discovered.DiscoveredEffects`) and any new one.
    :meth:`robocal.serve.bundle.Bundle.joint_effects` is where a bundle's effects are listed."""
    out: list[JointEffect] = []
    if compliance is not None:
        out.append(ComplianceEffect(compliance))
    out.extend(e for e in effects if e is not None)
    return out


def needs(effects: Sequence[JointEffect]) -> set[str]:
    """The signals (of :data:`SIGNALS`) the effects need."""
    return set().union(*(set(e.needs) for e in effects)) if effects else set()


@dataclass(frozen=True)
class JointOffsets:
    """The sum of the effects at commanded joints, for the targets the Newton solver asks about:
    ``self(q (k, n), rows (k,)) -> dq (k, n)`` (the :data:`robocal.kinematics.ik.JointOffset` hook)."""

    effects: tuple[JointEffect, ...]
    signals: Signals

    def __call__(self, q: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        s = self.signals if rows is None else self.signals.rows(rows)
        dq = np.zeros_like(q)
        for e in self.effects:
            dq += e.offsets(q, s)
        return dq

    def notes(self, q: np.ndarray) -> list[list[str]]:
        """Per target, what the effects say about their own reach at the commanded joints ``q (m, n)``: an effect
        with a ``notes(q) -> list[list[str]]`` method (e.g. a residual layer outside its calibrated region) adds
        its notes; the others say nothing."""
        out: list[list[str]] = [[] for _ in range(len(q))]
        for e in self.effects:
            fn = getattr(e, "notes", None)
            if fn is not None:
                for k, ns in enumerate(fn(q)):
                    out[k].extend(ns)
        return out


def compose(effects: Sequence[JointEffect], signals: Signals) -> JointOffsets | None:
    """One :class:`JointOffsets` for ``effects`` with the targets' ``signals``; None without effects. A signal an
    effect needs and that is not given is an error naming the effects and the signals (ValueError)."""
    if not effects:
        return None
    missing = sorted(needs(effects) - signals.given())
    if missing:
        raise ValueError(f"the joint-space effects {[e.name for e in effects]} need {missing} with every target")
    return JointOffsets(tuple(effects), signals)


def signal_ranges(effects: Sequence[Mapping[str, Any]]) -> dict[str, list[float] | None]:
    """The logged signals ``effects`` (a calibration's) follow (a column of the campaign, given with each target),
    each with the values the effects were fitted on (``[lo, hi]``; None for a calibration written before they were
    recorded)."""
    out: dict[str, list[float] | None] = {}
    for e in effects:
        if e.get("signal") in ("logged", "logged_frame"):
            col = str(e["column"])
            rng = e.get("range")
            out[col] = out.get(col) or (None if rng is None else [float(rng[0]), float(rng[1])])
    return out


def signal_reasons(
    effects: Sequence[Mapping[str, Any]], logged: Mapping[str, np.ndarray] | None
) -> dict[int, list[str]]:
    """Per target (its index), one reason per logged signal whose value lies outside the values its effects were
    fitted on (by more than a tenth of their span): the effect is extrapolated there, the target corrected with
    the reason (flagged), never refused for it — a linear tilt extrapolates (newcomer pass 14: 16 of 30 targets
    0.1-0.5 mrad past a 1.6 mrad span were refused where compensation.csv corrected them right). The service and
    ``compensation.csv`` say it alike."""
    out: dict[int, list[str]] = {}
    for col, rng in signal_ranges(effects).items():
        if rng is None or logged is None or col not in logged:
            continue
        v = np.asarray(logged[col], dtype=float)
        slack = 0.1 * (rng[1] - rng[0])
        for k in np.flatnonzero((v < rng[0] - slack) | (v > rng[1] + slack)).tolist():
            out.setdefault(k, []).append(
                f"signals.{col} = {v[k]:.6g} outside the values its effects were fitted on [{rng[0]:.6g}, "
                f"{rng[1]:.6g}]: extrapolated"
            )
    return out
