"""Fleet tracking in MLflow: a run per robot and campaign, a registered model per robot, an alias to serve.

* Every campaign is one run in the experiment ``robocal-fleet`` (default), named ``<serial> <campaign>``, tagged
  ``robocal.serial``, ``robocal.campaign``, ``robocal.key`` (the cache key) and ``robocal.status``; its metrics are
  the accuracy before/after and on the validation rows; its artifacts the ``calibration.json``,
  ``summary.json`` and the serve bundle (``bundle/``).
* Each accepted calibration becomes a version of the registered model ``robot-<serial>`` whose source is the
  run's ``bundle`` artifact directory (a plain artifact directory: MLflow 3 with a SQLite store registers any run
  artifact path; no pyfunc flavour is needed because the service loads bundles, not Python models).
* The alias ``production`` (configurable) points at the accepted version of the newest campaign.

Idempotent: a campaign whose key already has a run is not logged again, so re-running the fleet (or adding a
campaign) adds runs only for what is new. By default the driver logs (one writer, as SQLite wants) while workers
compute; ``tracking.log_from: workers`` has each Ray task log its own robot (for a tracking server, where the
driver's logging would otherwise be the serial part of a big fleet).

``robocal serve --model robot-<serial>@production`` resolves the alias with :func:`resolve_model`, downloads
the bundle and serves it; :class:`AliasWatcher` polls the alias and hands a newly promoted version to the
server's reload (no restart, connections stay open).
"""

from __future__ import annotations

import re
import sys
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from robocal.errors import ConfigError, RobocalError

MODEL_PREFIX = "robot-"
DEFAULT_EXPERIMENT = "robocal-fleet"
DEFAULT_ALIAS = "production"
_SPEC_RE = re.compile(r"^(?P<name>[A-Za-z0-9][A-Za-z0-9._-]*)@(?P<alias>[A-Za-z0-9_-]+)$")


def model_name(serial: str) -> str:
    return f"{MODEL_PREFIX}{serial}"


