"""Report plots: plain arrays in, a matplotlib Figure out.

Every function validates its inputs first (``ValueError`` naming the argument and the expected shape)
and builds a fresh :class:`matplotlib.figure.Figure` under one house style. Figures are not registered
with pyplot, so nothing needs closing; :meth:`robocal.report.html.Report.figure` embeds them and
:func:`save_figure` writes them to PNG or SVG atomically. The backend is Agg (no display needed).
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping, Sequence
from functools import wraps
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from robocal.io import write_bytes
from robocal.metrics import ErrorStats

__all__ = [
    "AFTER_COLOR",
    "BEFORE_COLOR",
    "STYLE",
    "bar_table",
    "convergence",
    "error_histogram",
    "error_per_pose",
    "parameter_errors",
    "residuals_vs_joints",
    "save_figure",
    "styled",
    "time_series",
]

BEFORE_COLOR = "#c44e52"
AFTER_COLOR = "#4c72b0"
_XYZ_COLORS = ("#d62728", "#2ca02c", "#1f77b4")
#: the house style of every report figure (matplotlib rc parameters; :func:`styled` applies it)
STYLE: dict[Any, Any] = {
    "font.size": 10.0,  # figures are shown at ~700-1000 px wide in the reports: 9 pt and below read poorly
    "axes.titlesize": 11.0,
    "axes.labelsize": 10.0,
    "axes.grid": True,
    "grid.color": "#dddddd",
    "grid.linewidth": 0.6,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.axisbelow": True,
    "legend.fontsize": 9.0,
    "legend.frameon": False,
    "xtick.labelsize": 9.0,
    "ytick.labelsize": 9.0,
    "lines.linewidth": 1.4,
}
_MAX_LABELLED = 60  # above this many rows, per-row tick labels are left out

P = ParamSpec("P")
R = TypeVar("R")


def styled(func: Callable[P, R]) -> Callable[P, R]:
    """Run ``func`` under the house style (artists take their style when created)."""

    @wraps(func)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with plt.rc_context(STYLE):
            return func(*args, **kwargs)

    return wrapper


# ---------------------------------------------------------------------------- validation helpers


def _fail(func: str, name: str, expected: str, got: str) -> ValueError:
    return ValueError(f"The '{name}' parameter of {func} must be {expected}. Got {got} instead.")


def _array(x: Any, func: str, name: str) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise _fail(func, name, "an array of numbers", f"{type(x).__name__}") from None
    return arr


def _errors(x: Any, func: str, name: str) -> np.ndarray:
    """An error magnitude per row: shape (m,) as is, or the Euclidean norm of each row of (m, 3)."""
    arr = _array(x, func, name)
    if arr.ndim == 2 and arr.shape[1] == 3:
        arr = np.linalg.norm(arr, axis=1)
    if arr.ndim != 1 or arr.size == 0:
        raise _fail(func, name, "a non-empty array of shape (m,) or (m, 3)", f"shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise _fail(func, name, "finite", f"{int(np.sum(~np.isfinite(arr)))} non-finite values")
    return arr


def _vector(x: Any, func: str, name: str, n: int | None = None, allow_nan: bool = False) -> np.ndarray:
    arr = _array(x, func, name)
    if arr.ndim != 1 or arr.size == 0 or (n is not None and arr.shape[0] != n):
        want = f"shape ({n},)" if n is not None else "a non-empty 1-D array"
        raise _fail(func, name, want, f"shape {arr.shape}")
    bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
    if np.any(bad):
        raise _fail(func, name, "finite", f"{int(np.sum(bad))} non-finite values")
    return arr


def _labels(labels: Any, n: int, func: str, name: str = "labels") -> list[str]:
    if isinstance(labels, str) or not isinstance(labels, Sequence | np.ndarray):
        raise _fail(func, name, f"a sequence of {n} labels", type(labels).__name__)
    out = [str(s) for s in labels]
    if len(out) != n:
        raise _fail(func, name, f"a sequence of {n} labels", f"{len(out)} labels")
    return out


def _stats(e: np.ndarray) -> str:
    st = ErrorStats.of(e)
    return f"mean {st.mean_mm:.3g}, RMS {st.rms_mm:.3g}, max {st.max_mm:.3g}"


# ---------------------------------------------------------------------------- plots


@styled
def error_per_pose(
    before_mm: Any,
    after_mm: Any,
    labels: Sequence[str] | None = None,
    ylabel: str = "3-D position error (mm)",
) -> Figure:
    """Error of each row before and after calibration, side by side.

    Parameters
    ----------
    before_mm, after_mm : array_like, shape (m,) or (m, 3)
        Error magnitudes in mm, or error vectors whose Euclidean norm is taken.
    labels : sequence of str, shape (m,), optional
        Row labels (e.g. ``"c07/T1"``), shown on the x axis when there are at most 60 rows.
    ylabel : str
    """
    func = "error_per_pose"
    before = _errors(before_mm, func, "before_mm")
    after = _errors(after_mm, func, "after_mm")
    m = before.shape[0]
    if after.shape[0] != m:
        raise _fail(func, "after_mm", f"of the same length as before_mm ({m})", f"length {after.shape[0]}")
    names = _labels(labels, m, func) if labels is not None else None
    # wide enough for labelled bars, but not so wide that the page shrinks the text (points above 60 rows)
    fig = Figure(
        figsize=(min(max(6.5, 0.16 * m + 2.0), 11.0) if m <= _MAX_LABELLED else 9.0, 3.8), layout="constrained"
    )
    ax = fig.add_subplot()
    x = np.arange(m)
    if m <= _MAX_LABELLED:
        w = 0.4
        ax.bar(x - w / 2, before, w, color=BEFORE_COLOR, label=f"before ({_stats(before)})")
        ax.bar(x + w / 2, after, w, color=AFTER_COLOR, label=f"after ({_stats(after)})")
    else:
        ax.plot(x, before, "o", ms=3, color=BEFORE_COLOR, label=f"before ({_stats(before)})")
        ax.plot(x, after, "o", ms=3, color=AFTER_COLOR, label=f"after ({_stats(after)})")
    ax.axhline(before.mean(), color=BEFORE_COLOR, ls="--", lw=0.9)
    ax.axhline(after.mean(), color=AFTER_COLOR, ls="--", lw=0.9)
    if names is not None and m <= _MAX_LABELLED:
        ax.set_xticks(x, names, rotation=90, fontsize=7 if m > 25 else 8)
    else:
        ax.set_xlabel("row (in campaign order)")
    ax.set_xlim(-0.7, m - 0.3)
    ax.set_ylim(bottom=0)
    ax.set_ylabel(ylabel)
    fig.legend(loc="outside upper center", ncols=2)  # outside the data
    return fig


@styled
def error_histogram(before_mm: Any, after_mm: Any, bins: int = 20, xlabel: str = "3-D position error (mm)") -> Figure:
    """Histograms of the errors before and after calibration, one panel each (their scales differ).

    Parameters
    ----------
    before_mm : array_like, shape (m,) or (m, 3)
    after_mm : array_like, shape (k,) or (k, 3)
        Error magnitudes in mm (or vectors, normed per row); ``k`` may differ from ``m``.
    bins : int
    """
    func = "error_histogram"
    before = _errors(before_mm, func, "before_mm")
    after = _errors(after_mm, func, "after_mm")
    if not isinstance(bins, int | np.integer) or bins < 1:
        raise _fail(func, "bins", "a positive int", repr(bins))
    fig = Figure(figsize=(9.0, 3.4), layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, e, color, title in ((axes[0], before, BEFORE_COLOR, "before"), (axes[1], after, AFTER_COLOR, "after")):
        ax.hist(e, bins=int(bins), color=color, alpha=0.85, edgecolor="white", linewidth=0.5)
        st = ErrorStats.of(e)
        ax.axvline(st.mean_mm, color="k", ls="--", lw=1.0, label=f"mean {st.mean_mm:.3g}")
        ax.axvline(st.rms_mm, color="k", ls=":", lw=1.0, label=f"RMS {st.rms_mm:.3g}")
        ax.set_title(f"{title}: n = {st.n}, max {st.max_mm:.3g}")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("count")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.legend(loc="upper right")
    return fig


@styled
def residuals_vs_joints(q_rad: Any, residual_mm: Any, joint_names: Sequence[str] | None = None) -> Figure:
    """Residuals against each joint angle, one panel per joint (look for trends: unmodelled effects).

    Parameters
    ----------
    q_rad : array_like, shape (m, n)
        Joint angles in rad (shown in degrees).
    residual_mm : array_like, shape (m, 3) or (m,)
        Residual vectors (x, y, z components plotted) or scalar residuals, mm.
    joint_names : sequence of str, shape (n,), optional
    """
    func = "residuals_vs_joints"
    q = _array(q_rad, func, "q_rad")
    if q.ndim != 2 or q.shape[0] == 0 or q.shape[1] == 0:
        raise _fail(func, "q_rad", "a non-empty array of shape (m, n)", f"shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise _fail(func, "q_rad", "finite", f"{int(np.sum(~np.isfinite(q)))} non-finite values")
    m, n = q.shape
    r = _array(residual_mm, func, "residual_mm")
    if not ((r.ndim == 1 and r.shape[0] == m) or (r.ndim == 2 and r.shape == (m, 3))):
        raise _fail(func, "residual_mm", f"of shape ({m}, 3) or ({m},) to match q_rad", f"shape {r.shape}")
    if not np.all(np.isfinite(r)):
        raise _fail(func, "residual_mm", "finite", f"{int(np.sum(~np.isfinite(r)))} non-finite values")
    names = _labels(joint_names, n, func, "joint_names") if joint_names is not None else [f"q{j + 1}" for j in range(n)]
    ncols = min(n, 3)
    nrows = -(-n // ncols)
    fig = Figure(figsize=(3.4 * ncols, 2.6 * nrows + 0.4), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols, sharey=True, squeeze=False)).ravel()
    qd = np.rad2deg(q)
    ms = 3.0 if m <= 300 else 1.5
    for j in range(n):
        ax: Axes = axes[j]
        if r.ndim == 2:
            for c, (comp, color) in enumerate(zip("xyz", _XYZ_COLORS, strict=True)):
                ax.plot(qd[:, j], r[:, c], "o", ms=ms, alpha=0.7, color=color, label=comp if j == 0 else None)
        else:
            ax.plot(qd[:, j], r, "o", ms=ms, alpha=0.7, color=AFTER_COLOR)
        ax.axhline(0.0, color="k", lw=0.7)
        ax.set_xlabel(f"{names[j]} angle (deg)")
        if j % ncols == 0:
            ax.set_ylabel("residual (mm)")
    for ax in axes[n:]:
        ax.set_visible(False)
    if r.ndim == 2:
        fig.legend(loc="outside upper right", ncols=3, markerscale=2.0)
    return fig


def _runs(value: Any, func: str, key: str) -> list[np.ndarray]:
    """One method's histories as a list of 1-D runs."""
    name = f"histories[{key!r}]"
    if isinstance(value, np.ndarray):
        value = [value] if value.ndim == 1 else list(value)
    if isinstance(value, str) or not isinstance(value, Sequence | np.ndarray) or len(value) == 0:
        raise _fail(func, name, "a non-empty list of numbers or a list of runs", type(value).__name__)
    nested = all(isinstance(v, Sequence | np.ndarray) and not isinstance(v, str) for v in value)
    runs_in = list(value) if nested else [value]
    runs = []
    for i, run in enumerate(runs_in):
        arr = _array(run, func, name)
        if arr.ndim != 1 or arr.size == 0:
            raise _fail(func, name, "runs that are non-empty 1-D lists of numbers", f"run {i} of shape {arr.shape}")
        if np.any(np.isnan(arr)) or np.any(np.isneginf(arr)):
            raise _fail(func, name, "free of NaN and -inf", f"run {i} with such values")
        runs.append(arr)
    return runs


