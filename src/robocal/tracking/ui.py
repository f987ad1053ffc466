"""``make ui``: MLflow's server over the store, with the runs table's view."""

from __future__ import annotations

import os
import sys

from robocal.tracking.pending import flush
from robocal.tracking.store import _report, artifact_location, ensure_store, tracking_uri
from robocal.tracking.view import headline_metrics, runs_view_url, set_runs_view

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
