"""Forward selection of effects on what the current model cannot explain.

One step: at the joint fit of the current model (geometry + accepted effects) every remaining candidate's
regressor is projected onto the orthogonal complement of the model's column space (what the model cannot
absorb). A candidate the model absorbs completely is unidentifiable and is never chosen. The others get a nested
F-test on the projected regressor (Bonferroni family-wise threshold over the library), a BIC change, and the
share of the excess chi² they would remove; the best by log p that passes all three and improves a grouped
(whole-pose) cross-validation is accepted, the whole model is refitted jointly, and effects accepted earlier
that no longer pass a Wald test are dropped. The search stops when no candidate passes. The chi² against the
tracker noise is used only after the search, to flag an unexplained residual (gating the search on a global
chi² test loses power against a two-parameter signal).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from robocal.calibration.config import CalibrationConfig
from robocal.calibration.fit import calibrate
from robocal.calibration.screening import describe_outliers
from robocal.calibration.start import fit_data, present_stations, present_targets
from robocal.data.contract import Campaign
from robocal.discovery import progress
from robocal.discovery.axes import with_calibrate_order
from robocal.discovery.candidates import Candidate, SkippedCandidate, build_library
from robocal.discovery.choices import (
    counterbalance_choice,
    counterbalance_offered,
    first_search,
    without_counterbalance,
)
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.cv import fold_cv, pose_groups
from robocal.discovery.equations import propose
from robocal.discovery.ftest import backward_check, best_candidate
from robocal.discovery.gross import left_out, retest, screen_record, screen_sample, settle
from robocal.discovery.grow import (
    distinct_windows,
    finish,
    grow,
    held_out_check,
    orders_not_tried,
    paired_log10_p,
    physics_candidates,
    variant_candidate,
)
from robocal.discovery.logged import signal_gaps
from robocal.discovery.model import Accepted, ExtendedModel, Fit, fit_model
from robocal.discovery.physics import periodic_window
from robocal.discovery.refit import calibration_prior, refitter, release, start
from robocal.discovery.scoring import Step
from robocal.discovery.session_cv import Sessions
from robocal.discovery.state import DiscoveryState
from robocal.discovery.steps import step_candidate
from robocal.discovery.systematic import misfit_candidates
from robocal.errors import ConfigError
from robocal.identification.identifiability import ParameterSpec
from robocal.identification.model import FitData
from robocal.robot import RobotDescription


@dataclass
class DiscoveryResult:
    """Everything a discovery run found; :func:`robocal.discovery.summary.summary` turns it into JSON."""

    robot: RobotDescription
    config: DiscoveryConfig
    campaign: Campaign
    rows: np.ndarray  # campaign rows used for fitting (calibration)
    library: list[Candidate]
    skipped: list[SkippedCandidate]
    unidentifiable: dict[str, float]  # key -> absorbed share (first step it was found absorbed)
    geometric: Fit
    final: Fit
    accepted: list[Accepted]
    steps: list[Step]
    n_tests: int
    threshold_log10_p: float
    wall_time_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def chi2_p_value(self) -> float:
        return float(stats.chi2.sf(self.final.rss, self.final.dof))

    @property
    def unexplained(self) -> bool:
        return bool(self.chi2_p_value < self.config.chi2_alpha)


def _arm_rows(campaign: Campaign, robot: RobotDescription) -> tuple[Campaign, int]:
    """The campaign without the rows of a part on a positioner (they are calibrate's: the positioner's axes, issue
    34) and how many were left out; discovery models the arm on the other rows."""
    if robot.positioner is None:
        return campaign, 0
    from robocal.calibration.positioner import part_rows

    part = part_rows(campaign, robot)
    if not part.any():
        return campaign, 0
    progress.note(
        f"{int(part.sum())} rows measure the part on the positioner: left out (robocal calibrate fits the "
        "positioner's axes); discovery models the arm on the other rows"
    )
    return campaign.subset(~part), int(part.sum())


def discover(campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig | None = None) -> DiscoveryResult:
    """Run the discovery on the campaign's calibration rows (all rows when there is no validation split).

    Gross errors: the geometric calibration's outlier test (``cfg.outliers``) gives the first kept rows; the
    search runs on them; every calibration row is then tested again against the *extended* model (a row the
    geometric model could not explain may be explained now, and a blunder hidden by a large model error
    stands out once the effects are modelled), and the search is repeated from scratch on the new kept rows
    until the set is stable (at most three rounds). No effect is ever fitted to a flagged row. A campaign of more
    than ``cfg.outlier_screen_rows`` kept rows (issue 31) runs its first search on a pose-grouped sample of that
    many rows (:func:`robocal.discovery.gross.screen_sample`), only to find the gross errors; that search's
    effects refitted on the kept rows settle the set (:func:`robocal.discovery.gross.settle`: one joint fit per
    pass, a row left out stays out), and one search on every settled row follows; the rows its own test then
    flags among those it fitted are reported (``gross_error_screen``), not searched again (12 000 rows of
    the UR10 grid series: three searches on 8 300 rows before, one on 3 000 and one on 8 300 now).

    Noise: the search weights positions by the noise the data show (the calibration's ``fit.noise.used_mm``:
    the configured value or, when the campaign allows a model-free estimate, the larger of the two), and
    "unexplained" is judged against it.
    """
    from robocal.identification import misfit

    cfg = cfg or DiscoveryConfig()
    t0 = time.perf_counter()
    campaign, n_part = _arm_rows(campaign, robot)
    has_val = bool(np.any(campaign.split == "validation"))
    rows_all = np.flatnonzero(campaign.split == "calibration") if has_val else np.arange(campaign.n_rows)
    if len(rows_all) == 0:
        raise ConfigError(f"campaign {campaign.source} has no calibration rows")
    cal = campaign.subset(rows_all)
    targets = present_targets(cal)
    ccfg = CalibrationConfig(
        noise_mm=cfg.noise_mm,
        noise_deg=cfg.noise_deg,
        fixed=cfg.fixed,
        use_orientation=cfg.use_orientation,
        outliers=cfg.outliers,
        outlier_alpha=cfg.outlier_alpha,
    )
    geo = calibrate(cal, robot, ccfg)
    assert geo.start is not None  # a fit of calibrate, with its start
    # the campaign's orientations as calibrate used them (left out when they are not the robot's: its note)
    use_rot = bool(geo.fit["uses_orientation"])
    ccfg = replace(ccfg, use_orientation=use_rot)
    data_all = fit_data(cal, use_orientation=use_rot, targets=targets, stations=present_stations(cal))
    noise = geo.fit["noise"]
    sigma = float(noise["used_mm"])
    sigma_rad = float(np.deg2rad(cfg.noise_deg))
    library, skipped = build_library(campaign, robot, cfg)
    library, axis_fit = with_calibrate_order(library, campaign, robot, geo)  # a linear axis's: calibrate's order
    not_tried = orders_not_tried(cfg, len(np.unique(np.asarray(cal.pose_id).astype(str))))
    skipped += [not_tried] if not_tried is not None else []
    # a systematic misfit the geometric calibration named is offered to the search (issue 33 item 4)
    library += misfit_candidates(campaign, geo.fit.get("systematic_misfit") or [])
    m = cal.n_rows
    rounds_args = (ccfg, cal, rows_all, data_all, geo, library, skipped, sigma, sigma_rad)
    out = _rounds(campaign, robot, cfg, *rounds_args)
    if not out[-1] and counterbalance_offered(campaign, robot, cfg):
        # searched in full: the final models decide (robocal.discovery.choices.counterbalance_choice)
        progress.note("counterbalance: the search again without it on the shoulder's weight effect")
        off = _rounds(campaign, robot, without_counterbalance(cfg, out[0].extra), *rounds_args)
        same = np.array_equal(out[1], off[1])  # the same rows kept: a paired test pose by pose
        sse = [_pose_sse(campaign, cfg, rows_all[o[1]], o[0].final) for o in (off, out)] if same else None
        keep_with, cb_record = counterbalance_choice(out[0], off[0], sse)
        release((off if keep_with else out)[0].final)
        for key in ("transmission_window", "geometry_prior"):  # decided by the first, kept for the second
            if not keep_with and key in out[0].extra:
                off[0].extra.setdefault(key, out[0].extra[key])
        out = out if keep_with else off
        out[0].extra["counterbalance"] = cb_record
        out[0].config = cfg  # the settings as given (the record says which search was kept)
    res, kept, test, loud, systematic, rounds, n_search, sample = out
    assert res is not None
    # every calibration row's residual under the final model, for the outlier list
    fit = res.final
    r, _, _, _ = fit.model.residuals_and_jacobian(fit.theta, data_all, rows_all, cols=np.zeros(0, dtype=int))
    rr = r.reshape(m, fit.d)
    # the rows left out of the final fit, by kind (robocal.discovery.gross.left_out)
    kinds: tuple[list[dict[str, Any]], ...] = ([], [], [], [])
    if isinstance(cfg.outliers, tuple):
        listed = describe_outliers(cal, ~kept, rr[:, :3], rr[:, 3:] if fit.d == 6 else None, None, listed=True)
        kinds = (listed, [], [], [])
    elif test is not None:
        kinds = left_out(cal, kept, loud, test, systematic, rr, sample, rounds, signal_gaps(cal, fit))
    outliers, quiet, in_misfit_out, earlier = kinds
    if "signal" in cfg.effects:
        from robocal.discovery.logged import record

        logged = record(campaign, robot)
        if logged is not None:
            res.extra["logged_signals"] = logged
    res.extra.update(
        outliers=outliers,
        left_out_poorly_predicted=quiet,
        **({"left_out_systematic": in_misfit_out} if in_misfit_out else {}),
        **({"left_out_earlier": earlier} if earlier else {}),
        systematic_misfit=misfit.public(systematic),
        outlier_rule=(
            f"a calibration row is left out of the fit when its studentised residual against the final model stands "
            f"out (F test, Bonferroni over the {m} rows at family-wise alpha {ccfg.outlier_alpha:g}); it is a gross "
            "error when it also stands out from the rows' own scatter (robust scale: the median row sum of squares, "
            "the same rate), else it is listed under left_out_poorly_predicted"
            + (f"; {misfit.RULE}" if systematic else "")
        ),
        outlier_rounds=rounds,
        outlier_searches=n_search,
        **(
            {"gross_error_screen": screen_record(cfg, geo, cal, kept & test.flagged, n_search, sample)}
            if sample
            else {}
        ),
        noise=noise,
        sigma_mm=sigma,
        uses_orientation=use_rot,
        geometric_calibration=geo,
        calibrate_axis_fit=axis_fit,
        kept_rows=rows_all[kept],
        **({"positioner_part_rows_left_out": n_part} if n_part else {}),
    )
    res.wall_time_s = time.perf_counter() - t0
    return res


def _rounds(
    campaign: Campaign,
    robot: RobotDescription,
    cfg: DiscoveryConfig,
    ccfg: CalibrationConfig,
    cal: Campaign,
    rows_all: np.ndarray,
    data_all: FitData,
    geo: Any,
    library: list[Candidate],
    skipped: list[SkippedCandidate],
    sigma: float,
    sigma_rad: float,
) -> tuple[DiscoveryResult, np.ndarray, Any, np.ndarray, list[dict[str, Any]], int, int, int]:
    """The searches and the gross-error rounds of :func:`discover` (its docstring): the last search's result, the
    rows it ran on (``kept``, calibration-row mask), its row test, the rows standing out from the rows' own
    scatter, the systematic misfits, the rounds, the searches run and the screen's sample size (0: not
    screened)."""
    from robocal.identification import robust

    m = cal.n_rows
    kept = np.asarray(geo.start.kept, dtype=bool).copy()
    res: DiscoveryResult | None = None
    test = None
    rounds = 0
    systematic: list[dict[str, Any]] = []
    loud = np.ones(m, dtype=bool)
    n_search = sample = 0
    decided: DiscoveryConfig | None = None  # the settings the first search chose (grow_geometry, the window)
    records: dict[str, Any] = {}  # and how it chose them
    # a large campaign finds its gross errors first by a search on a pose-grouped sample: the rounds then cost one
    # full search, not up to three
    large = cfg.outliers == "auto" and 0 < cfg.outlier_screen_rows < int(kept.sum())
    for rounds in range(1, 4):
        idx = np.flatnonzero(kept)
        screen = large and rounds == 1
        if screen:
            idx = screen_sample(cal.pose_id, cal.q, idx, cfg.outlier_screen_rows, cfg.seed)
            sample = len(idx)
            progress.note(f"gross-error screen: the search on a pose-grouped sample of {len(idx)} of the "
                          f"{int(kept.sum())} kept rows, to find the gross errors")  # fmt: skip
        args = (rows_all[idx], data_all.rows(idx), geo, library, skipped, sigma, sigma_rad)
        if decided is None:
            # grow_geometry auto, several transmission windows: the searches on the first search's rows (a large
            # campaign's sample), the settings with the lower cross-validated error kept for the later rounds (a
            # few rows fewer) and the full search
            res, decided, records = first_search(campaign, robot, cfg, args, _windows, _pose_sse, screen)
            records = {k: {**v, "decided_on_rows": len(idx)} for k, v in records.items()}
        else:
            res = _search(campaign, robot, decided, *args)
        res.config = cfg
        res.extra.update(records)
        n_search += 1
        if cfg.outliers != "auto":
            break
        used = np.zeros(m, dtype=bool)
        used[idx] = True
        test, loud, systematic = retest(res.final, data_all, rows_all, cal, used, ccfg.outlier_alpha)
        if test.flagged.sum() > ccfg.outlier_max_share * m:
            if screen:  # the sample's model cannot tell: the search on every kept row judges (as without a screen)
                res = None
                continue
            # more rows stand out than gross errors can be: a model error the library cannot name, not blunders
            test = robust.RowTest(test.F, test.p_value, ~kept, test.threshold_F, test.alpha, test.d)
            break
        if screen:
            # the sample's effects refitted on the kept rows and every row tested again until no row the refit
            # used stands out: the full search runs on a settled set
            kept = settle(res.final, kept & ~test.flagged, robot, cfg, geo, data_all, rows_all, cal, sigma, sigma_rad,
                           ccfg.outlier_alpha, ccfg.outlier_max_share)  # fmt: skip
        elif large or np.array_equal(~test.flagged, kept) or rounds == 3:
            # the one full search of a large campaign (rows its own test flags among those it fitted are reported,
            # not searched again), converged, or the last round: `kept` stays the set the search ran on, so the
            # rows reported as left out of the fit are the ones it left out (the UR10 reported 18 of 1 046 out
            # while fitting 1 035)
            break
        else:
            kept = ~test.flagged
        res = None  # the round's fits (their Jacobians) let go before the next search
    assert res is not None
    return res, kept, test, loud, systematic, rounds, n_search, sample


def _windows(
    campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, args: tuple[Any, ...]
) -> tuple[DiscoveryResult, DiscoveryConfig, dict[str, Any]]:
    """The first search with each transmission window, and the settings it decides for the later ones: with
    several values of ``transmission_min_visits`` that give different windows on these rows, the search with each
    (the one with the lower pose-grouped cross-validated mean position error kept: ``extra["transmission_window"]``);
    within each, ``grow_geometry: auto`` (:func:`_either`). Returns the result, the settings decided and their
    records."""
    values = distinct_windows(campaign, robot, cfg, args[0])
    out: dict[int, DiscoveryResult] = {}
    cv: dict[str, float] = {}
    sse: dict[int, np.ndarray] = {}
    for mv in values:
        c = replace(cfg, transmission_min_visits=(mv,))
        if len(values) > 1:
            progress.note(f"transmission window: the search with intervals of at least {mv} distinct angle(s)")
        out[mv] = (
            _either(campaign, robot, c, args) if cfg.grow_geometry == "auto" else _search(campaign, robot, c, *args)
        )
        cv[str(mv)] = float(out[mv].extra["cv"].get("cv_mean_position_mm", float("nan")))
        if len(values) > 1 and cfg.cv_folds >= 2:
            sse[mv] = _pose_sse(campaign, cfg, args[0], out[mv].final)
    # another window than the first (every visit) must lower the held-out error significantly, as an effect must
    # (the paired test per pose group at cv_alpha; on the UR10's series D a 0.7 % lower first search ended 17 %
    # higher after its gross-error rounds): the lowest of those that do, else the first
    lp = {str(v): paired_log10_p(sse[values[0]], sse[v]) for v in values[1:] if v in sse}
    better = [v for v in values[1:] if cv[str(v)] < cv[str(values[0])] and lp.get(str(v), 0.0) < np.log10(cfg.cv_alpha)]
    chosen = min(better, key=lambda v: cv[str(v)]) if better else values[0]
    for mv in values:
        if mv != chosen:
            release(out.pop(mv).final)  # the other searches' fits let go (their Jacobians)
    res = out[chosen]
    decided = replace(cfg, transmission_min_visits=(chosen,))
    records: dict[str, Any] = {}
    if "grow_geometry" in res.extra:
        records["grow_geometry"] = res.extra["grow_geometry"]
        decided = replace(decided, grow_geometry=res.extra["grow_geometry"]["chosen"])
    if len(values) > 1:
        records["transmission_window"] = {
            "chosen_min_visits": chosen,
            "cv_mean_position_mm": cv,
            "lower_than_every_visit_log10_p": lp,
            "rule": "the gear transmission error is applied on the joint angles the calibration visited, in "
            "intervals of visits closer than the gap; an interval of fewer than min_visits distinct angles (one or "
            "two poses far from the others) is left out of the window. The search ran with each value of "
            "transmission_min_visits that gives other windows; one other than the first is kept when its "
            "pose-grouped cross-validated error is lower by the paired test per pose group at cv_alpha "
            "(lower_than_every_visit_log10_p), the lowest such; decided on the first search's rows "
            "(decided_on_rows) and kept for the later searches",
        }
    return res, decided, records


def _pose_sse(campaign: Campaign, cfg: DiscoveryConfig, rows: np.ndarray, fit: Fit) -> np.ndarray:
    """The fit's pose-grouped held-out sums of squares (per pose group, for a paired test); its Jacobian let go."""
    cal = campaign.subset(rows)
    f = fold_cv(fit, np.repeat(pose_groups(cal.pose_id, cal.q), fit.d), cfg.cv_folds, cfg.seed)
    out = f.group_sse(f.base_err)
    del f
    release(fit)
    return out


