"""Many small effects, chosen together: forward selection by pose-grouped cross-validation.

Real robots carry many small effects rather than one dominant one, so after the library's F-test search (and the
dictionary) every remaining candidate — the library's leftovers, the gear transmission error of each joint as a
long Fourier series and the compliance under the arm's own weight without link masses
(:mod:`robocal.discovery.physics`) — is offered to a selection that adds, one per step, the candidate that
lowers the pose-grouped cross-validated error most, fitted jointly with the geometry and everything accepted so
far (a ridge where the candidate has a prior). A candidate is accepted only when its cross-validated gain is
significant: a one-sided paired t-test over the held-out poses of the per-pose squared-error differences, at
``cv_alpha`` divided by the number of candidates and variants tried in that step (Bonferroni), so that on data
with nothing left to find the selection stops at once (the false-discovery control; ``benchmarks/`` checks it
on null twins). The logged signals' candidates (:mod:`robocal.discovery.logged`) are a family of their own at the
same ``cv_alpha``, as in the F-test search.

Cross-validation is linearised at the current joint fit (like :func:`robocal.discovery.ftest.
cross_validation_gain`): each fold refits every free parameter of the current model and the candidate on the
other poses (normal equations with the priors, the candidate's block by its Schur complement) and predicts the
held-out residuals. Variants of one candidate (Fourier orders, prior widths) are tried on the same folds and
the best is the candidate's score.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from robocal.data.contract import Campaign
from robocal.discovery import engine, progress
from robocal.discovery.candidates import Candidate, SkippedCandidate
from robocal.discovery.config import DiscoveryConfig
from robocal.discovery.cv import fold_cv, paired_log10_p, pose_paired_log10_p
from robocal.discovery.gram import RowsOf
from robocal.discovery.model import Accepted, Fit
from robocal.discovery.scoring import Score, Step, Variant, regressor
from robocal.discovery.served import served_conflict
from robocal.discovery.session_cv import session_own
from robocal.discovery.state import DiscoveryState, Refit
from robocal.discovery.weight import weight_candidates
from robocal.metrics import ErrorStats
from robocal.robot import RobotDescription

_DEG = float(np.rad2deg(1.0))


def physics_candidates(
    campaign: Campaign,
    robot: RobotDescription,
    cfg: DiscoveryConfig,
    rows: np.ndarray,
    effects: tuple[str, ...] = ("transmission", "weight"),
) -> list[tuple[Candidate, list[Variant]]]:
    """The transmission-error candidate of every moving joint (Fourier orders x prior widths as variants) and,
    without logged torques or currents, the compliance under the arm's own weight of every joint with a
    gravity torque (of those two, the ``effects`` the settings also name). Signals for every campaign row;
    coverage and bases from the fitted ``rows``."""
    from robocal.compensation.signals import coverage_weight, fourier_signal
    from robocal.discovery.physics import (
        configurations,
        lowest_harmonic,
        periodic_window,
        visited_intervals,
        visited_span_deg,
    )

    out: list[tuple[Candidate, list[Variant]]] = []
    q = campaign.q
    n = robot.n_joints
    n_poses = len(np.unique(np.asarray(campaign.pose_id)[rows].astype(str)))
    if "transmission" in cfg.effects and "transmission" in effects:
        orders = resolved_orders(cfg, n_poses)
        kmax = max(orders) if orders else 0
        q_conf = configurations(q[rows])  # the visits a window counts: one per configuration
        for j in range(n):  # a reducer's error of its angle: not a linear axis's (mm)
            if kmax == 0 or robot.prismatic[j] or float(np.ptp(q[rows, j])) < np.deg2rad(1.0):
                continue
            gap, taper = periodic_window(cfg, kmax)
            # the search's one window (discovery.search._first_search runs one search per value that differs)
            mv = min(cfg.transmission_min_visits)
            visited = visited_intervals(q_conf[:, j], gap, mv)
            h0 = lowest_harmonic(visited_span_deg(visited)) if visited else kmax + 1
            if h0 > kmax:
                continue
            w = coverage_weight(q[:, j], visited, taper)
            h = np.arange(h0, kmax + 1)
            S = fourier_signal(q[:, j], h, w)
            centre = S[rows].mean(axis=0)  # the constant part belongs to the geometry's joint offset
            S = S - centre
            names = tuple(f"sin{k}" for k in h) + tuple(f"cos{k}" for k in h)
            cand = Candidate(
                f"transmission:j{j + 1}", "transmission", j + 1, None,
                cause=f"gear transmission error of the joint-{j + 1} reducer: a periodic error of the joint's own "
                "angle with many harmonics per revolution (applied only on the angles the calibration visited)",
                signal=f"sin/cos(h·q{j + 1}), h = {h0}..K", shape="joint", S=S,
                coef_names=names, coef_units=("rad",) * len(names),
                extra={"visited_deg": visited, "taper_deg": taper, "gap_deg": gap, "harmonics": h.tolist(),
                       "centre": centre.tolist(), "min_visits": mv},
            )  # fmt: skip
            H = len(h)
            variants = [
                Variant(np.concatenate([np.arange(k - h0 + 1), H + np.arange(k - h0 + 1)]), float(np.deg2rad(t)),
                        f"harmonics {h0}..{k}, tau={t}°")
                for k in orders
                if k >= h0
                for t in cfg.transmission_prior_deg
            ]  # fmt: skip
            out.append((cand, variants))
    if "weight" in effects:
        out += weight_candidates(campaign, robot, cfg, rows, q)
    return out


Pool = list[tuple[list[Candidate], list[Variant]]]


def pooled(single: list[tuple[Candidate, list[Variant]]]) -> Pool:
    """Every candidate on its own, plus the compliance under the arm's own weight of all joints as one candidate
    (one physical cause: tested once, so that small deflections on several joints are not lost to the
    multiple-testing correction of testing each joint alone)."""
    pool: Pool = [([c], v) for c, v in single]
    weights = [(c, v[0]) for c, v in single if c.effect == "weight"]
    if len(weights) > 1:
        cols, taus, k0 = [], [], 0
        for c, v in weights:
            assert v.columns is not None  # joint effects: their columns are known
            cols.append(k0 + v.columns)
            taus.append(np.full(len(v.columns), v.prior_rad))
            k0 += c.S.shape[1]
        pool.append(
            ([c for c, _ in weights], [Variant(np.concatenate(cols), np.concatenate(taus), weights[0][1].label)])
        )
    return pool


def _member_variants(members: list[Candidate], v: Variant) -> list[tuple[Candidate, Variant]]:
    """A pooled variant split back into one variant per member candidate."""
    if len(members) == 1:
        return [(members[0], v)]
    assert v.columns is not None  # pooled candidates are joint effects
    out, k0 = [], 0
    tau = np.broadcast_to(np.asarray(v.prior_rad, dtype=float), (len(v.columns),))
    for c in members:
        k = c.S.shape[1]
        sel = (v.columns >= k0) & (v.columns < k0 + k)
        out.append((c, Variant(v.columns[sel] - k0, float(tau[sel][0]), v.label)))
        k0 += k
    return out


def variant_candidate(cand: Candidate, v: Variant) -> Candidate:
    """The candidate restricted to a variant's columns, with the variant's prior."""
    if v.columns is None:
        return cand
    extra = dict(cand.extra)
    if v.prior_rad is not None:
        extra["prior_rad"] = v.prior_rad
    if "harmonics" in extra:
        h = np.asarray(cand.extra["harmonics"])
        extra["harmonics"] = h[v.columns[: len(v.columns) // 2]].tolist()
    if "balancer_harmonics" in extra and max(v.columns) < len(extra["scale"]):  # the weight without it
        extra = {k: x for k, x in extra.items() if not k.startswith("balancer_")}
    if "centre" in extra and np.ndim(extra["centre"]) == 1:  # per column (a logged signal's is one number)
        extra["centre"] = np.asarray(cand.extra["centre"])[v.columns].tolist()
    extra["variant"] = v.label
    names = tuple(cand.coef_names[i] for i in v.columns)
    every = np.array_equal(v.columns, np.arange(cand.S.shape[1]))  # every column: its signals, no (m, q) copy
    units = tuple(cand.coef_units[i] for i in v.columns)
    S = cand.S if every else cand.S[:, v.columns]
    return replace(cand, S=S, coef_names=names, coef_units=units, extra=extra)


def cv_position_mm(fit: Fit, err_w: np.ndarray) -> np.ndarray:
    """Held-out position errors ``(m,)`` mm (3-D norm per row) from whitened held-out residuals."""
    e = (err_w / fit.weights).reshape(-1, fit.d)[:, :3]
    return np.asarray(np.linalg.norm(e, axis=1))


def grow(state: DiscoveryState, leftovers: list[Candidate], refit: Refit) -> None:
    """The cross-validated selection (module docstring). ``leftovers``: library candidates not accepted by the
    F-test search; ``refit``: the selection's refit (the state's, or one holding the geometry). Appends one
    :class:`~robocal.discovery.scoring.Step` per accepted candidate (and a final one saying why it stopped) and
    advances the state's fit and accepted effects; the state's record becomes the cross-validation record."""
    cfg = state.cfg
    single: list[tuple[Candidate, list[Variant]]] = [
        (c, [Variant(np.arange(c.S.shape[1]) if c.shape == "joint" else None, None, "")])
        for c in leftovers
        if c.shape in ("joint", "param", "tracker", "frame", "axis")
    ]
    taken = {a.cand.key for a in state.accepted}  # the F-test search's weight effects are accepted already
    physics = physics_candidates(state.campaign, state.robot, cfg, state.rows)
    pool = pooled(single + [(c, v) for c, v in physics if c.key not in taken])
    n_var = sum(len(v) for _, v in pool)
    state.record = {"candidates": ["+".join(c.key for c in m) for m, _ in pool], "n_variants": n_var, "steps": []}
    if cfg.cv_folds < 2 or not pool:
        return
    for step in range(cfg.grow_max_steps):
        progress.note(f"cross-validated selection: step {step + 1} (at most {cfg.grow_max_steps})")
        left = _step(state, pool, refit)
        if not left:  # nothing accepted (None), or nothing left to offer
            break
        pool = left
    _prune(state, refit)


def finish(state: DiscoveryState) -> None:
    """After the parametric model (library, selection, equations): the residual layer when the same
    cross-validated test accepts it, then the cross-validated estimate and each effect's contribution (into the
    state's record)."""
    cfg, record = state.cfg, state.record
    record.setdefault("steps", [])
    if cfg.layer and cfg.cv_folds >= 2:
        progress.note("residual layer")
        layer_pool = layer_candidates(state.campaign, cfg, state.rows)
        if layer_pool:
            _step(state, layer_pool, state.refit, what="residual layer")
    if state.sessions is not None:
        from robocal.discovery.session_cv import open_windows, opened_candidate

        opened, record["windows"] = open_windows(state.fit, state.sessions, cfg.min_held_out_gain)
        if opened:
            state.accepted = [Accepted(opened_candidate(a.cand, state.campaign.q), a.params)
                              if a.cand.key in opened else a for a in state.accepted]  # fmt: skip
            state.fit = state.refit(state.accepted, state.fit)
    if cfg.cv_folds >= 2:
        progress.note("final held-out check")
        record.update(held_out_check(state, final=True))


