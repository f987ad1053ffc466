"""Calibrate a fleet: one task per robot (its campaigns that are not cached), in-process or on Ray.

Per campaign, the worker reads the campaign (:func:`robocal.read_campaign`), calibrates it
(:func:`robocal.calibrate`), validates it (:func:`robocal.validate`) and writes, atomically::

    OUT/robots/<serial>/<campaign>/calibration.json   CalibrationResult.to_dict() without timings
                                   summary.json       key, status, accepted, fit and validation figures, parameters
                                   bundle/            a serve bundle (robocal.serve.bundle.write_bundle)

The cache key of a campaign is the sha256 of its folder's content, the robot description's bytes, the
calibration settings and the robocal version: a campaign whose ``summary.json`` carries the same key is not
computed again, so adding a campaign to one robot computes only that campaign (and the fleet-level files).

Outputs are deterministic: no timings, no wall-clock dates (a bundle's ``created`` is the campaign's date),
the same bytes whatever the engine or the number of workers. On Ray the workers write the campaign files
themselves (the output folder must then be on a file system every node sees, as for Hydra's Ray launcher);
the driver writes the fleet-level files and does the MLflow tracking while the workers compute.
"""

from __future__ import annotations

import hashlib
import json
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from robocal.errors import ConfigError, RobocalError
from robocal.fleet.layout import Fleet, RobotFolder, campaign_dir
from robocal.parallel import start_ray
from robocal.status import CampaignStatus

#: keys of the calibration's ``fit`` that are timings (never written: outputs must not depend on the machine)
TIMING_KEYS = ("wall_time_s", "solver_time_s", "elapsed_s", "time_s")
ENGINES = ("local", "ray")


@dataclass(frozen=True)
class Job:
    """The campaigns of one robot to compute: ``campaigns`` is ``[(name, path, key), ...]`` in date order."""

    serial: str
    robot: str
    out_dir: str
    campaigns: tuple[tuple[str, str, str], ...]
    calibration: dict[str, Any] = field(default_factory=dict)
    acceptance: dict[str, Any] = field(default_factory=dict)
    #: when set, the task logs its robot to MLflow itself: FleetTracker keyword arguments
    track: dict[str, Any] | None = None
    #: the robot's cached summaries and every campaign name in date order (for the tracking of the whole robot)
    known: tuple[dict[str, Any], ...] = ()
    order: tuple[str, ...] = ()


def _strip_timings(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _strip_timings(v) for k, v in obj.items() if k not in TIMING_KEYS}
    if isinstance(obj, list):
        return [_strip_timings(v) for v in obj]
    return obj


def campaign_key(robot: RobotFolder, campaign_sha256: str, calibration: Mapping[str, Any]) -> str:
    """The cache key of one campaign's results (see the module docstring)."""
    from robocal import __version__

    blob = json.dumps(
        {
            "robocal": __version__,
            "campaign": campaign_sha256,
            "robot": robot.robot if not robot.robot.startswith("/") else Path(robot.robot).name,
            "robot_sha256": robot.robot_sha256,
            "calibration": dict(calibration),
        },
        sort_keys=True,
    )
    return hashlib.sha256(blob.encode()).hexdigest()


