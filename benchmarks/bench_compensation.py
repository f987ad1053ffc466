"""Offline compensation of many poses with a real robot's full model (issue 25 item 5: "12 000 poses in <= 10 s").

    python benchmarks/bench_compensation.py --calibration D/calibration.json \
        --robot ../shared/data/ur10-ipa/robot.yaml --data ../shared/data/ur10-ipa [--poses 12000] [--layer]

``D`` is the output folder of ``robocal discover`` on the robot's data (its ``calibration.json`` carries the
geometry and every joint-level effect the service applies). The poses are the data's joint configurations moved
by up to +-5 deg per joint (seeded), so they lie in the calibrated region. Timed, one process, single-threaded
BLAS: ``robocal.compensate`` (the offline path of ``compensation.csv``) on all poses in one call, and the
service's ``correct`` (the path the program filter shares) in requests of 1 000 targets.

``--layer`` adds a residual layer on every joint (the model the discovery writes when cross-validation accepts
one: 100 k-means centres of the data's configurations, 30 deg length scale, coefficients drawn at the prior's
0.002 deg): its cost, on data where the discovery did not accept one.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np


def _with_layer(cal: dict, q: np.ndarray, seed: int) -> dict:
    from robocal.compensation.signals import layer_features
    from robocal.discovery.physics import layer_centres

    centres = layer_centres(q, 100, seed)
    ell = float(np.deg2rad(30.0))
    _, d = layer_features(q, centres, ell)
    inside = float(np.quantile(d, 0.95))
    rng = np.random.default_rng(seed)
    layer = [
        {"key": f"layer:j{j}", "effect": "layer", "joint": j, "harmonic": None, "signal": "layer",
         "centres_rad": centres.tolist(), "length_rad": ell, "inside_rad": inside,
         "coefficients": rng.normal(0.0, np.deg2rad(0.002), len(centres)).tolist(),
         "coefficient_names": [f"c{k}" for k in range(len(centres))], "units": ["rad"] * len(centres)}
        for j in range(1, q.shape[1] + 1)
    ]  # fmt: skip
    return {**cal, "effects": [*cal.get("effects", []), *layer]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calibration", type=Path, required=True)
    ap.add_argument("--robot", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True, help="the robot's campaign folder (its configurations)")
    ap.add_argument("--poses", type=int, default=12_000)
    ap.add_argument("--layer", action="store_true", help="add a residual layer on every joint (its cost)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep-bundle", type=Path, help="also write the bundle served here (e.g. for bench_serve.py)")
    args = ap.parse_args()

    import robocal
    from robocal.data import read_campaign
    from robocal.robot import load_robot
    from robocal.serve.bundle import load_bundle, write_bundle
    from robocal.serve.protocol import Service

    robot = load_robot(args.robot)
    camp = read_campaign(args.data, robot)
    cal_dict = json.loads(args.calibration.read_text(encoding="utf-8"))
    if args.layer:
        cal_dict = _with_layer(cal_dict, camp.q, args.seed)
    rng = np.random.default_rng(args.seed)
    q = camp.q[rng.integers(0, camp.n_rows, args.poses)] + np.deg2rad(rng.uniform(-5.0, 5.0, (args.poses, 6)))
    keys = [e["key"] for e in cal_dict.get("effects", [])]
    print(f"{args.poses} poses; effects applied: {', '.join(keys) or 'none'}")

    cal = robocal.load_calibration(cal_dict, robot)
    robocal.compensate(cal, q[:10])  # warm-up: the compiled kernels (each call builds its effect tables again)
    t = time.perf_counter()
    comp = robocal.compensate(cal, q)  # one robocal.Corrected
    dt = time.perf_counter() - t
    st = np.asarray(comp.status)
    print(f"robocal.compensate (compensation.csv's path), one call: {dt:.2f} s "
          f"({args.poses / dt:,.0f} poses/s); status ok {np.mean(st == 'ok'):.1%}")  # fmt: skip

    with tempfile.TemporaryDirectory() as tmp:
        cpath = Path(tmp) / "calibration.json"
        cpath.write_text(json.dumps(cal_dict), encoding="utf-8")
        bdir = Path(tmp) / "bundle"
        write_bundle(bdir, args.robot, cpath)
        svc = Service(load_bundle(bdir))
        batches = [q[k : k + 1000] for k in range(0, args.poses, 1000)]
        svc.correct({"targets": [{"q_deg": r.tolist()} for r in np.rad2deg(batches[0][:10])]})  # warm-up
        t = time.perf_counter()
        n_ref = 0
        for b in batches:
            out = svc.correct({"targets": [{"q_deg": r.tolist()} for r in np.rad2deg(b)]})
            n_ref += out["n_refused"]
        dt = time.perf_counter() - t
        print(f"service correct (the program filter's path), {len(batches)} requests of <= 1000 targets: {dt:.2f} s "
              f"({args.poses / dt:,.0f} poses/s incl. request parsing); refused {n_ref}")  # fmt: skip
        if args.keep_bundle is not None:
            write_bundle(args.keep_bundle, args.robot, cpath)
            print(f"wrote the bundle to {args.keep_bundle}")


if __name__ == "__main__":
    main()
