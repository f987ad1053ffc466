"""MLflow tracking, in one place. MLflow is imported lazily: ``import robocal`` stays light.

Where runs go (first that applies):

1. ``$MLFLOW_TRACKING_URI`` (e.g. ``http://host:5000`` or ``sqlite:////abs/path/mlflow.db``);
2. the ``uri`` argument (the ``tracking.uri`` config value, when not null);
3. ``sqlite:///<repo>/mlflow.db`` with artifacts in ``<repo>/mlartifacts``; ``<repo>`` is ``$DVC_ROOT``
   when DVC runs the stage (for queued experiments DVC points it at the *parent* repository, so runs made in
   DVC's temporary copies are not lost), else the repository that holds this package.

A SQLite store is created (tables, migrations) once, under a lock, by :func:`ensure_store`, before any
parallel run: a brand-new SQLite file raced by parallel writers fails.

Tracking never costs results. Every MLflow call made through :class:`StageRun` is guarded: if MLflow
errors, the error is printed to stderr (``robocal tracking: ...``), the run is marked broken and the stage
carries on writing its files; ``required=True`` makes :meth:`StageRun.close` raise afterwards, so the stage
fails *after* its outputs are on disk. Nothing here is silent.

Start-up cost. Importing MLflow and opening its SQLite store costs ~2.5 s of CPU, more than most stages compute.
So a pipeline stage records its run with :class:`PendingRun` (no MLflow import): the run (params, metrics,
tags, times, copies of its artifacts) goes to ``<store dir>/mlflow-pending/`` and a detached
``python -m robocal.tracking flush`` writes it to MLflow with its original start and end times, while DVC
goes on with the next stage. Flushers take turns under a lock and one flusher writes every pending run, so
a pipeline pays MLflow's import about once instead of once per stage. ``python -m robocal.tracking flush``
(``make ui`` runs it) waits for the last runs and retries any a flusher could not write; its errors are printed
(a detached flusher's go to ``mlflow-pending/flush.log``). Runs that must be written before the stage ends use
:class:`StageRun` directly: ``tracking.required=true``, Hydra sweeps (nested runs), the optimizer comparison.

Hydra sweeps: :func:`start_sweep` opens a parent run and exports its id in :data:`PARENT_ENV`; every job
(also in joblib worker processes, which inherit the environment) opens its run nested under it.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, TypeVar
from urllib.parse import unquote, urlparse

from robocal.errors import RobocalError
from robocal.status import StageStatus

#: Environment variable carrying the parent run id of a Hydra sweep to its jobs.
PARENT_ENV = "ROBOCAL_MLFLOW_PARENT_RUN_ID"
#: Default experiment name.
DEFAULT_EXPERIMENT = "robocal"
#: Default SQLite file name, in the repository root.
DB_NAME = "mlflow.db"
#: Default artifact directory name, next to the SQLite file.
ARTIFACT_DIR = "mlartifacts"

_REPO_ROOT = Path(__file__).resolve().parents[2]
_ENSURED: dict[tuple[str, str], str] = {}  # (uri, experiment) -> experiment id, per process

T = TypeVar("T")


class TrackingError(RobocalError, RuntimeError):
    """MLflow failed while ``required`` tracking was asked for (raised after the stage's files are written)."""


# ----------------------------------------------------------------------------------------------- where


def repo_root() -> Path:
    """The repository the runs belong to: ``$DVC_ROOT`` when set (DVC stages, queued experiments), else ours."""
    env = os.environ.get("DVC_ROOT")
    return Path(env).resolve() if env else _REPO_ROOT


def tracking_uri(uri: str | None = None) -> str:
    """The tracking URI: ``$MLFLOW_TRACKING_URI``, else ``uri``, else ``sqlite:///<repo>/mlflow.db`` (absolute).

    A relative ``sqlite:///x.db`` is made absolute against the repository root, so queued DVC experiments
    (which run in temporary copies) and Hydra jobs (any working directory) all write to the same file.
    """
    chosen = os.environ.get("MLFLOW_TRACKING_URI") or uri or f"sqlite:///{repo_root() / DB_NAME}"
    if chosen.startswith("sqlite:///") and not chosen.startswith("sqlite:////"):
        rel = chosen[len("sqlite:///") :]
        chosen = f"sqlite:///{(repo_root() / rel).resolve()}"
    elif "://" not in chosen:  # a bare path: a local SQLite file
        chosen = f"sqlite:///{(repo_root() / chosen).resolve()}"
    return chosen


def sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI, else None."""
    if not uri.startswith("sqlite:"):
        return None
    return Path(unquote(urlparse(uri).path))


def artifact_location(uri: str) -> str | None:
    """Artifact root for a new experiment: ``<db dir>/mlartifacts`` for SQLite stores, else the server's choice."""
    db = sqlite_path(uri)
    return (db.parent / ARTIFACT_DIR).resolve().as_uri() if db is not None else None


# ----------------------------------------------------------------------------------------------- store


@contextlib.contextmanager
def _dir_lock(directory: Path) -> Iterator[None]:
    """An exclusive ``flock`` on a directory (no lock file left behind); a no-op where flock is unsupported."""
    fd = None
    try:
        fd = os.open(directory, os.O_RDONLY)
        fcntl.flock(fd, fcntl.LOCK_EX)
    except OSError:
        if fd is not None:
            os.close(fd)
        fd = None
    try:
        yield
    finally:
        if fd is not None:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)


