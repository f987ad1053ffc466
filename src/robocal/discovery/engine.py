"""Where discovery's per-candidate work runs: in this process (``local``) or as Ray tasks (``ray``), issue 31
item 4.

The cross-validated selection and the residual layer score every candidate of a step against the same fold
sums (:class:`robocal.discovery.cv.FoldCV`); with the Ray engine the fold sums are put in Ray's object store
once per step and each candidate is one task (one CPU) that returns its variants' per-pose held-out sums of
squares. The driver then decides exactly as the local engine does, from the same numbers (each task runs the
same code on the same inputs), so the result is the same. The engine is chosen by :func:`use` (``robocal
discover --engine ray``), not by the discovery settings: it changes where the work runs, never what is found.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from robocal.errors import ConfigError

#: a candidate's work: ("joint", blocks) or ("dense", Z), with its variants (see FoldCV)
Job = tuple[str, Any, Sequence[Any]]

_STATE: dict[str, Any] = {"engine": "local"}


@contextlib.contextmanager
def use(engine: str = "local", workers: int | None = None, address: str | None = None) -> Iterator[None]:
    """Within the block, discovery's per-candidate work runs on ``engine``: ``local`` or ``ray`` (a local Ray
    instance of ``workers`` CPUs, default all, or the cluster at ``address``; shut down after the block when
    it was started here)."""
    if engine not in ("local", "ray"):
        raise ConfigError(f"The 'engine' setting must be 'local' or 'ray'. Got {engine!r} instead.")
    started = False
    if engine == "ray":
        import os

        import ray

        from robocal.parallel import start_ray

        started = not ray.is_initialized()
        start_ray(int(workers or os.cpu_count() or 1), address)
    prev = dict(_STATE)
    _STATE["engine"] = engine
    try:
        yield
    finally:
        _STATE.clear()
        _STATE.update(prev)
        if started:
            import ray

            ray.shutdown()


def current() -> str:
    return str(_STATE["engine"])


def _group_sse(cv: Any, kind: str, payload: Any, variants: Sequence[Any]) -> list[np.ndarray]:
    """The per-pose held-out sums of squares of each variant of one candidate."""
    errs = cv.with_joint_variants(payload, variants) if kind == "joint" else cv.with_variants(payload, variants)
    return [cv.group_sse(e) for e in errs]


def group_sse(cv: Any, jobs: Sequence[Callable[[], Job]], tick: Callable[[int], None] | None = None) -> list[
    list[np.ndarray]
]:  # fmt: skip
    """Every candidate's variants scored against ``cv``: per job (a function giving the candidate's work when
    called: the local engine calls it just before scoring, so one dense regressor is held at a time), the
    per-pose held-out sums of squares of each variant."""
    if current() == "local" or len(jobs) < 2:
        out = []
        for i, job in enumerate(jobs):
            if tick is not None:
                tick(i)
            out.append(_group_sse(cv, *job()))
        return out
    import ray

    ref = ray.put(cv)
    task = ray.remote(num_cpus=1, max_retries=1)(_group_sse)
    pending = [task.remote(ref, *job()) for job in jobs]
    return list(ray.get(pending))


__all__ = ["Job", "current", "group_sse", "use"]
