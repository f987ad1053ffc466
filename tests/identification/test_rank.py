"""The rank analysis keeps a well-conditioned set (:func:`robocal.identification.identifiability.analyse`).

It keeps the candidates in priority order, each when its part orthogonal to those kept before it exceeds ``rtol``
of its norm. That test, column by column, does not bound the set's smallest singular value: a URDF written from a
calibration (axes 1e-3 rad off parallel) kept 34 parameters whose smallest singular value was 1e-16 of the
largest (``robocal calibrate``: a RuntimeWarning from the covariance's negative diagonal and a prior of 1e5
chosen)."""

from __future__ import annotations

import numpy as np

from robocal.identification.identifiability import analyse


def _kahan(n: int, c: float, rows: int = 200) -> np.ndarray:
    """``Q R`` with ``R`` Kahan's matrix: every diagonal entry of ``R`` at least ``s^(n-1)`` (well above 1e-6), its
    smallest singular value far below."""
    s = np.sqrt(1.0 - c * c)
    R = np.diag(s ** np.arange(n)) @ (np.eye(n) - c * np.triu(np.ones((n, n)), 1))
    Q, _ = np.linalg.qr(np.random.default_rng(0).normal(size=(rows, n)))
    return Q @ R


def _cond(J: np.ndarray) -> float:
    sv = np.linalg.svd(J / np.linalg.norm(J, axis=0), compute_uv=False)
    return float(sv[-1] / sv[0])


def test_a_set_each_column_of_which_passes_alone_is_still_judged_as_a_whole():
    J = _kahan(60, 0.25)
    assert _cond(J) < 1e-6  # singular as a set (8.9e-8), though every column passes the greedy test (> 0.14)
    ident = analyse(J, [f"p{i}" for i in range(60)], list(range(60)), rtol=1e-6)
    assert _cond(J[:, ident.kept]) > 1e-6
    assert len(ident.kept) == 59  # one direction is missing: one column given up, no more
    (gone,) = ident.eliminated
    assert gone.reason == "not identifiable with these poses" and gone.absorbed_by  # said, with its absorbers


def test_a_well_conditioned_set_is_kept_whole():
    J = _kahan(40, 0.05)
    assert _cond(J) > 1e-3
    ident = analyse(J, [f"p{i}" for i in range(40)], list(range(40)), rtol=1e-6)
    assert len(ident.kept) == 40 and not ident.eliminated
