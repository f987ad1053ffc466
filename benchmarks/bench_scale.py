"""Scale of calibrate and discover with the row count (issue 31 item 5).

    python benchmarks/bench_scale.py                      # twin and the UR10 series, 1 500 .. 12 000 rows
    python benchmarks/bench_scale.py --sizes 1500 3000 --sets ur10 --commands discover
    python benchmarks/bench_scale.py --sets twin --sizes 1500 3000 6000 12000 24000

Each (set, size, command) runs ``robocal calibrate`` / ``robocal discover`` in its own subprocess, so that its
peak RSS is its own (``wait4``'s rusage of that child); the table gives wall time, CPU time (user + system: on a
shared machine the wall time also holds the other work's share), peak RSS, and per doubling of the rows the
ratio of each to the previous size.

Sets: ``ur10`` — the first N rows of the UR10 grid series (``--ur10``, default ``../shared/data/ur10-ipa-A``,
11 911 rows: the 12 000 size is the whole series), with its robot.yaml; ``twin`` — a simulated KR16 campaign of
N rows (80 % calibration, 20 % validation poses; a joint-4 gear error and joint-2/5 backlash to find).
Campaigns are written once into ``--work`` (default a temporary folder) and reused; each run's console (with
discovery's progress lines: time and peak memory per step) is ``--work``/out-SET-COMMAND-ROWS.log.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
UR10 = ROOT.parent / "shared" / "data" / "ur10-ipa-A"

TWIN_EFFECTS = {
    "gear": {"joint": 4, "harmonics": [{"harmonic": 1, "amplitude_deg": 0.005, "phase_deg": 40.0}]},
    "backlash": {"joints": {2: 0.006, 5: 0.02}},
}


def ur10_campaign(src: Path, n: int, work: Path) -> tuple[Path, str]:
    d = work / f"ur10-{n}"
    if not (d / "poses.csv").exists():
        d.mkdir(parents=True, exist_ok=True)
        for f in src.iterdir():
            if f.is_file() and f.name != "poses.csv":
                shutil.copy(f, d / f.name)
        with open(src / "poses.csv") as fi, open(d / "poses.csv", "w") as fo:
            for i, line in enumerate(fi):
                if i > n:
                    break
                fo.write(line)
    return d, str(d / "robot.yaml")


def twin_campaign(n: int, work: Path) -> tuple[Path, str]:
    from robocal.sim.scenario import load_scenario
    from robocal.sim.twin import simulate

    d = work / f"twin-{n}"
    if not (d / "poses.csv").exists():
        sc = load_scenario("geometric")
        n_cal = (4 * n) // 5
        sc.update(n_poses=n_cal, n_validation_poses=n - n_cal, effects=TWIN_EFFECTS)
        simulate(sc, d, seed=1)
    return d, "kr16_2"


def measure(cmd: list[str], env: dict[str, str], log: Path) -> tuple[float, float, float, int]:
    """Wall s, CPU s (user + system), peak RSS MB and exit status of one subprocess (its console in ``log``)."""
    t0 = time.perf_counter()
    with open(log, "w") as f:
        p = subprocess.Popen(cmd, env=env, stdout=f, stderr=subprocess.STDOUT)
        _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    rc = os.waitstatus_to_exitcode(status)
    p.returncode = rc
    if rc:
        print(f"  failed ({rc}): {' '.join(cmd)}\n{log.read_text()[-2000:]}", file=sys.stderr)
    return wall, ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024.0, rc


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1500, 3000, 6000, 12000])
    ap.add_argument("--sets", nargs="+", default=["twin", "ur10"], choices=["twin", "ur10"])
    ap.add_argument("--commands", nargs="+", default=["calibrate", "discover"], choices=["calibrate", "discover"])
    ap.add_argument("--ur10", type=Path, default=UR10, help="the UR10 series folder (data contract)")
    ap.add_argument("--work", type=Path, default=None, help="campaigns and outputs (default: a temporary folder)")
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="bench_scale_"))
    work.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    exe = shutil.which("robocal") or "robocal"
    print(f"campaigns and outputs in {work}; robocal = {exe}")
    print(f"{'set':5s} {'command':9s} {'rows':>6s} {'wall s':>8s} {'CPU s':>8s} {'RSS MB':>8s}   per doubling: "
          "wall, CPU, RSS")  # fmt: skip
    for s in a.sets:
        for c in a.commands:
            prev: tuple[int, float, float, float] | None = None
            for n in a.sizes:
                d, robot = ur10_campaign(a.ur10, n, work) if s == "ur10" else twin_campaign(n, work)
                out = work / f"out-{s}-{c}-{n}"
                cmd = [exe, c, str(d), "--robot", robot, "--out", str(out), "--no-report"]
                wall, cpu, rss, rc = measure(cmd, env, work / f"out-{s}-{c}-{n}.log")
                line = f"{s:5s} {c:9s} {n:6d} {wall:8.1f} {cpu:8.1f} {rss:8.0f}"
                if prev is not None and rc == 0:
                    k = n / prev[0]
                    per = 1.0 / max(1e-9, math.log2(k))
                    line += (f"   x{(wall / prev[1]) ** per:.2f}  x{(cpu / prev[2]) ** per:.2f}  "
                             f"x{(rss / prev[3]) ** per:.2f}")  # fmt: skip
                print(line + ("" if rc == 0 else "  FAILED"), flush=True)
                prev = (n, wall, cpu, rss) if rc == 0 else None
    return 0


if __name__ == "__main__":
    sys.exit(main())
