"""Discrete choices that do not depend on the last bits of a float, and column norms without a copy.

Two candidates whose scores are equal in exact arithmetic (symmetric poses, an effect offered twice under two
names) differ in floating point only by rounding noise, which changes with the BLAS kernel and the CPU; a plain
``argmax`` or ``sorted`` then picks one or the other, and a planned pose set or a list of named effects differs
between machines (issue 30 item 4). Here scores within a relative tolerance of each other count as tied, and a
tie goes to the lower index (the input order, which the caller keeps deterministic).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Iterable, Sequence
from typing import TypeVar

import numpy as np

#: Scores closer than this (relative to the largest magnitude among them, and never less than TIE_ATOL) tie.
#: Rounding noise between BLAS kernels was measured at <= 1e-9 relative on the pipeline's fits; two candidates
#: whose true scores differ by less than 1e-8 are equally good for any purpose a calibration has.
TIE_RTOL = 1e-8
#: Absolute floor of the tie tolerance (scores near zero: a gain of 1e-14 and one of 3e-14 are both zero).
TIE_ATOL = 1e-12

T = TypeVar("T")


def _tolerance(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    scale = float(np.max(np.abs(finite))) if finite.size else 0.0
    return max(TIE_RTOL * scale, TIE_ATOL)


def argmax_tied(values: Sequence[float] | np.ndarray) -> int:
    """Index of the largest value; values within the tie tolerance of the largest go to the lowest index."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        raise ValueError("argmax_tied: empty sequence")
    best = float(np.max(v))
    if not np.isfinite(best):
        return int(np.argmax(v))
    return int(np.flatnonzero(v >= best - _tolerance(v))[0])


def sorted_tied(items: Iterable[T], key: Callable[[T], float]) -> list[T]:
    """``items`` sorted by ``key`` ascending, with keys within the tie tolerance of each other kept in input
    order: the keys are snapped to a grid of the tolerance, anchored at the smallest key, before a stable sort.
    Keys differing by less than the tolerance can still fall either side of a grid line, but two keys that are
    equal in exact arithmetic (differing by rounding noise far below the tolerance) almost never do."""
    seq = list(items)
    if not seq:
        return seq
    keys = np.array([key(x) for x in seq], dtype=float)
    finite = np.isfinite(keys)
    tol = _tolerance(keys)
    snapped = keys.copy()
    if finite.any():
        lo = float(np.min(keys[finite]))
        snapped[finite] = np.round((keys[finite] - lo) / tol)
    order = np.argsort(snapped, kind="stable")
    return [seq[i] for i in order]


#: rows per chunk of :func:`column_norms` (bounds its temporary: chunk x k floats)
NORM_CHUNK = 4096


def column_norms(A: np.ndarray, chunk: int = NORM_CHUNK) -> np.ndarray:
    """``np.linalg.norm(A, axis=0)`` of a C-ordered ``(M, k)`` matrix, bit for bit, without its two ``(M, k)``
    temporaries: the squares are summed over row chunks, each chunk's sum continuing from the rows before it (the
    order numpy's reduction over the leading axis of a C-ordered array takes). Another layout: ``np.linalg.norm``."""
    if A.ndim != 2 or not A.flags.c_contiguous or A.shape[0] <= chunk:
        return np.asarray(np.linalg.norm(A, axis=0))
    acc = np.add.reduce(A[:chunk] * A[:chunk], axis=0)
    for c0 in range(chunk, A.shape[0], chunk):
        blk = A[c0 : c0 + chunk]
        acc = np.add.reduce(np.concatenate([acc[None, :], blk * blk]), axis=0)
    return np.asarray(np.sqrt(acc))


#: ``gram(J, r) -> (JᵀJ, Jᵀr)`` (``r`` None: ``Jᵀr`` not formed) of a Jacobian whose owner knows its structure
Gram = Callable[[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray | None]]
_GRAMS: dict[int, tuple[weakref.ref[np.ndarray], Gram]] = {}


def attach_gram(J: np.ndarray, gram: Gram) -> None:
    """Let the solver form the normal equations of the Jacobian ``J`` (this very array, not a copy or a view of
    it) by ``gram(J, r)`` instead of ``JᵀJ`` over its rows: a model whose columns have a product structure (a
    joint-level effect's ``v ⊗ S``) forms them in fewer operations (the same numbers up to rounding). ``gram``
    must not hold ``J`` itself: the entry goes with the array."""
    key = id(J)

    def gone(_: object, key: int = key) -> None:
        _GRAMS.pop(key, None)

    _GRAMS[key] = (weakref.ref(J, gone), gram)


def normal_equations(J: np.ndarray, r: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """``(JᵀJ, Jᵀr)`` of ``J``, by its owner's :func:`attach_gram` when it has one (``Jᵀr`` None without ``r``), or
    by the Jacobian itself when it is held by its factors (a ``normal_equations`` method:
    :class:`robocal.discovery.gram.FactoredJacobian`)."""
    if not isinstance(J, np.ndarray):
        return J.normal_equations(r)
    e = _GRAMS.get(id(J))
    if e is not None and e[0]() is J:
        return e[1](J, r)
    return J.T @ J, (None if r is None else J.T @ r)


def gram_of(J: np.ndarray) -> Gram | None:
    """The gram :func:`attach_gram` gave ``J`` (this very array), or None."""
    e = _GRAMS.get(id(J))
    return e[1] if e is not None and e[0]() is J else None


def has_gram(J: np.ndarray) -> bool:
    return not isinstance(J, np.ndarray) or gram_of(J) is not None


__all__ = [
    "NORM_CHUNK",
    "TIE_ATOL",
    "TIE_RTOL",
    "Gram",
    "argmax_tied",
    "attach_gram",
    "column_norms",
    "gram_of",
    "has_gram",
    "normal_equations",
    "sorted_tied",
]
