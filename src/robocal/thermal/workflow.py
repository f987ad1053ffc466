"""Thermal workflow: thermal fit -> screening -> validation, shared by the pipeline stages and ``robocal thermal``.

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

from robocal.config import parse, setting, sub_settings
from robocal.errors import ConfigError, DataError
from robocal.identification.calibrate import CalibrationConfig, CalibrationResult, calibrate, load_calibration
from robocal.io import write_json
from robocal.robot import RobotDescription
from robocal.thermal.identify import StateDrift, find_states, identify_states
from robocal.thermal.model import ParameterModel, ThermalModel
from robocal.thermal.regression import ParameterChoice, RegressionConfig, fit_drift

if TYPE_CHECKING:
    from robocal.data.contract import Campaign
    from robocal.thermal.compensate import CompensationLimits, ThermalCompensation

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
    compensation : :class:`robocal.thermal.compensate.CompensationLimits` mapping (when a compensated target is
    refused or flagged: correction bound, convergence tolerance, temperature range margin).
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
    def limits(self) -> CompensationLimits:
        from robocal.thermal.compensate import CompensationLimits

        return CompensationLimits.from_mapping(self.compensation)

    @property
    def regression_config(self) -> RegressionConfig:
        return RegressionConfig.from_mapping(self.regression)

    def calibration_config(self) -> CalibrationConfig:
        return CalibrationConfig.from_mapping(
            {"noise_mm": self.noise_mm, "noise_deg": self.noise_deg, **dict(self.reference_calibration)},
            "thermal.reference_calibration",
        )


def _check_limits(compensation: Mapping[str, Any]) -> None:
    """``thermal.compensation`` parsed as :class:`CompensationLimits` (its errors name the key early)."""
    from robocal.thermal.compensate import CompensationLimits

    sub_settings(CompensationLimits)(compensation)


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


def check_warm_up(part: Campaign, state: np.ndarray, which: str) -> None:
    if part.temperatures is None:
        raise DataError("the campaign has no temperatures (temperatures.csv)", file=part.source)
    if int(state.max()) < 2:
        raise DataError(
            f"the {which} rows hold {int(state.max()) + 1} temperature state(s); a warm-up needs the pose set measured "
            f"cold and at >= 2 later states (states are separated by pauses > thermal.state_gap_s)",
            file=part.poses_file,
            column="timestamp",
        )


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


def write_fit(fit: ThermalFit, out: str | Path) -> dict[str, Any]:
    """Files of the thermal fit: reference_calibration.json, states.json (the screening's drift file),
    thermal_model_all.json, thermal_model_traditional.json, regression.json, summary.json. Returns the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "reference_calibration.json", fit.reference.to_dict())
    write_json(out / "states.json", fit.drift.to_dict())
    write_json(out / "thermal_model_all.json", fit.model_all.to_dict())
    write_json(out / "thermal_model_traditional.json", fit.model_traditional.to_dict())
    write_json(
        out / "regression.json",
        {
            n: {"chosen": o.chosen.label(), "p_value_vs_no_drift": o.p_value, "candidates": o.table[:10]}
            for n, o in fit.outcomes.items()
        },
    )
    summary = fit_summary(fit)
    write_json(out / "summary.json", summary)
    return summary


def fit_summary(fit: ThermalFit) -> dict[str, Any]:
    d = fit.drift
    return {
        "robot": fit.robot.name,
        "n_states": int(d.deta.shape[0]),
        "state_t_min": d.t_min.tolist(),
        "n_identified": len(d.names),
        "identified": list(d.names),
        "eliminated": [e.describe() for e in d.identifiability.eliminated],
        "sigma_scale": d.sigma_scale,
        "reference_fit": {
            k: fit.reference.fit.get(k) for k in ("rms_position_mm", "max_position_mm", "rms_orientation_deg", "n_rows")
        },
        "drift_rms_mm": d.drift_rms_mm.tolist(),
        "residual_rms_mm": d.residual_rms_mm.tolist(),
        "drifting": list(fit.model_all.names),
        "traditional_parameters": list(fit.traditional_params),
        "equations": fit.model_all.equations(),
        "equations_with_stderr": fit.model_all.equations(stderr=True),
        "equations_absolute": fit.model_all.equations(absolute=True),
        "equations_traditional": fit.model_traditional.equations(),
    }