def held_out_check(state: DiscoveryState, final: bool = False) -> dict[str, Any]:
    """An effect earns its place by its held-out gain: the pose-grouped cross-validated RMS error of the model as
    fitted (whitened positions and, with a 6-DoF probe, orientations) without it (linearised,
    :func:`contributions`) must exceed the model's own by more than the share ``cfg.min_held_out_gain``. The
    effects that do not are dropped together and the model refitted; repeated until every joint-level effect
    passes (a :class:`Step` per round, of phase ``held-out`` for the ``final`` check after the layer and
    ``held-out parametric`` before it, and for the final check one saying that every effect passes; the state's
    ``record["dropped_no_gain"]`` with each one's gain and its position-only gain in mm). Advances the state's fit
    and effects; returns the final contributions. With the state's ``sessions`` an effect must also not raise the
    leave-one-session-out error by more than the same share (``session_gain >= -min_held_out_gain``): one that
    holds within the session but hurts in the next is dropped too."""
    dropped = state.record.setdefault("dropped_no_gain", [])
    thr = state.cfg.min_held_out_gain
    phase = "held-out" if final else "held-out parametric"
    for _ in range(5):
        fit = state.fit
        con = contributions(state)
        gains = {k: float(e["held_out_gain"]) for k, e in con["effects"].items()}
        weak = sorted(k for k, g in gains.items() if not g > thr)
        s_gains = {k: float(e["session_gain"]) for k, e in con["effects"].items() if "session_gain" in e}
        # hurting in a session left out: by more than the share, and pose by pose more than chance (cv_alpha)
        s_p = {k: float(e.get("session_hurt_log10_p", 0.0)) for k, e in con["effects"].items()}
        hurts = sorted(k for k, g in s_gains.items() if g < -thr and s_p[k] < np.log10(state.cfg.cv_alpha)
                       and k not in weak)  # fmt: skip
        weak = sorted(weak + hurts)
        # a robot-side effect that a measurement-side one cancels: the model as served worse than the geometry
        clash, served = served_conflict(fit, state.steps[0].rms_before_mm if state.steps else None)
        if clash is not None and clash not in weak:
            weak = sorted([*weak, clash])
        if not weak:
            if final and gains:
                state.steps.append(
                    Step(None, f"held-out check: every joint-level effect lowers the held-out error by more than "
                         f"{thr:.2%}", fit.rms_mm, fit.rms_mm, fit.rss, fit.rss, fit.dof, [], phase=phase)
                )  # fmt: skip
            return con
        before = fit
        state.accepted = [a for a in state.accepted if a.cand.key not in weak]
        state.fit = fit = state.refit(state.accepted, before)
        cv_mean = float(con["cv_mean_position_mm"])
        dropped += [
            {"key": k, "held_out_gain": gains.get(k), "threshold": thr,
             **({"position_gain_mm": float(con["effects"][k]["cv_mean_without_mm"]) - cv_mean}
                if k in con["effects"] else {}),
             **({"session_gain": s_gains[k], "hurts_in_new_session": k in hurts} if k in s_gains else {}),
             **({"served_conflict": served} if k == clash else {})}
            for k in weak
        ]  # fmt: skip
        state.steps.append(
            Step(None, f"held-out check: dropped {', '.join(weak)} (held-out gain at most {thr:.2%}"
                 + (f"; {', '.join(hurts)}: raise the error in a session left out by more than {thr:.2%}" if hurts
                    else "")
                 + (f"; {clash}: cancels a measurement-side effect, the model as served "
                    f"{served['served_rms_mm']:.4g} mm RMS where the geometry fits {served['geometric_rms_mm']:.4g}"
                    if clash is not None else "") + ")",
                 before.rms_mm, fit.rms_mm, before.rss, fit.rss, fit.dof, [], weak, before.residuals_mm,
                 fit.residuals_mm, phase=phase)
        )  # fmt: skip
    return contributions(state)


