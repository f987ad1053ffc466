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

The modules: ``store`` (where runs go, the store, retry), ``values`` (what a run logs), ``naming`` (run names),
``view`` (the UI's runs table), ``runs`` (:class:`StageRun`, sweeps), ``pending`` (:class:`PendingRun`,
:func:`flush`), ``ui`` (``make ui``), ``command`` (``python -m robocal.tracking``). Every name is importable from
``robocal.tracking``.
"""

from robocal.tracking.command import main
from robocal.tracking.naming import NAME_SEP, SKIPPED_STATUS, campaign_label, run_title, skipped_title
from robocal.tracking.pending import PENDING_DIR, PendingRun, flush, pending_dir
from robocal.tracking.runs import StageRun, TrackingError, end_sweep, start_sweep
from robocal.tracking.store import (
    ARTIFACT_DIR,
    DB_NAME,
    DEFAULT_EXPERIMENT,
    EXPERIMENT_KIND,
    PARENT_ENV,
    artifact_location,
    ensure_store,
    repo_root,
    retry,
    sqlite_path,
    tracking_uri,
)
from robocal.tracking.ui import UI_ENV, UI_WORKERS, serve_ui, ui_command
from robocal.tracking.values import default_tags, flatten, git_commit, numeric_metrics, param_key
from robocal.tracking.view import (
    RUN_NAME_COLUMN,
    RUN_NAME_WIDTH_PX,
    RUNS_VIEW_QUERY,
    VIEW_KEY,
    VIEW_TAG_PREFIX,
    headline_metrics,
    runs_view_state,
    runs_view_url,
    set_runs_view,
)

__all__ = [
    "ARTIFACT_DIR",
    "DB_NAME",
    "DEFAULT_EXPERIMENT",
    "EXPERIMENT_KIND",
    "NAME_SEP",
    "PARENT_ENV",
    "PENDING_DIR",
    "RUNS_VIEW_QUERY",
    "RUN_NAME_COLUMN",
    "RUN_NAME_WIDTH_PX",
    "SKIPPED_STATUS",
    "UI_ENV",
    "UI_WORKERS",
    "VIEW_KEY",
    "VIEW_TAG_PREFIX",
    "PendingRun",
    "StageRun",
    "TrackingError",
    "artifact_location",
    "campaign_label",
    "default_tags",
    "end_sweep",
    "ensure_store",
    "flatten",
    "flush",
    "git_commit",
    "headline_metrics",
    "main",
    "numeric_metrics",
    "param_key",
    "pending_dir",
    "repo_root",
    "retry",
    "run_title",
    "runs_view_state",
    "runs_view_url",
    "serve_ui",
    "set_runs_view",
    "skipped_title",
    "sqlite_path",
    "start_sweep",
    "tracking_uri",
    "ui_command",
]
