"""Systematic misfit: rows that stand out together under one condition are one model error, not many blunders.

The gross-error rule (:mod:`robocal.identification.robust`) tests each row on its own. A model error confined to
part of the campaign (one tracker placement, the rows above some joint-2 angle, a region of the workspace, a time
window, one value of a logged column) makes many rows stand out at once; calling them dozens of blunders hides
the one cause and throws away the data that show it.

The test: the flagged rows (``K`` of ``m``) are tested for enrichment under every condition the campaign offers —
one level of a categorical column (station, target, an extra column with at most :data:`MAX_LEVELS` values) or
an interval of an ordered one (every joint angle, the time, the measured x / y / z, a numeric extra column),
with the interval's ends at flagged rows' values. Under the null "the flagged rows are isolated blunders, at
random rows" the number of flagged rows inside a condition of ``n`` rows is hypergeometric ``(m, K, n)``; a
condition is significant when its upper-tail p-value is below ``alpha / (conditions tested)`` (Bonferroni) and it
holds at least :data:`MIN_ROWS` flagged rows. The most significant condition is named; its flagged rows are taken
off the blunder list and the rest are tested again (at most :data:`MAX_CLUSTERS` conditions). An interval is
grown to the next flagged rows beyond its ends while they misfit like it (see below) and it stays significant:
a warm-up's fading tail belongs to the warm-up.

Inside a named condition a row stays a gross error when it stands out from the condition's own scatter: its
position residual about the condition's median residual, against the larger of the condition's robust scale and
the campaign's, at the same family-wise ``alpha`` (chi² with 3 degrees of freedom, Bonferroni over the rows).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from robocal.data.campaign import Campaign
from robocal.metrics import ErrorStats

#: a systematic misfit holds at least this many flagged rows (fewer are a few blunders, e.g. the three targets of
#: one pose). 5 before: a URDF arm's elbow compliance, which calibrate does not model, made 4 rows of one elbow
#: range stand out, listed as 4 gross errors (0.14-0.18 mm among rows of 0.053 mm RMS); now one systematic misfit
MIN_ROWS = 4
#: at most this many conditions are named
MAX_CLUSTERS = 3
#: a column with at most this many distinct values is read as categorical (one condition per value)
MAX_LEVELS = 12
#: at most this many interval ends per ordered column (flagged rows' values, evenly by rank)
MAX_ENDS = 60


@dataclass(frozen=True)
class Condition:
    """One condition on the rows: a level of a categorical column or an interval of an ordered one."""

    kind: str  # station | target | column | joint | time | workspace
    column: str
    level: str | None = None
    lo: float | None = None
    hi: float | None = None
    unit: str = ""

    def text(self) -> str:
        if self.level is not None:
            return f"{self.column} = {self.level}"
        assert self.lo is not None and self.hi is not None
        u = f" {self.unit}" if self.unit else ""
        return f"{self.column} in [{self.lo:.6g}, {self.hi:.6g}]{u}"

    def holds(self, camp: Campaign) -> np.ndarray:
        """The rows of ``camp`` (any subset of the campaign: calibration, validation, all) under the condition."""
        v = column_values(camp, self.column)
        if v is None:
            return np.zeros(camp.n_rows, dtype=bool)
        if self.level is not None:
            return np.asarray(v.astype(str) == self.level)
        x = np.asarray(v, dtype=float)
        return np.asarray((x >= float(self.lo)) & (x <= float(self.hi)))  # type: ignore[arg-type]

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, "column": self.column}
        if self.level is not None:
            out["level"] = self.level
        else:
            # the ends are values of the data (flagged rows'): written whole, so that the condition read back from
            # the JSON holds on exactly the same rows
            out["range"] = [float(self.lo), float(self.hi)]  # type: ignore[arg-type]
            out["unit"] = self.unit
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Condition:
        """The condition of a record (:meth:`to_dict`)."""
        if "level" in d:
            return cls(str(d["kind"]), str(d["column"]), level=str(d["level"]))
        lo, hi = d["range"]
        return cls(str(d["kind"]), str(d["column"]), lo=float(lo), hi=float(hi), unit=str(d.get("unit", "")))


def column_values(camp: Campaign, column: str) -> np.ndarray | None:
    """The values of a named column of the campaign (the names :func:`columns` gives), or None."""
    if column == "station":
        return np.asarray(camp.station).astype(str)
    if column == "target":
        return np.asarray(camp.target).astype(str)
    if column == "time_s":
        return np.asarray(camp.timestamp_s, dtype=float)
    if column in ("x_mm", "y_mm", "z_mm"):
        return np.asarray(camp.p_mm[:, "xyz".index(column[0])], dtype=float)
    if column.startswith("q") and column.endswith("_deg") and column[1:-4].isdigit():
        j = int(column[1:-4]) - 1
        return np.rad2deg(camp.q[:, j]) if 0 <= j < camp.n_joints else None
    if column.startswith("q") and column.endswith("_mm") and column[1:-3].isdigit():  # a linear axis (mm)
        j = int(column[1:-3]) - 1
        return np.asarray(camp.q[:, j], dtype=float) if 0 <= j < camp.n_joints else None
    if column in camp.extra:
        return np.asarray(camp.extra[column])
    return None


def _numeric(v: np.ndarray) -> np.ndarray | None:
    try:
        x = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return None
    return x if np.all(np.isfinite(x)) else None


def columns(camp: Campaign) -> list[tuple[str, str, str, bool]]:
    """The columns a condition may be on: ``(kind, column, unit, ordered)``."""
    out: list[tuple[str, str, str, bool]] = []
    if camp.has_stations:
        out.append(("station", "station", "", False))
    if len(set(np.asarray(camp.target).tolist())) > 1:
        out.append(("target", "target", "", False))
    # a linear axis (a track, a lifting column) in mm as its column is: it was read as degrees of its mm (a
    # column's top 1.3 m named "q1_deg in [74 000, 86 000] deg")
    slide = camp.prismatic if camp.prismatic is not None else np.zeros(camp.n_joints, dtype=bool)
    out += [("joint", f"q{j + 1}_mm", "mm", True) if slide[j] else ("joint", f"q{j + 1}_deg", "deg", True)
            for j in range(camp.n_joints)]  # fmt: skip
    out.append(("time", "time_s", "s after the first row", True))
    out += [("workspace", f"{a}_mm", "mm (measured, tracker frame)", True) for a in "xyz"]
    for name in sorted(camp.extra):
        v = np.asarray(camp.extra[name])
        n_levels = len(set(v.astype(str).tolist()))
        if n_levels < 2:
            continue
        x = _numeric(v)
        if x is not None and n_levels > MAX_LEVELS:
            out.append(("column", name, "", True))
        elif n_levels <= MAX_LEVELS:
            out.append(("column", name, "", False))
    return out


def _scores(camp: Campaign, pool: np.ndarray, flagged: np.ndarray) -> list[tuple[Condition, int, int]]:
    """Every condition tested, with its rows ``n`` and flagged rows ``k`` among the ``pool`` rows; only conditions
    holding at least :data:`MIN_ROWS` flagged rows (the others cannot be named and are not counted as tests)."""
    out: list[tuple[Condition, int, int]] = []
    F = pool & flagged
    for kind, col, unit, ordered in columns(camp):
        v = column_values(camp, col)
        assert v is not None
        if not ordered:
            s = v.astype(str)
            for level in sorted(set(s[F].tolist())):
                n_in, k_in = int(np.sum(pool & (s == level))), int(np.sum(F & (s == level)))
                if k_in >= MIN_ROWS:
                    out.append((Condition(kind, col, level=level), n_in, k_in))
            continue
        x = np.asarray(v, dtype=float)
        xp, xf = np.sort(x[pool]), np.sort(x[F])
        fv = np.unique(xf)
        if len(fv) > MAX_ENDS:
            fv = fv[np.unique(np.round(np.linspace(0, len(fv) - 1, MAX_ENDS)).astype(int))]
        a, b = np.triu_indices(len(fv))
        lo, hi = fv[a], fv[b]
        n = np.searchsorted(xp, hi, side="right") - np.searchsorted(xp, lo, side="left")
        k = np.searchsorted(xf, hi, side="right") - np.searchsorted(xf, lo, side="left")
        for i in np.flatnonzero(k >= MIN_ROWS):
            out.append((Condition(kind, col, lo=float(lo[i]), hi=float(hi[i]), unit=unit), int(n[i]), int(k[i])))
    return out


def _log10_enrichment(k: np.ndarray, N: int, K: int, n: np.ndarray) -> np.ndarray:
    """log10 P(at least ``k`` of the ``K`` flagged rows among ``n`` of ``N``) per interval: the hypergeometric
    tail, evaluated once per distinct ``(k, n)`` (intervals share them; scipy's tail sums the mass function, and
    the scoring of every interval was a tenth of discovery's time on the UR10's 6 000 rows)."""
    k, n = np.asarray(k), np.asarray(n)
    if not k.size:
        return np.zeros(0)
    kn, inv = np.unique(np.stack([k, n]), axis=1, return_inverse=True)
    return np.asarray(hypergeom_logsf(kn[0] - 1, N, K, kn[1]) / np.log(10.0))[np.ravel(inv)]


#: terms of the mass function summed per block of :func:`hypergeom_logsf` (bounds its temporaries)
_LSE_CHUNK = 1 << 20


def hypergeom_logsf(k: np.ndarray, M: int, n: int, N: np.ndarray) -> np.ndarray:
    """``scipy.stats.hypergeom.logsf(k, M, n, N)`` (``P(X > k)``, ``n`` of ``M`` marked, ``N`` drawn) for integer
    arrays ``k``, ``N``, vectorised: scipy's own branches (the tail's mass function summed directly, or
    ``log(1 - cdf)`` where the head has fewer terms) and its log-sum-exp, over all elements at once instead of a
    Python loop per element (issue 31: at 12 000 UR10 rows scipy's loop was a fifth of discovery's time). The same
    numbers up to the order of summation; the terms scipy adds beyond ``min(n, N)`` are ``exp(-inf) = 0``."""
    k, N = np.broadcast_arrays(np.asarray(k, dtype=np.int64), np.asarray(N, dtype=np.int64))
    lo, hi = np.maximum(N - (M - n), 0), np.minimum(n, N)
    out = np.where(k < lo, 0.0, -np.inf)
    inner = (k >= lo) & (k < hi)
    head = inner & ((k + 0.5) * (M + 0.5) < (n - 0.5) * (N - 0.5))
    tail = inner & ~head
    out[tail] = _lse_pmf(k[tail] + 1, hi[tail] + 1, M, n, N[tail])
    out[head] = np.log1p(-np.exp(_lse_pmf(np.zeros(int(head.sum()), dtype=np.int64), k[head] + 1, M, n, N[head])))
    return out


def _lse_pmf(start: np.ndarray, stop: np.ndarray, M: int, n: int, N: np.ndarray) -> np.ndarray:
    """Per element, log Σ_{j = start}^{stop - 1} pmf(j; M, n, N), as scipy's logsumexp of its ``_logpmf``: the
    largest terms (``c`` of them) apart, ``log1p(s / c) + log(c) + max``."""
    from scipy.special import betaln

    out = np.empty(len(start))
    if not len(start):
        return out
    length = stop - start
    ends = np.cumsum(length)
    i0 = 0
    while i0 < len(start):  # blocks of elements of at most _LSE_CHUNK terms (one element at least)
        i1 = max(int(np.searchsorted(ends, ends[i0] - length[i0] + _LSE_CHUNK, side="right")), i0 + 1)
        L = length[i0:i1]
        seg = np.repeat(np.arange(i1 - i0), L)
        offs = np.concatenate([[0], np.cumsum(L)[:-1]])
        j = start[i0:i1][seg] + (np.arange(len(seg)) - offs[seg])
        Nj = N[i0:i1][seg]
        bad = M - n
        a = (
            betaln(n + 1, 1) + betaln(bad + 1, 1) + betaln(M - Nj + 1, Nj + 1)
            - betaln(j + 1, n - j + 1) - betaln(Nj - j + 1, bad - Nj + j + 1) - betaln(M + 1, 1)
        )  # fmt: skip
        amax = np.maximum.reduceat(a, offs)
        top = a == amax[seg]
        c = np.add.reduceat(top.astype(float), offs)
        s = np.add.reduceat(np.where(top, 0.0, np.exp(a - amax[seg])), offs)
        out[i0:i1] = np.log1p(s / c) + np.log(c) + amax
        i0 = i1
    return out


def _extend(
    camp: Campaign,
    cond: Condition,
    pool: np.ndarray,
    F: np.ndarray,
    alike: np.ndarray,
    N: int,
    K: int,
    log_thr: float,
) -> tuple[Condition, np.ndarray]:
    """An interval grown, one flagged row at a time on either side, to the next flagged rows that misfit like the
    cluster (``alike``: not apart from its median residual by its own scatter) while it stays significant (a
    warm-up's tail, where the misfit fades). Returns the condition and its rows among the ``pool``."""
    x = np.asarray(column_values(camp, cond.column), dtype=float)
    lo, hi = float(cond.lo), float(cond.hi)  # type: ignore[arg-type]
    # the row counts of every interval by binary search on the sorted values, and the enrichment test of the whole
    # sequence of candidate ends in one call: the same numbers as growing it one row at a time, without a pass
    # over the rows and a scalar test per row (issue 31: on the UR10 that loop was a quarter of discovery's time)
    xp, xf = np.sort(x[pool]), np.sort(x[pool & F])
    for side in (-1, 1):
        out = pool & F & ((x < lo) if side < 0 else (x > hi))
        seq = np.flatnonzero(out)[np.argsort(-x[out] if side < 0 else x[out], kind="stable")]  # nearest first
        not_alike = np.flatnonzero(~alike[seq])
        seq = seq[: not_alike[0]] if len(not_alike) else seq
        if not len(seq):
            continue
        ends = x[seq]
        nlo = np.minimum(lo, ends) if side < 0 else np.full(len(seq), lo)
        nhi = np.full(len(seq), hi) if side < 0 else np.maximum(hi, ends)
        n = np.searchsorted(xp, nhi, side="right") - np.searchsorted(xp, nlo, side="left")
        k = np.searchsorted(xf, nhi, side="right") - np.searchsorted(xf, nlo, side="left")
        lp = _log10_enrichment(k, N, K, n)
        fails = np.flatnonzero(~(lp < log_thr))
        t = int(fails[0]) if len(fails) else len(seq)  # the ends before the first that is not significant
        if t > 0:
            lo, hi = float(nlo[t - 1]), float(nhi[t - 1])
    ext = Condition(cond.kind, cond.column, lo=lo, hi=hi, unit=cond.unit)
    return ext, ext.holds(camp) & pool


def find(
    camp: Campaign, flagged: np.ndarray, resid_mm: np.ndarray, scale_mm: float, alpha: float
) -> tuple[list[dict[str, Any]], np.ndarray]:
    """Systematic misfits among the ``flagged`` rows of ``camp`` (module docstring).

    resid_mm : (m, 3) position residuals at the fit the rows were flagged against; scale_mm : the campaign's
    robust per-coordinate scale of a correct row; alpha : the family-wise rate of the gross-error rule.
    Returns one record per named condition (``condition``, ``n_rows`` flagged rows it explains, their ``size_mm``
    and ``offset_mm``, the enrichment test) and the mask of the flagged rows that are the misfit, not blunders.
    """
    m = len(flagged)
    flagged = np.asarray(flagged, dtype=bool)
    explained = np.zeros(m, dtype=bool)
    found: list[dict[str, Any]] = []
    pool = np.ones(m, dtype=bool)  # rows not yet under a named condition
    for _ in range(MAX_CLUSTERS):
        F = flagged & pool & ~explained
        K, N = int(F.sum()), int(pool.sum())
        if K < MIN_ROWS:
            break
        scored = _scores(camp, pool, F)
        if not scored:
            break
        log_thr = float(np.log10(alpha / len(scored)))
        n = np.array([s[1] for s in scored])
        k = np.array([s[2] for s in scored])
        lp = _log10_enrichment(k, N, K, n)
        # the most significant; among equals the one holding more flagged rows, then the first tested
        i = int(np.lexsort((np.arange(len(k)), -k, np.round(lp, 9)))[0])
        if not lp[i] < log_thr:
            break
        cond = scored[i][0]
        inside = cond.holds(camp) & pool
        members = inside & F
        centre = np.median(resid_mm[inside], axis=0)
        dev2 = np.sum((resid_mm - centre) ** 2, axis=1)
        s2 = max(float(np.median(dev2[inside])) / float(stats.chi2.ppf(0.5, 3)), scale_mm**2, 1e-300)
        alike = stats.chi2.sf(dev2 / s2, 3) >= alpha / max(m, 1)  # rows that do not stand out of the cluster
        lp_named = float(lp[i])
        if cond.level is None:
            cond, inside = _extend(camp, cond, pool, F, alike, N, K, log_thr)
            members = inside & F
            lp_named = float(stats.hypergeom.logsf(int(members.sum()) - 1, N, K, int(inside.sum())) / np.log(10.0))
        apart = members & ~alike
        named = members & ~apart
        if int(named.sum()) < MIN_ROWS:
            break
        offset = resid_mm[named].mean(axis=0)  # the rows named: over a broad condition the mean of all is ~0
        found.append(
            {
                "condition": cond.text(),
                **cond.to_dict(),
                "n_rows": int(named.sum()),
                "n_rows_in_condition": int(inside.sum()),
                "n_flagged": K,
                "size_mm": round(float(np.linalg.norm(offset)), 4),
                "offset_mm": [round(float(v), 4) for v in offset],
                "rms_mm": round(ErrorStats.of(resid_mm[named]).rms_mm, 4),
                "log10_p": round(lp_named, 2),
                "threshold_log10_p": round(log_thr, 2),
                "n_conditions_tested": len(scored),
                "rows_left_as_gross_errors": int(apart.sum()),
                "_mask": named,
                "_condition": cond,
            }
        )
        explained |= named
        pool &= ~inside
    return found, explained


RULE = (
    "flagged rows that share a condition (a station, target or value of a logged column, an interval of a joint "
    "angle, the time, the measured x/y/z or a numeric column) beyond chance (hypergeometric enrichment, Bonferroni "
    f"over the conditions, at least {MIN_ROWS} rows) are one systematic misfit, not gross errors; inside it a row "
    "stays a gross error when it stands out from the condition's own scatter"
)


def public(found: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The records without their private arrays (for JSON)."""
    return [{k: v for k, v in f.items() if not k.startswith("_")} for f in found]


def line(found: list[dict[str, Any]], what: str = "not gross errors: kept, and offered to discovery") -> str:
    """One console line per systematic misfit, or the empty string (``what``: what becomes of its rows)."""
    return "\n".join(
        f"systematic misfit: {f['n_rows']} row(s) with {f['condition']} misfit together by {f['size_mm']:.3f} mm "
        f"(offset {f['offset_mm']} mm; {what})"
        for f in found
    )


__all__ = ["MIN_ROWS", "RULE", "Condition", "column_values", "columns", "find", "line", "public"]
