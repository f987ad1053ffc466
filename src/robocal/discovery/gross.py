"""The gross-error rounds of discovery (:func:`robocal.discovery.search.discover`): every calibration row tested
against an extended model (:func:`retest`), the pose-grouped sample a large campaign's first search runs on
(:func:`screen_sample`), and the kept rows settled by refits without a search (:func:`settle`, issue 31)."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

from robocal.data.contract import Campaign
from robocal.discovery import progress
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.cv import group_labels, pose_groups
from robocal.discovery.model import Fit
from robocal.discovery.refit import refitter
from robocal.identification.model import FitData
from robocal.robot import RobotDescription


def retest(
    fit: Fit, data_all: FitData, rows_all: np.ndarray, cal: Campaign, kept: np.ndarray, alpha: float
) -> tuple[Any, np.ndarray, list[dict[str, Any]]]:
    """Every calibration row tested against the extended model ``fit``: the row test, then the flagged rows that
    share a condition taken off as a systematic misfit. Returns the test (``flagged``: the rows left out of the
    fit), the rows that stand out from the rows' own scatter (a flagged row is a gross error only when it does)
    and the systematic misfits."""
    from robocal.identification import misfit, robust

    m = cal.n_rows
    fit.release()  # the search's Jacobian is not held through this one (every calibration row)
    progress.note(f"gross-error test: every one of the {m} calibration rows against the discovered model")
    # the free columns only, whitened in place (no (M, n) matrix, no copy), a chunk of rows at a time (each row's
    # residuals and Jacobian are its own: the same numbers as the whole campaign's; issue 31)
    w = np.tile(fit.weights[: fit.d], m)
    row_of = np.repeat(np.arange(m), fit.d)

    def rows_jacobian(a: int, b: int) -> np.ndarray:
        idx = np.arange(a, b)
        _, J, _, _ = fit.model.residuals_and_jacobian(fit.theta, data_all.rows(idx), rows_all[idx], cols=fit.free)
        J *= w[a * fit.d : b * fit.d, None]
        return J

    r, _, _, _ = fit.model.residuals_and_jacobian(fit.theta, data_all, rows_all, cols=np.zeros(0, dtype=int))
    # the leverages of the fit with its prior (the effects a prior determines, the residual layer's: without it the
    # kept rows' JᵀJ is singular and the test's verdict is round-off: on the UR10's 3 000 rows a change of 1e-15 in
    # the Jacobian changed 61 of its 2 094 verdicts)
    prec = fit.model.prior_precision()[fit.free]
    test = robust.row_test(r * w, rows_jacobian, row_of, m, kept, alpha, prior=prec if np.any(prec > 0) else None,
                           n_params=len(fit.free))  # fmt: skip
    # a row is a gross error only when it also stands out from the rows' own scatter (robust scale: the median
    # row sum of squares, the same Bonferroni rate): a row that only the extended model's leverage singles out
    # (a 0.04 mm row among 0.1 mm ones, issue 30 item 9) is not a blunder. Such rows are still left out of the
    # fit (on the UR10 keeping them costs 0.025 mm held-out: they pull the flexible effects), reported apart
    loud = robust.robust_screen(r * w, row_of, m, alpha, len(fit.free))
    systematic: list[dict[str, Any]] = []
    if test.flagged.sum() >= misfit.MIN_ROWS:
        # rows that misfit together under one condition are a systematic misfit of the model: kept, named
        rp = r.reshape(m, fit.d)[:, :3]
        e2 = np.sum(rp**2, axis=1)
        scale = float(np.sqrt(np.median(e2[kept]) / stats.chi2.ppf(0.5, 3)))
        systematic, explained = misfit.find(cal, test.flagged, rp, scale, alpha)
        test = robust.RowTest(test.F, test.p_value, test.flagged & ~explained, test.threshold_F, test.alpha, test.d)
    return test, loud, systematic


def screen_sample(pose_id: np.ndarray, q: np.ndarray, idx: np.ndarray, n_max: int, seed: int) -> np.ndarray:
    """Of the rows ``idx`` (positions in the calibration rows), whole cross-validation groups (poses joined with
    the configurations measured again, :func:`robocal.discovery.cv.pose_groups`) drawn at random (``seed``) until
    the next would pass ``n_max`` rows; sorted."""
    groups = pose_groups(np.asarray(pose_id)[idx], q[idx])
    uniq, g, counts = group_labels(groups)
    order = np.random.default_rng(seed).permutation(len(uniq))
    take = np.zeros(len(uniq), dtype=bool)
    take[order[np.cumsum(counts[order]) <= n_max]] = True
    return np.asarray(idx[take[g]])


def screen_record(
    cfg: DiscoveryConfig, geo: Any, cal: Campaign, fitted_flagged: np.ndarray, searches: int, sample: int
) -> dict[str, Any]:
    """``discovery.json``'s ``gross_error_screen`` of a screened campaign: the kept rows, the sample's size, the
    searches run and the file rows the final search fitted that its own row test flags (``fitted_flagged``)."""
    return {
        "kept_rows": int(np.count_nonzero(geo.start.kept)),
        "sample_rows": int(sample),
        "searches": int(searches),
        "flagged_by_final_model": [int(v) for v in np.asarray(cal.row_number)[fitted_flagged]],
        "rule": f"more than outlier_screen_rows = {cfg.outlier_screen_rows} kept rows: the first search ran on a "
        "pose-grouped sample of at most that many rows, only to find the gross errors; its effects refitted on "
        "every kept row settled the set (a row left out stays out); one search on every kept row followed. "
        "flagged_by_final_model: file rows that search fitted and its own row test flags (not searched again)",
    }


def settle(
    final: Fit,
    kept: np.ndarray,
    robot: RobotDescription,
    cfg: DiscoveryConfig,
    geo: Any,
    data_all: FitData,
    rows_all: np.ndarray,
    cal: Campaign,
    sigma: float,
    sigma_rad: float,
    alpha: float,
    max_share: float,
    passes: int = 6,
) -> np.ndarray:
    """The kept rows after a search's row test (``kept``), settled: the search's effects (its ``final`` fit)
    refitted on them (one joint fit, no search) and every calibration row tested again, until no row the refit
    used stands out (a row left out stays out, so the rounds cannot cycle; at most ``passes`` fits). A test that
    flags more rows than gross errors can be stops it at the last set."""
    accepted = list(final.model.accepted)
    prev: Fit | None = final
    for i in range(passes):
        idx = np.flatnonzero(kept)
        progress.note(f"gross-error screen: the sample's {len(accepted)} effects refitted on the {len(idx)} kept rows "
                      f"(pass {i + 1}, at most {passes})")  # fmt: skip
        refit = refitter(robot, cfg, geo, data_all.rows(idx), rows_all[idx], sigma, sigma_rad)
        fit = refit(accepted, prev)
        test, _, _ = retest(fit, data_all, rows_all, cal, kept, alpha)
        if test.flagged.sum() > max_share * len(kept):
            break
        if not np.any(kept & test.flagged):  # no row the refit used stands out
            break
        kept, prev = kept & ~test.flagged, fit  # a row left out stays out (the rounds cannot cycle)
    return kept


__all__ = ["retest", "screen_record", "screen_sample", "settle"]


def left_out(
    cal: Campaign,
    kept: np.ndarray,
    loud: np.ndarray,
    test: Any,
    systematic: list[dict[str, Any]],
    rr: np.ndarray,
    sample: int,
    rounds: int,
    filled: dict[str, np.ndarray] | None = None,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]]]:
    """The calibration rows left out of the final fit (``~kept``), by what the final model's row ``test`` says of
    them (``rr``: every row's residuals against it): gross errors (flagged and standing out from the rows' own
    scatter, ``loud``), poorly predicted (flagged, not loud), of a systematic misfit the final test names, and left
    out earlier (by the gross-error screen of a large campaign, ``sample`` > 0, or rounds that did not settle) that
    the final model does not single out. Each row with its reason. ``filled``: per logged column an effect of the
    final model follows, the rows whose reading was empty and filled (:func:`filled_rows`): a flagged row among
    them is poorly predicted, not a gross error (newcomer pass 9: rows whose inclinometer cells were empty, filled
    from the joint angles to 0.45 mrad, ~1.4 mm at the tool, were listed as gross errors)."""
    from robocal.calibration.screening import describe_outliers

    out = ~np.asarray(kept, dtype=bool)
    pos, rot = rr[:, :3], (rr[:, 3:] if rr.shape[1] == 6 else None)
    in_misfit = np.zeros(len(out), dtype=bool)
    for f in systematic:
        in_misfit |= np.asarray(f["_mask"], dtype=bool)
    by = "the gross-error screen" if sample else f"an earlier round (the gross-error rounds did not settle in {rounds})"
    fill, cols = filled_rows(cal, filled or {})
    gross = describe_outliers(cal, out & loud & test.flagged & ~in_misfit & ~fill, pos, rot, test)
    quiet = describe_outliers(cal, out & ~loud & test.flagged & ~in_misfit & ~fill, pos, rot, test)
    for o in quiet:
        o["reason"] = (
            "left out of the fit, not a gross error: " + o["reason"] + ", but its error does not stand out from "
            "the rows' own scatter (robust scale)"
        )
    guessed = out & test.flagged & ~in_misfit & fill
    for o, i in zip(describe_outliers(cal, guessed, pos, rot, test), np.flatnonzero(guessed), strict=True):
        o["reason"] = (
            f"left out of the fit, not a gross error: {o['reason']}, but its {', '.join(cols[int(i)])} reading was "
            "empty and filled: the misfit may be the fill's"
        )
        quiet.append(o)
    misfit_rows = []
    for f in systematic:
        for o in describe_outliers(cal, np.asarray(f["_mask"], dtype=bool) & out, pos, rot, test):
            o["reason"] = (
                f"left out of the fit by {by}, not a gross error: the final model's test puts it in the systematic "
                f"misfit of the rows with {f['condition']}"
            )
            misfit_rows.append(o)
    stale = out & ~test.flagged & ~in_misfit
    earlier = describe_outliers(cal, stale, pos, rot, test)
    for o, i in zip(earlier, np.flatnonzero(stale), strict=True):
        o["reason"] = (
            f"left out of the fit by {by}, not a gross error: against the final model it does not stand out (p = "
            f"{test.p_value[i]:.3g}, F = {test.F[i]:.4g})"
        )
    return gross, quiet, misfit_rows, earlier


def filled_rows(cal: Campaign, filled: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[int, list[str]]]:
    """The calibration rows (``cal``'s) with a filled reading among ``filled`` (per column, a mask over ``cal``'s
    rows), and the columns each one had filled."""
    mask = np.zeros(cal.n_rows, dtype=bool)
    cols: dict[int, list[str]] = {}
    for name, m in filled.items():
        for i in np.flatnonzero(m):
            cols.setdefault(int(i), []).append(name)
        mask |= m
    return mask, cols