def _client(uri: str) -> Any:
    from mlflow.tracking import MlflowClient

    return MlflowClient(tracking_uri=uri)


def ensure_store(uri: str | None = None, experiment: str = DEFAULT_EXPERIMENT) -> str:
    """Create the store (SQLite tables and migrations) and the experiment once; return the experiment id.

    Safe to call from several processes at once: SQLite stores are created under a lock on their directory.
    Call it in the parent process before starting parallel jobs. The experiment is tagged
    :data:`EXPERIMENT_KIND` (also an existing one that is not), so the UI opens it on its runs table.
    """
    uri = tracking_uri(uri)
    key = (uri, experiment)
    if key in _ENSURED:
        return _ENSURED[key]
    db = sqlite_path(uri)
    lock: contextlib.AbstractContextManager[None] = contextlib.nullcontext()
    if db is not None:
        db.parent.mkdir(parents=True, exist_ok=True)
        lock = _dir_lock(db.parent)
    with lock:
        client = _client(uri)
        exp = client.get_experiment_by_name(experiment)  # creates / migrates the SQLite tables on first use
        if exp is not None:
            exp_id = str(exp.experiment_id)
            for k, v in EXPERIMENT_KIND.items():
                if exp.tags.get(k) != v:
                    client.set_experiment_tag(exp_id, k, v)
        else:
            exp_id = str(
                client.create_experiment(experiment, artifact_location=artifact_location(uri), tags=EXPERIMENT_KIND)
            )
    _ENSURED[key] = exp_id
    return exp_id


# ----------------------------------------------------------------------------------------------- values