@styled
def convergence(
    histories: Mapping[str, Any],
    xlabel: str = "iteration",
    ylabel: str = "objective",
) -> Figure:
    """Convergence curves on a log y axis.

    Parameters
    ----------
    histories : mapping of str to list of float or list of lists of float
        Per method, one run (values per iteration, shape (k,)) or several runs (possibly of different
        lengths). With several runs each is drawn thin and the median over runs (a run that stopped early
        keeps its last value) thick. Values must be positive to appear on the log axis.
    """
    func = "convergence"
    if not isinstance(histories, Mapping) or len(histories) == 0:
        raise _fail(func, "histories", "a non-empty mapping of name to list", type(histories).__name__)
    data = {str(k): _runs(v, func, str(k)) for k, v in histories.items()}
    fig = Figure(figsize=(6.8, 3.8), layout="constrained")
    ax = fig.add_subplot()
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (name, runs) in enumerate(data.items()):
        color = colors[i % len(colors)]
        if len(runs) == 1:
            ax.plot(np.arange(runs[0].size), runs[0], color=color, label=name)
            continue
        k = max(r.size for r in runs)
        padded = np.array([np.pad(r, (0, k - r.size), mode="edge") for r in runs])
        for r in runs:
            ax.plot(np.arange(r.size), r, color=color, lw=0.6, alpha=0.35)
        ax.plot(np.arange(k), np.median(padded, axis=0), color=color, lw=2.0, label=f"{name} (median of {len(runs)})")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, which="minor", color="#eeeeee", lw=0.4)
    fig.legend(loc="outside upper center", ncols=3)  # outside the data
    return fig