def _either(
    campaign: Campaign, robot: RobotDescription, cfg: DiscoveryConfig, args: tuple[Any, ...]
) -> DiscoveryResult:
    """``grow_geometry: auto``: the search with the geometry refitted jointly and with it frozen, the one with the
    lower pose-grouped cross-validated mean position error kept (``extra["grow_geometry"]``: both figures and the
    choice; joint without a cross-validation). Run on the first search's rows only (:func:`_rounds`)."""
    out: dict[str, DiscoveryResult] = {}
    cv: dict[str, float] = {}
    sse: dict[str, np.ndarray] = {}
    for mode in ("joint", "frozen"):
        progress.note(f"grow_geometry auto: the search with the geometry {mode}")
        out[mode] = _search(campaign, robot, replace(cfg, grow_geometry=mode), *args)
        cv[mode] = float(out[mode].extra["cv"].get("cv_mean_position_mm", float("nan")))
        if cfg.cv_folds >= 2:  # the held-out error per pose group, for the paired test
            sse[mode] = _pose_sse(campaign, cfg, args[0], out[mode].final)
    # the frozen geometry must lower the held-out error significantly, as an effect must (the paired test per pose
    # group at cv_alpha): a near tie keeps the joint refit (a NaN, no cross-validation, keeps it too)
    lp = paired_log10_p(sse["joint"], sse["frozen"]) if sse else 0.0
    chosen = "frozen" if cv["frozen"] < cv["joint"] and lp < np.log10(cfg.cv_alpha) else "joint"
    other = out.pop("frozen" if chosen == "joint" else "joint")
    release(other.final)  # the other search's fits let go (their Jacobians)
    res = out[chosen]
    res.config = cfg
    res.extra["grow_geometry"] = {
        "chosen": chosen,
        "cv_mean_position_mm": cv,
        "frozen_lower_log10_p": lp,
        "rule": "grow_geometry auto: the selection searched with the geometry refitted jointly and with it frozen "
        "at the model found before it; frozen is kept when its pose-grouped cross-validated error is lower by the "
        "paired test per pose group at cv_alpha (frozen_lower_log10_p), else joint; decided "
        "on the first search's rows (decided_on_rows: a large campaign's gross-error sample) and kept for the "
        "gross-error rounds and the full search",
    }
    return res


