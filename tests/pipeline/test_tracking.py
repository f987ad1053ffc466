"""robocal.tracking: where runs go, what is logged, and that MLflow trouble never costs a stage its results."""

from __future__ import annotations

import json
import multiprocessing as mp
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from robocal import tracking

REPO = Path(__file__).resolve().parents[2]


def test_import_robocal_does_not_import_mlflow() -> None:
    code = "import sys, robocal, robocal.tracking, robocal.pipeline; print('mlflow' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_uri_default_env_and_relative(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.delenv("DVC_ROOT", raising=False)
    assert tracking.tracking_uri() == f"sqlite:///{REPO / 'mlflow.db'}"
    # DVC sets DVC_ROOT to the parent repository for queued experiments: runs must land there
    monkeypatch.setenv("DVC_ROOT", str(tmp_path))
    assert tracking.tracking_uri() == f"sqlite:///{tmp_path / 'mlflow.db'}"
    assert tracking.tracking_uri("sqlite:///sub/x.db") == f"sqlite:///{tmp_path / 'sub' / 'x.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "http://127.0.0.1:5999")
    assert tracking.tracking_uri("sqlite:///ignored.db") == "http://127.0.0.1:5999"
    assert tracking.artifact_location(f"sqlite:///{tmp_path}/m.db") == (tmp_path / "mlartifacts").as_uri()


def test_flatten_and_numeric_metrics() -> None:
    cfg = {"a": {"b": 1, "c": [1, 2]}, "joints": [{"x": 1}], "s": "t", "n": None}
    assert tracking.flatten(cfg) == {"a.b": 1, "a.c": "[1, 2]", "s": "t", "n": None}
    m = tracking.numeric_metrics({"fit": {"rms_mm": 0.1, "ok": True, "name": "x", "bad": float("nan")}, "k": 3})
    assert m == {"fit.rms_mm": 0.1, "fit.ok": 1.0, "k": 3.0}


def _ensure(uri: str) -> str:
    return tracking.ensure_store(uri, "robocal")


@pytest.mark.e2e  # four processes racing on a new store (13 s): make e2e (CI), outside make test's 5 minutes
def test_a_new_sqlite_store_survives_parallel_first_use(tmp_path: Path) -> None:
    # a brand-new SQLite file raced by parallel writers fails without the lock in ensure_store
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    with mp.get_context("spawn").Pool(3) as pool:
        ids = pool.map(_ensure, [uri] * 3)
    assert len(set(ids)) == 1
    with sqlite3.connect(tmp_path / "mlflow.db") as con:
        assert con.execute("select count(*) from experiments where name = 'robocal'").fetchone()[0] == 1


