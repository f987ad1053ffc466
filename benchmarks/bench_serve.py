"""Compensation service benchmarks (issue 8): latency, batch throughput, 100k requests, memory.

    python benchmarks/bench_serve.py [--requests 100000] [--batch 1000] [--bundle DIR]

Builds a bundle from a twin campaign (geometric calibration + the stand-in-free thermal model when
robocal.thermal is available, else geometric only), or takes ``--bundle DIR`` (e.g. a real robot's discovered
calibration: ``robocal discover ../shared/data/ur10-ipa --robot ../shared/data/ur10-ipa/robot.yaml --out D``,
then ``robocal serve --make-bundle B --robot ../shared/data/ur10-ipa/robot.yaml --calibration D/calibration.json``), starts the server in a subprocess on loopback and prints:
p50/p99 round-trip latency of single-target requests, batch throughput (corrections/s), and the server's
RSS before/after ``--requests`` mixed requests (valid, malformed, refused) with the count of crashes.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from robocal.serve.client import Client

REPO = Path(__file__).resolve().parents[1]


def rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1


def make_bundle(d: Path) -> Path:
    from robocal.data import read_campaign
    from robocal.robot import load_robot
    from robocal.sim.closed_loop import build_bundle
    from robocal.sim.scenario import load_scenario
    from robocal.sim.twin import simulate

    robot = load_robot("kr16_2")
    simulate(load_scenario("thermal"), d / "camp", seed=0, robot=robot)
    read_campaign(d / "camp", robot)
    return build_bundle(d / "camp", robot, d)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--requests", type=int, default=100_000)
    ap.add_argument("--latency", type=int, default=5000)
    ap.add_argument("--batch", type=int, default=1000)
    ap.add_argument("--bundle", type=Path, help="an existing bundle (default: build one from the thermal twin)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bdir = args.bundle if args.bundle is not None else make_bundle(Path(tmp))
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        s.close()
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
        proc = subprocess.Popen(
            [sys.executable, "-m", "robocal.cli", "serve", "--bundle", str(bdir), "--port", str(port)],
            env=env,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            for _ in range(300):
                try:
                    c = Client("127.0.0.1", port)
                    break
                except OSError:
                    time.sleep(0.1)
            info = c.info()
            temps = {s_: 28.0 for s_ in info["sensors"]}
            lim = np.array(info["q_limits_deg"])
            rng = np.random.default_rng(0)
            q = rng.uniform(lim[:, 0] * 0.5, lim[:, 1] * 0.5, (args.batch, 6))
            q[:, 4] = np.where(np.abs(q[:, 4]) < 15, 30.0, q[:, 4])  # away from the wrist singularity
            for k in range(200):  # warm-up
                c.correct(q[k % len(q)][None], temperatures=temps)
            lat = []
            for k in range(args.latency):
                line = json.dumps({"temperatures": temps, "targets": [{"q_deg": q[k % len(q)].tolist()}]}).encode()
                t = time.perf_counter()
                c.send_raw(line)
                lat.append(time.perf_counter() - t)
            lat_ms = np.array(lat) * 1e3
            print(
                f"latency (1 target/request, {args.latency} requests): p50 {np.percentile(lat_ms, 50):.3f} ms, "
                f"p99 {np.percentile(lat_ms, 99):.3f} ms, max {lat_ms.max():.3f} ms"
            )
            body = json.dumps({"temperatures": temps, "targets": [{"q_deg": r.tolist()} for r in q]}).encode()
            times = []
            for _ in range(10):
                t = time.perf_counter()
                r = c.send_raw(body)
                times.append(time.perf_counter() - t)
            assert r["ok"] and r["n"] == args.batch
            best = min(times)
            print(
                f"batch ({args.batch} targets/request, round trip incl. JSON): median {np.median(times) * 1e3:.1f} ms, "
                f"{args.batch / np.median(times):,.0f} corrections/s (best {args.batch / best:,.0f}); server compute "
                f"{r['elapsed_ms']:.1f} ms; refused {r['n_refused']}"
            )
            rss0 = rss_kb(proc.pid)
            bad = [
                b"{not json",
                b"\xff\xfe",
                b'{"targets": [{"q_deg": [1, 2]}]}',
                b'{"op": "nope"}',
                b"[]",
                json.dumps({"temperatures": dict(temps, T_j1_C=90.0), "targets": [{"q_deg": q[0].tolist()}]}).encode(),
            ]
            kinds = {"ok": 0, "error": 0}
            t0 = time.perf_counter()
            rss_mid = None
            for k in range(args.requests):
                if k % 5 == 4:
                    r = c.send_raw(bad[k % len(bad)])
                else:
                    r = c.send_raw(
                        json.dumps({"temperatures": temps, "targets": [{"q_deg": q[k % len(q)].tolist()}]}).encode()
                    )
                kinds["ok" if r.get("ok") else "error"] += 1
                if k == args.requests // 10:
                    rss_mid = rss_kb(proc.pid)
            dt = time.perf_counter() - t0
            stats = c.request({"op": "stats"})
            rss1 = rss_kb(proc.pid)
            alive = proc.poll() is None
            print(
                f"{args.requests} requests in {dt:.1f} s: {kinds['ok']} ok, {kinds['error']} error replies, "
                f"internal errors {stats['internal']}, server alive: {alive}"
            )
            print(
                f"server RSS: {rss0} kB before, {rss_mid} kB after 10 %, {rss1} kB after 100 % "
                f"(growth over the last 90 %: {rss1 - (rss_mid or rss1)} kB)"
            )
            c.close()
        finally:
            proc.terminate()
            proc.wait(10)


if __name__ == "__main__":
    main()
