"""The MLflow UI's runs table: its address and the shared view (columns, widths, order) ``make ui`` opens."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from robocal.tracking.store import _client, repo_root, tracking_uri
from robocal.tracking.values import numeric_metrics, param_key

RUNS_VIEW_QUERY = "?workflowType=machine_learning"
#: The runs table's view (columns, widths, order) is an MLflow "shared view": an experiment tag
#: ``mlflow.sharedViewState.<key>`` holding the view's JSON, opened by the URL query ``viewStateShareKey=<key>``.
VIEW_TAG_PREFIX = "mlflow.sharedViewState."
VIEW_KEY = "robocal-runs"
#: the run-name column's width (px): ``geometric_fit (skipped) · abb-irb120 · workspace`` in full
RUN_NAME_WIDTH_PX = 380
RUN_NAME_COLUMN = "attributes.`Run Name`"


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