def _search(
    campaign: Campaign,
    robot: RobotDescription,
    cfg: DiscoveryConfig,
    rows: np.ndarray,
    data: FitData,
    geo: Any,
    library: list[Candidate],
    skipped: list[SkippedCandidate],
    sigma: float,
    sigma_rad: float,
) -> DiscoveryResult:
    """Forward selection on the campaign rows ``rows`` (their fit data ``data``), from the geometric fit ``geo``."""
    t0 = time.perf_counter()
    progress.note(f"the search on {len(rows)} rows (at most 3 searches: the gross-error rounds)")
    cal = campaign.subset(rows)
    targets = geo.model.target_names
    T_ref = geo.model.T_ref
    # the geometry's parameters as calibrate and plan see them (discovery.fixed resolved once, by the one value)
    fixed = set(ParameterSpec.of(geo.model, cfg.fixed, "discovery.fixed").fixed)

    base_prior = calibration_prior(geo, cfg)

    refit = refitter(robot, cfg, geo, data, rows, sigma, sigma_rad)
    geometric = refit([], None)
    # without link masses the compliance under the arm's own weight (robocal.discovery.physics, with its prior on
    # the deflection) is the library's compliance: tested here with it, so that a gear harmonic fitted over less
    # than its period (a smooth trend) cannot stand in for it first; the F-test takes its unpenalised directions
    weight = [variant_candidate(c, v[0]) for c, v in physics_candidates(campaign, robot, cfg, rows, ("weight",))]
    # the logged signals (robocal.discovery.logged) are a family of their own at the same alpha, so that a
    # campaign's extra columns cannot move the library's threshold: without a signal effect the search is the same
    n_signal = sum(1 for c in library if c.effect == "signal")
    n_tests = max(len(library) - n_signal + len(weight), 1)
    log_thr = float(np.log10(cfg.alpha / n_tests))
    log_thr_signal = float(np.log10(cfg.alpha / max(n_signal, 1)))
    unident: dict[str, float] = {}
    # several sessions (tracker stations): the selection is judged in a session left out too (issue 33)
    sessions = Sessions.of(
        data.station_index, geo.model.station_names, campaign.q[rows],
        periodic_window(cfg, max(cfg.transmission_orders))[0],
    ) if cfg.cv_folds >= 2 else None  # fmt: skip
    # grouped by pose and by configuration (a configuration measured again under another pose id is one group)
    groups = np.repeat(pose_groups(cal.pose_id, cal.q), geometric.d)
    groups.setflags(write=False)  # one array for the whole search (its sorted labels kept, cv.group_labels)
    state = DiscoveryState(campaign, robot, cfg, rows, data, groups, refit, geometric, sessions=sessions)
    _library(state, list(library) + weight, log_thr, log_thr_signal, unident)
    # no pause for a fresh registration: the tracker's step at the time a scan of the library's residuals finds,
    # offered once (its own family's test; not offered when its scan does not pass it)
    step = step_candidate(campaign, rows, state.fit, cfg.alpha) if _step_wanted(cfg, library) else None
    if step is not None:
        progress.note("library F-test search: a tracker step scanned for")
        _library(state, [step], log_thr, log_thr_signal, unident)
    from_library = {a.cand.key for a in state.accepted}
    # many small effects chosen together by cross-validation (physics first), then equations for what is left,
    # then the residual layer (robocal.discovery.grow)
    if cfg.grow_max_steps > 0:
        taken = {a.cand.key for a in state.accepted}
        leftovers = [c for c in library if c.key not in taken and c.key not in unident]
        grow_refit = refit
        if cfg.grow_geometry == "frozen":

            def grow_refit(accepted: list[Accepted], prev: Fit | None) -> Fit:
                """The selection's effects on top of the geometry found so far, held (the geometry stays the
                calibration's, so where a windowed effect is off the model is the geometric one)."""
                assert prev is not None
                model = ExtendedModel(robot, targets, T_ref, accepted, like=geo.model, base_prior=base_prior)
                theta0 = start(model, prev, geo)
                held = fixed | set(model.base.names)
                return fit_model(model, theta0, data, rows, sigma, held, cfg.rank_tol, cfg.max_iter,
                                 sigma_rad=sigma_rad)  # fmt: skip

            # and every refit after it (the equations, the held-out checks' drops, the layer): a frozen geometry
            # refitted jointly by the final check was the joint refit's model again (to 1e-11), unsaid
            state.refit = grow_refit
        grow(state, leftovers, grow_refit)
    if cfg.dictionary:
        progress.note("proposed equations (the dictionary)")
        propose(state)
    if cfg.cv_folds >= 2 and state.accepted:
        # what the parametric model keeps earns its place before the layer is offered (the layer's after it)
        progress.note("held-out check of the parametric model")
        held_out_check(state)
        dropped = {d["key"] for d in state.record.get("dropped_no_gain", [])}
        if dropped & from_library:
            # an effect the library took and the check dropped may have stood in for another the library's F-test
            # passed after it (a gear harmonic of joint 2 for the weight on joint 3 of a heavy arm measured in 18
            # configurations): the library once more without the dropped ones, its additions checked the same way
            taken = {a.cand.key for a in state.accepted}
            again = [c for c in list(library) + weight if c.key not in taken | dropped and c.key not in unident]
            n_before = len(state.accepted)
            progress.note("library F-test search again, without the effects the held-out check dropped")
            _library(state, again, log_thr, log_thr_signal, unident)
            if len(state.accepted) > n_before:
                held_out_check(state)
    # the parametric model is kept for its validation (its parameters), not its (M, k) Jacobian
    parametric = replace(state.fit, J_w=np.zeros((0, state.fit.k)), gram=None, factored=None)
    finish(state)
    if sessions is not None:
        # judged as the discovered model is: its tool re-measured in the session left out when the discovered one
        # holds a re-seated tool (newcomer pass 15: 0.0655 beside a geometric 0.2659 that kept the old tool, most of
        # the gap the tool's; the geometry with its tool re-measured there is 0.08-0.09)
        reseat = any(a.cand.effect == "session" for a in state.fit.model.accepted)
        state.record["geometric_session_cv"] = {
            **{k: v for k, v in sessions.summary(geometric, reseat=reseat).items() if k != "sse"},
            **({"tool_re_measured": True} if reseat else {}),
        }
    release(geometric)  # the last cross-validation's fold sums, and the geometric fit's Jacobian (evaluated if read)
    return DiscoveryResult(
        robot=robot,
        config=cfg,
        campaign=campaign,
        rows=rows,
        library=library if step is None else [*library, step],
        skipped=skipped,
        unidentifiable=unident,
        geometric=geometric,
        final=state.fit,
        accepted=state.accepted,
        steps=state.steps,
        n_tests=n_tests,
        threshold_log10_p=log_thr,
        wall_time_s=time.perf_counter() - t0,
        extra={
            "cv": state.record,
            "parametric": parametric,
            "signal_tests": n_signal,
            "signal_threshold_log10_p": log_thr_signal,
        },
    )