@styled
def time_series(t_min: Any, series: Mapping[str, Any], ylabel: str, xlabel: str = "time (min)") -> Figure:
    """Several signals against time on one axis (e.g. temperatures or drift).

    Parameters
    ----------
    t_min : array_like, shape (k,)
        Time in minutes.
    series : mapping of str to array_like of shape (k,)
        NaN marks a missing sample (a gap in the line).
    ylabel : str
    """
    func = "time_series"
    t = _vector(t_min, func, "t_min")
    if not isinstance(series, Mapping) or len(series) == 0:
        raise _fail(func, "series", "a non-empty mapping of name to array", type(series).__name__)
    data = {str(k): _vector(v, func, f"series[{str(k)!r}]", n=t.size, allow_nan=True) for k, v in series.items()}
    fig = Figure(figsize=(7.5, 3.6), layout="constrained")
    ax = fig.add_subplot()
    marker = "o" if t.size <= 40 else None
    for name, y in data.items():
        ax.plot(t, y, marker=marker, ms=3, label=name)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if len(data) > 1 or next(iter(data)):
        fig.legend(loc="outside upper center", ncols=min(len(data), 5))  # outside the data
    return fig


@styled
def bar_table(
    labels: Sequence[str], values: Mapping[str, Any], ylabel: str, annotate: bool = True, fmt: str = "{:.3g}"
) -> Figure:
    """Grouped bars: one group per label, one bar per series (e.g. mean / max error per method).

    Parameters
    ----------
    labels : sequence of str, shape (g,)
        Group names on the x axis.
    values : mapping of str to array_like of shape (g,)
        One series per key (its legend entry).
    ylabel : str
    annotate : bool
        Print each bar's value above it with ``fmt``.
    """
    func = "bar_table"
    if isinstance(labels, str) or not isinstance(labels, Sequence | np.ndarray) or len(labels) == 0:
        raise _fail(func, "labels", "a non-empty sequence of str", type(labels).__name__)
    names = [str(s) for s in labels]
    g = len(names)
    if not isinstance(values, Mapping) or len(values) == 0:
        raise _fail(func, "values", "a non-empty mapping of name to list", type(values).__name__)
    data = {str(k): _vector(v, func, f"values[{str(k)!r}]", n=g) for k, v in values.items()}
    s = len(data)
    fig = Figure(figsize=(min(max(5.5, 0.5 * g * s + 2.0), 14.0), 3.8), layout="constrained")
    ax = fig.add_subplot()
    x = np.arange(g)
    w = 0.8 / s
    for i, (name, y) in enumerate(data.items()):
        bars = ax.bar(x + (i - (s - 1) / 2) * w, y, w, label=name)
        if annotate:
            ax.bar_label(bars, labels=[fmt.format(v) for v in y], fontsize=7, padding=1.5)
    tilt = max(len(n) for n in names) * g >= 80
    ax.set_xticks(x, names, rotation=30 if tilt else 0, ha="right" if tilt else "center")
    ax.set_ylabel(ylabel)
    ax.axhline(0.0, color="k", lw=0.7)
    ax.grid(False, axis="x")
    if s > 1:
        fig.legend(loc="outside upper center", ncols=3)  # outside the data
    return fig


