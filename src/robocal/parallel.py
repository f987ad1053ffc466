"""The Ray engine, started once for whatever runs on it: a fleet's campaigns (:mod:`robocal.fleet.engine`) and a
large discovery's candidate scoring (:mod:`robocal.discovery.engine`). Ray itself schedules; nothing here does."""

from __future__ import annotations

import os

from robocal.errors import ConfigError

__all__ = ["ray_available", "start_ray"]


def ray_available() -> tuple[bool, str]:
    """(True, "") when Ray can be imported, else (False, why)."""
    try:
        import ray  # noqa: F401
    except Exception as exc:  # ImportError, or a broken install
        return False, f"ray cannot be imported ({type(exc).__name__}: {exc}); pip install 'robocal[fleet]'"
    return True, ""


def start_ray(workers: int, address: str | None = None) -> None:
    """Start a local Ray instance with ``workers`` CPUs (no dashboard), or connect to ``address``."""
    ok, why = ray_available()
    if not ok:
        raise ConfigError(why)
    import ray

    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if ray.is_initialized():
        return
    env = {
        "env_vars": {v: os.environ.get(v, "1") for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    }
    if address:
        ray.init(address=address, runtime_env=env, log_to_driver=False, configure_logging=False)
    else:
        ray.init(
            num_cpus=int(workers),
            include_dashboard=False,
            runtime_env=env,
            log_to_driver=False,
            configure_logging=False,
        )