def _prune(state: DiscoveryState, refit: Refit) -> None:
    """Backward check of what the selection added: an effect (a member of a pooled candidate included) whose
    removal does not raise the cross-validated error contributes nothing held-out and is dropped (one pass,
    then the model is refitted with ``refit``). The library's F-test effects are left to their own Wald check."""
    fit, record = state.fit, state.record
    added = {c for st in record["steps"] for c in st.get("members", [st["key"]])}
    cv = fold_cv(fit, state.groups, state.cfg.cv_folds, state.cfg.seed)
    base = float(np.sum(cv.base_err**2))
    drop = []
    for a, sl in zip(fit.model.accepted, fit.model.slices, strict=True):
        if a.cand.key not in added or a.cand.shape != "joint":
            continue
        keep = np.array([i for i, p in enumerate(fit.free) if not (sl.start <= p < sl.stop)])
        e = cv.base_err_without(keep)
        if float(np.sum(e**2)) <= base:
            drop.append(a.cand.key)
    record["pruned"] = drop
    del cv  # not held through the refit (its fit's Jacobian)
    if drop:
        state.accepted = [a for a in state.accepted if a.cand.key not in drop]
        state.fit = refit(state.accepted, fit)


def _step(state: DiscoveryState, pool: Pool, refit: Refit, what: str = "cross-validated selection") -> Pool | None:
    """One step of the selection: score every pool entry, accept the best significant one (the state's fit
    refitted jointly with ``refit``; the pool without it comes back) or record why nothing was accepted (then
    None comes back and the state's fit is left as it was). The fold sums are the state's fit's
    (:func:`robocal.discovery.cv.fold_cv`: the last step's when it accepted nothing), let go before the refit."""
    phase = "layer" if what == "residual layer" else "selection"
    fit, cfg, rows, data = state.fit, state.cfg, state.rows, state.data
    cv = fold_cv(fit, state.groups, cfg.cv_folds, cfg.seed)
    sse0 = cv.group_sse(cv.base_err)
    scores: list[tuple[float, float, Score, list[Candidate], Variant, dict[str, tuple[str, ...]]]] = []
    # the logged signals are a family of their own at the same cv_alpha (as in the F-test search)
    n_sig = sum(len(v) for m, v in pool if m[0].effect == "signal")
    n_tests = max(sum(len(v) for _, v in pool) - n_sig, 1)
    thr_lib = float(np.log10(cfg.cv_alpha / n_tests))
    thr_sig = float(np.log10(cfg.cv_alpha / max(n_sig, 1)))
    drift: list[dict[str, tuple[str, ...]]] = [{} for _ in pool]
    q_of: list[int] = [0] * len(pool)

    def job(i: int, members: list[Candidate]) -> Any:
        def make() -> tuple[str, Any, list[Variant]]:
            if all(c.shape == "joint" for c in members):
                # joint-level: the candidate's factors, not its (M, q) regressor (robocal.discovery.cv)
                blocks = [(int(c.joint) - 1, RowsOf(np.asarray(c.S), rows)) for c in members if c.joint is not None]
                q_of[i] = sum(S.shape[1] for _, S in blocks)
                drift[i].update({c.key: () for c in members})
                return "joint", blocks, pool[i][1]
            regs = [regressor(c, fit, rows, data) for c in members]
            q_of[i] = sum(z.shape[1] for z, _ in regs)
            drift[i].update({c.key: prm for c, (_, prm) in zip(members, regs, strict=True)})
            return "dense", np.hstack([z for z, _ in regs]), pool[i][1]

        return make

    ticker = progress.Ticker(f"{what}: candidates scored", len(pool))
    sse_all = engine.group_sse(cv, [job(i, m) for i, (m, _) in enumerate(pool)], ticker.tick)
    del cv  # not held through the refit (its fit's Jacobian)
    for i_pool, (members, variants) in enumerate(pool):
        thr = thr_sig if members[0].effect == "signal" else thr_lib
        q_all, drifted = q_of[i_pool], drift[i_pool]
        best: tuple[float, float, Variant] | None = None
        for v, sse1 in zip(variants, sse_all[i_pool], strict=True):
            tot = float(sse1.sum())
            if best is None or tot < best[0]:
                best = (tot, paired_log10_p(sse0, sse1), v)
        assert best is not None
        tot, lp, v = best
        gain = float((sse0.sum() - tot) / sse0.sum()) if sse0.sum() > 0 else 0.0
        key = members[0].key if len(members) == 1 else f"{members[0].effect}:all"
        label = members[0].label if len(members) == 1 else f"{members[0].effect}, every joint"
        q = q_all if v.columns is None else len(v.columns)
        sc = Score(key, label, "tested", float("nan"), q, log10_p=lp, cv_gain=gain)
        sc.passes = bool(gain > 0 and lp < thr)
        scores.append((tot, lp, sc, members, v, drifted))
    scores.sort(key=lambda s: s[0])
    passing = [s for s in scores if s[2].passes]
    if not passing:
        state.steps.append(
            Step(None, f"{what}: nothing lowers the held-out error significantly", fit.rms_mm, fit.rms_mm, fit.rss,
                 fit.rss, fit.dof, [s[2] for s in scores], phase=phase)
        )  # fmt: skip
        return None
    _tot, lp, sc, members, v, drifted = passing[0]
    sc.status = "accepted"
    chosen = [variant_candidate(c, vv) for c, vv in _member_variants(members, v)]
    before = fit
    state.accepted = [*state.accepted, *(Accepted(c, drifted.get(c.key, ())) for c in chosen)]
    state.fit = fit = refit(state.accepted, before)
    state.steps.append(
        Step(sc.key, f"{sc.label} ({v.label})" if v.label else sc.label, before.rms_mm, fit.rms_mm, before.rss,
             fit.rss, fit.dof, [s[2] for s in scores], [], before.residuals_mm, fit.residuals_mm, phase=phase)
    )  # fmt: skip
    thr = thr_sig if members[0].effect == "signal" else thr_lib
    state.record["steps"].append({"key": sc.key, "variant": v.label, "log10_p": lp, "threshold_log10_p": thr,
                                  "cv_gain": sc.cv_gain, "members": [c.key for c in chosen]})  # fmt: skip
    taken = {c.key for c in members}
    return [(m, vs) for m, vs in pool if not taken & {c.key for c in m}]


