"""Atomic output writing: a failed run never leaves a half-written file in place of the last good one.

Files are created with the permissions of an ordinary ``open()`` (``0o666`` less the user's umask), not the
``0o600`` of a temporary file.

Reproducible mode (:func:`reproducible`, which the pipeline runner turns on around a stage): the same
config gives the same bytes. Every JSON written leaves out timings (keys ``time_s``, ``times_s`` and
``*_time_s``: they go to MLflow and the console instead) and writes every float at the precision it deserves
(:func:`tracked_float`): :data:`SIGNIFICANT_DIGITS` significant digits, and for quantities whose noise is absolute
(a length in mm, a p-value's log, a numerical leftover at machine precision) a fixed number of decimals from
:data:`ABSOLUTE_DECIMALS`, so float noise in the last bits (another BLAS kernel, another CPU) does not change a
file tracked by DVC.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import math
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

#: Significant digits of the floats written in reproducible mode unless :data:`PRECISION` says otherwise: the
#: model's own values (parameters, frames) converge to far better than 1e-9 relative, so they keep 9 digits...
SIGNIFICANT_DIGITS = 9
#: ... and no more decimals than this: a value's noise is also absolute (a kinematic error of 8.5e-6 rad came out
#: 8.51680062e-06 vs 8.51680063e-06 under the Sandybridge kernel, 1e-15 rad apart); 1e-12 (rad, mm, deg) is a
#: picometre at a metre's reach. Quantities that are legitimately smaller say so in :data:`PRECISION`.
FLOOR_DECIMALS = 12
#: Precision of the derived statistics whose last digits are noise: key -> ("sig", n) significant digits or
#: ("dec", n) decimals (noise that is absolute, not relative). A pattern ``*suffix`` matches a key's end.
#: Measured between the Haswell and Prescott kernels on the default pipeline (69 numbers of 6 850 differed at 9
#: digits); each rule leaves a margin of >= 30 over the largest difference seen and stays finer than the
#: quantity's own uncertainty:
#: - ``leftover`` (an eliminated parameter's column not explained by the kept ones; 0 in exact arithmetic):
#:   1e-17..4e-15 -> 12 decimals, i.e. written 0.0 when it is noise.
#: - ``log10_p`` up to 8e-6 absolute, ``delta_bic`` 1e-8 -> 2 decimals (p to 2 %; at 3 decimals one of the
#:   ~100 values a run writes fell on a rounding boundary often enough to matter).
#: - ``cv_gain`` (a difference of cross-validated RMS, mm) up to 1.5e-7 mm -> 4 decimals (0.1 µm, far below a
#:   CV gain's own standard error; at 5 decimals a value at -0.009055 flipped between kernels); any other
#:   ``*_mm`` -> 6 decimals (1 nm); ``*_deg`` -> 7 decimals.
#: - ``F``, ``excess_share``, ``p_value`` up to 2e-9 relative -> 6 significant digits; ``stderr`` 1e-9 -> 5
#:   (a standard error is itself known to ~2 digits); correlation ``matrix`` 3.5e-9 -> 6 decimals.
PRECISION: dict[str, tuple[str, int]] = {
    "leftover": ("dec", 12),
    "log10_p": ("dec", 2),
    "delta_bic": ("dec", 2),
    "cv_gain": ("dec", 4),
    "*_mm": ("dec", 6),
    "*_deg": ("dec", 7),
    "F": ("sig", 6),
    "excess_share": ("sig", 6),
    "p_value": ("sig", 6),
    "*p_value_vs_no_drift": ("sig", 6),
    "stderr": ("sig", 5),
    "matrix": ("dec", 6),
    # legitimately tiny: written to their significant digits whatever their size
    "covariance": ("sig", 9),
    "ftol": ("sig", 9),
    "xtol": ("sig", 9),
    "gtol": ("sig", 9),
    "alpha": ("sig", 9),
    "cv_alpha": ("sig", 9),
    "outlier_alpha": ("sig", 9),
    "rank_tol": ("sig", 9),
    "absorbed_tol": ("sig", 9),
    "min_signal_std": ("sig", 9),
}


#: An estimate written with its standard error (a dict of exactly ``value``, ``stderr``, ``unit``: discovery's
#: ``estimates``) keeps its value to the decimal of the standard error's third significant digit: a thermal
#: drift of 0.00101883632 +- 0.0035 mm/degC came out ...632 vs ...633 under the Prescott and Haswell kernels (the
#: 9 significant digits of a poorly determined coefficient are noise), now 0.00102.
ESTIMATE_STDERR_DIGITS = 3


def _estimate(o: dict[str, Any]) -> dict[str, Any]:
    """An estimate dict with its value rounded by its standard error (:data:`ESTIMATE_STDERR_DIGITS`)."""
    v, se = o.get("value"), o.get("stderr")
    if not isinstance(v, float | np.floating) or not isinstance(se, float | np.floating):
        return o
    if not (math.isfinite(float(v)) and math.isfinite(float(se)) and float(se) > 0):
        return o
    n = ESTIMATE_STDERR_DIGITS - 1 - math.floor(math.log10(float(se)))
    return {**o, "value": round(float(v), n) + 0.0}


_REPRODUCIBLE: contextvars.ContextVar[bool] = contextvars.ContextVar("robocal_reproducible", default=False)


@contextlib.contextmanager
def reproducible(on: bool = True) -> Iterator[None]:
    """Within the block, JSON output leaves out timings and rounds floats (see the module docstring)."""
    token = _REPRODUCIBLE.set(on)
    try:
        yield
    finally:
        _REPRODUCIBLE.reset(token)


def is_reproducible() -> bool:
    """True inside :func:`reproducible`: outputs must not carry timings."""
    return _REPRODUCIBLE.get()


def is_timing(key: object) -> bool:
    """A key that holds a measured duration in seconds (``time_s``, ``times_s``, ``wall_time_s``, ...)."""
    k = str(key)
    return k in ("time_s", "times_s") or k.endswith(("_time_s", "_times_s"))


def round_float(value: float, digits: int = SIGNIFICANT_DIGITS) -> float:
    """``value`` rounded to ``digits`` significant digits (non-finite values unchanged)."""
    if not math.isfinite(value) or value == 0.0:
        return value
    return float(f"{value:.{digits}g}")


def _precision(key: object) -> tuple[str, int] | None:
    k = str(key)
    if k in PRECISION:
        return PRECISION[k]
    for pattern, rule in PRECISION.items():
        if pattern.startswith("*") and k.endswith(pattern[1:]):
            return rule
    return None


def tracked_float(value: float, key: object = None) -> float:
    """``value`` as a tracked output writes it under ``key``: by its rule in :data:`PRECISION`, else to
    :data:`SIGNIFICANT_DIGITS` significant digits and at most :data:`FLOOR_DECIMALS` decimals; ``-0.0`` is
    written ``0.0``."""
    if not math.isfinite(value):
        return value
    rule = _precision(key)
    if rule is None:
        return round_float(round(value, FLOOR_DECIMALS)) + 0.0
    kind, n = rule
    return (round(value, n) if kind == "dec" else round_float(value, n)) + 0.0


def display_path(path: str | Path) -> str:
    """``path`` as it is written into outputs and messages: relative to the working directory when it lies under
    it (a pipeline runs at the repository root, so its outputs do not depend on where the checkout is: same
    config, same bytes in any clone), else absolute."""
    p = Path(path)
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except (ValueError, OSError):
        return str(p)


def _umask() -> int:
    """The process umask, read without changing it where Linux allows (os.umask would race threads)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"cannot serialise {type(o).__name__} to JSON")


