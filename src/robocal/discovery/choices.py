"""What the first search of a discovery decides for the later ones, by its cross-validation
(:func:`robocal.discovery.search.discover`): besides the transmission error's window and ``grow_geometry``
(:mod:`robocal.discovery.search`), whether a thin campaign keeps robocal calibrate's prior toward the nominal
geometry under the effects (``geometry_prior``), and whether the shoulder's weight effect carries a
counterbalance (``counterbalance``). Each choice runs the first search both ways on the same rows and keeps one
by the pose-grouped cross-validated error; the later searches (the gross-error rounds, a large campaign's full
search) run with the settings chosen, recorded in ``discovery.json`` under the setting's name."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from robocal.data.contract import Campaign
from robocal.discovery import progress
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.cv import paired_log10_p
from robocal.discovery.refit import calibration_prior, release
from robocal.robot import RobotDescription

#: the level of the paired test that lets calibrate's prior go (one two-way choice, not a family of candidates as
#: cv_alpha controls): newcomer pass 12's heavy arm from two stations had CV 0.232 mm with the prior, 0.142 without
#: (p = 0.012), held out 0.174 with it and 0.093 without; the thin twin's tie (p = 0.56) keeps it
PRIOR_ALPHA = 0.05

#: one first search: ``(result, the settings it decided, their records)``
Searched = tuple[Any, DiscoveryConfig, dict[str, Any]]
Windows = Callable[[Campaign, RobotDescription, DiscoveryConfig, tuple[Any, ...]], Searched]
PoseSSE = Callable[[Campaign, DiscoveryConfig, np.ndarray, Any], np.ndarray]


#: what discovery.json's ``counterbalance`` says of its rule
COUNTERBALANCE_RULE = (
    "the shoulder's weight effect (the first revolute joint the arm's weight loads) carries the harmonics of its "
    "own angle a counterbalance's torque adds (a heavy robot's spring or hydro-pneumatic cylinder); the search "
    "ran with them offered and without them (the second with the first's transmission window and geometry prior), "
    "and the final model with the lower pose-grouped cross-validated mean error is kept; with_lower_log10_p: the "
    "paired test per pose group of that difference, said, not required (null: the two searches kept other rows). "
    "A large campaign (its first search on the gross-error screen's sample) is searched without them (their "
    "choice would cost a search of the sample both ways; counterbalance: on offers them)"
)


def first_search(
    campaign: Campaign,
    robot: RobotDescription,
    cfg: DiscoveryConfig,
    args: tuple[Any, ...],
    windows: Windows,
    pose_sse: PoseSSE,
    screened: bool,
) -> Searched:
    """The first search (``windows``: :func:`robocal.discovery.search._windows`, on ``args``' rows) and the
    settings it decides (:func:`_geometry_prior`). A ``screened`` campaign (its first search on the gross-error
    screen's sample: a large one) is searched without the counterbalance's columns under ``counterbalance:
    auto`` (their choice costs a search of the sample both ways, ~30 s at UR10 A's 12 000 rows; ``on`` offers
    them); a campaign searched in full decides it on its final models (:func:`robocal.discovery.search.discover`)."""
    skip = screened and counterbalance_offered(campaign, robot, cfg)
    if skip:
        cfg = replace(cfg, counterbalance="off")
    res, decided, records = _geometry_prior(campaign, robot, cfg, args, windows, pose_sse)
    if skip:
        records["counterbalance"] = {"chosen": "without", "rule": COUNTERBALANCE_RULE}
    return res, decided, records


def counterbalance_choice(with_: Any, without: Any, sse: list[np.ndarray] | None = None) -> tuple[bool, dict[str, Any]]:
    """Whether the search with the shoulder's counterbalance columns is kept against the one without them (each a
    :class:`~robocal.discovery.search.DiscoveryResult`), and the record: the lower pose-grouped cross-validated
    mean error (a tie, or no cross-validation, leaves them out). Measured on the final models: UR10 series B (no
    counterbalance) 0.0855 mm CV with them, 0.0900 without (held out 0.0965 and 0.1025), series D 0.112 and
    0.1013 (held out 0.128 and 0.109); newcomer pass 11's counterbalanced arm 0.159 and 0.229 (0.123, 0.208). On
    series D the first searches said the other way (0.1035 with, 0.1159 without): the final models decide where
    the search runs in full."""
    cv = {"with": _cv(with_), "without": _cv(without)}
    lp = paired_log10_p(*sse) if sse is not None else None  # None: other rows kept, no pose-by-pose pairing
    keep = bool(cv["with"] < cv["without"])
    return keep, {"chosen": "with" if keep else "without", "cv_mean_position_mm": cv, "with_lower_log10_p": lp,
                  "rule": COUNTERBALANCE_RULE}  # fmt: skip


def without_counterbalance(cfg: DiscoveryConfig, extra: dict[str, Any]) -> DiscoveryConfig:
    """The settings of the search without the counterbalance's columns: the transmission window and the geometry
    prior the search with them decided (``extra``: its records), not decided again (one search less)."""
    out = replace(cfg, counterbalance="off")
    if "transmission_window" in extra:
        out = replace(out, transmission_min_visits=(int(extra["transmission_window"]["chosen_min_visits"]),))
    if "geometry_prior" in extra:
        out = replace(out, geometry_prior=str(extra["geometry_prior"]["chosen"]))
    return out


def _cv(res: Any) -> float:
    return float(res.extra["cv"].get("cv_mean_position_mm", float("nan")))


def counterbalance_offered(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig) -> bool:
    """Whether ``counterbalance: auto`` has the search offer the shoulder's weight effect with a counterbalance's
    columns (the weight model is offered: no logged torques or currents; a revolute joint), so that the search
    runs both ways: also where the effect with them was not taken (a twin whose shoulder took the compliance
    from its described masses with them offered, the weight without them: 0.0312 -> 0.0281 mm held out)."""
    if cfg.counterbalance != "auto" or "weight" not in cfg.effects:
        return False
    if campaign.tau_Nm is not None or campaign.current_A is not None:
        return False
    return not all(robot.prismatic)


def _geometry_prior(
    campaign: Campaign,
    robot: RobotDescription,
    cfg: DiscoveryConfig,
    args: tuple[Any, ...],
    windows: Windows,
    pose_sse: PoseSSE,
) -> Searched:
    """With ``geometry_prior: auto`` and a thin campaign's prior toward the nominal geometry (robocal calibrate's,
    its strength chosen by the cross-validation of the geometry alone), the searches with the prior and without
    it: the prior is let go when the discovered model's pose-grouped cross-validated error is lower without it by
    the paired test at :data:`PRIOR_ALPHA` (``extra["geometry_prior"]``). A heavy arm in 18 configurations: the
    prior chosen for a geometry that misfit its weight deflection (CV 0.37 mm) pulled the geometry under the weight
    effects toward nominal, 0.163 mm held out where the same effects without it gave 0.081 (CV 0.155 against
    0.093)."""
    if cfg.geometry_prior != "auto" or calibration_prior(args[2]) is None:
        return windows(campaign, robot, cfg, args)
    out: dict[str, Searched] = {}
    cv: dict[str, float] = {}
    sse: dict[str, np.ndarray] = {}
    for mode in ("calibration", "none"):
        progress.note(f"geometry prior: the search {'with' if mode == 'calibration' else 'without'} the prior")
        out[mode] = windows(campaign, robot, replace(cfg, geometry_prior=mode), args)
        cv[mode] = _cv(out[mode][0])
        if cfg.cv_folds >= 2:
            sse[mode] = pose_sse(campaign, cfg, args[0], out[mode][0].final)
    # calibrate kept the prior where it clearly beat none: it is let go where none clearly beats it under the
    # effects (the paired test per pose group at PRIOR_ALPHA); a near tie keeps it (a thin twin: 0.0516 against
    # 0.0530 mm CV, p = 0.56, held out 0.0483 without it where it gives 0.0285)
    lp = paired_log10_p(sse["calibration"], sse["none"]) if sse else 0.0
    chosen = "none" if cv["none"] < cv["calibration"] and lp < np.log10(PRIOR_ALPHA) else "calibration"
    release(out.pop("none" if chosen == "calibration" else "calibration")[0].final)
    res, decided, records = out[chosen]
    records["geometry_prior"] = {
        "chosen": chosen,
        "cv_mean_position_mm": cv,
        "none_lower_log10_p": lp,
        "rule": "a thin campaign's prior toward the nominal geometry (robocal calibrate's, chosen by the "
        "cross-validation of the geometry alone): the search ran with it and without it, and the prior is let go "
        "when the discovered model's pose-grouped cross-validated error is lower without it by the paired test per "
        "pose group at 5 % (none_lower_log10_p), else kept; decided on the first search's rows and kept for "
        "the later searches",
    }
    return res, replace(decided, geometry_prior=chosen), records


__all__ = [
    "COUNTERBALANCE_RULE",
    "counterbalance_choice",
    "counterbalance_offered",
    "first_search",
    "without_counterbalance",
]