def test_run_logs_params_metrics_artifacts_and_nests(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.setenv("DVC_EXP_NAME", "exp-1")
    (tmp_path / "report.html").write_text("<html></html>")
    parent = tracking.start_sweep("fit", ["x=1,2"])
    with tracking.StageRun("fit") as run:
        run.log_params({"optimizer": {"name": "lm", "max_iter": 100}})
        run.log_metrics({"fit": {"rms_position_mm": 0.02}, "status": "ok"})
        run.log_artifact(tmp_path / "report.html")
    tracking.end_sweep(parent)
    client = MlflowClient(uri)
    child = client.get_run(run.run_id)
    assert child.data.params["optimizer.max_iter"] == "100"
    assert child.data.metrics == {"fit.rms_position_mm": 0.02}
    assert child.data.tags["mlflow.parentRunId"] == parent.run_id
    assert child.data.tags["dvc.exp_name"] == "exp-1"
    assert child.data.tags["robocal.stage"] == "fit"
    assert child.info.status == "FINISHED"
    assert [a.path for a in client.list_artifacts(run.run_id)] == ["report.html"]
    assert client.get_run(parent.run_id).info.status == "FINISHED"


def test_mlflow_errors_are_printed_not_fatal(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    run = tracking.StageRun("fit", uri=f"sqlite:///{blocker}/sub/mlflow.db").start()
    run.log_metrics({"a": 1.0})
    run.close()
    assert run.run_id is None and run.errors
    assert "robocal tracking: start run failed" in capsys.readouterr().err
    required = tracking.StageRun("fit", uri=f"sqlite:///{blocker}/sub/mlflow.db", required=True).start()
    with pytest.raises(tracking.TrackingError, match="required"):
        required.close()


def test_disabled_tracking_does_nothing(tmp_path: Path) -> None:
    run = tracking.StageRun("fit", enabled=False, uri=f"sqlite:///{tmp_path / 'm.db'}", required=True).start()
    run.log_metrics({"a": 1.0})
    run.close()
    assert run.run_id is None and not (tmp_path / "m.db").exists()


def test_a_pending_run_reaches_mlflow_with_everything(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """PendingRun records without importing MLflow; the flush writes the same run a StageRun would."""
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    art = tmp_path / "out"
    art.mkdir()
    (art / "report.html").write_text("<html></html>")
    with tracking.PendingRun("fit", tags={"x": "1"}) as run:
        run.log_params({"scenario": {"drift": {"T_j6_C^2": 0.5}}, "a": None})
        run.log_metrics({"fit": {"rms_mm": 0.1}, "flag": True})
        run.set_tags({"robocal.status": "ok"})
        run.log_text("a: 1\n", "params.yaml")
        run.log_artifact(art)
        (art / "report.html").write_text("changed after logging")  # the copy was taken when logged
    tracking.flush(uri=uri)  # waits for the detached flusher, writes what is left
    assert not [d for d in tracking.pending_dir(uri).iterdir() if d.is_dir()]
    from mlflow.tracking import MlflowClient

    client = MlflowClient(uri)
    (r,) = client.search_runs([client.get_experiment_by_name("robocal").experiment_id])
    assert r.info.status == "FINISHED" and r.info.end_time >= r.info.start_time
    assert r.data.params == {"scenario.drift.T_j6_C_pow2": "0.5", "a": "null"}
    assert r.data.metrics == {"fit.rms_mm": 0.1, "flag": 1.0}
    assert r.data.tags["x"] == "1" and r.data.tags["robocal.stage"] == "fit" and r.data.tags["robocal.status"] == "ok"
    names = {a.path for a in client.list_artifacts(r.info.run_id)}
    assert {"params.yaml", "report.html"} <= names  # a folder's files, as StageRun.log_artifact logs them
    local = client.download_artifacts(r.info.run_id, "report.html", str(tmp_path / "dl"))
    assert Path(local).read_text() == "<html></html>"


@pytest.mark.e2e  # an MLflow server started (6 s): make e2e (CI), outside make test's 5 minutes
def test_make_ui_prints_the_runs_table_not_the_genai_view(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 23, item 11 and issue 30, item 10: MLflow 3's UI opens in its GenAI view unless the URL asks for the
    machine-learning workflow; the address also opens the stored view of the runs table (run names in full, the
    status tag and the headline metrics as columns)."""
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    cmd = [sys.executable, "-m", "robocal.tracking", "ui-url", "--port", "5123"]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    exp_id = tracking.ensure_store(uri)
    assert out.stdout.strip() == (
        f"http://127.0.0.1:5123/#/experiments/{exp_id}/runs?workflowType=machine_learning"
        "&viewStateShareKey=robocal-runs"
    )
    from mlflow.tracking import MlflowClient

    exp = MlflowClient(uri).get_experiment(exp_id)
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
    view = json.loads(exp.tags["mlflow.sharedViewState.robocal-runs"])
    assert view["columnWidths"] == {"attributes.`Run Name`": 380}
    assert view["columnOrder"][0] == "attributes.`Run Name`"  # widths apply to the columns of columnOrder only
    assert view["selectedColumns"][0] == "tags.`robocal.status`"
    assert set(tracking.headline_metrics(REPO)) >= {"fit_rms_mm", "val_mean_mm"}  # reports/metrics/*.json
    assert "metrics.`fit_rms_mm`" in view["selectedColumns"]
    assert "robocal.tracking ui " in (REPO / "Makefile").read_text()


def test_headline_metrics_are_the_numeric_keys_of_the_metrics_files(tmp_path: Path) -> None:
    (tmp_path / "reports" / "metrics").mkdir(parents=True)
    (tmp_path / "reports" / "metrics" / "b.json").write_text('{"b": "ok", "rms_mm": 0.1, "n": 3}')
    (tmp_path / "reports" / "metrics" / "a.json").write_text('{"a": "skipped", "x^2": 1.5, "n": 4}')
    assert tracking.headline_metrics(tmp_path) == ["x_pow2", "n", "rms_mm"]


def test_make_ui_serves_with_one_worker_and_no_job_runner(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 30, item 10: `make ui` answered after ~60 s: MLflow 3's server started 4 web workers and a GenAI job
    runner with 7 consumers, each importing MLflow, on a 2-core machine."""
    cmd = tracking.ui_command("127.0.0.1", 5000, f"sqlite:///{tmp_path / 'mlflow.db'}")
    assert cmd[1:4] == ["-m", "mlflow", "ui"] and cmd[cmd.index("--workers") + 1] == "1"
    assert cmd[cmd.index("--backend-store-uri") + 1] == f"sqlite:///{tmp_path / 'mlflow.db'}"
    assert cmd[cmd.index("--default-artifact-root") + 1] == (tmp_path / "mlartifacts").as_uri()
    from mlflow.environment_variables import MLFLOW_SERVER_ENABLE_JOB_EXECUTION

    for k, v in tracking.UI_ENV.items():
        monkeypatch.setenv(k, v)
    assert MLFLOW_SERVER_ENABLE_JOB_EXECUTION.get() is False
