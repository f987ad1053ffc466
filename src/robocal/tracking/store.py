"""Where runs go and the store: the tracking URI, the SQLite store created once under a lock, and the
retry of a write that met SQLite contention.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar
from urllib.parse import unquote, urlparse

#: Environment variable carrying the parent run id of a Hydra sweep to its jobs.
PARENT_ENV = "ROBOCAL_MLFLOW_PARENT_RUN_ID"
#: Default experiment name.
DEFAULT_EXPERIMENT = "robocal"
#: Default SQLite file name, in the repository root.
DB_NAME = "mlflow.db"
#: Default artifact directory name, next to the SQLite file.
ARTIFACT_DIR = "mlartifacts"

_REPO_ROOT = Path(__file__).resolve().parents[3]
_ENSURED: dict[tuple[str, str], str] = {}  # (uri, experiment) -> experiment id, per process

T = TypeVar("T")

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


#: The experiment tag that marks the experiment as classic machine learning (model training), not GenAI. MLflow 3's
#: UI (3.17) does not choose its view from it: the view is the sidebar's "workflow type", taken from the URL's
#: ``workflowType`` query, else from the browser's local storage (``mlflow.workflowType``, GenAI until the user
#: switches) -- so the address ``make ui`` prints carries :data:`RUNS_VIEW_QUERY`.
EXPERIMENT_KIND = {"mlflow.experimentKind": "custom_model_development"}


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
