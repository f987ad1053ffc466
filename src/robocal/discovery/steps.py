"""A tracker bumped without a pause: the step of its frame at a time the campaign does not mark (issue 33 item 4).

A pause longer than ``registration_gap_h`` offers a fresh registration after it (``regap``,
:mod:`robocal.discovery.candidates`). A tracker knocked (or a base that moved) mid-campaign leaves no pause and no
label: the rows after an unknown time are measured in another frame. After the library's first search (so that the
robot's own effects — a heavy arm's compliance — are in the model, not in the residuals the scan reads) every time
between two calibration rows with at least :data:`STEP_MIN_SHARE` of them, and :data:`STEP_MIN_ROWS`, on each side
(each tracker station's rows apart) is scanned for the rigid step of the station's frame that explains most of the
residuals off the model's column space, from running sums of each row's 6 x 6 normal equations. The best is offered
to the library's F-test once, its test its own family's (as the logged signals'): Bonferroni over the times scanned
at the search's ``alpha``; when even its scan statistic does not pass that threshold it is not offered (the search
and its records are as before). Named, it is a measurement-side effect: it corrects the figures, never the robot.

On newcomer pass 16's heavy arm (132 rows, a tracker bumped 0.3 mm / 50 µrad after row 60 with no pause) the step
was named a 4-row time cluster, held-out 0.0798 mm against the oracle's 0.0239.
"""

from __future__ import annotations

import numpy as np

from robocal.data.contract import Campaign
from robocal.discovery.candidates import Candidate
from robocal.discovery.ftest import basis, f_log10_sf
from robocal.discovery.model import Fit

#: the frame parameters of the first station (the others' are ``station_<name>_tx`` ..)
FRAME = ("base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz")
#: a step leaves at least this share of a station's calibration rows on each side
STEP_MIN_SHARE = 0.05
#: and at least this many rows (two poses of three reflectors)
STEP_MIN_ROWS = 6
HOUR_S = 3600.0
#: at most this many times scanned per station (evenly by rank among those possible)
MAX_STEP_TIMES = 400
#: rows per pass of the scan's sums
CHUNK_ROWS = 2048


def step_scan(
    t_s: np.ndarray, A: np.ndarray, r: np.ndarray, Q: np.ndarray, max_times: int = MAX_STEP_TIMES
) -> tuple[float, int, float] | None:
    """The best time for a step of a frame, from rows at times ``t_s (m,)`` with the frame's whitened Jacobian ``A
    (m, d, 6)``, whitened residuals ``r (m, d)`` and the current model's orthonormal basis at those rows ``Q (m, d,
    k)``: ``(time between the two rows, times scanned, the whitened residual sum of squares the step removes off
    the model)``, or None when no time leaves enough rows on each side. The step is centred (its constant part is the
    frame's own); its columns are projected off the model's, from running sums of ``AᵀA``, ``Aᵀr`` and ``QᵀA``
    per row (at most ``max_times`` times, evenly by rank: the sums per stretch between two)."""
    order = np.argsort(t_s, kind="stable")
    t = t_s[order]
    m = len(t)
    least = max(STEP_MIN_ROWS, int(np.ceil(STEP_MIN_SHARE * m)))
    k = np.arange(least - 1, m - least)  # the step after row k
    k = k[t[k] < t[k + 1]]  # between two times
    if len(k) == 0:
        return None
    if len(k) > max_times:
        k = k[np.unique(np.linspace(0, len(k) - 1, max_times).round().astype(int))]
    seg = np.searchsorted(k, np.arange(m), side="left")  # stretch of each time-ordered row: ..k[0] is 0
    n_seg = len(k) + 1
    G = np.zeros((n_seg, 6, 6))
    b = np.zeros((n_seg, 6))
    C = np.zeros((n_seg, Q.shape[2], 6))
    for c0 in range(0, m, CHUNK_ROWS):
        i = order[c0 : c0 + CHUNK_ROWS]
        s_i = seg[c0 : c0 + CHUNK_ROWS]
        np.add.at(G, s_i, np.einsum("mai,maj->mij", A[i], A[i]))
        np.add.at(b, s_i, np.einsum("mai,ma->mi", A[i], r[i]))
        np.add.at(C, s_i, np.einsum("mak,maj->mkj", Q[i], A[i]))
    G, b, C = (np.cumsum(x, axis=0) for x in (G, b, C))  # rows up to k[j] in [j]
    f = ((m - 1 - k) / m)[:, None]  # share after
    b_s = (1 - f) * (b[-1] - b[:-1]) - f * b[:-1]
    C_s = (1 - f)[:, :, None] * (C[-1] - C[:-1]) - f[:, :, None] * C[:-1]
    N = (1 - f)[:, :, None] ** 2 * (G[-1] - G[:-1]) + f[:, :, None] ** 2 * G[:-1]
    N = N - np.einsum("bki,bkj->bij", C_s, C_s)  # off the model's columns
    ok = np.linalg.cond(N) < 1e12
    if not np.any(ok):
        return None
    gain = np.full(len(k), -np.inf)
    gain[ok] = np.einsum("ki,ki->k", b_s[ok], np.linalg.solve(N[ok], b_s[ok][:, :, None])[:, :, 0])
    best = int(np.argmax(gain))
    return float((t[k[best]] + t[k[best] + 1]) / 2.0), len(k), float(gain[best])