def _step_wanted(cfg: DiscoveryConfig, library: list[Candidate]) -> bool:
    """A tracker step is scanned for when ``regap`` is searched and the library holds no registration after a
    pause (:mod:`robocal.discovery.steps`)."""
    return "regap" in cfg.effects and not any(c.effect == "regap" for c in library)


def _library(
    state: DiscoveryState, remaining: list[Candidate], log_thr: float, log_thr_signal: float, unident: dict[str, float]
) -> None:
    """The library's F-test search (module docstring) from the state's fit, over the candidates ``remaining``, at the
    thresholds ``log_thr`` (the library) and ``log_thr_signal`` (the logged signals); ``unident`` gathers the
    candidates found absorbed. Each accepted effect advances the state's fit and effects (and a Wald check may drop
    earlier ones); a :class:`Step` per step, and one saying why it stopped."""
    cfg, refit = state.cfg, state.refit
    for step in range(cfg.max_steps):
        progress.note(f"library F-test search: step {step + 1} (at most {cfg.max_steps}), {len(remaining)} candidates")
        fit = state.fit
        scores, chosen = best_candidate(
            remaining, fit, state.rows, state.data, cfg, log_thr, state.groups, unident, log_thr_signal
        )
        if chosen is None:
            state.steps.append(
                Step(None, None, fit.rms_mm, fit.rms_mm, fit.rss, fit.rss, fit.dof, scores, phase="library")
            )
            break
        cand, params = chosen
        before = fit
        members = list(cand.extra["members"]) if cand.shape == "pair" else [cand]
        state.accepted.extend(Accepted(c, params if c is cand else ()) for c in members)
        gone = {c.key for c in members} | {cand.key}
        remaining = [c for c in remaining if c.key not in gone
                     and not (c.shape == "pair" and gone & {m.key for m in c.extra["members"]})]  # fmt: skip
        fit = refit(state.accepted, before)
        state.accepted, fit, dropped = backward_check(state.accepted, fit, log_thr, refit, log_thr_signal)
        state.fit = fit
        state.steps.append(
            Step(
                cand.key, cand.label, before.rms_mm, fit.rms_mm, before.rss, fit.rss, fit.dof, scores, dropped,
                before.residuals_mm, fit.residuals_mm, phase="library",
            )
        )  # fmt: skip
