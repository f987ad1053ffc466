"""Atomic output writing: a failed run never leaves a half-written file in place of the last good one.

Files are created with the permissions of an ordinary ``open()`` (``0o666`` less the user's umask), not the
``0o600`` of a temporary file.

Reproducible mode (:func:`reproducible`, which the pipeline runner turns on around a stage): the same
config gives the same bytes. Every JSON written leaves out timings (keys ``time_s``, ``times_s`` and
``*_time_s``: they go to MLflow and the console instead) and rounds floats to :data:`SIGNIFICANT_DIGITS`
significant digits, so float noise in the last bits does not change a file tracked by DVC.
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

#: Significant digits of the floats written in reproducible mode (float noise sits near the 15th).
SIGNIFICANT_DIGITS = 9
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

    def clean(o: Any) -> Any:
        if isinstance(o, dict):
            return {str(k): clean(v) for k, v in o.items() if not (repro and is_timing(k))}
        if isinstance(o, list | tuple):
            return [clean(v) for v in o]
        if isinstance(o, np.ndarray):
            return clean(o.tolist())
        if isinstance(o, float | np.floating):
            f = float(o)
            if not np.isfinite(f):
                return None
            return round_float(f) if repro else f
        return o

    return json.dumps(clean(obj), indent=2, sort_keys=False, default=_default) + "\n"


def write_json(path: str | Path, obj: Any) -> Path:
    return write_text(path, to_json(obj))
