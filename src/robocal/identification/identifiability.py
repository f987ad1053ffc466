"""Which parameters the measurements can identify, and what absorbs the others.

The Jacobian columns are scaled to unit norm (so mm and rad compare), the numerical rank is read
from the singular values, and columns are kept in a priority order (frames and tools first, then the
joint-level parameters base to flange): a column is kept when the part of it that the columns before
it cannot explain is larger than ``rtol`` of its norm. This is a QR factorisation (against the kept
columns only) whose pivot order is fixed by physical preference instead of column norms; the rank it
finds equals the SVD rank unless parameters are nearly (not exactly) redundant, which the report then says.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from robocal.errors import ConfigError
from robocal.numerics import column_norms


@dataclass(frozen=True)
class Eliminated:
    """A parameter left at its nominal value because others absorb its effect.

    ``absorbed_by`` lists ``(name, coefficient)``: the column is (nearly) ``sum coefficient * column(name)``
    in physical units, i.e. an error of 1 unit in this parameter looks like ``coefficient`` units of each.
    ``leftover`` is the relative norm of the part no kept column explains (0 = exactly redundant).
    """

    name: str
    absorbed_by: tuple[tuple[str, float], ...]
    leftover: float
    reason: str

    def combination(self) -> str:
        """The parameters that absorb this one, as a signed sum: ``0.5·d2 − 35·tool_T1_y`` (no ``+ +35``)."""
        out = ""
        for k, (n, c) in enumerate(self.absorbed_by):
            mag = f"{abs(c):.3g}·{n}"
            if k == 0:
                out = f"−{mag}" if c < 0 else mag
            else:
                out += f" − {mag}" if c < 0 else f" + {mag}"
        return out

    def describe(self) -> str:
        if not self.absorbed_by:
            return f"{self.name}: {self.reason}"
        return f"{self.name} with {self.combination()} ({self.reason})"

    def to_dict(self) -> dict[str, object]:
        return {
            "name": self.name,
            "absorbed_by": [{"name": n, "coefficient": c} for n, c in self.absorbed_by],
            "leftover": self.leftover,
            "reason": self.reason,
            "text": self.describe(),
        }


@dataclass(frozen=True)
class Identifiability:
    """Result of :func:`analyse`.

    kept : ndarray of int
        Column indices identified, in the priority order.
    eliminated : tuple of Eliminated
    rank : int
        Numerical rank of the candidate columns from the SVD.
    singular_values : ndarray
        Of the unit-column-scaled candidate Jacobian.
    """

    kept: np.ndarray
    eliminated: tuple[Eliminated, ...]
    rank: int
    singular_values: np.ndarray
    names: tuple[str, ...] = field(default_factory=tuple)

    @property
    def condition_number(self) -> float:
        s = self.singular_values[: self.rank]
        return float(s[0] / s[-1]) if len(s) else float("inf")


def analyse(
    J: np.ndarray,
    names: tuple[str, ...] | list[str],
    candidates: np.ndarray | list[int],
    rtol: float = 1e-6,
    max_absorbers: int = 4,
) -> Identifiability:
    """Identify the parameters among ``candidates`` (column indices, in priority order).

    Parameters
    ----------
    J : ndarray, shape (M, n)
        Jacobian of the (whitened) residuals w.r.t. all parameters.
    names : sequence of str, length n
    candidates : sequence of int
        Columns that may be fitted, most preferred first.
    rtol : float
        A column is kept when its part orthogonal to the kept columns exceeds ``rtol`` times its norm.
    """
    names = tuple(names)
    cand = np.asarray(candidates, dtype=int)
    Jc = J[:, cand]  # a copy (fancy index), normalised in place: one (M, k) matrix, not three
    norms = column_norms(Jc)
    Jc /= np.where(norms > 0, norms, 1.0)
    # QR in the priority order, against the kept columns only: left[k] is the norm of the part of column k
    # that the kept columns before it cannot explain. (One Householder QR over all candidates would let each
    # dropped column use up a dimension of R, so later columns would be judged against a wrong span, and
    # with fewer residuals than candidates nothing after the M-th candidate could be kept.) The rows are
    # first reduced by one QR (an orthogonal change of coordinates: distances and singular values are kept);
    # then [kept, pending] is factorised again after each dropped column: |R_jj| holds up to the next drop.
    A: np.ndarray = np.linalg.qr(Jc, mode="r")  # type: ignore[assignment]
    del Jc  # not held beside the kept columns' copy below
    left_all = np.zeros(len(cand))
    kept_pos: list[int] = []
    pending = [k for k in range(len(cand)) if norms[k] > 0.0]
    while pending:
        block = kept_pos + pending
        Rb: np.ndarray = np.linalg.qr(A[:, block], mode="r")  # type: ignore[assignment]
        d = np.zeros(len(block))
        diag = np.abs(np.diag(Rb))
        d[: len(diag)] = diag  # beyond the row count nothing is left to explain
        d = d[len(kept_pos) :]
        left_all[pending] = d
        drop = np.flatnonzero(d <= rtol)
        stop = int(drop[0]) if drop.size else len(pending)
        kept_pos += pending[:stop]
        pending = pending[stop + 1 :]
    for k in _ill_conditioned(A, kept_pos, rtol):  # the greedy pass keeps each column by its own share only
        left_all[k] = min(left_all[k], rtol)  # not kept: "not identifiable with these poses"
    kept: list[int] = []
    weak: list[tuple[int, float, str]] = []
    for k, c in enumerate(cand):
        left = float(left_all[k])
        if norms[k] == 0.0:
            weak.append((c, 1.0, "has no effect on the measurements"))
        elif left > rtol:
            kept.append(c)
        else:
            weak.append((c, left, "redundant" if left < 1e-9 else "not identifiable with these poses"))
    sv = np.linalg.svd(A, compute_uv=False)  # those of Jc
    rank = int(np.sum(sv > rtol * sv[0])) if len(sv) else 0

    eliminated = []
    Jk = J[:, kept]
    absorbed = [c for c, _, reason in weak if not reason.startswith("has no")]
    betas = np.linalg.lstsq(Jk, J[:, absorbed], rcond=None)[0] if absorbed and kept else None
    kn = column_norms(Jk)
    for c, left, reason in weak:
        if reason.startswith("has no") or betas is None:
            eliminated.append(Eliminated(names[c], (), left, reason))
            continue
        beta = betas[:, absorbed.index(c)]
        contrib = np.abs(beta) * kn
        order = np.argsort(-contrib)
        top = [i for i in order[:max_absorbers] if contrib[i] > 0.1 * contrib[order[0]]]
        eliminated.append(
            Eliminated(names[c], tuple((names[kept[i]], float(beta[i])) for i in top), float(left), reason)
        )
    return Identifiability(
        kept=np.array(kept, dtype=int),
        eliminated=tuple(eliminated),
        rank=rank,
        singular_values=sv,
        names=names,
    )


def _ill_conditioned(A: np.ndarray, kept_pos: list[int], rtol: float) -> list[int]:
    """Kept columns (positions in ``kept_pos``' order, by priority) to drop until the kept set's smallest singular
    value (its columns normalised: ``A``'s are) is above ``rtol`` of its largest: each round drops, of the columns
    that make up the weakest direction (its right singular vector's entries within a tenth of the largest), the
    one of lowest priority. Each column's own share left by the ones before it (the greedy pass) above ``rtol``
    does not make the set well conditioned: a URDF written from a calibration (axes 1e-3 rad off parallel) kept
    34 columns whose smallest singular value was 1e-16 of the largest, and the fit stopped at its start."""
    keep = list(kept_pos)
    dropped: list[int] = []
    while len(keep) > 1:
        _, sv, Vt = np.linalg.svd(A[:, keep], full_matrices=False)
        if sv[-1] > rtol * sv[0]:
            break
        v = np.abs(Vt[-1])
        worst = max(i for i in range(len(keep)) if v[i] >= 0.1 * v.max())  # the lowest priority among them
        dropped.append(keep.pop(worst))
    return dropped


def resolve_fixed(names: Sequence[str], patterns: Sequence[str], setting: str) -> set[str]:
    """The parameter names the shell-style ``patterns`` of the setting ``setting`` (e.g. ``calibration.fixed``)
    hold at their start (``theta*``, ``a2``); a pattern that matches no name of ``names`` is a :class:`ConfigError`
    naming the setting and the pattern. The one resolution (:attr:`ParameterSpec.fixed` for calibrate and plan)."""
    out: set[str] = set()
    for p in patterns:
        hits = fnmatch.filter(names, p)
        if not hits:
            raise ConfigError(f"The '{setting}' setting names {p!r}, which matches no parameter of {tuple(names)}")
        out.update(hits)
    return out


#: The order the rank analysis keeps parameters in, by kind (:func:`analyse`): frames, tools, then the joint-level
#: parameters base -> flange; a kind in no group is never a candidate.
PRIORITY: tuple[tuple[str, ...], ...] = (("base",), ("tool", "tool_rot"), ("kinematic",))


def keep_order(
    kinds: Sequence[str],
    names: Sequence[str],
    fixed: set[str] | frozenset[str],
    priority: tuple[tuple[str, ...], ...] = PRIORITY,
) -> list[int]:
    """Priority order for keeping parameters in the rank analysis: the kinds of each group of ``priority`` in
    turn (:data:`PRIORITY`: base frames, tools, then joint-level parameters base -> flange), each in index
    order; ``fixed`` names left out (:meth:`ParameterSpec.keep_order`)."""
    order = [i for group in priority for i, k in enumerate(kinds) if k in group]
    return [i for i in order if names[i] not in fixed]


def _frozen_vector(value: Any, name: str, n: int) -> np.ndarray | None:
    if value is None:
        return None
    arr = np.array(value, dtype=float)
    if arr.shape != (n,):
        raise ConfigError(f"The {name!r} parameter of ParameterSpec must have shape ({n},). Got {arr.shape} instead.")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class ParameterSpec:
    """Which parameters a fit has and how it treats each, as one value (calibrate, plan, discovery).

    names, kinds, units : one each per parameter (kinds as :attr:`robocal.identification.model.CalibrationModel.
    kinds`: ``base``, ``tool``, ``tool_rot``, ``kinematic``, or a kind of the caller's, e.g. the plan's ``axis``);
    fixed_patterns : shell patterns (``beta*``) of the setting ``setting`` (``calibration.fixed``) held at their
    start, resolved once here: a pattern that matches no name is a :class:`ConfigError` naming the setting;
    held : names the fit holds itself (the poorly determined ones); priority : the kind groups in the order the
    rank analysis keeps parameters (:data:`PRIORITY`); lower, upper, scale : per-parameter bounds and typical
    magnitudes when a search has them (:meth:`around`), else None.
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    units: tuple[str, ...] = ()
    fixed_patterns: tuple[str, ...] = ()
    setting: str = "fixed"
    held: frozenset[str] = frozenset()
    priority: tuple[tuple[str, ...], ...] = PRIORITY
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    scale: np.ndarray | None = None
    fixed: frozenset[str] = field(init=False)

    def __post_init__(self) -> None:
        put = object.__setattr__  # frozen: normalise once, here
        put(self, "names", tuple(self.names))
        put(self, "kinds", tuple(self.kinds))
        put(self, "units", tuple(self.units))
        put(self, "fixed_patterns", tuple(self.fixed_patterns))
        put(self, "held", frozenset(self.held))
        put(self, "priority", tuple(tuple(g) for g in self.priority))
        n = len(self.names)
        if len(self.kinds) != n or (self.units and len(self.units) != n):
            raise ConfigError(
                f"ParameterSpec needs one kind (and unit) per name: {n} names, {len(self.kinds)} kinds, "
                f"{len(self.units)} units"
            )
        unknown = sorted(self.held - set(self.names))
        if unknown:
            raise ConfigError(f"ParameterSpec holds {unknown}, which are not parameters of {self.names}")
        for name in ("lower", "upper", "scale"):
            put(self, name, _frozen_vector(getattr(self, name), name, n))
        fixed = resolve_fixed(self.names, self.fixed_patterns, self.setting) | self.held
        put(self, "fixed", frozenset(fixed))

    @classmethod
    def of(cls, model: Any, fixed_patterns: Sequence[str] = (), setting: str = "fixed") -> ParameterSpec:
        """The parameters of a model (anything with ``names``, ``kinds`` and ``units``: a
        :class:`~robocal.identification.model.CalibrationModel`)."""
        return cls(tuple(model.names), tuple(model.kinds), tuple(model.units), tuple(fixed_patterns), setting)

    @property
    def n(self) -> int:
        return len(self.names)

    def holding(self, names: Sequence[str]) -> ParameterSpec:
        """The same parameters with ``names`` held too."""
        return replace(self, held=self.held | frozenset(names))

    def keep_order(self) -> list[int]:
        """The candidates of the rank analysis in the order it keeps them (:attr:`priority`), fixed ones out."""
        return keep_order(self.kinds, self.names, self.fixed, self.priority)

    def indices(self, kinds: Sequence[str]) -> np.ndarray:
        """The parameters of the given kinds that are not fixed, in index order."""
        return np.array(
            [i for i, k in enumerate(self.kinds) if k in kinds and self.names[i] not in self.fixed], dtype=int
        )

    def around(self, x: np.ndarray, half_mm: float, half_rad: float) -> ParameterSpec:
        """Bounds ``x ± half`` (``half_mm`` for lengths, ``half_rad`` for angles) with the half-widths as scale."""
        if len(self.units) != self.n:
            raise ConfigError("ParameterSpec.around needs the parameters' units")
        half = np.array([half_mm if u == "mm" else half_rad for u in self.units])
        x = np.asarray(x, dtype=float)
        return replace(self, lower=x - half, upper=x + half, scale=half)
