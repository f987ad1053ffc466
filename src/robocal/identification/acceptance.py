"""Is a calibration acceptable? One rule, for the geometric workflow (``summary.json`` status) and the fleet
(``accepted``: registered and served).

:func:`judge` reads a calibration's fit record (``calibration.json`` ``fit``) and, when there are validation rows,
the calibrated and the nominal model's validation figures (:class:`robocal.calibration.validation.Validation`
or its record), and returns a :class:`Verdict`: the *problems* (the calibration must not be used) and the
*warnings* (usable, with care), each a sentence, in this order:

0. the campaign has too few joint configurations to determine the model (``fit.configurations``, written by
   :mod:`robocal.identification.thin`): always a problem; a thin campaign (fewer configurations than give
   ``thin_ratio`` equations per parameter, or one identified with a prior): ``thin`` (a warning by default),
   saying how many configurations there were, how many the model needs and what was done;
1. the fit did not converge (stopped on its iteration limit, or not finite): ``not_converged``;
2. more rows stood out than gross errors can be, or rows misfit together under one condition (a systematic
   misfit): the model misses an effect: ``suspects``;
3. the fit's RMS 3-D error is worse than ``max_rms_ratio`` x its start: always a problem. The baseline is
   the fit's own "before" (``fit.before``: the nominal kinematics with frames and tools fitted to convergence)
   **on the same kept rows** as the fit's RMS: rows left out as gross errors count in neither;
4. on the validation rows, the calibrated model's mean error is worse than the nominal model's: a problem;
5. on the validation rows, the mean error is above ``max_validation_mean_mm`` (when set): a problem;
6. on the validation rows, the largest error is worse than the nominal model's while the mean improved: a
   warning.

``not_converged`` and ``suspects`` are ``problem``, ``warning`` or ``ignore``: the workflow reports a fit that
stopped early as a warning and leaves suspects to the fit record (which says to run discovery); the fleet serves
nothing of either (:data:`FLEET`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from robocal.config import parse, setting

__all__ = ["FLEET", "AcceptanceRules", "Verdict", "judge", "thin_campaign", "thin_is_warned", "too_few_configurations"]

LEVELS = ("problem", "warning", "ignore")


@dataclass(frozen=True)
class AcceptanceRules:
    """When a calibration is acceptable (module doc).

    max_rms_ratio : the fit's RMS may be at most this times its start's (same rows). max_validation_mean_mm : a
    limit on the validation mean error (mm), None for none. not_converged, suspects, thin : ``problem``,
    ``warning`` or ``ignore``.
    """

    max_rms_ratio: float = setting(1.0, gt=0)
    max_validation_mean_mm: float | None = setting(None, gt=0)
    not_converged: str = setting("warning", choices=LEVELS)
    suspects: str = setting("ignore", choices=LEVELS)
    thin: str = setting("warning", choices=LEVELS)

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None, where: str = "acceptance") -> AcceptanceRules:
        return parse(cls, cfg, where)


#: the fleet's rules (conf/fleet/default.yaml ``acceptance`` sets the two limits): it serves neither a fit that
#: did not converge nor one whose rows say the model misses an effect
FLEET = {"not_converged": "problem", "suspects": "problem"}


@dataclass(frozen=True)
class Verdict:
    """The problems (must not be used) and warnings (usable with care) of a calibration, in rule order."""

    problems: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    @property
    def acceptable(self) -> bool:
        return not self.problems


def _iterations(n: Any) -> str:
    return f"{n} iteration" + ("" if n == 1 else "s")


def too_few_configurations(design: Mapping[str, Any]) -> str:
    """The problem of a campaign with too few configurations (its ``fit.configurations`` record)."""
    return (
        f"too few configurations to determine the model: {design['n']} distinct joint configuration(s) "
        f"({design['n_rows']} rows) give {design['equations']} equations ({design['equations_rule']}) for the "
        f"model's {design['model_parameters']} parameters; at least {design['needed']} configurations are needed "
        f"(more equations than parameters), {design['thin_below']} to determine it well: measure more poses"
    )


def thin_is_warned(design: Mapping[str, Any]) -> bool:
    """Whether a campaign's ``fit.configurations`` record is a warning: thin, or identified with a prior (a sparse
    campaign whose prior the cross-validation declined is recorded, not warned about)."""
    return bool(design.get("thin")) or float((design.get("prior") or {}).get("strength") or 0.0) > 0


def thin_campaign(design: Mapping[str, Any]) -> str:
    """The warning of a thin campaign, or one identified with a prior: the configurations, what the model needs
    and what was done (its ``fit.configurations`` record)."""
    text = (
        f"{design['n']} configurations ({design['equations']} equations: at most 6 a configuration, one flange "
        f"pose, however many targets) for the model's {design['model_parameters']} parameters: it needs at least "
        f"{design['needed']} configurations, {design['thin_below']} to be determined well"
    )
    prior = design.get("prior")
    if not isinstance(prior, Mapping):
        return f"thin campaign: {text}"
    se = f" ± {prior['cv_mean_position_se_mm']:g}" if "cv_mean_position_se_mm" in prior else ""
    cv = (
        f"CV estimate of the held-out mean error {prior['cv_mean_position_mm']:g}{se} mm"
        if "cv_mean_position_mm" in prior
        else ""
    )
    if float(prior.get("strength") or 0.0) > 0:
        done = (
            f"identified with a prior toward the nominal description (strength {prior['strength']:g}, "
            f"{prior['strength_rule']}; {cv}, {prior['cv_mean_position_mm_without_prior']:g} mm without the prior)"
        )
    else:
        done = f"identified without a prior ({prior['strength_rule']}{'; ' + cv if cv else ''})"
    head = "thin campaign" if design.get("thin") else f"{prior['why']}"
    return f"{head}: {text}; {done}"


def judge(
    fit: Mapping[str, Any],
    validation: Mapping[str, Any] | None = None,
    validation_before: Mapping[str, Any] | None = None,
    rules: AcceptanceRules | None = None,
) -> Verdict:
    """The :class:`Verdict` of a calibration by its fit record and validation figures (module doc)."""
    r = rules or AcceptanceRules()
    found: list[tuple[str, str]] = []  # (level, text) in rule order
    design = fit.get("configurations")
    if isinstance(design, Mapping):
        if not design.get("enough", True):
            found.append(("problem", too_few_configurations(design)))
        elif thin_is_warned(design):
            found.append((r.thin, thin_campaign(design)))
    if fit.get("orientation_left_out"):  # the campaign's orientations are not the robot's: positions only
        found.append(("warning", str(fit["orientation_left_out"])))
    if fit.get("success") is False:
        found.append(
            (
                r.not_converged,
                f"the fit did not converge: {fit.get('message', 'no message')} ({_iterations(fit.get('nit'))}); the "
                "result may be far from the least-squares minimum (raise max_iter, or check the data: joint units, "
                "robot, targets)",
            )
        )
    if fit.get("outlier_suspects"):
        found.append((r.suspects, "too many rows stand out: the model misses an effect (run robocal discover)"))
    for f in fit.get("systematic_misfit") or []:  # the same model error, with the condition it lives under
        found.append(
            (
                r.suspects,
                f"{f['n_rows']} rows with {f['condition']} misfit together by {f['size_mm']:.3f} mm: the model misses "
                "an effect there (run robocal discover)",
            )
        )
    after, before = fit.get("rms_position_mm"), (fit.get("before") or {}).get("rms_position_mm")
    if after is not None and before is not None and not float(after) <= r.max_rms_ratio * float(before):
        times = "" if r.max_rms_ratio == 1.0 else f"{r.max_rms_ratio:g} x "
        found.append(
            (
                "problem",
                f"the fit's RMS error {float(after):.4f} mm is worse than {times}its start ({float(before):.4f} mm)",
            )
        )
    vmean = None if not validation else validation.get("mean_position_mm")
    bmean = None if not validation_before else validation_before.get("mean_position_mm")
    # worse by more than round-off (a model re-read from its own calibrated URDF starts where it ends)
    if vmean is not None and bmean is not None and vmean > bmean * (1 + 1e-6) + 1e-9:
        found.append(
            (
                "problem",
                f"on the validation poses the calibrated model ({vmean:.4f} mm mean error) is worse than the nominal "
                f"one ({bmean:.4f} mm)",
            )
        )
    vmax = r.max_validation_mean_mm
    if vmax is not None and vmean is not None and float(vmean) > vmax:
        found.append(("problem", f"validation mean error {float(vmean):.4f} mm above the limit {vmax:g} mm"))
    if validation and validation_before and vmean is not None and bmean is not None and vmean <= bmean:
        worst, worst_before = validation.get("max_position_mm", 0.0), validation_before.get("max_position_mm")
        if worst_before is not None and worst > worst_before:
            found.append(
                (
                    "warning",
                    f"on the validation poses the largest error of the calibrated model ({worst:.4f} mm) is worse "
                    f"than the nominal one's ({worst_before:.4f} mm), although the mean improved",
                )
            )
    return Verdict(
        tuple(t for level, t in found if level == "problem"), tuple(t for level, t in found if level == "warning")
    )
