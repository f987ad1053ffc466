"""The one safety policy: when a corrected target is answered ``ok``, ``flagged`` or ``refused``.

The same :class:`SafetyPolicy` (and the same defaults, stated here once) decides for the online service
(``serve.safety`` in conf/serve/default.yaml), the program filter (``robocal filter --config FILE
safety.KEY=VALUE``) and the thermal stage's controller CSV (``thermal.compensation``). Every target gets one
of :data:`STATUSES` with its reasons, in this order:

- the nominal inverse kinematics did not reach the target (service pose targets): refused;
- the Newton iteration did not converge (residual above ``max_residual_mm`` / ``max_residual_deg``, near a
  singularity): refused;
- the target or its corrected joints outside the joint limits (with ``joint_limit_margin_deg``):
  ``on_joint_limits``;
- the correction beyond the calibration's own joint-space correction above ``max_correction_deg``, or the
  error predicted after that correction above ``max_error_mm``: ``on_correction_bound``;
- temperatures outside the thermal model's fitted range by more than ``temperature_margin_C`` (a
  request-level reason): ``on_temperature_range``.

**What the correction bound bounds.** A calibration's joint zero offsets (and its thermal drift of them, the
compliance deflection and the discovered joint-level effects) move every target by the same joint angle
whatever the pose: a real ABB IRB 120 calibration has zero offsets of 1.3/2.0/1.2 deg, so its every
correction is about 2 deg, and a bound on the whole correction refuses every target of a good calibration
or, set to 5 deg as the thermal stage had to, lets a wrong solution near a singularity through. What goes
wrong near a singularity (or with a model that does not fit the pose) is the *rest*: the part of the
correction that the Newton iteration finds from Cartesian errors. So the bound is on
``|dq - dq_own|``, where ``dq_own = -(zero offsets) - (joint-space effects at the corrected joints)`` is the
calibration's own correction at that pose (exact for a model that has only joint offsets), and the error
bound on the error left after ``dq_own``; a target is refused only when both the whole correction (error)
and what is beyond the calibration's own exceed the bound, so the policy never refuses what a bound on the
whole correction accepted (and the service computes the second only for the targets above the bound).
With 0.5 deg / 5 mm a real calibration passes (IRB 120: 0.10-0.11 deg beyond its offsets) and a target that
needs degrees of extra correction is still refused.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robocal.config import parse, setting
from robocal.status import TargetStatus

#: per-target status, in every consumer (service reply, filter table, controller CSV): :class:`TargetStatus`
STATUSES = tuple(TargetStatus)
POLICIES = ("refuse", "flag")


@dataclass(frozen=True)
class SafetyPolicy:
    """Limits on what a correction answers (module doc); every consumer's defaults.

    max_correction_deg : largest joint correction beyond the calibration's own joint-space correction (deg).
    max_error_mm : largest predicted error left after the calibration's own joint-space correction (mm).
    joint_limit_margin_deg : margin inside the joint limits (deg). temperature_margin_C : tolerance around the
    thermal model's fitted temperature range (degC). max_residual_mm / max_residual_deg : Newton residual above
    which the target did not converge (always refused). on_* : ``refuse`` or ``flag``.
    """

    max_correction_deg: float = setting(0.5, ge=0)
    max_error_mm: float = setting(5.0, ge=0)
    joint_limit_margin_deg: float = setting(0.0, ge=0)
    temperature_margin_C: float = setting(0.0, ge=0)
    max_residual_mm: float = setting(0.001, ge=0)
    max_residual_deg: float = setting(1e-4, ge=0)
    on_correction_bound: str = setting("refuse", choices=POLICIES)
    on_joint_limits: str = setting("refuse", choices=POLICIES)
    on_temperature_range: str = setting("refuse", choices=POLICIES)

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None, where: str = "safety") -> SafetyPolicy:
        return parse(cls, cfg, where)

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    def _limits(self, q_limits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint range (n,) rad narrowed by the margin, cached per joint-limit table."""
        key = q_limits.tobytes()
        cache = self.__dict__.setdefault("_limits_cache", {})
        hit = cache.get(key)
        if hit is None:
            mg = np.deg2rad(self.joint_limit_margin_deg)
            hit = cache[key] = (q_limits[:, 0] + mg, q_limits[:, 1] - mg)
        return hit

    def judge(
        self,
        converged: np.ndarray,
        residual_mm: np.ndarray,
        residual_rad: np.ndarray,
        excess_deg: np.ndarray,
        rest_mm: np.ndarray,
        q_target: np.ndarray,
        q_corrected: np.ndarray,
        q_limits: np.ndarray,
        joint_names: Sequence[str],
        request_reasons: Sequence[str] = (),
        unreachable: np.ndarray | None = None,
    ) -> tuple[list[str], list[list[str]]]:
        """Status (one of :data:`STATUSES`) and reasons of every target (module doc for the order).

        converged (m,); residual_mm / residual_rad (m, 3) the predicted position / orientation (rotation vector)
        error after the correction, or their norms (m,) mm / deg; excess_deg / rest_mm (m,); q_target /
        q_corrected (m, n) rad; q_limits (n, 2) rad; request_reasons apply to every target (temperatures outside
        the fitted range: ``on_temperature_range``); unreachable (m,) True where the nominal inverse kinematics
        failed.
        """
        m = len(converged)
        if residual_mm.ndim == 1:
            res_mm, res_deg = residual_mm, residual_rad
        else:
            res_mm = np.sqrt((residual_mm * residual_mm).sum(axis=1))
            res_deg = np.rad2deg(np.sqrt((residual_rad * residual_rad).sum(axis=1)))
        lo, hi = self._limits(q_limits)
        out_j = (np.minimum(q_target, q_corrected) < lo) | (np.maximum(q_target, q_corrected) > hi)
        out_any = out_j.any(axis=1)
        too_big = (excess_deg > self.max_correction_deg) | (rest_mm > self.max_error_mm)
        # (a NaN anywhere fails these comparisons: not converged)
        bad_conv = ~(converged & (res_mm <= self.max_residual_mm) & (res_deg <= self.max_residual_deg))
        if unreachable is not None:
            bad_conv |= unreachable
        flag = bad_conv | out_any | too_big
        if not request_reasons and not flag.any():  # the usual case: every target ok
            return [TargetStatus.OK] * m, [[] for _ in range(m)]
        status: list[str] = [TargetStatus.OK] * m
        reasons: list[list[str]] = [[] for _ in range(m)]
        refuse_all = bool(request_reasons) and self.on_temperature_range == "refuse"
        # only the targets with a reason are looked at one by one
        for k in range(m) if request_reasons else np.flatnonzero(flag).tolist():
            r = list(request_reasons)
            refuse = refuse_all
            if unreachable is not None and unreachable[k]:
                r.append("the pose target is unreachable from q_seed_deg (nominal inverse kinematics did not converge)")
                refuse = True
            elif bad_conv[k]:
                r.append(f"compensation did not converge (residual {res_mm[k]:.4g} mm; near a singularity?)")
                refuse = True
            if out_any[k]:
                qt_deg, qc_deg = np.rad2deg(q_target[k]), np.rad2deg(q_corrected[k])
                r.append(
                    "outside the joint limits: "
                    + ", ".join(
                        f"{joint_names[j]}={qt_deg[j]:.4f} deg (corrected {qc_deg[j]:.4f})"
                        for j in np.flatnonzero(out_j[k]).tolist()
                    )
                )
                refuse |= self.on_joint_limits == "refuse"
            if too_big[k]:
                r.append(
                    f"correction {excess_deg[k]:.4g} deg / predicted error {rest_mm[k]:.4g} mm exceeds the bound "
                    f"({self.max_correction_deg} deg / {self.max_error_mm} mm), also beyond the calibration's own "
                    "joint offsets and effects"
                )
                refuse |= self.on_correction_bound == "refuse"
            status[k] = TargetStatus.REFUSED if refuse else (TargetStatus.FLAGGED if r else TargetStatus.OK)
            reasons[k] = r
        return status, reasons