def flatten(mapping: Mapping[str, Any], prefix: str = "", sep: str = ".") -> dict[str, Any]:
    """Nested mappings to ``{"a.b.c": value}``; lists of scalars become their string form, lists holding
    mappings are left out (too wide for a parameter table: log the whole config as an artifact instead)."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{sep}{key}" if prefix else str(key)
        if isinstance(value, Mapping):
            out.update(flatten(value, name, sep))
        elif isinstance(value, list | tuple):
            if not any(isinstance(v, Mapping | list | tuple) for v in value):
                out[name] = str(list(value))
        else:
            out[name] = value
    return out


_KEY_OK = re.compile(r"[^A-Za-z0-9_\-. :/]")


def param_key(key: str) -> str:
    """``key`` in MLflow's name charset (alphanumerics, ``_ - . space : /``): others become ``_``, ``^`` as in
    ``T_j6_C^2`` becomes ``_pow`` (so the logged key still reads as the power it is)."""
    return _KEY_OK.sub("_", key.replace("^", "_pow"))


def numeric_metrics(mapping: Mapping[str, Any]) -> dict[str, float]:
    """The numeric leaves of a (nested) mapping, flattened; bools count as 0/1, non-finite values are dropped."""
    out: dict[str, float] = {}
    for key, value in flatten(mapping).items():
        if isinstance(value, bool):
            out[key] = float(value)
        elif isinstance(value, int | float) and math.isfinite(float(value)):
            out[key] = float(value)
        elif hasattr(value, "item") and isinstance(value.item(), int | float):  # numpy scalars
            f = float(value.item())
            if math.isfinite(f):
                out[key] = f
    return out


def git_commit(cwd: Path | None = None) -> str | None:
    """The current git commit of the repository, or None (no git, no commit yet)."""
    try:
        res = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=cwd or repo_root(),
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    sha = res.stdout.strip()
    return sha if res.returncode == 0 and len(sha) == 40 else None


def default_tags(stage: str) -> dict[str, str]:
    """Tags every run gets: stage name, DVC experiment / stage when DVC runs it, git commit when there is one."""
    tags = {"robocal.stage": stage}
    for env, tag in (("DVC_EXP_NAME", "dvc.exp_name"), ("DVC_STAGE", "dvc.stage"), ("DVC_ROOT", "dvc.root")):
        if os.environ.get(env):
            tags[tag] = os.environ[env]
    sha = git_commit()
    if sha:
        tags["mlflow.source.git.commit"] = sha
    return tags


#: what joins the parts of a run's name: ``<stage> · <campaign> · <experiment>``
NAME_SEP = " · "
#: The MLflow run status of a skipped stage: FINISHED -- the stage ended as it should, having nothing to do (KILLED
#: showed a red cross, as if it had failed). What says "skipped" is the run's name, ``<stage> (skipped) · ...``, and
#: its tags: ``robocal.status = skipped`` (a column of the runs table :func:`set_runs_view` opens) and
#: ``robocal.skipped = <reason>``.
SKIPPED_STATUS = "FINISHED"
#: The experiment tag that marks the experiment as classic machine learning (model training), not GenAI. MLflow 3's
#: UI (3.17) does not choose its view from it: the view is the sidebar's "workflow type", taken from the URL's
#: ``workflowType`` query, else from the browser's local storage (``mlflow.workflowType``, GenAI until the user
#: switches) -- so the address ``make ui`` prints carries :data:`RUNS_VIEW_QUERY`.
EXPERIMENT_KIND = {"mlflow.experimentKind": "custom_model_development"}
RUNS_VIEW_QUERY = "?workflowType=machine_learning"
#: The runs table's view (columns, widths, order) is an MLflow "shared view": an experiment tag
#: ``mlflow.sharedViewState.<key>`` holding the view's JSON, opened by the URL query ``viewStateShareKey=<key>``.
VIEW_TAG_PREFIX = "mlflow.sharedViewState."
VIEW_KEY = "robocal-runs"
#: the run-name column's width (px): ``geometric_fit (skipped) · abb-irb120 · workspace`` in full
RUN_NAME_WIDTH_PX = 380
RUN_NAME_COLUMN = "attributes.`Run Name`"


def campaign_label(campaign: str | None, scenario: str | None = None) -> str:
    """How a run names its campaign: the folder's name (``abb-irb120`` for ``../shared/data/abb-irb120``), or
    ``twin <scenario>`` for the twin's default campaign (``data/raw/default``)."""
    if not campaign:
        return f"twin {scenario}" if scenario else "no campaign"
    name = Path(str(campaign).rstrip("/")).name or str(campaign)
    if Path(str(campaign)).as_posix().rstrip("/").endswith("data/raw/default") and scenario:
        return f"twin {scenario}"
    return name


def run_title(stage: str, campaign: str, experiment: str | None = None) -> str:
    """``<stage> · <campaign> · <experiment>``: the DVC experiment (``$DVC_EXP_NAME``) when DVC runs one, else
    ``experiment`` (e.g. a Hydra job's overrides), else ``workspace`` (a plain ``dvc repro``)."""
    exp = os.environ.get("DVC_EXP_NAME") or experiment or "workspace"
    return NAME_SEP.join((stage, campaign, exp))


def skipped_title(name: str) -> str:
    """``compliance_fit · twin thermal · workspace`` -> ``compliance_fit (skipped) · twin thermal · workspace``."""
    stage, sep, rest = name.partition(NAME_SEP)
    return name if stage.endswith("(skipped)") else f"{stage} (skipped){sep}{rest}"


def runs_view_url(experiment_id: str, base: str = "http://127.0.0.1:5000", view: bool = False) -> str:
    """The MLflow UI's runs table of an experiment (what ``make ui`` prints); with ``view``, in the columns
    :func:`set_runs_view` stored."""
    share = f"&viewStateShareKey={VIEW_KEY}" if view else ""
    return f"{base.rstrip('/')}/#/experiments/{experiment_id}/runs{RUNS_VIEW_QUERY}{share}"


