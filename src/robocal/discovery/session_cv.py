"""Leave-one-session-out cross-validation: what a model is worth in a session it was not fitted on (issue 33
item 2).

Pose-grouped cross-validation (:class:`robocal.discovery.grow.FoldCV`) holds out poses of the session the model
was fitted in: same tracker placement, same day, the same region of the joints. A plant uses the model in the
next session. When a campaign holds several sessions (tracker stations: another placement, another day,
another cell), each session in turn is held out, as a new session would be met:

* the model (geometry, tools, every effect) is refitted on the other sessions: the linearised refit of
  :class:`~robocal.discovery.grow.FoldCV` (normal equations of the other sessions' rows, the priors included);
* the held-out session's tracker is registered on its own rows (its six frame parameters fitted to them, the model
  frozen: a new session always registers its tracker; on the other half of its poses, below), and its rows'
  errors are what is left; when the model
  holds a re-seated tool (a ``session`` effect: a tool that moved between sessions), the held-out session
  re-measures its tool too;
* the effects that belong to the sessions they were measured in (the tracker's drift and scale, a logged signal
  declared on the tracker, a re-seated tool: :func:`session_own`) are not carried into the held-out one — a new
  session has its own tracker state: the model is refitted on the other sessions without them;
* an effect defined on the joint angles the calibration visited (the transmission error's coverage window,
  the residual layer's gate) is applied in the held-out session only where the *other* sessions visited:
  exactly what the service would do with a model fitted without it.

The held-out session's poses are split in two halves (alternately, in the order measured): each half is judged
with the tracker (and tool) registered on the other half, so no row is judged by a frame fitted to it (sessions
below :data:`MIN_SESSION_ROWS` rows are not held out). The first-order refit is the one pose-grouped CV uses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from sklearn.metrics import pairwise_distances_argmin_min

from robocal.compensation.signals import coverage_weight, layer_features, layer_gate
from robocal.discovery.model import Fit
from robocal.discovery.physics import configurations, visited_intervals
from robocal.metrics import ErrorStats

#: a session is held out only with at least this many rows: its tracker registration fits six parameters to the
#: rows it is judged on, at 20 rows (60 equations) a tenth of them; a campaign of many small stations (a robot on a
#: column measured at each height) is judged by pose-grouped cross-validation alone
MIN_SESSION_ROWS = 20


@dataclass(frozen=True)
class Sessions:
    """The sessions of the fitted rows: ``index (m,)`` into ``names`` (-1: a session too small to hold out),
    the model's station of each session (``station``), the fitted rows' joint angles ``q (m, n)`` rad."""

    index: np.ndarray
    names: tuple[str, ...]
    station: tuple[int, ...]
    q: np.ndarray
    gap_deg: float

    @staticmethod
    def of(
        station_index: np.ndarray | None, station_names: tuple[str, ...], q: np.ndarray, gap_deg: float
    ) -> Sessions | None:
        """The sessions of a fit's rows (``station_index (m,)`` into the model's ``station_names``), or None when
        fewer than two of them have :data:`MIN_SESSION_ROWS` rows."""
        if station_index is None:
            return None
        st = np.asarray(station_index, dtype=int)
        big = [s for s in range(len(station_names)) if int(np.sum(st == s)) >= MIN_SESSION_ROWS]
        if len(big) < 2:
            return None
        index = np.full(len(st), -1, dtype=int)
        for i, s in enumerate(big):
            index[st == s] = i
        return Sessions(index, tuple(station_names[s] for s in big), tuple(big), np.asarray(q, dtype=float), gap_deg)

    # ------------------------------------------------------------------------------------------------ errors
    def _coverage(self, cand: Any, held: np.ndarray, opened: frozenset[str] = frozenset()) -> np.ndarray | None:
        """Per held-out row, the share of a windowed effect the service would apply with the model fitted on the
        other sessions (1 where they visited, 0 far outside); None for an effect without a window or one in
        ``opened`` (applied beyond the angles visited)."""
        ex = cand.extra
        if cand.key in opened:
            return None
        # the same for every fit and every effect left out: computed once per effect, window and session
        memo = self.__dict__.setdefault("_coverage_memo", {})
        key = (cand.key, ex.get("taper_deg"), ex.get("length_rad"), held.tobytes())
        if key not in memo:
            memo[key] = self._coverage_of(cand, held)
        return memo[key]

    def _coverage_of(self, cand: Any, held: np.ndarray) -> np.ndarray | None:
        """:meth:`_coverage`, computed."""
        ex = cand.extra
        if "visited_deg" in ex and cand.joint is not None:
            j = int(cand.joint) - 1
            visited = visited_intervals(configurations(self.q[~held])[:, j], float(ex.get("gap_deg", self.gap_deg)),
                                        int(ex.get("min_visits", 1)))  # fmt: skip
            return coverage_weight(self.q[held, j], visited, float(ex["taper_deg"]))
        if "centres_rad" in ex:
            ell, inside = float(ex["length_rad"]), float(ex["inside_rad"])
            _, d_all = layer_features(self.q[held], np.asarray(ex["centres_rad"], dtype=float), ell)
            g_all = layer_gate(d_all, inside, ell)
            # the gate of the other sessions' own calibrated region: distance to their nearest pose
            d_own = np.sqrt(nearest_sq_distances(self.q[held], self.q[~held]))
            g_own = layer_gate(d_own, inside, ell)
            return np.where(g_all > 0, np.minimum(g_own / np.maximum(g_all, 1e-300), 1.0), 0.0)
        return None

    def halves(self, i: int) -> np.ndarray:
        """Session ``i``'s rows in two halves (bool over its rows, True: the first half): its poses (distinct joint
        configurations, in row order) alternately in one and the other, every target of a pose in the same half.
        A held-out session's frame is registered on one half and judges the other, and the reverse."""
        memo = self.__dict__.setdefault("_halves_memo", {})
        if i not in memo:
            q = self.q[self.index == i]
            _, first, pose = np.unique(np.round(q, 9), axis=0, return_index=True, return_inverse=True)
            rank = np.argsort(np.argsort(first))  # the poses in the order the session measured them
            memo[i] = rank[np.asarray(pose).ravel()] % 2 == 0
        return np.asarray(memo[i])

    def _grams(self, fit: Fit) -> tuple[np.ndarray, np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
        """The normal equations of the fit, all rows and each session's (``JᵀJ``, ``Jᵀr``), formed once per fit
        (every effect left out is a slice of them, :meth:`errors` with ``keep``)."""
        cache = self.__dict__.setdefault("_cache", {})
        if cache.get("fit") is not fit:
            A, r = fit.J_w, fit.r_w
            per = []
            for i in range(len(self.station)):
                t = np.repeat(self.index == i, fit.d)
                per.append((A[t].T @ A[t], A[t].T @ r[t]))
            cache.update(fit=fit, G=A.T @ A, b=A.T @ r, per=per)
        return cache["G"], cache["b"], cache["per"]

    def errors(
        self,
        fit: Fit,
        opened: frozenset[str] = frozenset(),
        keep: np.ndarray | None = None,
        reseat: bool | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Whitened held-out residuals ``(M,)`` of every held-out session's rows (0 on rows of no session) and
        the mask ``(M,)`` of the residuals held out; the effects in ``opened`` applied without their window;
        ``keep``: only these free parameters (positions in ``fit.free``), the others removed from the model as
        :func:`robocal.discovery.grow.replace_fit_columns` removes them (first order); ``reseat``: the held-out
        session's tool re-measured too (None: when ``fit`` holds a re-seated tool; the geometric model is judged
        so when the discovered one does, like with like)."""
        A, r, d = fit.J_w, fit.r_w, fit.d
        k_all = len(fit.free)
        keep = np.arange(k_all) if keep is None else np.asarray(keep, dtype=int)
        # the sessions' own effects (the tracker's drift and scale, a re-seated tool) are not carried into a new
        # session: the model is refitted on the others without them. (Fitted with them and then left out of the
        # held-out prediction, a scale drift confounded with the geometry inside one session kept the full fit's
        # compromise between the sessions: an optimistic figure.)
        model = fit.model
        own = {p for a, sl in zip(model.accepted, model.slices, strict=True) if session_own(a.cand)
               for p in range(sl.start, sl.stop)}  # fmt: skip
        keep = np.array([k for k in keep if int(fit.free[k]) not in own], dtype=int)
        drop = np.setdiff1d(np.arange(k_all), keep)
        free = fit.free[keep]
        prec = fit.model.prior_precision()[free]
        th_all = fit.theta[fit.free]
        th = th_all[keep]
        thd = th_all[drop]
        G0, b0, per = self._grams(fit)
        G = G0[np.ix_(keep, keep)]
        b = b0[keep] - G0[np.ix_(keep, drop)] @ thd
        col = {int(p): i for i, p in enumerate(free)}
        out = np.zeros_like(r)
        mask = np.zeros(len(r), dtype=bool)
        reseated = any(a.cand.effect == "session" for a in model.accepted) if reseat is None else reseat
        tool_cols = [p for p, kind in enumerate(model.base.kinds) if kind in ("tool", "tool_rot")]
        for i, s in enumerate(self.station):
            held = self.index == i
            t = np.repeat(held, d)
            Gs, bs = per[i]
            H = G - Gs[np.ix_(keep, keep)] + np.diag(prec)
            g = b - (bs[keep] - Gs[np.ix_(keep, drop)] @ thd) + prec * th
            At = A[t][:, keep]
            rt = r[t] - A[t][:, drop] @ thd
            for a, sl in zip(model.accepted, model.slices, strict=True):
                if a.cand.shape != "joint":
                    continue
                w = self._coverage(a.cand, held, opened)
                if w is None:
                    continue
                cols = [col[p] for p in range(sl.start, sl.stop) if p in col]
                if not cols:
                    continue
                wr = np.repeat(w, d)
                # the effect as applied with the others' coverage: its share (1 - w) taken out of the prediction
                rt = rt - (1.0 - wr) * (At[:, cols] @ th[cols])
                At[:, cols] *= wr[:, None]
            step = np.linalg.pinv(H, rcond=1e-12, hermitian=True) @ g
            e = rt - At @ step
            frame = [col[int(p)] for p in model.base.station_columns(s) if int(p) in col]
            if reseated:  # the tool re-seated between sessions: a new session re-measures it as well
                frame += [col[p] for p in tool_cols if p in col]
            if frame:  # each half of the session's poses judged with the frame registered on the other half
                F = At[:, frame]
                half = np.repeat(self.halves(i), d)
                judged = e.copy()
                for h in (half, ~half):
                    judged[h] = e[h] - F[h] @ np.linalg.lstsq(F[~h], e[~h], rcond=None)[0]
                e = judged
            out[t] = e
            mask |= t
        return out, mask

    def position_mm(self, fit: Fit, err_w: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Held-out 3-D position errors (mm) of the held-out rows."""
        e = (err_w / fit.weights).reshape(-1, fit.d)[:, :3]
        return np.asarray(np.linalg.norm(e[mask.reshape(-1, fit.d)[:, 0]], axis=1))

    def summary(
        self,
        fit: Fit,
        opened: frozenset[str] = frozenset(),
        keep: np.ndarray | None = None,
        reseat: bool | None = None,
    ) -> dict[str, Any]:
        """``{"sessions", "mean_position_mm", "rms_position_mm", "per_session": {name: mean mm}, "sse"}``
        (:meth:`errors`' arguments)."""
        err, mask = self.errors(fit, opened, keep, reseat)
        return self.summary_of(fit, err, mask)

    def summary_of(self, fit: Fit, err: np.ndarray, mask: np.ndarray) -> dict[str, Any]:
        """:meth:`summary` of :meth:`errors`' held-out residuals ``err`` (rows ``mask``)."""
        e = self.position_mm(fit, err, mask)
        held = self.index[self.index >= 0]
        stats = ErrorStats.of(e)
        return {
            "sessions": list(self.names),
            "mean_position_mm": stats.mean_mm,
            "rms_position_mm": stats.rms_mm,
            "per_session": {n: ErrorStats.of(e[held == i]).mean_mm for i, n in enumerate(self.names)},
            "sse": float(np.sum(err[mask] ** 2)),
        }


#: effect families that belong to the session they were measured in (the tracker's drift, its air and length
#: scale, a fresh registration after a pause, a systematic misfit of some rows): a new session has its own
MEASUREMENT_FAMILIES = ("drift", "air", "regap", "scale", "misfit")


def session_own(cand: Any) -> bool:
    """Whether an effect belongs to the session it was measured in — the tracker's state (a measurement-side
    effect) or the session's own tool (``session``) — so that a model fitted on other sessions does not carry
    it into a new one: the held-out session gets none of it (its tracker, and a re-seated tool, registered)."""
    return (
        cand.effect in MEASUREMENT_FAMILIES
        or cand.effect == "session"
        or (cand.extra.get("side", "robot") in ("measurement", "session"))
    )


def open_windows(fit: Fit, sessions: Sessions, thr: float) -> tuple[list[str], dict[str, Any]]:
    """Whether each transmission error holds beyond the joint angles the calibration visited, decided by the
    sessions (issue 33 item 2: by evidence, not by a fixed rule): the leave-one-session-out error with the effect
    applied everywhere (its Fourier series continued, fitted on the other sessions) against the same with its
    window. Returns the effects whose window the evidence opens (the error falls by more than the share ``thr``)
    and the record ``{key: {"windowed_mm", "applied_everywhere_mm", "opened"}}``."""
    base = sessions.summary(fit)
    out: dict[str, Any] = {}
    opened = []
    for a in fit.model.accepted:
        if a.cand.shape != "joint" or "visited_deg" not in a.cand.extra:
            continue
        key = a.cand.key
        o = sessions.summary(fit, frozenset({key}))
        gain = float(np.sqrt(base["sse"] / max(o["sse"], 1e-300)) - 1)
        out[key] = {
            "windowed_mm": base["mean_position_mm"],
            "applied_everywhere_mm": o["mean_position_mm"],
            "opened": bool(gain > thr),
        }
        if gain > thr:
            opened.append(key)
    return opened, out


def opened_candidate(cand: Any, q: np.ndarray) -> Any:
    """A transmission candidate with its window open: the Fourier series of the joint angle on every row ``q
    (m_all, n)`` rad less the same centre (on the calibration's rows, all inside their window, it is unchanged)."""
    from dataclasses import replace

    from robocal.compensation.signals import fourier_signal

    assert cand.joint is not None
    S = fourier_signal(q[:, cand.joint - 1], np.asarray(cand.extra["harmonics"], dtype=int))
    S = S - np.asarray(cand.extra.get("centre", 0.0), dtype=float)
    return replace(cand, S=S, extra={**cand.extra, "visited_deg": [[0.0, 360.0]], "window": "opened by the sessions"})


def nearest_sq_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Squared distance of each row of ``a`` to its nearest row of ``b`` (scikit-learn, in chunks)."""
    _, d = pairwise_distances_argmin_min(a, b, metric="sqeuclidean")
    return np.asarray(d)


__all__ = ["MEASUREMENT_FAMILIES", "MIN_SESSION_ROWS", "Sessions", "open_windows", "opened_candidate", "session_own"]
