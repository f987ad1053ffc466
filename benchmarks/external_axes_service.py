"""The compensation service for a robot on external axes (issue 34), checked against the twin's truth.

For each scenario (``track``: a KR16-2 on a 6 m track; ``column``: on a lifting column) and seed, the twin writes
a campaign, ``robocal.calibrate`` and :func:`robocal.calibration.axes.fit_axis_errors` fit it, and the
calibration with its ``axes`` is bundled (:func:`robocal.serve.bundle.write_bundle`). Fresh targets are sent to the
service (:class:`robocal.serve.protocol.Service`, the ``correct`` op) as joint targets and as pose targets (the
nominal pose, ``ext_mm`` with it), with the external axis kept and moved (``move_external``). Printed: targets not
refused, the twin's error at the meant position before and after (mean / max, mm, over the targets served), the
largest joint difference between the pose and the joint targets' corrections, the largest external axis move,
and the time per target of the external-axes path against a revolute KR16-2 bundle's (same number of joint
targets; the revolute path runs the compiled chain).

    python benchmarks/external_axes_service.py [--scenarios track column] [--seeds 1] [--targets 200]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

import robocal
from robocal.calibration.axes import axis_errors, calibration_axes, fit_axis_errors, term_named
from robocal.data.contract import read_campaign
from robocal.io import write_json
from robocal.kinematics.axes import augment
from robocal.kinematics.chain import build_chain, fk, propagate
from robocal.kinematics.ik import quaternions
from robocal.robot import load_robot
from robocal.serve.bundle import load_bundle, write_bundle
from robocal.serve.protocol import Service
from robocal.sim.scenario import load_scenario, sample_poses
from robocal.sim.twin import simulate


def true_points(robot, truth, q, payload):
    chain = build_chain(robot)
    eta = np.array([truth["kinematic_errors"][n] for n in chain.param_names])
    terms = [term_named(robot, n) for n in truth["axis_errors"]]
    E = axis_errors(robot, q, payload, terms, np.array(list(truth["axis_errors"].values())))
    st = propagate(augment(chain, [0]), np.concatenate([q, E], axis=1), eta, np.array(truth["tracker_T_base"]))
    t = np.array(truth["tools_mm"]["T1"])
    return st.o + st.x * t[0] + st.y * t[1] + st.z * t[2]


def ask(service: Service, **req) -> dict:
    reply = json.loads(service.handle_line(json.dumps({"op": "correct", **req}).encode()))
    assert reply["ok"], reply
    return reply


def per_target_ms(service: Service, targets: list, repeat: int = 3) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        ask(service, targets=targets)
        best = min(best, time.perf_counter() - t0)
    return 1e3 * best / len(targets)


def one(name: str, seed: int, n_targets: int, tmp: Path) -> None:
    sc = load_scenario(name)
    robot = load_robot(sc["robot"])
    out = tmp / f"{name}_{seed}"
    truth = simulate(dict(sc, n_validation_poses=0), out / "camp", seed=seed, robot=robot)
    camp = read_campaign(out / "camp", robot)
    res = robocal.calibrate(camp, robot)
    fit = fit_axis_errors(camp, res)
    write_json(out / "cal.json", res.to_dict() | {"axes": calibration_axes(fit)})
    service = Service(load_bundle(write_bundle(out / "bundle", robot.name, out / "cal.json")))
    payload = float(sc.get("payload_kg", 0.0))
    q_t = sample_poses(robot, n_targets, np.random.default_rng(2000 + seed), 0.8)
    joints = [{"q_deg": np.rad2deg(q[1:]).tolist(), "ext_mm": [float(q[0])]} for q in q_t]
    tool = service.bundle.tools["T1"]
    T = fk(build_chain(robot), q_t) @ tool
    quat = quaternions(T[:, :3, :3])
    seeds = np.rad2deg(q_t[:, 1:]) + 2.0
    poses = [{"xyz_mm": T[k, :3, 3].tolist(), "quat_wxyz": quat[k].tolist(), "q_seed_deg": seeds[k].tolist(),
              "ext_mm": [float(q_t[k, 0])]} for k in range(len(q_t))]  # fmt: skip
    Tb = res.model.base_transform(fit.x) @ fk(build_chain(robot), q_t)
    p_des = Tb[:, :3, 3] + Tb[:, :3, :3] @ res.model.tools(fit.x)[0]
    pl = np.full(len(q_t), payload)
    before = np.linalg.norm(true_points(robot, truth, q_t, pl) - p_des, axis=1)
    by_joint = {}
    for move in (False, True):
        for kind, targets in (("joint", joints), ("pose", poses)):
            reply = ask(service, targets=targets, move_external=move, payload_kg=payload)
            ok = np.array([r["status"] != "refused" for r in reply["results"]])
            qc = np.array(
                [[*r["ext_mm"], *np.deg2rad(r["q_deg"])] for r in reply["results"] if r["status"] != "refused"]
            )
            after = np.linalg.norm(true_points(robot, truth, qc, pl[ok]) - p_des[ok], axis=1)
            b, move_mm = before[ok], np.abs(qc[:, 0] - q_t[ok, 0]).max()
            line = (
                f"{name} seed {seed} {kind:5s} move_external={move!s:5s}: served {ok.sum()}/{len(ok)}, twin error "
                f"before {b.mean():.3f} / {b.max():.3f} mm, after {after.mean():.4f} / {after.max():.4f} mm, "
                f"largest axis move {move_mm:.3f} mm"
            )
            if kind == "joint":
                by_joint[move] = reply
            else:
                d = [np.abs(np.subtract(rp["q_deg"], rj["q_deg"])).max()
                     for rp, rj in zip(reply["results"], by_joint[move]["results"], strict=True)
                     if rp["status"] != "refused" and rj["status"] != "refused"]  # fmt: skip
                line += f", pose vs joint targets {max(d):.1e} deg ({sum(v > 1e-3 for v in d)} > 1e-3)"
            print(line)
    ms = per_target_ms(service, joints)
    print(f"{name} seed {seed}: {ms:.3f} ms per joint target ({len(joints)} per request, external-axes path)")


def revolute_ms(n_targets: int, tmp: Path) -> None:
    robot = load_robot("kr16_2")
    simulate(dict(load_scenario("geometric"), n_poses=60, n_validation_poses=0), tmp / "rev", seed=0)
    write_json(tmp / "rev.json", robocal.calibrate(read_campaign(tmp / "rev", robot), robot).to_dict())
    service = Service(load_bundle(write_bundle(tmp / "rev_bundle", "kr16_2", tmp / "rev.json")))
    q = sample_poses(robot, n_targets, np.random.default_rng(7), 0.8)
    ms = per_target_ms(service, [{"q_deg": np.rad2deg(r).tolist()} for r in q])
    print(f"kr16_2 (revolute, compiled): {ms:.3f} ms per joint target ({n_targets} per request)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenarios", nargs="+", default=["track", "column"])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--targets", type=int, default=200)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        for name in a.scenarios:
            for seed in range(a.seeds):
                one(name, seed, a.targets, Path(d))
        revolute_ms(a.targets, Path(d))


if __name__ == "__main__":
    main()
