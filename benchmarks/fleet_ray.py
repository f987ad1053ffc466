"""Fleet on local Ray: throughput at 1 and 2 workers, Amdahl's serial fraction, projections, planted events.

    python benchmarks/fleet_ray.py                         # 200 robots x 3 campaigns (the issue's figure)
    python benchmarks/fleet_ray.py --robots 20 --tracking  # smaller, and with MLflow tracking + registry on

Steps: the twin writes the fleet (``robocal fleet --simulate``); the fleet is processed on a local Ray instance
with 1 CPU, then (from scratch, into another folder) with 2 CPUs, then in-process (``--engine local``).
Throughput is campaigns per minute of the engine phase (Ray's start-up and the workers' first import are
timed apart: a service pays them once); the fleet files (trend tests, report) are timed apart too, and an
end-to-end figure (engine + fleet files) is given with its own serial fraction. With T1 and T2 the engine
times, the speed-up is S = T1 / T2 and Amdahl's law S(p) = 1 / (f + (1 - f) / p) gives the serial fraction
f = 2 / S - 1, from which 16 CPUs (one node) and 160 CPUs (10 such nodes) are projected. The three output
folders must be byte-identical (determinism whatever the engine or worker count). The planted events must all be
flagged, none elsewhere.

The machine is shared: the load average is printed with the figures; a busy machine lowers the 2-worker speed-up
and so inflates f (the projection is then pessimistic).
"""

from __future__ import annotations

import argparse
import filecmp
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "1")
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")


def same_tree(a: Path, b: Path) -> list[str]:
    """Relative paths whose bytes differ (or exist on one side only)."""
    fa = {p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file()}
    fb = {p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file()}
    diff = sorted(fa ^ fb)
    diff += [r for r in sorted(fa & fb) if not filecmp.cmp(a / r, b / r, shallow=False)]
    return diff