def headline_metrics(root: Path | None = None) -> list[str]:
    """The stages' headline metrics: the numeric keys of ``reports/metrics/*.json`` (what ``dvc exp show``
    shows), in the files' order; the stages log them to MLflow under the same names."""
    keys: list[str] = []
    for f in sorted((root or repo_root()).glob("reports/metrics/*.json")):
        try:
            data = json.loads(f.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(data, dict):
            keys += [param_key(k) for k in numeric_metrics(data) if param_key(k) not in keys]
    return keys


def runs_view_state(metrics: list[str]) -> dict[str, Any]:
    """The runs table's view: the run name wide enough to read, the status tag and the headline ``metrics`` as
    columns, newest first (MLflow's view-state keys; columns named ``metrics.`key```, ``tags.`key```)."""
    columns = ["tags.`robocal.status`", *[f"metrics.`{m}`" for m in metrics]]
    return {
        "orderByKey": "attributes.start_time",
        "orderByAsc": False,
        "selectedColumns": columns,
        # the UI applies widths to the columns of columnOrder only
        "columnOrder": [RUN_NAME_COLUMN, *columns],
        "columnWidths": {RUN_NAME_COLUMN: RUN_NAME_WIDTH_PX},
        "runsHiddenMode": "SHOW_ALL",
    }


def set_runs_view(experiment_id: str, metrics: list[str], uri: str | None = None) -> None:
    """Store :func:`runs_view_state` as the experiment's shared view :data:`VIEW_KEY`."""
    state = json.dumps(runs_view_state(metrics), sort_keys=True)
    _client(tracking_uri(uri)).set_experiment_tag(experiment_id, VIEW_TAG_PREFIX + VIEW_KEY, state)


def _report(what: str, exc: BaseException) -> None:
    print(f"robocal tracking: {what} failed: {type(exc).__name__}: {exc}", file=sys.stderr)
    if os.environ.get("ROBOCAL_DEBUG"):
        traceback.print_exc()


def retry(fn: Callable[[], T], attempts: int = 4, delay_s: float = 0.25) -> T:
    """Retry transient SQLite contention ("database is locked") from parallel writers."""
    for k in range(attempts):
        try:
            return fn()
        except Exception as exc:
            if k == attempts - 1 or "locked" not in str(exc).lower():
                raise
            time.sleep(delay_s * (2**k))
    raise AssertionError("unreachable")  # pragma: no cover


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


#: How ``make ui`` runs MLflow's server: one web worker (one person looks at the runs; MLflow's default of 4 each
#: import MLflow) and no job runner (MLflow 3's GenAI jobs: a runner and seven huey consumers, each importing
#: MLflow again; robocal starts no job). Measured on the 2-core machine under load: the runs table answered after
#: 138 s with 15 processes and 30 CPU-s, and after 43 s with 2 processes and 10 CPU-s.
UI_ENV = {"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
UI_WORKERS = 1


def ui_command(host: str, port: int, uri: str | None = None) -> list[str]:
    """The ``mlflow ui`` command ``make ui`` runs over the store ``uri`` (see :data:`UI_ENV`)."""
    uri = tracking_uri(uri)
    cmd = [sys.executable, "-m", "mlflow", "ui", "--backend-store-uri", uri, "--host", host, "--port", str(port)]
    art = artifact_location(uri)
    if art is not None:
        cmd += ["--default-artifact-root", art]
    return [*cmd, "--workers", str(UI_WORKERS)]


def serve_ui(host: str, port: int, uri: str | None = None) -> int:
    """``make ui``: write the pending runs, store the runs table's view, print its address, then become the MLflow
    server (one MLflow import before the server's own)."""
    n = flush(uri=uri)
    exp_id = ensure_store(uri)
    try:
        set_runs_view(exp_id, headline_metrics(), uri)
        view = True
    except Exception as exc:  # the UI still serves; the table opens in MLflow's default columns
        _report("storing the runs table's view", exc)
        view = False
    print(f"robocal tracking: {n} pending run(s) written")
    print(f"open the runs table: {runs_view_url(exp_id, f'http://{host}:{port}', view)}", flush=True)
    os.environ.update(UI_ENV)
    cmd = ui_command(host, port, uri)
    os.execv(cmd[0], cmd)
    return 0  # pragma: no cover (execv does not return)


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m robocal.tracking", description="MLflow runs of robocal")
    sub = parser.add_subparsers(dest="action", required=True)
    f = sub.add_parser("flush", help="write the pending runs (mlflow-pending/) to MLflow; waits for a flusher at work")
    f.add_argument("--dir", default=None, help="the pending-runs folder (default: the one of the tracking store)")
    u = sub.add_parser("ui-url", help="print the MLflow UI's address of the runs table (what `make ui` opens)")
    u.add_argument("--port", type=int, default=5000)
    s = sub.add_parser("ui", help="flush, store the runs table's view, print its address and serve the MLflow UI")
    s.add_argument("--port", type=int, default=5000)
    s.add_argument("--host", default="127.0.0.1")
    args = parser.parse_args(argv)
    if args.action == "ui-url":
        exp_id = ensure_store()
        set_runs_view(exp_id, headline_metrics())
        print(runs_view_url(exp_id, f"http://127.0.0.1:{args.port}", view=True))
        return 0
    if args.action == "ui":
        return serve_ui(args.host, args.port)
    n = flush(args.dir)
    left = [d for d in (Path(args.dir) if args.dir else pending_dir()).glob("*") if d.is_dir()]
    print(f"robocal tracking: {n} pending run(s) written" + (f"; {len(left)} could not be" if left else ""))
    return 1 if left else 0


if __name__ == "__main__":
    sys.exit(main())