def cached_summary(out_dir: str | Path, serial: str, campaign: str, key: str) -> dict[str, Any] | None:
    """The stored summary of a campaign when its key matches and its files are all there, else None."""
    d = campaign_dir(out_dir, serial, campaign)
    try:
        s = json.loads((d / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(s, dict) or s.get("key") != key:
        return None
    if s.get("status") != CampaignStatus.ERROR and not (
        (d / "calibration.json").is_file() and (d / "bundle/manifest.json").is_file()
    ):
        return None
    return s


def accept(fit: Mapping[str, Any], validation: Mapping[str, Any], rules: Mapping[str, Any]) -> tuple[bool, str]:
    """Is a calibration good enough to serve? (accepted, reason): the one rule
    (:func:`robocal.identification.acceptance.judge`) with the fleet's levels (:data:`~robocal.identification.
    acceptance.FLEET`) and ``rules`` (the ``acceptance`` settings); the reason is the first problem."""
    from robocal.identification.acceptance import FLEET, AcceptanceRules, judge

    verdict = judge(fit, validation, None, AcceptanceRules.from_mapping({**FLEET, **rules}))
    if verdict.problems:
        return False, verdict.problems[0]
    return True, "converged, not worse than before"


def _calibrate_one(
    serial: str, robot_ref: str, name: str, path: str, key: str, out: Path, cal_cfg: Mapping[str, Any], rules: Mapping
) -> dict[str, Any]:
    import robocal
    from robocal.calibration.config import CalibrationConfig
    from robocal.io import write_json
    from robocal.serve.bundle import MANIFEST, write_bundle

    d = campaign_dir(out, serial, name)
    base = {"serial": serial, "campaign": name, "date": name[:10], "robot": Path(robot_ref).name, "key": key}
    try:
        robot = robocal.load_robot(robot_ref)
        campaign = robocal.read_campaign(path, robot)
        result = robocal.calibrate(campaign, robot, CalibrationConfig.from_mapping(cal_cfg))
        validation = robocal.validate(result, campaign)
    except RobocalError as exc:  # bad data: recorded (and cached: the same bytes fail the same way)
        summary = {**base, "status": CampaignStatus.ERROR, "accepted": False, "reason": str(exc)}
        write_json(d / "summary.json", summary)
        return summary
    except Exception as exc:  # a bug or a numerical failure: reported, not cached (the next run tries again),
        # and the rest of the fleet goes on
        (d / "summary.json").unlink(missing_ok=True)
        return {**base, "status": CampaignStatus.ERROR, "accepted": False, "reason": f"{type(exc).__name__}: {exc}"}
    cal = _strip_timings(result.to_dict())
    fit = cal["fit"]
    ok, reason = accept(fit, validation, rules)
    write_json(d / "calibration.json", cal)
    write_bundle(d / "bundle", robot_ref, d / "calibration.json")
    manifest = json.loads((d / "bundle" / MANIFEST).read_text(encoding="utf-8"))
    manifest["created"] = f"{name[:10]}T00:00:00+00:00"  # the campaign's date: deterministic bytes
    manifest["fleet"] = {"serial": serial, "campaign": name, "key": key}
    write_json(d / "bundle" / MANIFEST, manifest)
    summary = {
        **base,
        "status": CampaignStatus.OK if ok else CampaignStatus.REJECTED,
        "accepted": ok,
        "reason": reason,
        "fit": {
            "rms_before_mm": fit["before"]["rms_position_mm"],
            "rms_after_mm": fit["rms_position_mm"],
            "mean_after_mm": fit["mean_position_mm"],
            "max_after_mm": fit["max_position_mm"],
            "reduced_chi2": fit["reduced_chi2"],
            "n_rows": fit["n_rows"],
            "n_outliers": len(fit["outliers"]),
            "success": fit["success"],
        },
        "validation": {
            k: validation.get(k) for k in ("n_rows", "mean_position_mm", "max_position_mm", "rms_position_mm")
        },
        "parameters": cal["parameters"],
    }
    write_json(d / "summary.json", summary)
    return summary


def process_robot(job: Job) -> list[dict[str, Any]]:
    """Compute every campaign of ``job`` (the task a worker runs); returns their summaries in date order."""
    out = Path(job.out_dir)
    return [
        _calibrate_one(job.serial, job.robot, name, path, key, out, job.calibration, job.acceptance)
        for name, path, key in job.campaigns
    ]


TaskResult = tuple[list[dict[str, Any]], float, float, dict[str, Any] | None]


def timed_process_robot(job: Job) -> TaskResult:
    """:func:`process_robot`, the CPU and wall seconds it took in its worker (for the benchmark; never written) and,
    when ``job.track`` is set, the outcome of logging the robot to MLflow from the worker (else None)."""
    import time

    c0, t0 = time.process_time(), time.perf_counter()
    out = process_robot(job)
    tracked = None
    if job.track is not None:
        from robocal.fleet.registry import FleetTracker

        by_name = {s["campaign"]: s for s in (*job.known, *out)}
        tracker = FleetTracker(**job.track)
        res = tracker.track_robot(job.serial, [by_name[c] for c in job.order], job.out_dir)
        tracked = {**res, "errors": tracker.errors}
    return out, time.process_time() - c0, time.perf_counter() - t0, tracked


# ----------------------------------------------------------------------------------------------- engines

OnDone = Callable[[Job, TaskResult], None]


def run_local(jobs: list[Job], on_done: OnDone) -> None:
    """Run the jobs one after the other in this process."""
    for job in jobs:
        on_done(job, timed_process_robot(job))


def run_ray(jobs: list[Job], on_done: OnDone, workers: int, address: str | None = None, keep: bool = False) -> None:
    """Run the jobs as Ray tasks (one CPU each) on a local instance of ``workers`` CPUs or the cluster at
    ``address``; ``on_done`` is called in the driver as each robot finishes. Ray is shut down afterwards unless it
    was already running or ``keep``."""
    import ray

    started_here = not ray.is_initialized()
    start_ray(workers, address)
    try:
        task = ray.remote(num_cpus=1, max_retries=1)(timed_process_robot)
        pending = {task.remote(job): job for job in jobs}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job = pending.pop(ref)
                on_done(job, ray.get(ref))
    finally:
        if started_here and not keep:
            ray.shutdown()


# ----------------------------------------------------------------------------------------------- the fleet


def plan(
    fleet: Fleet, out_dir: str | Path, settings: Mapping[str, Any], track: Mapping[str, Any] | None = None
) -> tuple[list[Job], dict[str, dict[str, Any]]]:
    """The jobs still to run and the cached summaries ``{serial: {campaign: summary}}``; with ``track``
    (FleetTracker keyword arguments) each job logs its robot to MLflow itself."""
    cal_cfg = dict(settings.get("calibration") or {})
    rules = dict(settings.get("acceptance") or {})
    jobs: list[Job] = []
    cached: dict[str, dict[str, Any]] = {}
    for r in fleet.robots:
        todo = []
        for c in r.campaigns:
            key = campaign_key(r, c.sha256, cal_cfg)
            s = cached_summary(out_dir, r.serial, c.name, key)
            if s is None:
                todo.append((c.name, str(c.path), key))
            else:
                cached.setdefault(r.serial, {})[c.name] = s
        if todo:
            jobs.append(
                Job(
                    r.serial,
                    r.robot,
                    str(Path(out_dir).resolve()),
                    tuple(todo),
                    cal_cfg,
                    rules,
                    dict(track) if track is not None else None,
                    tuple(cached.get(r.serial, {}).values()),
                    tuple(c.name for c in r.campaigns),
                )
            )
    return jobs, cached


def calibrate_fleet(
    fleet: Fleet,
    out_dir: str | Path,
    settings: Mapping[str, Any],
    engine: str = "local",
    workers: int = 1,
    address: str | None = None,
    on_robot: Callable[[str, list[dict[str, Any]]], None] | None = None,
    progress: bool = True,
    track: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Calibrate every campaign of the fleet that is not cached; returns ``{"summaries": {serial: [summary, ...]},
    "computed": [(serial, campaign), ...], "cached": n, "worker_cpu_s" / "worker_wall_s": CPU / wall
    seconds of the tasks}``.
    ``on_robot(serial, summaries)`` runs in this process once a robot's campaigns are all known (cached or
    computed), e.g. for tracking; with ``track`` (FleetTracker keyword arguments) the tasks log their robots
    themselves, ``on_robot`` is called only for robots with nothing to compute, and ``"tracked"`` holds
    ``{serial: outcome}``."""
    if engine not in ENGINES:
        raise ConfigError(f"The 'engine' parameter must be one of {ENGINES}. Got {engine!r} instead.")
    if int(workers) < 1:
        raise ConfigError(f"The 'workers' parameter must be >= 1. Got {workers!r} instead.")
    jobs, cached = plan(fleet, out_dir, settings, track)
    tracked: dict[str, dict[str, Any]] = {}
    n_todo = sum(len(j.campaigns) for j in jobs)
    n_cached = fleet.n_campaigns - n_todo
    computed: list[tuple[str, str]] = []
    results: dict[str, dict[str, Any]] = {s: dict(v) for s, v in cached.items()}
    from tqdm import tqdm

    bar = tqdm(
        total=n_todo,
        unit="campaign",
        desc="fleet (local)" if engine == "local" else f"fleet (ray, {workers} CPUs)",
        disable=not progress or n_todo == 0,
        file=sys.stderr,
    )

    worker = [0.0, 0.0]  # CPU and wall seconds of the tasks

    def done(job: Job, result: TaskResult) -> None:
        summaries, cpu, wall, track_result = result
        worker[0] += cpu
        worker[1] += wall
        for s in summaries:
            results.setdefault(job.serial, {})[s["campaign"]] = s
            computed.append((job.serial, s["campaign"]))
        bar.update(len(summaries))
        if track_result is not None:
            tracked[job.serial] = track_result
        elif on_robot is not None:
            on_robot(job.serial, [results[job.serial][c.name] for c in fleet.robot(job.serial).campaigns])

    try:
        if engine == "local" or not jobs:
            run_local(jobs, done)
        else:
            run_ray(jobs, done, workers, address)
    finally:
        bar.close()
    if on_robot is not None:  # robots with nothing to compute: tracking catches up on them (a no-op when done)
        todo = {j.serial for j in jobs}
        for r in fleet.robots:
            if r.serial not in todo:
                on_robot(r.serial, [results[r.serial][c.name] for c in r.campaigns])
    summaries = {r.serial: [results[r.serial][c.name] for c in r.campaigns] for r in fleet.robots}
    return {
        "summaries": summaries,
        "computed": sorted(computed),
        "cached": n_cached,
        "worker_cpu_s": worker[0],
        "worker_wall_s": worker[1],
        "tracked": tracked,
    }