def load_fit(out: str | Path, campaign: Campaign, robot: RobotDescription, cfg: ThermalConfig) -> ThermalFit:
    """Restore a :class:`ThermalFit` from :func:`write_fit`'s files (the per-state drift is re-identified:
    it takes milliseconds and needs the campaign anyway)."""
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


def thermal_json(
    fit: ThermalFit,
    proposed: ThermalModel,
    selected: Sequence[str],
    source: str,
    ev: Mapping[str, Any],
    screening_result: Any = None,
) -> dict[str, Any]:
    """The ``thermal.json`` summary of ``robocal thermal``."""
    keep = ("mean_position_mm", "max_position_mm", "mean_orientation_deg", "max_orientation_deg")

    def rows(tab: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
        return {m: {k: v for k, v in s.items() if k in keep} for m, s in tab.items()}

    out: dict[str, Any] = {
        "robot": fit.robot.name,
        "selected": list(selected),
        "selected_from": source,
        "model": {p.name: model_entry(p, proposed) for p in proposed.parameters},
        "equations": proposed.equations(),
        "equations_with_stderr": proposed.equations(stderr=True),
        "equations_absolute": proposed.equations(absolute=True),
        "T_ref_C": dict(zip(proposed.sensors, proposed.T_ref_C.tolist(), strict=True)),
        "validation": rows(ev["table"]),
        "validation_at_state": {"t_min": ev["at_state_min"], **rows(ev["at_state"])},
        "thermal_fit": fit_summary(fit),
    }
    if "closed_loop" in ev:
        out["closed_loop"] = rows(ev["closed_loop"])
        out["closed_loop_refused"] = {
            m: {k: v for k, v in s.items() if k.startswith("n_")} for m, s in ev["closed_loop"].items()
        }
    if "compensation" in ev:
        out["compensation"] = ev["compensation"]
    if "extrapolation" in ev:
        out["extrapolation"] = ev["extrapolation"]
    out["warnings"] = [
        w for w in (ev.get("extrapolation", {}).get("warning"), ev.get("compensation", {}).get("warning")) if w
    ]
    if screening_result is not None:
        out["screening"] = screening_result.to_dict()
    return out


def model_entry(p: ParameterModel, model: ThermalModel) -> dict[str, Any]:
    """One parameter of ``thermal.json``'s ``model``: form, sensors and order with how cross-validation chose
    them, coefficients with standard errors, and the equation (eq. 28 form)."""
    ref = dict(zip(model.sensors, model.T_ref_C.tolist(), strict=True))
    st = dict(p.stats)
    entry: dict[str, Any] = {
        "form": p.form,
        "unit": "mm" if p.kind == "length" else "rad",
        "sensors": list(p.sensors),
        "order": p.order,
        "terms": [list(e) for e in p.terms],
        "coefficients": [float(c) for c in p.coefficients],
        "stderr": [float(c) for c in p.stderr],
        "coefficient_unit": f"{'mm' if p.kind == 'length' else 'rad'} per degC^order",
        "lambda_per_C": p.lambda_per_C,
        "equation": p.equation(ref),
        "equation_with_stderr": p.equation(ref, stderr=True),
        "equation_absolute": p.equation_absolute(ref),
        "cross_validation": {
            "method": "leave-one-state-out; the smallest model within cv_tolerance of the best CV error, kept only "
            "when it beats 'no drift' (chi-square test)",
            "candidate_sensors": st.get("candidate_sensors"),
            "n_candidates": st.get("n_candidates"),
            "cv_rmse": st.get("cv_rmse"),
            "cv_best_rmse": st.get("cv_best_rmse"),
            "cv_tolerance": st.get("cv_tolerance"),
            "no_drift_cv_rmse": st.get("no_drift_cv_rmse"),
            "p_value_vs_no_drift": st.get("p_value_vs_no_drift"),
            "alternatives": st.get("cv_alternatives"),
        },
        "fit": {k: st.get(k) for k in ("n_states", "rmse", "chi2", "dof", "reduced_chi2", "state_stderr")},
    }
    return entry


def read_truth(data_dir: str | Path) -> dict[str, Any] | None:
    """``truth.json`` beside the data (twin campaigns), else None."""
    p = Path(data_dir) / "truth.json"
    if not p.is_file():
        return None
    data = json.loads(p.read_text(encoding="utf-8"))
    return data if isinstance(data, dict) and "kinematic_errors" in data else None


def write_validation(
    fit: ThermalFit,
    out: str | Path,
    selected: Sequence[str],
    source: str,
    truth: Mapping[str, Any] | None = None,
    screening_result: Any = None,
) -> tuple[dict[str, Any], ThermalModel, dict[str, Any]]:
    """Fit the proposed model, validate, write ``thermal.json``, ``thermal_model.json`` (the proposed model),
    ``validation.csv`` (per-row errors by method) and ``compensation.csv`` (the controller CSV of the validation
    poses at the state nearest ``validation_at_min``). Returns ``(thermal.json dict, proposed model, evaluation)``."""
    import pandas as pd

    from robocal.io import atomic_write
    from robocal.thermal.compensate import (
        compensate_targets,
        extrapolation_summary,
        range_excess,
        write_controller_csv,
    )
    from robocal.thermal.validate import reorder

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    proposed, _, _ = fit_selected(fit, selected)
    ev = validate_thermal(fit, proposed, truth)
    val = fit.campaign.validation()
    vstate = ev["state"]
    assert val.temperatures is not None
    T_val = reorder(val.temperatures, val.sensor_names, proposed.sensors)
    limits = fit.cfg.limits
    ev["extrapolation"] = extrapolation_summary(proposed, T_val, vstate, ev["t_min"], limits.range_margin_C)
    k = int(np.argmin(np.abs(np.asarray(ev["t_min"]) - fit.cfg.validation_at_min)))
    sel = vstate == k
    comp = compensate_targets(
        fit.reference,
        proposed,
        T_val[sel].mean(axis=0),
        val.q[sel],
        val.target[sel],
        ids=[f"{p}/{t}" for p, t in zip(val.pose_id[sel], val.target[sel], strict=True)],
        orientation=bool(ev["has_orientation"]),
        limits=limits,
        q_limits=np.asarray(fit.robot.q_limits, dtype=float),
    )
    ev["compensation"] = compensation_summary(comp, float(ev["t_min"][k]))
    summary = thermal_json(fit, proposed, selected, source, ev, screening_result)
    write_json(out / "thermal_model.json", proposed.to_dict())
    write_json(out / "thermal.json", summary)
    frame = pd.DataFrame(
        {"pose_id": val.pose_id, "target": val.target, "state": vstate, "t_min": np.asarray(ev["t_min"])[vstate]}
    )
    for m, e in ev["errors"].items():
        frame[f"{m}_position_mm"] = e
        if ev["errors_deg"][m] is not None:
            frame[f"{m}_orientation_deg"] = ev["errors_deg"][m]
    frame["proposed_extrapolation_C"] = range_excess(proposed, T_val).max(axis=1) if len(T_val) else 0.0
    atomic_write(out / "validation.csv", lambda p: frame.to_csv(p, index=False, float_format="%.6f"))
    write_controller_csv(out / "compensation.csv", comp)
    return summary, proposed, ev


#: A joint correction above this (deg) is flagged in the report: a thermal drift of a fraction of a millimetre needs
#: a joint move this large only near a singularity (wrist q5 ~ 0, stretched or folded arm), where the correction is
#: unreliable. Flagged, not refused: the refusal bound is ``thermal.compensation.max_correction_deg``.
LARGE_CORRECTION_DEG = 0.5


def compensation_summary(comp: ThermalCompensation, t_min: float) -> dict[str, Any]:
    """The ``compensation`` entry of ``thermal.json``: what ``compensation.csv`` holds and how many targets were
    refused or flagged, with the reasons."""
    from robocal.thermal.compensate import CSV_COLUMNS

    counts = comp.counts()
    flagged = [
        {"target_id": str(i), "status": str(s), "reason": str(r)}
        for i, s, r in zip(comp.ids, comp.status, comp.reason, strict=True)
        if s != "ok"
    ]
    warning = ""
    if flagged:
        warning = (
            f"{len(flagged)} of {len(comp.ids)} targets of compensation.csv are not ok ("
            + ", ".join(f"{k}: {v}" for k, v in counts.items() if v and k != "ok")
            + "); see the status and reason columns"
        )
    large = [
        {"target_id": str(i), "correction_max_deg": float(c), "status": str(st)}
        for i, c, st in zip(comp.ids, comp.correction_max_deg, comp.status, strict=True)
        if c > LARGE_CORRECTION_DEG
    ]
    return {
        "file": "compensation.csv",
        "t_min": t_min,
        "large_correction_deg": LARGE_CORRECTION_DEG,
        "large_corrections": sorted(large, key=lambda r: -r["correction_max_deg"]),
        "n_targets": len(comp.ids),
        "n_applied": int(np.sum(comp.applied)),
        "status_counts": counts,
        "extrapolation_C": comp.extrapolation_C,
        "max_correction_deg": float(np.max(comp.correction_max_deg)) if len(comp.ids) else 0.0,
        "limits": comp.limits.to_dict(),
        "flagged": flagged,
        "warning": warning,
        "columns": dict(CSV_COLUMNS),
    }


def run_all(
    data_dir: str | Path,
    robot: str | Path | RobotDescription,
    out_dir: str | Path,
    overrides: Mapping[str, Any] | None = None,
    screen_cfg: Mapping[str, Any] | None = None,
    report: bool = True,
    split: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """``robocal thermal``: thermal fit -> screening -> validation on the campaign in ``data_dir``."""
    from robocal.data.contract import read_campaign
    from robocal.robot import load_robot

    rob = robot if isinstance(robot, RobotDescription) else load_robot(robot)
    cfg = ThermalConfig.from_mapping(overrides)
    camp = read_campaign(data_dir, rob, split=split)
    if not camp.has_temperatures:
        raise DataError("no temperature log: the campaign has no temperatures.csv", file=data_dir)
    out = Path(out_dir)
    fit = fit_thermal(camp, rob, cfg)
    write_fit(fit, out)
    scr = run_screening(fit, screen_cfg) if cfg.proposed == "screen" else None
    if scr is not None:
        write_json(out / "screening.json", scr.to_dict())
    selected, source = choose_selected(fit, scr)
    truth = read_truth(data_dir)
    summary, proposed, ev = write_validation(fit, out, selected, source, truth, scr)
    if report:
        from robocal.report.html import Report
        from robocal.thermal.report import fit_report, validation_report

        rep = Report(f"Thermal compensation: {rob.name}", subtitle=f"campaign {data_dir}")
        fit_report(fit, rep, truth)
        if scr is not None:
            from robocal.thermal import screening

            screening.add_to_report(scr, rep)
        validation_report(rep, proposed, selected, source, ev, fit)
        rep.save(out / "report.html")
    return summary


__all__ = [
    "ThermalConfig",
    "ThermalFit",
    "check_warm_up",
    "choose_selected",
    "compensation_summary",
    "fit_selected",
    "fit_thermal",
    "load_fit",
    "model_entry",
    "read_truth",
    "run_all",
    "run_screening",
    "thermal_json",
    "traditional_parameters",
    "validate_thermal",
    "write_fit",
    "write_validation",
]
