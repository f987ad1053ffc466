"""MLflow at fleet scale: runs per campaign tagged by serial, accepted calibrations registered as robot-<serial>,
the service started on robot-<serial>@production replaced by the next version without a restart."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time

import pytest

from conftest import settings
from robocal.errors import ConfigError
from robocal.fleet.registry import AliasWatcher, parse_model_spec, resolve_model
from robocal.fleet.run import run_fleet
from robocal.serve.client import Client
from robocal.serve.server import Server, ServerConfig, ServerThread

Q = [10.0, -80.0, 60.0, 20.0, 40.0, 30.0]


def test_model_spec():
    assert parse_model_spec("robot-R0001@production") == ("robot-R0001", "production")
    for bad in ("robot-R0001", "@production", "robot R1@production", "robot-R1@"):
        with pytest.raises(ConfigError, match="expected <registered model>@<alias>"):
            parse_model_spec(bad)


@pytest.mark.e2e  # the MLflow registry and a served model swapped (14 s): make e2e (CI), outside make test's 5 minutes
def test_register_serve_by_alias_and_replace_without_restart(fleet_copy, tmp_path, monkeypatch):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.setenv("MLFLOW_DISABLE_TELEMETRY", "1")
    robot = fleet_copy / "R0001"
    later = sorted(p for p in robot.iterdir() if p.is_dir())[-1]
    held = tmp_path / later.name
    shutil.move(later, held)  # the robot's third campaign comes later
    cfg = settings(tracking={"enabled": True, "uri": uri})
    out = tmp_path / "out"
    first = run_fleet(fleet_copy, out, cfg, serials=["R0001"], progress=False)
    assert first["tracking"]["errors"] == [] and first["tracking"]["robots"]["R0001"]["alias_version"] == 2

    from mlflow.tracking import MlflowClient

    client = MlflowClient(uri)
    runs = client.search_runs([client.get_experiment_by_name("robocal-fleet").experiment_id])
    assert sorted(r.data.tags["robocal.campaign"] for r in runs) == ["2026-01-05", "2026-04-06"]
    assert {r.data.tags["robocal.serial"] for r in runs} == {"R0001"}
    # idempotent: a second run logs and registers nothing new
    again = run_fleet(fleet_copy, out, cfg, serials=["R0001"], progress=False)
    assert again["tracking"]["robots"]["R0001"] == {"logged": 0, "registered": [], "alias_version": 2}

    spec = "robot-R0001@production"
    cache = tmp_path / "models"
    version, path = resolve_model(spec, cache_dir=cache)
    assert version == 2 and (path / "manifest.json").is_file()
    server = Server(path, ServerConfig(port=0))
    with (
        ServerThread(server) as srv,
        AliasWatcher(spec, version, server.reload_sync, cache_dir=cache, interval_s=0.2) as watcher,
        Client("127.0.0.1", srv.port) as c,
    ):
        info = c.info()
        assert info["path"].endswith("v2")
        before = c.correct([Q])["results"][0]
        # the third campaign arrives: the fleet run registers version 3 and moves the alias
        shutil.move(held, later)
        third = run_fleet(fleet_copy, out, cfg, serials=["R0001"], progress=False)
        assert third["tracking"]["robots"]["R0001"] == {"logged": 1, "registered": [3], "alias_version": 3}
        deadline = time.monotonic() + 30  # polls every 0.2 s; the download is a local copy
        while c.ping()["bundle"] == info["bundle"] and time.monotonic() < deadline:
            time.sleep(0.1)
        assert watcher.version == 3
        # the same connection, now on version 3: another calibration, another correction
        assert c.info()["path"].endswith("v3")
        after = c.correct([Q])["results"][0]
        assert after["status"] == before["status"] == "ok"
        assert after["q_deg"] != before["q_deg"]
    with pytest.raises(ConfigError, match="no such registered model or alias"):
        resolve_model("robot-R0002@production", cache_dir=cache)
    # the command line: robocal serve --model ... serves the alias's version (the same hook as above)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "robocal.cli",
            "serve",
            "--model",
            spec,
            "--tracking-uri",
            uri,
            "--port",
            "0",
            "--model-cache",
            str(tmp_path / "cli-cache"),
        ],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    try:
        port = None
        assert proc.stderr is not None
        for line in proc.stderr:  # "robocal serve: serving bundle ... on 127.0.0.1:PORT"
            m = re.search(r"serving bundle .* on 127\.0\.0\.1:(\d+)", line)
            if m:
                port = int(m[1])
                break
        assert port is not None, "robocal serve --model did not start"
        with Client("127.0.0.1", port) as c:
            assert c.info()["path"].endswith("v3")
    finally:
        proc.terminate()
        proc.wait(10)