class FleetTracker:
    """Log a fleet's campaigns into MLflow and keep each robot's registered model and alias up to date.

    Parameters
    ----------
    uri : tracking URI (see :func:`robocal.tracking.tracking_uri`; ``None`` = the repository's ``mlflow.db``)
    experiment : experiment name
    alias : the alias moved to the newest accepted version
    register : register accepted calibrations in the model registry
    """

    def __init__(
        self,
        uri: str | None = None,
        experiment: str = DEFAULT_EXPERIMENT,
        alias: str = DEFAULT_ALIAS,
        register: bool = True,
    ) -> None:
        from robocal.tracking.store import ensure_store, tracking_uri

        self.uri = tracking_uri(uri)
        self.experiment = experiment
        self.alias = alias
        self.register = register
        self.errors: list[str] = []
        self.exp_id = ensure_store(self.uri, experiment)  # once, before anything runs in parallel
        from mlflow.tracking import MlflowClient

        self.client = MlflowClient(tracking_uri=self.uri)

    def _existing(self, serial: str) -> dict[str, Any]:
        runs = self.client.search_runs(
            [self.exp_id], filter_string=f"tags.`robocal.serial` = '{serial}'", max_results=10000
        )
        return {str(r.data.tags["robocal.key"]): r for r in runs if r.data.tags.get("robocal.key")}

    def track_robot(self, serial: str, summaries: Sequence[Mapping[str, Any]], out_dir: str | Path) -> dict[str, Any]:
        """Log the robot's new campaigns, register its new accepted calibrations, move the alias.

        Returns ``{"logged": n, "registered": [versions], "alias_version": v | None}``. MLflow errors are printed
        and collected in :attr:`errors` (tracking never costs results)."""
        from robocal.tracking.store import retry

        try:  # retried on SQLite contention ("database is locked") when several workers log at once
            return retry(lambda: self._track(serial, summaries, Path(out_dir)), attempts=6)
        except Exception as exc:
            msg = f"{serial}: {type(exc).__name__}: {exc}"
            self.errors.append(msg)
            print(f"robocal tracking: {msg}", file=sys.stderr)
            return {"logged": 0, "registered": [], "alias_version": None}

    def _track(self, serial: str, summaries: Sequence[Mapping[str, Any]], out: Path) -> dict[str, Any]:
        from mlflow.entities import Metric, Param, RunTag

        from robocal.fleet.layout import campaign_dir
        from robocal.tracking.values import default_tags, numeric_metrics

        existing = self._existing(serial)
        name = model_name(serial)
        logged, registered = 0, []
        versions = self._versions(name) if self.register else {}
        for s in summaries:
            run = existing.get(s["key"])
            if run is None:
                tags = {
                    **default_tags("fleet"),
                    "robocal.serial": serial,
                    "robocal.campaign": s["campaign"],
                    "robocal.status": s["status"],
                    "robocal.robot": s.get("robot", ""),
                }
                run = self.client.create_run(self.exp_id, tags=tags, run_name=f"{serial} {s['campaign']}")
                rid = run.info.run_id
                metrics = numeric_metrics({"fit": s.get("fit", {}), "validation": s.get("validation", {})})
                ts = 0  # a fixed timestamp: the campaign, not the moment it was logged, is what matters
                self.client.log_batch(
                    rid,
                    metrics=[Metric(k, v, ts, 0) for k, v in sorted(metrics.items())],
                    params=[
                        Param("serial", serial),
                        Param("campaign", s["campaign"]),
                        Param("accepted", str(s["accepted"])),
                    ],
                    tags=[RunTag("robocal.reason", str(s.get("reason", ""))[:5000])],
                )
                d = campaign_dir(out, serial, s["campaign"])
                for f in ("calibration.json", "summary.json"):
                    if (d / f).is_file():
                        self.client.log_artifact(rid, str(d / f))
                if (d / "bundle").is_dir():
                    self.client.log_artifacts(rid, str(d / "bundle"), "bundle")
                # the key last: a run interrupted before this point is not taken for a complete one next time
                self.client.set_tag(rid, "robocal.key", s["key"])
                self.client.set_terminated(rid, "FINISHED" if s["status"] != "error" else "FAILED")
                logged += 1
            if self.register and s.get("accepted") and s["key"] not in versions:
                if not versions and not self._model_exists(name):
                    self.client.create_registered_model(name, tags={"robocal.serial": serial})
                mv = self.client.create_model_version(
                    name,
                    source=f"{run.info.artifact_uri}/bundle",
                    run_id=run.info.run_id,
                    tags={"robocal.campaign": s["campaign"], "robocal.key": s["key"]},
                    description=f"{serial} calibrated on {s['campaign']}",
                )
                versions[s["key"]] = (s["campaign"], int(mv.version))
                registered.append(int(mv.version))
        alias_version = None
        if self.register and versions:
            # the alias follows the newest campaign (not the newest registration: a late-added old campaign does
            # not take production away from a newer one)
            _, alias_version = max(versions.values())
            cur = self._alias_version(name)
            if cur != alias_version:
                self.client.set_registered_model_alias(name, self.alias, str(alias_version))
        return {"logged": logged, "registered": registered, "alias_version": alias_version}

    def _model_exists(self, name: str) -> bool:
        from mlflow.exceptions import MlflowException

        try:
            self.client.get_registered_model(name)
            return True
        except MlflowException:
            return False

    def _versions(self, name: str) -> dict[str, tuple[str, int]]:
        """{cache key: (campaign, version)} of the model's versions (empty when the model does not exist)."""
        if not self._model_exists(name):
            return {}
        out = {}
        for mv in self.client.search_model_versions(f"name = '{name}'"):
            key = (mv.tags or {}).get("robocal.key")
            if key:
                out[key] = ((mv.tags or {}).get("robocal.campaign", ""), int(mv.version))
        return out

    def _alias_version(self, name: str) -> int | None:
        from mlflow.exceptions import MlflowException

        try:
            return int(self.client.get_model_version_by_alias(name, self.alias).version)
        except MlflowException:
            return None


# ----------------------------------------------------------------------------------------------- serving


def parse_model_spec(spec: str) -> tuple[str, str]:
    """``robot-<serial>@<alias>`` -> (model name, alias); a ConfigError naming the spec otherwise."""
    m = _SPEC_RE.match(spec or "")
    if not m:
        raise ConfigError(f"--model {spec!r}: expected <registered model>@<alias>, e.g. robot-R0001@production")
    return m["name"], m["alias"]


