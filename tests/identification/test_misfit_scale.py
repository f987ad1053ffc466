"""The systematic-misfit interval growth, vectorised (issue 31), ends where growing it one row at a time ended."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy import stats

from robocal.identification import misfit


def _reference(x, cond, pool, F, alike, N, K, log_thr):
    """The interval grown one flagged row at a time (the rule as first written)."""
    lo, hi = float(cond.lo), float(cond.hi)
    for side in (-1, 1):
        out = pool & F & ((x < lo) if side < 0 else (x > hi))
        for r in np.flatnonzero(out)[np.argsort(-x[out] if side < 0 else x[out], kind="stable")]:
            if not alike[r]:
                break
            nlo, nhi = min(lo, float(x[r])), max(hi, float(x[r]))
            inside = pool & (x >= nlo) & (x <= nhi)
            n, k = int(inside.sum()), int((inside & F).sum())
            if not float(stats.hypergeom.logsf(k - 1, N, K, n) / np.log(10.0)) < log_thr:
                break
            lo, hi = nlo, nhi
    return lo, hi


def test_the_vectorised_growth_ends_where_the_row_by_row_growth_ended():
    rng = np.random.default_rng(0)
    checked = grown = 0
    for trial in range(16):
        m = 400
        x = np.round(rng.uniform(0, 100, m), 1)  # ties included
        # a cluster of flagged rows in [40, 60] fading into its neighbours, and blunders elsewhere
        p = np.where((x > 40) & (x < 60), 0.8, np.where((x > 30) & (x < 70), 0.25, 0.02))
        F = rng.uniform(size=m) < p
        pool = rng.uniform(size=m) < 0.95
        alike = rng.uniform(size=m) < (0.97 if trial % 2 else 0.8)
        N, K = int(pool.sum()), int((pool & F).sum())
        cond = misfit.Condition("column", "c", lo=45.0, hi=55.0)
        camp = SimpleNamespace(extra={"c": x}, n_rows=m)
        log_thr = float(np.log10(0.001 / 100)) if trial % 3 else -2.0
        ext, rows = misfit._extend(camp, cond, pool, F, alike, N, K, log_thr)
        ref = _reference(x, cond, pool, F, alike, N, K, log_thr)
        assert (ext.lo, ext.hi) == ref, trial
        assert np.array_equal(rows, (x >= ref[0]) & (x <= ref[1]) & pool)
        checked += 1
        grown += ref != (45.0, 55.0)
    assert checked == 16 and grown >= 5  # the growth is exercised, not only the trivial case
