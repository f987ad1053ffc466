"""Thermal fit -> screening -> validation: the computations of the thermal workflow (:mod:`robocal.workflows.thermal`
writes their files; the pipeline stages thermal_fit, screen and validate run them one step each).

The campaign's calibration rows hold one warm-up (the pose set measured cold and then at later temperature
states), its validation rows another warm-up from cold. Steps:

1. :func:`fit_thermal`: geometric calibration at the cold (reference) state; per-state drift of every
   identifiable chain parameter (eq. 19-21); per-parameter regression (eq. 5-8, CV); the traditional model
   (non-zero a and d by linear expansion only, ref. [29] of the paper).
2. screening (:mod:`robocal.thermal.screening`) of the drift -> the selected parameters.
3. :func:`fit_selected` (the proposed model on the selected parameters) and :func:`validate_thermal` (none /
   traditional / proposed / all, and the oracle with a truth file).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.load import load_calibration
from robocal.calibration.result import CalibrationResult
from robocal.config import parse, setting, sub_settings
from robocal.errors import ConfigError, DataError
from robocal.robot import RobotDescription
from robocal.thermal.identify import StateDrift, find_states, identify_states
from robocal.thermal.model import ThermalModel
from robocal.thermal.regression import ParameterChoice, RegressionConfig, fit_drift

if TYPE_CHECKING:
    from robocal.compensation.safety import SafetyPolicy
    from robocal.data.campaign import Campaign

PROPOSED_SOURCES = ("screen", "drifting", "all")


@dataclass(frozen=True)
class ThermalConfig:
    """Settings of the thermal workflow (``conf/thermal/default.yaml``).

    noise_mm / noise_deg : tracker noise (1 sigma per coordinate / axis) for the reference calibration and
    the weights of the drift identification. state_gap_s : a pause longer than this starts a new temperature
    state. rank_tol : identifiability tolerance of the stacked Jacobian. rcond : SVD cut-off (eq. 21).
    use_orientation : use measured orientations when present. regression : :class:`RegressionConfig` mapping.
    proposed : where the proposed parameter set comes from: ``screen`` (the sensitivity screening's selection;
    when no screening is available the parameters with a drift model, as ``drifting``), ``drifting``, ``all``,
    or a list of names. validation_at_min : the validation state the paper samples (90 min). closed_loop :
    close the compensation loop on the twin when a truth file is present. screening_file : the screening
    result the validation stage reads. reference_calibration : extra :class:`CalibrationConfig` settings.
    compensation : the one safety policy's settings (:class:`robocal.compensation.safety.SafetyPolicy`: when a
    compensated target of the controller CSV is refused or flagged), over its defaults.
    """

    noise_mm: float = setting(0.015, gt=0)
    noise_deg: float = setting(0.005, gt=0)
    state_gap_s: float = setting(600.0, gt=0)
    rank_tol: float = setting(1e-3, gt=0)
    rcond: float = 1e-10
    use_orientation: bool = True
    regression: Mapping[str, Any] = setting(default_factory=dict, check=sub_settings(RegressionConfig))
    proposed: str | Sequence[str] = setting("screen", choices=PROPOSED_SOURCES)
    validation_at_min: float = 90.0
    closed_loop: bool = True
    screening_file: str = "reports/screen/screening.json"
    reference_calibration: Mapping[str, Any] = field(default_factory=dict)
    compensation: Mapping[str, Any] = setting(default_factory=dict, check=lambda m: _check_limits(m))

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None) -> ThermalConfig:
        return parse(cls, cfg, "thermal")

    @property
    def limits(self) -> SafetyPolicy:
        from robocal.compensation.safety import SafetyPolicy

        return SafetyPolicy.from_mapping(self.compensation, "thermal.compensation")

    @property
    def regression_config(self) -> RegressionConfig:
        return RegressionConfig.from_mapping(self.regression)

    def calibration_config(self) -> CalibrationConfig:
        return CalibrationConfig.from_mapping(
            {"noise_mm": self.noise_mm, "noise_deg": self.noise_deg, **dict(self.reference_calibration)},
            "thermal.reference_calibration",
        )


def _check_limits(compensation: Mapping[str, Any]) -> None:
    """``thermal.compensation`` parsed as the safety policy (its errors name the key early)."""
    from robocal.compensation.safety import SafetyPolicy

    sub_settings(SafetyPolicy)(compensation)


@dataclass
class ThermalFit:
    """Outputs of :func:`fit_thermal` (and what :func:`load_fit` restores)."""

    robot: RobotDescription
    campaign: Campaign
    state: np.ndarray  # (m,) state per row of campaign.calibration()
    reference: CalibrationResult
    drift: StateDrift  # every identifiable parameter
    model_all: ThermalModel
    model_traditional: ThermalModel
    outcomes: dict[str, ParameterChoice]
    traditional_params: tuple[str, ...]
    cfg: ThermalConfig

    @property
    def cal(self) -> Campaign:
        return self.campaign.calibration()


def traditional_parameters(robot: RobotDescription, chain_names: Sequence[str]) -> tuple[str, ...]:
    """The non-zero link lengths a_i and offsets d_i (ref. [29]: only they are compensated)."""
    if not robot.is_mdh:
        return ()
    out = []
    for i in range(robot.n_joints):
        if robot.d_mm[i] != 0.0:
            out.append(f"d{i + 1}")
        if robot.a_mm[i] != 0.0:
            out.append(f"a{i + 1}")
    order = {n: k for k, n in enumerate(chain_names)}
    return tuple(sorted((n for n in out if n in order), key=order.__getitem__))


def _warm_up(campaign: Campaign, which: str) -> Campaign:
    part = campaign.calibration() if which == "calibration" else campaign.validation()
    if part.n_rows == 0:
        raise DataError(
            f"the campaign has no {which} rows: a thermal campaign needs a warm-up in its calibration rows and a "
            "second one in its validation rows (column 'split')",
            file=campaign.source,
            column="split",
        )
    return part


#: A warm-up: the pose set measured cold and at this many later temperature states at least.
MIN_LATER_STATES = 2

#: pose/target pairs a later temperature state must share with the first (besides half of them) to count as the pose
#: set measured again (the drift of even one parameter from 3-D differences needs two)
MIN_SHARED_PAIRS = 2


def states_problem(part: Campaign, state: np.ndarray, which: str) -> str | None:
    """Why rows ``part`` with these temperature states (:func:`robocal.thermal.identify.find_states`) are not a
    warm-up, or None when they are one: fewer than ``1 + MIN_LATER_STATES`` states, or fewer than
    ``MIN_LATER_STATES`` later states measuring again at least half of the first state's pose/target pairs (and
    :data:`MIN_SHARED_PAIRS`; a campaign measured over several days, split into states by its pauses, measures other
    poses each time: the UR10's series A, 11 911 rows, 0 pairs shared)."""
    n_states = int(state.max()) + 1 if len(state) else 0
    if n_states - 1 < MIN_LATER_STATES:
        return (
            f"the {which} rows hold {n_states} temperature state(s); a warm-up needs the pose set measured cold and "
            f"at >= {MIN_LATER_STATES} later states (states are separated by pauses > thermal.state_gap_s or by a "
            "pose measured again)"
        )
    key = np.asarray([f"{p}\x00{t}" for p, t in zip(part.pose_id, part.target, strict=True)])
    first = set(key[state == 0].tolist())
    shared = [len(first & set(key[state == s].tolist())) for s in range(1, n_states)]
    need = max(MIN_SHARED_PAIRS, (len(first) + 1) // 2)
    again = sum(1 for c in shared if c >= need)
    if again >= MIN_LATER_STATES:
        return None
    return (
        f"the {which} rows hold {n_states} temperature states, but {again} of the later ones measure again at "
        f"least half of the first state's {len(first)} pose/target pairs (most shared: {max(shared)}); a warm-up "
        f"measures one pose set cold and again at >= {MIN_LATER_STATES} later states"
    )


def warm_up_problem(campaign: Campaign, which: str, state_gap_s: float) -> str | None:
    """Why the campaign's ``which`` rows ("calibration" / "validation") hold no warm-up the thermal workflow can
    use (no rows, no temperatures, fewer than ``1 + MIN_LATER_STATES`` temperature states), or None when they
    hold one. A temperature log that is not a warm-up (an air-temperature log of an ordinary campaign) is common:
    the pipeline's thermal stages skip with this reason; :func:`fit_thermal` raises it."""
    part = campaign.calibration() if which == "calibration" else campaign.validation()
    if part.temperatures is None:
        return "the campaign has no temperature log (temperatures.csv)"
    if part.n_rows == 0:
        return f"the campaign has no {which} rows (column 'split')"
    return states_problem(part, find_states(part, state_gap_s), which)


def check_warm_up(part: Campaign, state: np.ndarray, which: str) -> None:
    if part.temperatures is None:
        raise DataError("the campaign has no temperatures (temperatures.csv)", file=part.source)
    problem = states_problem(part, state, which)
    if problem is not None:
        raise DataError(problem, file=part.poses_file, column="timestamp")


def fit_thermal(campaign: Campaign, robot: RobotDescription, cfg: ThermalConfig) -> ThermalFit:
    """Step 1: reference calibration, per-state drift of every identifiable parameter, regressions."""
    cal = _warm_up(campaign, "calibration")
    state = find_states(cal, cfg.state_gap_s)
    check_warm_up(cal, state, "calibration")
    ref = calibrate(cal.subset(state == 0), robot, cfg.calibration_config())
    drift = identify_states(
        cal, state, ref, rank_tol=cfg.rank_tol, rcond=cfg.rcond, use_orientation=cfg.use_orientation
    )
    chain = ref.model.chain
    rcfg = cfg.regression_config
    model_all, outcomes = fit_drift(drift, robot, chain, rcfg, info={"method": "all"})
    trad = traditional_parameters(robot, chain.param_names)
    model_trad = _traditional(cal, state, ref, robot, cfg, trad)
    return ThermalFit(robot, campaign, state, ref, drift, model_all, model_trad, outcomes, trad, cfg)


def _traditional(
    cal: Campaign,
    state: np.ndarray,
    ref: CalibrationResult,
    robot: RobotDescription,
    cfg: ThermalConfig,
    params: Sequence[str],
) -> ThermalModel:
    chain = ref.model.chain
    if not params:
        return fit_drift(_empty_drift(cal, state), robot, chain, cfg.regression_config, params=[], info={})[0]
    d = identify_states(
        cal, state, ref, params=params, rank_tol=cfg.rank_tol, rcond=cfg.rcond, use_orientation=cfg.use_orientation
    )
    model, _ = fit_drift(
        d,
        robot,
        chain,
        cfg.regression_config,
        expansion_only=True,
        allow_none=False,
        info={"method": "traditional", "parameters": list(params)},
    )
    return model


def _empty_drift(cal: Campaign, state: np.ndarray) -> StateDrift:
    from robocal.identification.identifiability import Identifiability

    S = int(state.max()) + 1
    assert cal.temperatures is not None
    temps = np.array([cal.temperatures[state == s].mean(axis=0) for s in range(S)])
    return StateDrift(
        (),
        np.zeros(0, int),
        np.zeros(S),
        temps,
        tuple(cal.sensor_names),
        np.zeros((S, 0)),
        np.zeros((0, 0)),
        1.0,
        np.zeros(S, int),
        np.zeros(S),
        np.zeros(S),
        Identifiability(np.zeros(0, int), (), 0, np.zeros(0)),
    )


def fit_selected(
    fit: ThermalFit, selected: Sequence[str]
) -> tuple[ThermalModel, StateDrift, dict[str, ParameterChoice]]:
    """The proposed model: drift identified on the ``selected`` parameters only, then their regressions."""
    cfg = fit.cfg
    chain = fit.reference.model.chain
    if not selected:
        d = _empty_drift(fit.cal, fit.state)
        return fit_drift(d, fit.robot, chain, cfg.regression_config, info={"method": "proposed"})[0], d, {}
    d = identify_states(
        fit.cal,
        fit.state,
        fit.reference,
        params=selected,
        rank_tol=cfg.rank_tol,
        rcond=cfg.rcond,
        use_orientation=cfg.use_orientation,
    )
    # a screened parameter is compensated with its best model even when a single warm-up cannot prove its drift
    model, outcomes = fit_drift(
        d,
        fit.robot,
        chain,
        cfg.regression_config,
        allow_none=False,
        info={"method": "proposed", "selected": list(selected)},
    )
    return model, d, outcomes


def default_selection(fit: ThermalFit) -> list[str]:
    """Without a screening: the parameters whose regression found a drift (``drifting``)."""
    return list(fit.model_all.names)


def run_screening(fit: ThermalFit, screen_cfg: Mapping[str, Any] | None, seed: int = 0) -> Any:
    """The sensitivity screening on the fit's per-state drift, or None when the screening module is absent."""
    try:
        from robocal.thermal import screening
    except ImportError:
        return None
    cfg = dict(screen_cfg or {})
    if cfg.get("tool_mm") is None:
        cfg["tool_mm"] = {k: v.tolist() for k, v in fit.reference.tools.items()}
    drift = {n: tuple(fit.drift.deta[:, k].tolist()) for k, n in enumerate(fit.drift.names)}
    stderr = {n: float(fit.drift.stderr[k]) for k, n in enumerate(fit.drift.names)}
    return screening.screen(fit.robot, cfg, seed=seed, drift=drift, drift_stderr=stderr)


def choose_selected(fit: ThermalFit, screening_result: Any) -> tuple[list[str], str]:
    """The proposed parameter set and where it came from."""
    p = fit.cfg.proposed
    if not isinstance(p, str):
        return list(p), "config list"
    if p == "all":
        return list(fit.drift.names), "all identifiable"
    if p == "screen" and screening_result is not None:
        return list(screening_result.selected), "sensitivity screening"
    return default_selection(fit), "parameters with a drift model (no screening available)"


def load_fit(out: str | Path, campaign: Campaign, robot: RobotDescription, cfg: ThermalConfig) -> ThermalFit:
    """Restore a :class:`ThermalFit` from :func:`robocal.workflows.thermal.write_fit`'s files (the per-state drift
    is re-identified: it takes milliseconds and needs the campaign anyway)."""
    out = Path(out)
    try:
        ref = load_calibration(json.loads((out / "reference_calibration.json").read_text()), robot)
    except FileNotFoundError:
        raise ConfigError(f"missing {out / 'reference_calibration.json'} (run the thermal fit first)") from None
    cal = _warm_up(campaign, "calibration")
    state = find_states(cal, cfg.state_gap_s)
    check_warm_up(cal, state, "calibration")
    drift = identify_states(
        cal, state, ref, rank_tol=cfg.rank_tol, rcond=cfg.rcond, use_orientation=cfg.use_orientation
    )
    m_all = ThermalModel.from_json(out / "thermal_model_all.json")
    m_trad = ThermalModel.from_json(out / "thermal_model_traditional.json")
    trad = traditional_parameters(robot, ref.model.chain.param_names)
    return ThermalFit(robot, campaign, state, ref, drift, m_all, m_trad, {}, trad, cfg)


def validate_thermal(fit: ThermalFit, proposed: ThermalModel, truth: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Step 3: the validation warm-up compensated four ways (plus the oracle with a truth file)."""
    from robocal.thermal.validate import evaluate

    val = _warm_up(fit.campaign, "validation")
    vstate = find_states(val, fit.cfg.state_gap_s)
    if val.temperatures is None:
        raise DataError("the validation rows have no temperatures", file=val.source)
    models = {"none": None, "traditional": fit.model_traditional, "proposed": proposed, "all": fit.model_all}
    t = truth if (truth is not None and fit.cfg.closed_loop) else None
    ev = evaluate(fit.reference, val, vstate, models, truth=t, at_min=fit.cfg.validation_at_min, limits=fit.cfg.limits)
    if truth is not None and not fit.cfg.closed_loop:
        ev.pop("closed_loop", None)
    ev["state"] = vstate
    return ev


__all__ = [
    "ThermalConfig",
    "ThermalFit",
    "check_warm_up",
    "choose_selected",
    "fit_selected",
    "fit_thermal",
    "load_fit",
    "run_screening",
    "traditional_parameters",
    "validate_thermal",
    "warm_up_problem",
]