@styled
def parameter_errors(
    names: Sequence[str], estimate: Any, stderr: Any, truth: Any = None, xlabel: str = "value", k: float = 1.0
) -> Figure:
    """Estimated parameters with ``k`` standard errors as error bars, and the truth when known (simulation).

    Parameters
    ----------
    names : sequence of str, shape (p,)
        Parameter names, one row each (top to bottom in the given order).
    estimate : array_like, shape (p,)
    stderr : array_like, shape (p,)
        Non-negative; NaN where unknown (no bar drawn, hollow marker).
    truth : array_like, shape (p,), optional
    k : float
        Error bar half-width in standard errors.
    """
    func = "parameter_errors"
    if isinstance(names, str) or not isinstance(names, Sequence | np.ndarray) or len(names) == 0:
        raise _fail(func, "names", "a non-empty sequence of str", type(names).__name__)
    labels = [str(s) for s in names]
    p = len(labels)
    est = _vector(estimate, func, "estimate", n=p)
    se = _vector(stderr, func, "stderr", n=p, allow_nan=True)
    if np.any(se[~np.isnan(se)] < 0):
        raise _fail(func, "stderr", "non-negative (or NaN)", "negative values")
    tru = _vector(truth, func, "truth", n=p) if truth is not None else None
    if not (np.isfinite(k) and k > 0):
        raise _fail(func, "k", "a positive number", repr(k))
    fig = Figure(figsize=(7.0, min(max(2.2, 0.28 * p + 1.2), 14.0)), layout="constrained")
    ax = fig.add_subplot()
    y = np.arange(p)[::-1]
    known = ~np.isnan(se)
    ax.errorbar(
        est[known],
        y[known],
        xerr=k * se[known],
        fmt="o",
        ms=4,
        color=AFTER_COLOR,
        ecolor=AFTER_COLOR,
        capsize=3,
        label=f"estimate ± {k:g} std. error",
    )
    if np.any(~known):
        ax.plot(est[~known], y[~known], "o", ms=4, mfc="none", color=AFTER_COLOR, label="estimate (no std. error)")
    if tru is not None:
        ax.plot(tru, y, "x", ms=6, mew=1.6, color=BEFORE_COLOR, label="truth")
    ax.axvline(0.0, color="k", lw=0.7)
    ax.set_yticks(y, labels)
    ax.set_ylim(-0.7, p - 0.3)
    ax.set_xlabel(xlabel)
    ax.grid(False, axis="y")
    fig.legend(loc="outside upper center", ncols=3)  # outside the data
    return fig


