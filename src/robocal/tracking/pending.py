"""Pending runs: recorded to disk by a stage (:class:`PendingRun`, no MLflow import) and written to MLflow by
a detached flusher (:func:`flush`).
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from robocal.status import StageStatus
from robocal.tracking.naming import SKIPPED_STATUS, skipped_title
from robocal.tracking.runs import StageRun
from robocal.tracking.store import (
    DEFAULT_EXPERIMENT,
    _client,
    _dir_lock,
    _report,
    ensure_store,
    repo_root,
    retry,
    sqlite_path,
    tracking_uri,
)
from robocal.tracking.values import default_tags, flatten, numeric_metrics, param_key

# ----------------------------------------------------------------------------------------------- pending runs

#: Folder (beside the SQLite store, or in the repository for a tracking server) of runs not yet in MLflow.
PENDING_DIR = "mlflow-pending"
_RECORD = "run.json"


def pending_dir(uri: str | None = None) -> Path:
    """Where :class:`PendingRun` records runs for the store ``uri`` (see :func:`tracking_uri`)."""
    uri = tracking_uri(uri)
    db = sqlite_path(uri)
    return (db.parent if db is not None else repo_root()) / PENDING_DIR


class PendingRun:
    """A run recorded to disk now and written to MLflow by a detached flusher (module docstring).

    Same methods as :class:`StageRun`. Artifacts are copied when logged. If the record cannot be written
    (e.g. the folder cannot be created) the run falls back to a :class:`StageRun`, so nothing is lost silently.
    """

    def __init__(
        self,
        stage: str,
        *,
        enabled: bool = True,
        uri: str | None = None,
        experiment: str = DEFAULT_EXPERIMENT,
        tags: Mapping[str, str] | None = None,
        run_name: str | None = None,
    ) -> None:
        self.stage = stage
        self.enabled = enabled
        self.uri = tracking_uri(uri) if enabled else None
        self.experiment = experiment
        self.run_name = run_name or stage
        self.extra_tags = dict(tags or {})
        self.run_id: str | None = None  # known once written to MLflow
        self.errors: list[str] = []
        self._record: dict[str, Any] = {}
        self._tmp: Path | None = None
        self._fallback: StageRun | None = None
        self._closed = False
        self.end_status = "FINISHED"

    def start(self) -> PendingRun:
        if not self.enabled:
            return self
        assert self.uri is not None
        name = f"{time.strftime('%Y%m%dT%H%M%S')}-{os.getpid()}-{self.stage}"
        try:
            spool = pending_dir(self.uri)
            spool.mkdir(parents=True, exist_ok=True)
            self._tmp = spool / f".{name}.tmp"
            (self._tmp / "artifacts").mkdir(parents=True)
        except OSError:
            self._tmp = None
            self._fallback = StageRun(
                self.stage, uri=self.uri, experiment=self.experiment, tags=self.extra_tags, run_name=self.run_name
            ).start()
            return self
        self._record = {
            "uri": self.uri,
            "experiment": self.experiment,
            "run_name": self.run_name,
            "tags": {**default_tags(self.stage), **self.extra_tags},
            "start_ms": int(time.time() * 1000),
            "params": {},
            "metrics": [],
            "texts": [],
            "artifacts": [],
        }
        return self

    def log_params(self, params: Mapping[str, Any]) -> None:
        if self._fallback is not None:
            return self._fallback.log_params(params)
        if self._tmp is not None:
            self._record["params"].update({k: ("null" if v is None else str(v)) for k, v in flatten(params).items()})

    def log_metrics(self, metrics: Mapping[str, Any], step: int = 0) -> None:
        if self._fallback is not None:
            return self._fallback.log_metrics(metrics, step)
        if self._tmp is not None:
            ts = int(time.time() * 1000)
            self._record["metrics"] += [[k, v, ts, step] for k, v in sorted(numeric_metrics(metrics).items())]

    def set_tags(self, tags: Mapping[str, Any]) -> None:
        if self._fallback is not None:
            return self._fallback.set_tags(tags)
        if self._tmp is not None:
            self._record["tags"].update({str(k): str(v) for k, v in tags.items()})

    def mark_skipped(self, reason: str) -> None:
        """As :meth:`StageRun.mark_skipped`."""
        if self._fallback is not None:
            return self._fallback.mark_skipped(reason)
        self.run_name = skipped_title(self.run_name)
        if self._tmp is not None:
            self._record["run_name"] = self.run_name
        self.set_tags({"robocal.status": StageStatus.SKIPPED, "robocal.skipped": reason[:5000]})
        self.end_status = SKIPPED_STATUS

    def log_text(self, text: str, artifact_file: str) -> None:
        if self._fallback is not None:
            return self._fallback.log_text(text, artifact_file)
        if self._tmp is not None:
            self._record["texts"].append([text, artifact_file])

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        """Copy a file or a directory now (the stage may change it later); missing paths are skipped."""
        if self._fallback is not None:
            return self._fallback.log_artifact(path, artifact_path)
        p = Path(path)
        if self._tmp is None or not p.exists():
            return
        dest = self._tmp / "artifacts" / str(len(self._record["artifacts"])) / p.name
        try:
            if p.is_dir():
                shutil.copytree(p, dest)
            else:
                dest.parent.mkdir(parents=True)
                shutil.copy2(p, dest)
        except OSError as exc:
            self.errors.append(f"copy artifact {p}: {exc}")
            _report(f"copy artifact {p}", exc)
            return
        self._record["artifacts"].append([str(dest.relative_to(self._tmp)), artifact_path, p.is_dir()])

    def close(self, status: str = "FINISHED") -> None:
        """Finish the record, hand it to a detached flusher (started here) and return at once."""
        if self._closed:
            return
        self._closed = True
        if self._fallback is not None:
            self._fallback.close(status)
            return
        if self._tmp is None:
            return
        self._record.update(status=status, end_ms=int(time.time() * 1000))
        try:
            (self._tmp / _RECORD).write_text(json.dumps(self._record), encoding="utf-8")
            os.replace(self._tmp, self._tmp.parent / self._tmp.name[1 : -len(".tmp")])
        except OSError as exc:
            self.errors.append(f"record run: {exc}")
            _report("record run", exc)
            return
        spool = self._tmp.parent
        print(f"robocal tracking: run recorded; written to {self.uri} in the background", file=sys.stderr)
        try:
            with open(spool / "flush.log", "a", encoding="utf-8") as log:
                subprocess.Popen(
                    [sys.executable, "-m", "robocal.tracking", "flush", "--dir", str(spool)],
                    stdin=subprocess.DEVNULL,
                    stdout=log,
                    stderr=log,
                    start_new_session=True,  # not killed with the stage, not waited for by DVC
                    cwd=str(spool),
                )
        except OSError as exc:
            _report("start the flusher (run `python -m robocal.tracking flush`)", exc)

    def __enter__(self) -> PendingRun:
        return self.start()

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self.close(self.end_status if exc_type is None else ("KILLED" if exc_type is KeyboardInterrupt else "FAILED"))


def _write_record(record_dir: Path) -> str:
    """Write one pending run to MLflow; returns its run id. Raises on failure (the record is then kept)."""
    from mlflow.entities import Metric, Param

    rec = json.loads((record_dir / _RECORD).read_text(encoding="utf-8"))
    exp_id = ensure_store(rec["uri"], rec["experiment"])
    client = _client(rec["uri"])
    run = client.create_run(exp_id, start_time=rec["start_ms"], tags=rec["tags"], run_name=rec["run_name"])
    run_id = str(run.info.run_id)
    try:
        params = [Param(param_key(k), v[:6000]) for k, v in sorted(rec["params"].items())]
        for i in range(0, len(params), 100):
            client.log_batch(run_id, params=params[i : i + 100])
        metrics = [Metric(param_key(k), float(v), int(ts), int(step)) for k, v, ts, step in rec["metrics"]]
        for i in range(0, len(metrics), 1000):
            client.log_batch(run_id, metrics=metrics[i : i + 1000])
        for text, name in rec["texts"]:
            client.log_text(run_id, text, name)
        for rel, artifact_path, is_dir in rec["artifacts"]:
            src = record_dir / rel
            if is_dir:
                client.log_artifacts(run_id, str(src), artifact_path)
            else:
                client.log_artifact(run_id, str(src), artifact_path)
        client.set_terminated(run_id, rec["status"], end_time=rec["end_ms"])
    except Exception:
        client.set_terminated(run_id, "FAILED", end_time=rec["end_ms"])
        raise
    return run_id


def flush(directory: str | Path | None = None, uri: str | None = None) -> int:
    """Write every pending run of ``directory`` (default: :func:`pending_dir` of ``uri``) to MLflow, oldest
    first, under a lock (waits for a flusher at work). Returns how many runs it wrote; errors are printed and
    their records kept for the next flush."""
    spool = Path(directory) if directory is not None else pending_dir(uri)
    if not spool.is_dir():
        return 0
    written = 0
    failed: set[str] = set()
    with _dir_lock(spool):
        while True:
            todo = sorted(
                d for d in spool.iterdir() if d.is_dir() and not d.name.startswith(".") and d.name not in failed
            )
            if not todo:
                break
            for rec in todo:
                try:
                    run_id = retry(functools.partial(_write_record, rec))
                except Exception as exc:
                    failed.add(rec.name)
                    _report(f"writing the pending run {rec} to MLflow", exc)
                    continue
                shutil.rmtree(rec, ignore_errors=True)
                written += 1
                print(f"robocal tracking: run {run_id} ({rec.name}) written", file=sys.stderr)
    return written
