"""``robocal fleet``: read the fleet, calibrate what is new, track it, test the trends, write the fleet files.

Output folder::

    OUT/fleet.json                 counts, every campaign's summary (parameters left out), the trend tests and flags
    OUT/report.html                the fleet report (self-contained)
    OUT/robots/<serial>/<campaign>/   calibration.json, summary.json, bundle/ (robocal.fleet.engine)

``fleet.json`` and ``report.html`` are rewritten at every run (they depend on the whole fleet: the Bonferroni
correction counts every robot); the campaign folders only when their cache key changed.
"""

from __future__ import annotations

import copy
import json
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from robocal.errors import ConfigError, RobocalError
from robocal.status import CampaignStatus

DEFAULT_CONFIG = Path(__file__).resolve().parents[3] / "conf" / "fleet" / "default.yaml"


def load_settings(path: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The fleet settings: ``conf/fleet/default.yaml`` (or ``path``) with nested ``overrides`` merged in."""
    p = Path(path) if path else DEFAULT_CONFIG
    try:
        cfg = yaml.safe_load(p.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"cannot read the fleet settings {p}: {exc}") from None
    if not isinstance(cfg, dict):
        raise ConfigError(f"{p}: the fleet settings must be a mapping")

    def merge(a: dict[str, Any], b: Mapping[str, Any], where: str) -> dict[str, Any]:
        out = copy.deepcopy(a)
        for k, v in b.items():
            if isinstance(v, Mapping) and isinstance(out.get(k), dict):
                out[k] = merge(out[k], v, f"{where}{k}.")
            else:
                out[k] = v
        return out

    return merge(cfg, overrides or {}, "")


def run_fleet(
    fleet_dir: str | Path,
    out_dir: str | Path,
    settings: Mapping[str, Any] | None = None,
    engine: str = "local",
    workers: int = 1,
    address: str | None = None,
    serials: list[str] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Process a fleet folder into ``out_dir`` (see the module docstring); returns the fleet summary plus
    ``computed`` (the (serial, campaign) pairs calibrated in this run) and ``tracking`` (MLflow outcome).
    With ``serials``, only those robots are processed and no fleet-level file is written."""
    from robocal.fleet.engine import calibrate_fleet
    from robocal.fleet.layout import read_fleet
    from robocal.fleet.report import write_report
    from robocal.fleet.trends import analyse, truth_score
    from robocal.io import write_json

    cfg = dict(settings) if settings is not None else load_settings()
    fleet = read_fleet(fleet_dir, serials)
    out = Path(out_dir)
    if out.resolve() == fleet.path or any(
        out.resolve() == r.path or r.path in out.resolve().parents for r in fleet.robots
    ):
        raise ConfigError(f"--out {out} must not be the fleet folder or inside a robot's folder")
    out.mkdir(parents=True, exist_ok=True)
    tcfg = dict(cfg.get("tracking") or {})
    tracker = None
    track_log: dict[str, Any] = {"enabled": bool(tcfg.get("enabled", True)), "robots": {}, "errors": []}
    if track_log["enabled"]:
        from robocal.fleet.registry import FleetTracker

        try:
            tracker = FleetTracker(
                tcfg.get("uri"),
                str(tcfg.get("experiment") or "robocal-fleet"),
                str(tcfg.get("alias") or "production"),
                bool(tcfg.get("register", True)),
            )
            track_log["uri"] = tracker.uri
        except Exception as exc:
            track_log["errors"].append(f"{type(exc).__name__}: {exc}")
            print(f"robocal tracking: cannot open the store: {exc}", file=sys.stderr)

    def on_robot(serial: str, summaries: list[dict[str, Any]]) -> None:
        if tracker is not None:
            track_log["robots"][serial] = tracker.track_robot(serial, summaries, out)

    t0, c0 = time.perf_counter(), time.process_time()
    log_from = str(tcfg.get("log_from") or "driver")
    if log_from not in ("driver", "workers"):
        raise ConfigError(f"The 'tracking.log_from' fleet setting must be 'driver' or 'workers'. Got {log_from!r}.")
    track_kw: dict[str, Any] | None = None
    if tracker is not None and log_from == "workers":
        track_kw = {"uri": tracker.uri, "experiment": tracker.experiment, "alias": tracker.alias}
        track_kw["register"] = tracker.register
    res = calibrate_fleet(
        fleet, out, cfg, engine, workers, address, on_robot=on_robot, progress=progress, track=track_kw
    )
    for serial, outcome in res["tracked"].items():
        track_log["errors"] += outcome.pop("errors", [])
        track_log["robots"][serial] = outcome
    t1, c1 = time.perf_counter(), time.process_time()
    if tracker is not None:
        track_log["errors"] += tracker.errors
    summaries = res["summaries"]
    if serials:  # a part of the fleet (a DVC robot stage): its campaign files only, no fleet files
        return {
            "computed": res["computed"],
            "n_cached": res["cached"],
            "tracking": track_log,
            "timings_s": {
                "engine": t1 - t0,
                "engine_cpu": c1 - c0,
                "worker_cpu": res["worker_cpu_s"],
                "worker_wall": res["worker_wall_s"],
            },
        }
    dcfg = dict(cfg.get("drift") or {})
    trends = analyse(
        summaries,
        alpha=float(dcfg.get("alpha", 0.01)),
        kinds=tuple(dcfg.get("kinds") or ("kinematic",)),
        pattern_alpha=float(dcfg.get("pattern_alpha", 0.001)),
    )
    all_c = [s for v in summaries.values() for s in v]
    summary: dict[str, Any] = {
        "fleet": str(fleet.meta.get("name") or fleet.path.name),
        "counts": {
            "robots": len(fleet.robots),
            "campaigns": len(all_c),
            "accepted": sum(1 for s in all_c if s["status"] == CampaignStatus.OK),
            "rejected": sum(1 for s in all_c if s["status"] == CampaignStatus.REJECTED),
            "errors": sum(1 for s in all_c if s["status"] == CampaignStatus.ERROR),
        },
        "settings": {k: cfg.get(k) for k in ("calibration", "acceptance", "drift")},
        "robots": [
            {
                "serial": r.serial,
                "robot": Path(r.robot).name,
                "campaigns": [{k: v for k, v in s.items() if k != "parameters"} for s in summaries[r.serial]],
            }
            for r in fleet.robots
        ],
        "trends": {"test": trends["test"], "flags": trends["flags"], "robots": trends["robots"]},
    }
    truth_file = fleet.path / "truth.json"
    if truth_file.is_file():
        try:
            truth = json.loads(truth_file.read_text(encoding="utf-8"))
            summary["truth"] = truth_score(trends["flags"], truth)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            print(f"robocal fleet: {truth_file} ignored: {exc}", file=sys.stderr)
    write_json(out / "fleet.json", summary)
    write_report(out / "report.html", summary)
    if track_log["errors"] and tcfg.get("required"):
        raise RobocalError("MLflow tracking was required but failed: " + "; ".join(track_log["errors"]))
    # returned, never written: the driver's wall and CPU time in the engine phase, and the fleet files' wall time
    timings = {
        "engine": t1 - t0,
        "engine_cpu": c1 - c0,
        "worker_cpu": res["worker_cpu_s"],
        "worker_wall": res["worker_wall_s"],
        "fleet_files": time.perf_counter() - t1,
    }
    return {
        **summary,
        "computed": res["computed"],
        "n_cached": res["cached"],
        "tracking": track_log,
        "timings_s": timings,
    }