# ---------------------------------------------------------------------------- output


def save_figure(fig: Figure, path: str | Path, dpi: int = 150) -> Path:
    """Write ``fig`` to ``path`` atomically, PNG or SVG by the suffix (``.png`` / ``.svg``); returns the path.

    Metadata that changes from run to run (creation date, software version) is left out and SVG ids are
    salted with a constant, so the same figure built again gives the same file (useful under DVC).
    """
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in ("png", "svg"):
        raise ValueError(f"The 'path' parameter of save_figure must end in .png or .svg. Got {str(path)!r} instead.")
    if not hasattr(fig, "savefig"):
        raise ValueError(f"The 'fig' parameter of save_figure must be a matplotlib Figure. Got {type(fig).__name__}.")
    buf = io.BytesIO()
    meta: dict[str, Any] = {"Software": None} if fmt == "png" else {"Date": None, "Creator": None}
    with plt.rc_context({"svg.hashsalt": "robocal"}):  # stable SVG element ids
        fig.savefig(buf, format=fmt, dpi=dpi, metadata=meta)
    return write_bytes(path, buf.getvalue())


@styled
def term_before_after(term: Any, before: Any, after: Any, xlabel: str, ylabel: str) -> Figure:
    """A residual against a proposed term's value, before and after the term is in the model (two panels).

    term, before, after : array_like, shape (m,)
    """
    func = "term_before_after"
    x = _vector(term, func, "term")
    b = _vector(before, func, "before", n=x.size)
    a = _vector(after, func, "after", n=x.size)
    fig = Figure(figsize=(9.0, 3.4), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    for ax, y, title, color in ((axes[0], b, "before", "C3"), (axes[1], a, "after", "C0")):
        ax.scatter(x, y, s=9, color=color, alpha=0.8)
        if x.size > 2 and np.ptp(x) > 0:
            k = np.polyfit(x, y, 1)
            xs = np.linspace(x.min(), x.max(), 2)
            ax.plot(xs, np.polyval(k, xs), color="k", lw=1, label=f"slope {k[0]:.3g}")
            ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.22), frameon=False)
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_title(title)
        ax.set_xlabel(xlabel)
    axes[0].set_ylabel(ylabel)
    return fig