def step_candidate(campaign: Campaign, rows: np.ndarray, fit: Fit, alpha: float) -> Candidate | None:
    """The tracker's step at the time :func:`step_scan` finds on the fit's rows ``rows`` (of ``campaign``), when
    its scan statistic passes its family's threshold (``alpha`` over the times scanned), else None. Several
    stations: each one's rows scanned, the step in the one where it explains most, its frame stepping."""
    model, m, d = fit.model.base, len(rows), fit.d
    ident = {fit.model.names[i] for i in fit.free}
    t = np.asarray(campaign.timestamp_s, dtype=float)
    if np.ptp(t[rows]) <= 0:
        return None
    st = np.asarray(campaign.station if campaign.station is not None else ["S1"] * campaign.n_rows).astype(str)
    w = fit.weights[: d * m].reshape(m, d)
    r = fit.r_w[: d * m].reshape(m, d)
    Q = basis(fit).matrix()[: d * m].reshape(m, d, -1)
    best: tuple[float, int, float, int, tuple[str, ...]] | None = None
    n_times = 0
    for k, name in enumerate(model.station_names):
        params = FRAME if k == 0 else tuple(f"station_{name}_{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz"))
        mine = np.flatnonzero(st[rows] == name)
        if len(mine) == 0 or not set(params) <= ident:
            continue
        A = fit.Jx[mine][:, :, [model.index(p) for p in params]] * w[mine][:, :, None]
        found = step_scan(t[rows][mine], A, r[mine], Q[mine])
        if found is not None:
            n_times += found[1]
            if best is None or found[2] > best[2]:
                best = (*found, k, params)
    del Q
    if best is None:
        return None
    t_cut, _, gain, k, params = best
    rss = float(np.sum(r**2))
    thr = float(np.log10(alpha / n_times))
    dof = fit.dof - 6
    if dof <= 0 or f_log10_sf((gain / 6.0) / max((rss - gain) / dof, 1e-300), 6, dof) >= thr:
        return None
    name = model.station_names[k]
    ind = ((t > t_cut) & (st == name)).astype(float)
    S = (ind - ind[rows][st[rows] == name].mean()) * (st == name)
    where = f" of station {name}" if len(model.station_names) > 1 else ""
    return Candidate(
        "regap_step", "regap", None, None,
        cause=f"the tracker{where} was bumped (or the base moved) without a pause: from {t_cut / HOUR_S:.3f} h on "
        "its frame steps (the time found by a scan over the calibration rows' times, its test corrected for "
        "them; a measurement-side effect, never sent to the controller)",
        signal=f"measured after {t_cut / HOUR_S:.3f} h{where} (scanned over {n_times} times)", shape="param",
        S=S[:, None], params=params, signal_names=("after_step",),
        extra={"t_step_s": t_cut, "times_scanned": n_times, "station": name, "family_log10_p": thr},
    )  # fmt: skip


__all__ = ["step_candidate", "step_scan"]