def resolved_orders(cfg: DiscoveryConfig, n_poses: int) -> list[int]:
    """The transmission error's Fourier orders tried on ``n_poses`` poses: at most one coefficient pair per ~4
    poses (an order the poses cannot resolve is not tried)."""
    return [k for k in cfg.transmission_orders if 2 * k <= max(n_poses // 4, 0)]


def distinct_windows(campaign: Campaign, robot: Any, cfg: DiscoveryConfig, rows: np.ndarray) -> list[int]:
    """The values of ``cfg.transmission_min_visits`` that give different transmission windows on the rows ``rows``
    (the first of each set of values giving the same windows on every joint; one value when nothing differs: the
    search need not run again)."""
    from robocal.discovery.physics import configurations, periodic_window, visited_intervals

    values = sorted(set(cfg.transmission_min_visits))
    orders = resolved_orders(cfg, len(np.unique(np.asarray(campaign.pose_id)[rows].astype(str))))
    if len(values) < 2 or "transmission" not in cfg.effects or not orders:
        return values[:1]
    gap, _ = periodic_window(cfg, max(orders))
    joints = [j for j in range(robot.n_joints) if not robot.prismatic[j]]
    q_conf = configurations(campaign.q[rows])
    seen: list[list[list[list[float]]]] = []
    out = []
    for mv in values:
        w = [visited_intervals(q_conf[:, j], gap, mv) for j in joints]
        if w not in seen:
            seen.append(w)
            out.append(mv)
    return out


def orders_not_tried(cfg: DiscoveryConfig, n_poses: int) -> SkippedCandidate | None:
    """The transmission orders of the settings that ``n_poses`` poses cannot resolve, as a skipped candidate (with
    none left the effect is not tried at all: it vanished without a word, a newcomer's ``transmission_orders``)."""
    if "transmission" not in cfg.effects:
        return None
    kept = resolved_orders(cfg, n_poses)
    left = [k for k in cfg.transmission_orders if k not in kept]
    if not left:
        return None
    what = (
        "the transmission error is not tried"
        if not kept
        else f"only order{'s' * (len(kept) > 1)} {', '.join(map(str, kept))} {'are' if len(kept) > 1 else 'is'} tried"
    )
    return SkippedCandidate(
        "transmission", "transmission", None,
        f"orders {', '.join(map(str, left))} not tried: an order K needs 8 K poses (one coefficient pair per 4), the "
        f"calibration has {n_poses}; {what}",
    )  # fmt: skip


def layer_candidates(campaign: Campaign, cfg: DiscoveryConfig, rows: np.ndarray) -> Pool:
    """The residual layer: every joint's leftover error as a kernel ridge (Gaussian kernel on all joint angles,
    k-means centres of the calibration poses) — one pool entry per length scale, the prior widths as variants.
    Gated to the calibrated region (:func:`robocal.compensation.signals.layer_gate`)."""
    from robocal.compensation.signals import layer_features, layer_gate
    from robocal.discovery.physics import layer_centres

    q = campaign.q
    n_poses = len(np.unique(np.asarray(campaign.pose_id)[rows].astype(str)))
    D = min(cfg.layer_centres, max(n_poses // 4, 0))
    if D < 4:
        return []
    centres = layer_centres(q[rows], D, cfg.seed)
    moving = [j for j in range(q.shape[1]) if float(np.ptp(q[rows, j])) >= np.deg2rad(1.0)]
    pool: Pool = []
    for ell_deg in cfg.layer_length_deg:
        ell = float(np.deg2rad(ell_deg))
        F, d = layer_features(q, centres, ell)
        inside = float(np.quantile(d[rows], 0.95))
        S = F * layer_gate(d, inside, ell)[:, None]
        extra = {"centres_rad": centres.tolist(), "length_rad": ell, "inside_rad": inside}
        members = [
            Candidate(
                f"layer:j{j + 1}",
                "layer",
                j + 1,
                None,
                cause="residual layer: what the parametric model leaves on joint "
                f"{j + 1}, a smooth function of all joint angles (kernel ridge, Gaussian kernel of {ell_deg}°), "
                "applied only inside the calibrated region",
                signal=f"Gaussian kernel features of q ({len(centres)} centres)",
                shape="joint",
                S=S,
                coef_names=tuple(f"k{i + 1}" for i in range(len(centres))),
                coef_units=("rad",) * len(centres),
                extra=extra,
            )
            for j in moving
        ]
        ncol = len(centres) * len(members)
        variants = [
            Variant(np.arange(ncol), float(np.deg2rad(t)), f"length {ell_deg}°, tau {t}°") for t in cfg.layer_prior_deg
        ]
        pool.append((members, variants))
    return pool


def judged(cand: Any) -> bool:
    """Whether the held-out checks judge an effect: every joint-level effect, and a logged signal moving the base or
    the tool (robot side: it is carried to the controller and into a new session, so it must hold there too). The
    measurement's own effects (the tracker's drift, scale, a re-seated tool) are the session's, not judged here."""
    return cand.shape == "joint" or (cand.shape == "frame" and not session_own(cand))


def contributions(state: DiscoveryState) -> dict[str, Any]:
    """The cross-validated position error (mm) of the state's fit, and each joint-level effect's own
    contribution: the held-out error with that effect's coefficients removed from the model (linearised).
    With the state's ``sessions`` (a campaign of several sessions) the same in leave-one-session-out
    cross-validation (:mod:`robocal.discovery.session_cv`): ``session_cv`` and each effect's ``session_gain``."""
    fit, cfg, sessions = state.fit, state.cfg, state.sessions
    cv = fold_cv(fit, state.groups, max(cfg.cv_folds, 2), cfg.seed)
    own_err = sessions.errors(fit) if sessions is not None else None
    own = sessions.summary_of(fit, *own_err) if sessions is not None and own_err is not None else None
    e = ErrorStats.of(cv_position_mm(fit, cv.base_err))
    out: dict[str, Any] = {
        "cv_mean_position_mm": e.mean_mm,
        "cv_rms_position_mm": e.rms_mm,
        "effects": {},
    }
    if own is not None:
        out["session_cv"] = {k: v for k, v in own.items() if k != "sse"}
    model = fit.model
    for a, sl in zip(model.accepted, model.slices, strict=True):
        if not judged(a.cand):
            continue
        keep = np.array([i for i, p in enumerate(fit.free) if not (sl.start <= p < sl.stop)])
        if len(keep) == len(fit.free):
            continue
        err_without = cv.base_err_without(keep)
        e_without = ErrorStats.of(cv_position_mm(fit, err_without))
        out["effects"][a.cand.key] = {
            "cv_mean_without_mm": e_without.mean_mm,
            "cv_rms_without_mm": e_without.rms_mm,
            # the relative rise of the held-out RMS as fitted (whitened positions and, with a 6-DoF probe,
            # orientations) without the effect: the held-out check's gain (an effect that turns the tool shows here)
            "held_out_gain": float(np.sqrt(np.sum(err_without**2) / max(float(np.sum(cv.base_err**2)), 1e-300)) - 1),
        }
        if sessions is not None and own is not None and own_err is not None:
            err_k, mask_k = sessions.errors(fit, keep=keep)  # = sessions.summary(sub), from the normal equations
            other = sessions.summary_of(fit, err_k, mask_k)
            out["effects"][a.cand.key].update(
                session_mean_without_mm=other["mean_position_mm"],
                # the same rise in a session the model was not fitted on: negative, the effect hurts there
                session_gain=float(np.sqrt(other["sse"] / max(own["sse"], 1e-300)) - 1),
                # and whether that is more than chance, pose by pose (the paired test of the selection): a few
                # poses per session, each half registering the tracker for the other, move it either way
                session_hurt_log10_p=pose_paired_log10_p(state.groups, own_err, (err_k, mask_k)),
            )
    return out


def replace_fit_columns(fit: Fit, keep: np.ndarray) -> Fit:
    """The fit seen with only the free parameters ``keep`` (positions in ``fit.free``); the residual gains back
    what the removed parameters explained (first order)."""
    drop = np.setdiff1d(np.arange(len(fit.free)), keep)
    th = fit.theta.copy()
    r = fit.r_w - fit.J_w[:, drop] @ th[fit.free[drop]]
    th[fit.free[drop]] = 0.0
    return replace(fit, theta=th, free=fit.free[keep], r_w=r, J_w=fit.J_w[:, keep], cov=fit.cov[np.ix_(keep, keep)],
                   gram=None, factored=None)  # fmt: skip