def alias_version(spec: str, uri: str | None = None) -> int:
    """The version the alias of ``spec`` points at now (ConfigError when the model or alias does not exist)."""
    from mlflow.exceptions import MlflowException
    from mlflow.tracking import MlflowClient

    from robocal.tracking.store import tracking_uri

    name, alias = parse_model_spec(spec)
    client = MlflowClient(tracking_uri=tracking_uri(uri))
    try:
        return int(client.get_model_version_by_alias(name, alias).version)
    except MlflowException as exc:
        raise ConfigError(f"--model {spec}: no such registered model or alias in {tracking_uri(uri)}: {exc}") from None


def resolve_model(spec: str, uri: str | None = None, cache_dir: str | Path | None = None) -> tuple[int, Path]:
    """Resolve ``robot-<serial>@<alias>`` to (version, local bundle directory), downloading the version's bundle
    into ``cache_dir/<model>/v<version>/`` (default ``~/.cache/robocal/models``) unless it is already there."""
    import mlflow.artifacts
    from mlflow.tracking import MlflowClient

    from robocal.serve.bundle import MANIFEST
    from robocal.tracking.store import tracking_uri

    name, _ = parse_model_spec(spec)
    uri = tracking_uri(uri)
    version = alias_version(spec, uri)
    root = Path(cache_dir) if cache_dir else Path.home() / ".cache" / "robocal" / "models"
    dest = root / name / f"v{version}"
    if (dest / MANIFEST).is_file():
        return version, dest
    import shutil

    mv = MlflowClient(tracking_uri=uri).get_model_version(name, str(version))
    tmp = root / name / f".v{version}.partial"
    for stale in (tmp, dest):  # an interrupted download
        if stale.exists():
            shutil.rmtree(stale)
    tmp.mkdir(parents=True)
    try:
        try:
            got = Path(mlflow.artifacts.download_artifacts(artifact_uri=mv.source, dst_path=str(tmp), tracking_uri=uri))
        except Exception as exc:
            raise ConfigError(f"--model {spec}: cannot download version {version} from {mv.source}: {exc}") from None
        if not (got / MANIFEST).is_file():
            raise ConfigError(f"--model {spec}: version {version} ({mv.source}) holds no bundle {MANIFEST}")
        got.rename(dest)  # atomic: a half-downloaded bundle is never served
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return version, dest


class AliasWatcher:
    """Poll a model alias every ``interval_s`` seconds in a daemon thread; when it points at another version,
    download that bundle and call ``reload(path)`` (the server's :meth:`~robocal.serve.server.Server.reload_sync`).
    A failed download or reload is logged and retried at the next poll; the old bundle keeps serving."""

    def __init__(
        self,
        spec: str,
        version: int,
        reload: Callable[[Path], Any],
        uri: str | None = None,
        cache_dir: str | Path | None = None,
        interval_s: float = 5.0,
        log: Callable[[str], None] | None = None,
    ) -> None:
        if not interval_s > 0:
            raise ConfigError(f"The 'interval_s' parameter of AliasWatcher must be > 0. Got {interval_s!r} instead.")
        self.spec, self.version, self.reload = spec, int(version), reload
        self.uri, self.cache_dir, self.interval_s = uri, cache_dir, float(interval_s)
        self.log = log or (lambda msg: print(f"robocal serve: {msg}", file=sys.stderr, flush=True))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="robocal-alias-watch", daemon=True)

    def start(self) -> AliasWatcher:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(self.interval_s + 5)

    def check(self) -> bool:
        """Poll once; True when a new version was swapped in."""
        v = alias_version(self.spec, self.uri)
        if v == self.version:
            return False
        v, path = resolve_model(self.spec, self.uri, self.cache_dir)
        self.reload(path)
        self.log(f"{self.spec} moved from version {self.version} to {v}: serving {path}")
        self.version = v
        return True

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            try:
                self.check()
            except (RobocalError, OSError) as exc:
                self.log(f"watching {self.spec}: {exc}")
            except Exception as exc:  # MLflow server away for a moment: keep serving, try again
                self.log(f"watching {self.spec}: {type(exc).__name__}: {exc}")

    def __enter__(self) -> AliasWatcher:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()