def warm_up(workers: int) -> None:
    """Import the calibration code in every Ray worker (a service pays this once; it is not throughput)."""
    import ray

    def _warm() -> int:
        import importlib
        import time as _t

        for mod in ("robocal.fleet.engine", "robocal.calibration", "robocal.serve.bundle"):
            importlib.import_module(mod)

        _t.sleep(1.0)  # hold the CPU so that the next warm-up task lands on another worker
        return os.getpid()

    ray.get([ray.remote(num_cpus=1)(_warm).remote() for _ in range(workers)])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=200)
    ap.add_argument("--campaigns", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tracking", action="store_true", help="also a 2-worker run with MLflow tracking + registry")
    ap.add_argument("--work", default=None, help="working folder (default: a temporary one)")
    args = ap.parse_args()

    import ray

    from robocal.fleet.run import load_settings, run_fleet
    from robocal.fleet.twin import simulate_fleet
    from robocal.parallel import start_ray

    tmp = tempfile.TemporaryDirectory(prefix="fleet-bench-")
    work = Path(args.work or tmp.name)
    fleet_dir = work / "fleet"
    settings = load_settings()
    t = time.perf_counter()
    truth = simulate_fleet(fleet_dir, args.robots, args.campaigns, args.seed, settings["twin"])
    t_sim = time.perf_counter() - t
    n = args.robots * args.campaigns
    n_events = sum(len(r["events"]) for r in truth["robots"].values())
    print(f"twin fleet: {args.robots} robots x {args.campaigns} campaigns = {n} campaigns, {n_events} planted events")
    print(f"  written in {t_sim:.1f} s; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    settings["tracking"]["enabled"] = False
    engine_s: dict[str, float] = {}
    total_s: dict[str, float] = {}
    cpu: dict[str, tuple[float, float]] = {}
    outs: dict[str, Path] = {}
    res = None
    for workers in (1, 2):
        t = time.perf_counter()
        start_ray(workers)
        warm_up(workers)
        t_init = time.perf_counter() - t
        try:
            out = work / f"out-ray{workers}"
            res = run_fleet(fleet_dir, out, settings, engine="ray", workers=workers, progress=False)
        finally:
            ray.shutdown()
        e = res["timings_s"]["engine"]
        engine_s[f"ray{workers}"] = e
        cpu[f"ray{workers}"] = (res["timings_s"]["engine_cpu"], res["timings_s"]["worker_cpu"])
        outs[f"ray{workers}"] = out
        ff = res["timings_s"]["fleet_files"]
        total_s[f"ray{workers}"] = e + ff
        print(
            f"ray, {workers} worker(s): Ray start + worker warm-up {t_init:.1f} s; engine {e:.1f} s = "
            f"{60 * n / e:.0f} campaigns/min; CPU: driver {res['timings_s']['engine_cpu']:.1f} s, tasks "
            f"{res['timings_s']['worker_cpu']:.1f} s (the workers got "
            f"{res['timings_s']['worker_cpu'] / (workers * e):.0%} of {workers} CPU(s) over the phase; "
            f"tasks in flight on average {res['timings_s']['worker_wall'] / e:.2f}); "
            f"fleet files {ff:.1f} s; load average {os.getloadavg()[0]:.2f}"
        )
    out = work / "out-local"
    res_local = run_fleet(fleet_dir, out, settings, engine="local", progress=False)
    e = res_local["timings_s"]["engine"]
    outs["local"] = out
    print(f"in-process (--engine local): engine {e:.1f} s = {60 * n / e:.0f} campaigns/min")

    t1, t2 = engine_s["ray1"], engine_s["ray2"]
    S = t1 / t2
    f = min(max(2.0 / S - 1.0, 0.0), 1.0)
    r1 = 60 * n / t1

    def amdahl(p: int) -> float:
        return 1.0 / (f + (1.0 - f) / p)

    print(f"speed-up 2 vs 1 worker: {S:.2f}x; Amdahl serial fraction f = 2/S - 1 = {f:.3f}")
    for label, p in (("16-core node", 16), ("10 nodes x 16 cores", 160)):
        print(f"  projection, {label}: speed-up {amdahl(p):.1f}x -> {r1 * amdahl(p):.0f} campaigns/min")
    if f > 0:
        print(f"  (Amdahl's ceiling 1/f = {1 / f:.0f}x whatever the cluster)")
    # contention-free view: the driver's CPU time is the serial work, the tasks' CPU time the parallel work
    d_cpu, w_cpu = cpu["ray2"]
    f_cpu = d_cpu / (d_cpu + w_cpu)
    print(
        f"from CPU times (what a machine of one's own would give): serial fraction {f_cpu:.4f}; 16 CPUs -> "
        f"{1 / (f_cpu + (1 - f_cpu) / 16):.1f}x, 160 CPUs -> {1 / (f_cpu + (1 - f_cpu) / 160):.1f}x; one CPU does "
        f"{60 * n / (w_cpu + d_cpu):.0f} campaigns/min of CPU work -> 16 CPUs "
        f"{60 * n / (w_cpu + d_cpu) / (f_cpu + (1 - f_cpu) / 16):.0f}, 160 CPUs "
        f"{60 * n / (w_cpu + d_cpu) / (f_cpu + (1 - f_cpu) / 160):.0f} campaigns/min"
    )
    S_e2e = total_s["ray1"] / total_s["ray2"]
    f_e2e = min(max(2.0 / S_e2e - 1.0, 0.0), 1.0)
    p160 = 1.0 / (f_e2e + (1.0 - f_e2e) / 160)
    print(
        f"end to end (engine + fleet files): {total_s['ray1']:.1f} s vs {total_s['ray2']:.1f} s, speed-up "
        f"{S_e2e:.2f}x, serial fraction {f_e2e:.3f}, 160 CPUs -> {p160:.1f}x"
    )

    for a, b in (("ray1", "ray2"), ("ray1", "local")):
        d = same_tree(outs[a], outs[b])
        print(f"outputs {a} vs {b}: {'byte-identical' if not d else f'{len(d)} files differ, e.g. {d[:3]}'}")
    assert res is not None
    tr = res.get("truth", {})
    print(
        f"events: {tr.get('n_detected')}/{tr.get('n_events')} flagged, {tr.get('n_right_kind')} of the right kind; "
        f"false flags {tr.get('n_false_flags')} (on {tr.get('n_robots_without_event')} robots without an event); "
        f"missed {tr.get('missed')}; wrong kind {tr.get('wrong_kind')}; test {res['trends']['test']['rule']}"
    )
    c = res["counts"]
    print(f"calibrations: {c['accepted']} accepted, {c['rejected']} rejected, {c['errors']} errors")

    if args.tracking:
        for log_from in ("driver", "workers"):
            uri = f"sqlite:///{work / f'mlflow-{log_from}.db'}"
            settings["tracking"].update({"enabled": True, "uri": uri, "log_from": log_from})
            os.environ["MLFLOW_TRACKING_URI"] = uri
            start_ray(2)
            warm_up(2)
            try:
                out_t = work / f"out-tracked-{log_from}"
                res_t = run_fleet(fleet_dir, out_t, settings, engine="ray", workers=2, progress=False)
            finally:
                ray.shutdown()
            e = res_t["timings_s"]["engine"]
            print(
                f"ray, 2 workers, MLflow tracking + registry (SQLite) logged by the {log_from}: engine {e:.1f} s = "
                f"{60 * n / e:.0f} campaigns/min; tracking errors {len(res_t['tracking']['errors'])}; "
                f"load average {os.getloadavg()[0]:.2f}"
            )
    ok = not same_tree(outs["ray1"], outs["ray2"]) and tr.get("n_detected") == tr.get("n_events")
    ok = ok and tr.get("n_false_flags") == 0
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