def atomic_write(path: str | Path, writer: Callable[[Path], object]) -> Path:
    """Call ``writer(tmp_path)`` then rename the temporary file onto ``path`` (same directory, atomic).

    The file gets the permissions a plain ``open(path, "w")`` would give (``0o666`` less the umask), not the
    private ``0o600`` of the temporary file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        writer(tmp_path)
        os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp creates 0o600 whatever the umask
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    return path


def write_text(path: str | Path, text: str) -> Path:
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))


def write_bytes(path: str | Path, data: bytes) -> Path:
    return atomic_write(path, lambda p: p.write_bytes(data))


def to_json(obj: Any) -> str:
    """JSON text with numpy types converted; NaN/inf become null (strict JSON). In reproducible mode
    timings are left out and floats rounded (module docstring)."""
    repro = is_reproducible()

    def clean(o: Any, key: object = None) -> Any:
        if isinstance(o, dict):
            if repro and set(o) == {"value", "stderr", "unit"}:
                o = _estimate(o)
            return {str(k): clean(v, k) for k, v in o.items() if not (repro and is_timing(k))}
        if isinstance(o, list | tuple):
            return [clean(v, key) for v in o]
        if isinstance(o, np.ndarray):
            return clean(o.tolist(), key)
        if isinstance(o, float | np.floating):
            f = float(o)
            if not np.isfinite(f):
                return None
            return tracked_float(f, key) if repro else f
        return o

    return json.dumps(clean(obj), indent=2, sort_keys=False, default=_default) + "\n"


def as_written(obj: Any) -> Any:
    """``obj`` as :func:`write_json` writes it (plain JSON types; in reproducible mode rounded and without
    timings): what a report beside the JSON renders, so both show the same digits on any machine."""
    return json.loads(to_json(obj))


def write_json(path: str | Path, obj: Any) -> Path:
    return write_text(path, to_json(obj))
