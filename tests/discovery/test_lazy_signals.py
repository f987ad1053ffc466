"""Signals formed when read (issue 31): the dictionary's columns equal, row by row and bit for bit, the whole matrix
they replace, however they are read."""

from __future__ import annotations

import numpy as np

from robocal.compensation.signals import layer_features
from robocal.discovery.dictionary import Term, TermColumns


def _reads(S, whole: np.ndarray) -> None:
    rng = np.random.default_rng(0)
    m, k = whole.shape
    rows = np.sort(rng.choice(m, m // 3, replace=False))
    mask = np.zeros(m, bool)
    mask[rows] = True
    cols = np.array([k - 1, 0, k // 2])
    assert S.shape == whole.shape
    # exact: a row's value must not depend on which other rows are read with it (the search reads folds)
    assert np.array_equal(S[rows], whole[rows])
    assert np.array_equal(S[mask], whole[mask])
    assert np.array_equal(S[5:40], whole[5:40])
    assert np.array_equal(S[7], whole[7])
    assert np.array_equal(S[rows, 1], whole[rows, 1])
    sub = S.columns(cols)
    assert sub.shape == (m, 3)
    assert np.array_equal(sub[rows], whole[rows][:, cols])
    assert np.array_equal(sub.columns([2, 0])[rows], whole[rows][:, cols[[2, 0]]])
    assert np.array_equal(np.asarray(S), whole)


def test_layer_features_are_the_distances_element_by_element():
    """The residual layer's distances element by element (a row's value whatever rows are read with it: a pairwise
    distance routine through a matrix product gave values that depended on the rows read together)."""
    rng = np.random.default_rng(2)
    q = rng.uniform(-2.0, 2.0, (401, 6))
    centres = q[rng.choice(401, 20, replace=False)] + 0.01
    F, d = layer_features(q, centres, 0.5)
    ref = np.linalg.norm(q[:, None, :] - centres[None], axis=2)
    assert np.allclose(d, ref.min(axis=1), rtol=1e-14, atol=0)
    assert np.allclose(F, np.exp(-(ref**2) / 0.5), rtol=1e-12, atol=0)
    F7, d7 = layer_features(q[7:40], centres, 0.5)
    assert np.array_equal(F7, F[7:40]) and np.array_equal(d7, d[7:40])


def test_term_columns_equal_the_dictionary_matrix():
    rng = np.random.default_rng(3)
    q = rng.uniform(-3.0, 3.0, (301, 3))
    terms = [Term((("sin", 1, 2),)), Term((("cos", 3, 1), ("sin", 2, 2))), Term((("cos", 2, 1),))]
    fixed = rng.normal(size=(301, 2))
    whole = np.column_stack([np.sin(2 * q[:, 0]), np.cos(q[:, 2]) * np.sin(2 * q[:, 1]), np.cos(q[:, 1]), fixed])
    _reads(TermColumns(q, terms, fixed), whole)
