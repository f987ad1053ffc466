"""A stage's MLflow run, every call guarded (:class:`StageRun`), and the parent run of a Hydra sweep."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from robocal.errors import RobocalError
from robocal.status import StageStatus
from robocal.tracking.naming import SKIPPED_STATUS, skipped_title
from robocal.tracking.store import DEFAULT_EXPERIMENT, PARENT_ENV, _client, _report, ensure_store, retry, tracking_uri
from robocal.tracking.values import default_tags, flatten, numeric_metrics, param_key


class TrackingError(RobocalError, RuntimeError):
    """MLflow failed while ``required`` tracking was asked for (raised after the stage's files are written)."""


# ----------------------------------------------------------------------------------------------- runs


class StageRun:
    """One MLflow run of one stage (or one sweep job), every call guarded.

    Parameters
    ----------
    stage : str
        Stage name; the run name and the ``robocal.stage`` tag.
    enabled : bool
        False: every method is a no-op (``tracking.enabled: false``).
    uri : str, optional
        Tracking URI (see :func:`tracking_uri`).
    experiment : str
    parent_run_id : str, optional
        Nest under this run; default ``$ROBOCAL_MLFLOW_PARENT_RUN_ID`` (set by :func:`start_sweep`).
    tags : mapping, optional
        Extra tags.
    required : bool
        Raise :class:`TrackingError` from :meth:`close` when any MLflow call failed.
    """

    def __init__(
        self,
        stage: str,
        *,
        enabled: bool = True,
        uri: str | None = None,
        experiment: str = DEFAULT_EXPERIMENT,
        parent_run_id: str | None = None,
        tags: Mapping[str, str] | None = None,
        run_name: str | None = None,
        required: bool = False,
        quiet: bool = False,
    ) -> None:
        self.stage = stage
        self.enabled = enabled
        self.quiet = quiet  # no "run <id>" line (many nested runs under a progress bar)
        self.uri = tracking_uri(uri) if enabled else None
        self.experiment = experiment
        self.parent_run_id = parent_run_id or os.environ.get(PARENT_ENV) or None
        self.extra_tags = dict(tags or {})
        self.run_name = run_name or stage
        self.required = required
        self.run_id: str | None = None
        self.errors: list[str] = []
        self._client: Any = None
        self._closed = False
        self.end_status = "FINISHED"  # how a run that raised nothing ends (see mark_skipped)

    # -- guarded call
    def _call(self, what: str, fn: Callable[[], Any]) -> Any:
        if not self.enabled or (self.run_id is None and what != "start run"):
            return None
        try:
            return retry(fn)
        except Exception as exc:
            self.errors.append(f"{what}: {type(exc).__name__}: {exc}")
            _report(what, exc)
            return None

    def start(self) -> StageRun:
        """Create the store if needed and open the run (status RUNNING)."""

        def go() -> str:
            assert self.uri is not None
            exp_id = ensure_store(self.uri, self.experiment)
            self._client = _client(self.uri)
            tags = {**default_tags(self.stage), **self.extra_tags}
            if self.parent_run_id:
                tags["mlflow.parentRunId"] = self.parent_run_id
            run = self._client.create_run(exp_id, tags=tags, run_name=self.run_name)
            return str(run.info.run_id)

        self.run_id = self._call("start run", go)
        if self.run_id and not self.quiet:
            print(f"robocal tracking: run {self.run_id} ({self.run_name}) in {self.uri}", file=sys.stderr)
        return self

    def log_params(self, params: Mapping[str, Any]) -> None:
        """Log a (nested) mapping as flattened parameters (values cut to MLflow's length limit; keys with
        characters MLflow refuses, e.g. ``T_j6_C^2``, get them replaced: :func:`param_key`)."""
        from_flat = {param_key(k): ("null" if v is None else str(v)) for k, v in flatten(params).items()}

        def go() -> None:
            from mlflow.entities import Param

            items = [Param(k, v[:6000]) for k, v in sorted(from_flat.items())]
            for i in range(0, len(items), 100):
                self._client.log_batch(self.run_id, params=items[i : i + 100])

        self._call("log params", go)

    def log_metrics(self, metrics: Mapping[str, Any], step: int = 0) -> None:
        """Log the numeric leaves of a (nested) mapping as metrics."""
        values = {param_key(k): v for k, v in numeric_metrics(metrics).items()}

        def go() -> None:
            from mlflow.entities import Metric

            ts = int(time.time() * 1000)
            items = [Metric(k, v, ts, step) for k, v in sorted(values.items())]
            for i in range(0, len(items), 1000):
                self._client.log_batch(self.run_id, metrics=items[i : i + 1000])

        self._call("log metrics", go)

    def set_tags(self, tags: Mapping[str, Any]) -> None:
        def go() -> None:
            from mlflow.entities import RunTag

            self._client.log_batch(self.run_id, tags=[RunTag(str(k), str(v)) for k, v in tags.items()])

        self._call("set tags", go)

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        """Log a file or a directory (recursively) as artifacts; missing paths are skipped."""
        p = Path(path)
        if not p.exists():
            return
        if p.is_dir():
            self._call("log artifacts", lambda: self._client.log_artifacts(self.run_id, str(p), artifact_path))
        else:
            self._call("log artifact", lambda: self._client.log_artifact(self.run_id, str(p), artifact_path))

    def log_text(self, text: str, artifact_file: str) -> None:
        """Log ``text`` as the artifact file ``artifact_file`` (e.g. the stage's parameters as YAML)."""
        self._call("log text", lambda: self._client.log_text(self.run_id, text, artifact_file))

    def mark_skipped(self, reason: str) -> None:
        """The stage had nothing to do: tag it (``robocal.status``, ``robocal.skipped``) and end it as
        :data:`SKIPPED_STATUS`, so it does not look like a computed success."""
        self.run_name = skipped_title(self.run_name)
        tags = {
            "robocal.status": StageStatus.SKIPPED,
            "robocal.skipped": reason[:5000],
            "mlflow.runName": self.run_name,
        }
        self.set_tags(tags)
        self.end_status = SKIPPED_STATUS

    def close(self, status: str = "FINISHED") -> None:
        """End the run with ``status`` (FINISHED, FAILED, KILLED); raise if ``required`` and MLflow failed."""
        if self._closed:
            return
        self._closed = True
        self._call("end run", lambda: self._client.set_terminated(self.run_id, status))
        if self.required and self.enabled and (self.errors or self.run_id is None):
            raise TrackingError("MLflow tracking was required but failed: " + "; ".join(self.errors or ["no run"]))

    def __enter__(self) -> StageRun:
        return self.start()

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close(self.end_status)
        else:
            with contextlib.suppress(TrackingError):  # the stage's own error wins
                self.close("KILLED" if exc_type is KeyboardInterrupt else "FAILED")


# ----------------------------------------------------------------------------------------------- sweeps


def start_sweep(
    stage: str,
    overrides: list[str],
    *,
    enabled: bool = True,
    uri: str | None = None,
    experiment: str = DEFAULT_EXPERIMENT,
) -> StageRun:
    """Open the parent run of a Hydra sweep and export its id (:data:`PARENT_ENV`) for the jobs.

    Also creates the store first, so parallel jobs (joblib launcher) never race on a new SQLite file.
    """
    os.environ.pop(PARENT_ENV, None)  # a sweep is never nested in a stale parent
    parent = StageRun(
        stage,
        enabled=enabled,
        uri=uri,
        experiment=experiment,
        parent_run_id=None,
        tags={"robocal.sweep": "parent", "hydra.overrides": " ".join(overrides)},
        run_name=f"{stage} sweep",
    )
    parent.start()
    if parent.run_id:
        os.environ[PARENT_ENV] = parent.run_id
    return parent


def end_sweep(parent: StageRun, status: str = "FINISHED") -> None:
    """Close the parent run of a sweep and stop exporting its id."""
    os.environ.pop(PARENT_ENV, None)
    parent.close(status)
