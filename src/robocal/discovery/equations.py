"""The dictionary stage of discovery's search (:func:`robocal.discovery.search.discover`): after the library and
the cross-validated selection, equations proposed for what is left (:mod:`robocal.discovery.dictionary`), each one
accepted by the same tests as a library candidate."""

from __future__ import annotations

from robocal.discovery.candidates import Candidate
from robocal.discovery.cv import clear_cache
from robocal.discovery.ftest import ColumnSpace, basis, cross_validation_gain, score_candidate
from robocal.discovery.gram import FactoredSpace
from robocal.discovery.model import Accepted
from robocal.discovery.scoring import Score, Step, regressor
from robocal.discovery.state import DiscoveryState


def propose(state: DiscoveryState) -> None:
    """The dictionary stage (:mod:`robocal.discovery.dictionary`): after the library, propose equations (each one
    accepted advances the state's fit and effects)."""
    from robocal.discovery.dictionary import build_dictionary, log10_threshold, reading, select

    cfg, rows, data, groups = state.cfg, state.rows, state.data, state.groups
    dic = build_dictionary(state.campaign, state.robot, cfg.dictionary_harmonics, cfg.dictionary_product_harmonics)
    if dic.F.shape[1] == 0:
        return
    for k in range(cfg.dictionary_max_proposals):
        fit = state.fit
        clear_cache()  # the selection's fold sums (its fit's Jacobian) not held beside the basis (issue 31)
        # a fit holding its Jacobian by its factors: the basis held by them too (never an (M, k) matrix)
        F = fit.factors()
        space: ColumnSpace | FactoredSpace = F.space() if F is not None else basis(fit)
        props = select(
            fit.Jq,
            fit.weights,
            dic.F[rows],
            fit.r_w,
            space if isinstance(space, FactoredSpace) else space.matrix(),  # the dictionary's columns: by factors
            groups,
            cfg.dictionary_max_terms,
            cfg.dictionary_resamples,
            cfg.dictionary_stability,
            cfg.absorbed_tol,
            cfg.seed + 1000 * k,
        )
        best: tuple[Score, Candidate] | None = None
        scores: list[Score] = []
        for p in props:
            terms = [dic.terms[a] for a in p.atoms]
            labels = tuple(t.label for t in terms)
            cand = Candidate(
                "proposed:j{}:{}".format(p.joint, "+".join(labels)),
                "proposed",
                p.joint,
                None,
                cause=reading(p.joint, terms),
                signal=" + ".join(labels),
                shape="joint",
                S=dic.F.columns(p.atoms),  # formed when read
                coef_names=labels,
                coef_units=("rad",) * len(terms),
                extra={"terms": [t.to_dict() for t in terms], "stability": p.stability, "n_columns": p.n_columns},
            )
            Z, _ = regressor(cand, fit, rows, data)
            thr = log10_threshold(cfg.alpha, p.n_columns, len(terms))
            sc, Uk = score_candidate(cand, Z, space, fit, cfg, thr)
            cand.extra["threshold_log10_p"] = thr
            if sc.passes and cfg.cv_folds >= 2:
                sc.cv_gain = cross_validation_gain(fit, Uk, groups, cfg.cv_folds, cfg.seed)
                if sc.cv_gain <= 0:
                    sc.status = "failed cross-validation"
            scores.append(sc)
            if sc.passes and sc.status == "tested" and (best is None or sc.log10_p < best[0].log10_p):
                best = (sc, cand)
        if best is None:
            state.steps.append(Step(None, "dictionary: nothing proposed", fit.rms_mm, fit.rms_mm, fit.rss, fit.rss,
                                    fit.dof, scores, phase="equations"))  # fmt: skip
            break
        sc, cand = best
        sc.status = "accepted"
        before = fit
        state.accepted = [*state.accepted, Accepted(cand)]
        state.fit = fit = state.refit(state.accepted, before)
        state.steps.append(
            Step(cand.key, f"proposed equation for joint {cand.joint}", before.rms_mm, fit.rms_mm, before.rss,
                 fit.rss, fit.dof, scores, [], before.residuals_mm, fit.residuals_mm, phase="equations")
        )  # fmt: skip


__all__ = ["propose"]
