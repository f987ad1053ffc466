"""Issue 16 figures: programs filtered with a calibrated bundle and executed by the twin's true robot (KRL on the
KUKA KR16-2, RAPID on the ABB IRB 120), and the URDF round trip of a real robot's URDF.

    python benchmarks/cell_round_trips.py [--targets 50] [--seed 1] [--out DIR]

Program round trip, per robot:

1. a twin campaign (scenario ``geometric``: true joint-level errors, tracker frame, reflector T1, 15 um noise;
   80 calibration + 20 validation poses), its calibration and the validation mean error (tracker noise included);
2. a bundle (``write_bundle``) and a program of ``--targets`` Cartesian targets (plus a home axis target) at
   random joints inside 10-90 % of each range away from the singularities (|axis 5| >= 30 deg, the elbow >= 20 deg
   from stretched, the wrist centre >= 15 % of the reach off axis 1), the program's tool = the reflector's
   nominal offset, its base a fixture frame;
3. ``filter_program`` (``--tcp-from-bundle T1``: the TCP is the calibrated reflector), the filtered files written,
   read back, and every target turned into joints by the nominal controller's inverse kinematics (also without
   ``--tcp-from-bundle``: the program's nominal tool data on the calibrated flange; one reflector cannot tell a
   flange error from its own offset, so part of the flange error stays);
4. those joints "executed" by the true robot (true errors, true tracker frame, true reflector offset): the error
   at each target is the distance between where the reflector really is and where the program meant it, both in
   the tracker frame (the meant point through the calibrated tracker frame, as the calibration's own validation
   measures). Unfiltered: the original program through the same steps; also after the best rigid fit of the
   unfiltered points (the robot's error a frame registration cannot remove).

URDF round trip: the KUKA KR16-2 URDF shipped by ``rtb-data`` (tests/cell/data) in, a twin campaign on that POE
description, calibration, URDF out, re-parsed with yourdfpy: the largest tool-frame difference from the
calibrated model over 200 random configurations.
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

import robocal
from robocal.cell.programs.common import elbow_angle, frame, rot_zyx_deg, wrist_centre
from robocal.cell.programs.filter import filter_program, nominal_ik, read_program, write_filtered
from robocal.cell.programs.make import krl_program, rapid_module
from robocal.io import write_json
from robocal.kinematics.chain import build_chain, fk
from robocal.kinematics.ik import compile_chain, forward
from robocal.kinematics.transforms import kabsch
from robocal.serve.bundle import load_bundle, write_bundle

ROOT = Path(__file__).resolve().parents[1]


def sample_q(robot: robocal.RobotDescription, m: int, rng: np.random.Generator) -> np.ndarray:
    lim = robot.q_limits
    cc = compile_chain(build_chain(robot))
    reach = float(np.linalg.norm(robot.poe_flange0[:3, 3]) if robot.poe_flange0 is not None else 0.0) or float(
        np.abs(fk(build_chain(robot), np.zeros((1, robot.n_joints)))[0, :3, 3]).max()
    )
    out: list[np.ndarray] = []
    while len(out) < m:
        q = lim[:, 0] + (lim[:, 1] - lim[:, 0]) * (0.1 + 0.8 * rng.random(robot.n_joints))
        # a program taught away from the three singularities (where the service refuses large corrections):
        # |axis 5| >= 30 deg, the elbow >= 20 deg from stretched, the wrist centre >= 15 % of the reach off axis 1
        _, _, U, O = forward(cc, q[None], np.eye(4), record=True)
        wc = wrist_centre(U, O)[0]
        u1, o1 = U[0, :, 0], O[0, :, 0]
        off_axis1 = np.linalg.norm(np.cross(u1, wc - o1))
        if (
            abs(q[4]) >= np.deg2rad(30)
            and abs(elbow_angle(cc, q[None])[0]) >= np.deg2rad(20)
            and off_axis1 >= 0.15 * reach
        ):
            out.append(q)
    return np.array(out)


def calibrated_twin(robot_name: str, folder: Path, seed: int) -> tuple[object, dict, object, float]:
    robot = robocal.load_robot(robot_name)
    sc = robocal.load_scenario("geometric")
    sc["robot"] = robot_name
    if robot_name == "abb_irb120":
        # the scenario's 0.3 mm length errors are sized for a 1.6 m arm; the IRB 120 reaches 0.58 m: scale them
        sc["errors"] = {"length_mm": 0.1, "angle_deg": 0.02}
    truth = robocal.simulate(sc, folder / "camp", seed=seed)
    camp = robocal.read_campaign(folder / "camp", robot)
    res = robocal.calibrate(camp, robot)
    val = robocal.validate(res, camp)["mean_position_mm"]
    write_json(folder / "calibration.json", res.to_dict())
    bundle = load_bundle(write_bundle(folder / "bundle", robot_name, folder / "calibration.json"))
    return robot, truth, bundle, float(val)


def execute(prog_path: Path, bundle: object, truth: dict, cc_nom: object) -> tuple[np.ndarray, np.ndarray]:
    """Where the true reflector is (tracker frame) when the nominal controller runs the program, and where the
    program meant it (tracker frame, through the calibrated tracker frame); Cartesian targets only."""
    prog = read_program(prog_path)
    q = nominal_ik(prog, cc_nom, bundle.robot.q_limits)
    rows = [k for k, t in enumerate(prog.targets) if t.kind == "pose"]
    chain = bundle.chain
    eta_true = np.array([truth["kinematic_errors"][n] for n in chain.param_names])
    T_true = np.array(truth["tracker_T_base"])
    t_true = np.array(truth["tools_mm"]["T1"])
    flange = fk(chain, q[rows], eta_true, T_true)
    p_real = flange[:, :3, :3] @ t_true + flange[:, :3, 3]
    meant = np.array([(t.base @ t.T_base_tcp)[:3, 3] for k, t in enumerate(prog.targets) if k in rows])
    Tc = bundle.tracker_T_base
    p_meant = meant @ Tc[:3, :3].T + Tc[:3, 3]
    return p_real, p_meant


def program_round_trip(dialect: str, robot_name: str, n_targets: int, seed: int, work: Path) -> dict:
    t0 = time.perf_counter()
    robot, truth, bundle, val = calibrated_twin(robot_name, work / dialect, seed)
    t_cal = time.perf_counter() - t0
    cc_nom = compile_chain(bundle.chain)
    rng = np.random.default_rng(seed + 100)
    q = sample_q(robot, n_targets, rng)
    tool = frame(np.eye(3), [35.0, -20.0, 120.0])  # the reflector's nominal offset (scenario "geometric")
    reach = np.abs(fk(bundle.chain, q)[:, :3, 3]).max()
    base = frame(rot_zyx_deg(30.0, 0.0, 0.0), [0.3 * reach, -0.1 * reach, 0.1 * reach])
    src_dir, out_dir = work / dialect / "program", work / dialect / "filtered"
    src_dir.mkdir(parents=True)
    if dialect == "krl":
        s, d, c = krl_program("Cell16", cc_nom, q, tool, base)
        (src_dir / "Cell16.src").write_bytes(s.encode())
        (src_dir / "Cell16.dat").write_bytes(d.encode())
        (src_dir / "$config.dat").write_bytes(c.encode())
        main = src_dir / "Cell16.src"
    else:
        (src_dir / "Cell16.mod").write_bytes(rapid_module("Cell16", cc_nom, q, tool, base).encode())
        main = src_dir / "Cell16.mod"
    before = {p.name: p.read_bytes() for p in src_dir.iterdir()}
    t1 = time.perf_counter()
    res = filter_program(read_program(main), bundle, tcp_from_bundle="T1")
    # the same with the program's tool data taken as exact on the calibrated flange (no TCP from the calibration):
    # what is left is the part of the flange error a single reflector cannot separate from its own offset
    res_nominal_tcp = filter_program(read_program(main), bundle)
    t_filter = time.perf_counter() - t1
    write_filtered(res, out_dir)
    write_filtered(res_nominal_tcp, work / dialect / "filtered_nominal_tcp")
    if dialect == "krl":
        shutil.copy(src_dir / "$config.dat", work / dialect / "filtered_nominal_tcp" / "$config.dat")
    if dialect == "krl":
        shutil.copy(src_dir / "$config.dat", out_dir / "$config.dat")  # read-only tool/base data, as on the cell
    assert {p.name: p.read_bytes() for p in src_dir.iterdir()} == before, "the original program was modified"
    p_f, _ = execute(out_dir / main.name, bundle, truth, cc_nom)
    p_u, meant = execute(main, bundle, truth, cc_nom)  # what the original program meant
    p_n, _ = execute(work / dialect / "filtered_nominal_tcp" / main.name, bundle, truth, cc_nom)
    meant_u = meant
    e_f = np.linalg.norm(p_f - meant, axis=1)
    pose_rows = [k for k, t in enumerate(res.program.targets) if t.kind == "pose"]
    accepted = np.array([res.status[k] != "refused" for k in pose_rows])
    e_u = np.linalg.norm(p_u - meant_u, axis=1)
    R = kabsch(meant_u, p_u)
    e_u_rigid = np.linalg.norm(p_u - (meant_u @ R[:3, :3].T + R[:3, 3]), axis=1)
    return {
        "dialect": dialect,
        "robot": robot_name,
        "targets": len(e_f),
        "refused": res.n_refused,
        "flagged": res.n_flagged,
        "validation_mean_mm": val,
        "filtered_mean_mm": float(e_f.mean()),
        "filtered_max_mm": float(e_f.max()),
        "filtered_accepted_mean_mm": float(e_f[accepted].mean()),
        "accepted": int(accepted.sum()),
        "unfiltered_mean_mm": float(e_u.mean()),
        "nominal_tcp_mean_mm": float(np.linalg.norm(p_n - meant, axis=1).mean()),
        "unfiltered_rigid_mean_mm": float(e_u_rigid.mean()),
        "ratio_to_validation": float(e_f.mean() / val),
        "calibration_s": t_cal,
        "filter_s": t_filter,
    }


def urdf_round_trip(seed: int, work: Path) -> dict:
    from robocal.cell.urdf import export_calibration, load_urdf, urdf_fk

    src = ROOT / "tests" / "cell" / "data" / "kuka_kr16_2.urdf"
    digest = hashlib.sha256(src.read_bytes()).hexdigest()
    robot = robocal.load_robot(f"{src}#base_link:tool0")
    sc = robocal.load_scenario("geometric")
    robocal.simulate(sc, work / "urdf" / "camp", seed=seed, robot=robot)
    camp = robocal.read_campaign(work / "urdf" / "camp", robot)
    cal = robocal.calibrate(camp, robot)
    val = robocal.validate(cal, camp)["mean_position_mm"]
    u_path, y_path = export_calibration(cal, work / "urdf" / "out")
    urdf = load_urdf(u_path)
    chain = build_chain(robot)
    q = sample_q(robot, 200, np.random.default_rng(seed))
    T_model = fk(chain, q, cal.kinematic_errors)
    tool = np.eye(4)
    tool[:3, :3] = cal.model.tool_rotations(cal.x)[0]
    tool[:3, 3] = cal.tools["T1"]
    T_model = T_model @ tool
    T_urdf = urdf_fk(urdf, q, "robocal_tool_T1", "base_link", list(robot.joint_names))
    return {
        "urdf": str(src.relative_to(ROOT)),
        "parameters": int(chain.n_params),
        "identified": int(cal.identified[: chain.n_params].sum()),
        "validation_mean_mm": float(val),
        "max_position_diff_mm": float(np.abs(T_model[:, :3, 3] - T_urdf[:, :3, 3]).max()),
        "max_rotation_diff": float(np.abs(T_model[:, :3, :3] - T_urdf[:, :3, :3]).max()),
        "original_unchanged": hashlib.sha256(src.read_bytes()).hexdigest() == digest,
        "written": [str(u_path.name), str(y_path.name)],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, default=50)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=None, help="keep the files here (default: a temporary folder)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = a.out or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for dialect, robot in (("krl", "kr16_2"), ("rapid", "abb_irb120")):
            r = program_round_trip(dialect, robot, a.targets, a.seed, work)
            ok = r["filtered_mean_mm"] <= 1.2 * r["validation_mean_mm"]
            print(
                f"{dialect.upper():5s} {robot:10s} {r['targets']} Cartesian targets ({r['refused']} refused, "
                f"{r['flagged']} flagged): executed by the true robot, mean error filtered "
                f"{r['filtered_mean_mm']:.4f} mm "
                f"(max {r['filtered_max_mm']:.4f}; {r['filtered_accepted_mean_mm']:.4f} over the {r['accepted']} "
                f"accepted), unfiltered {r['unfiltered_mean_mm']:.4f} mm "
                f"({r['unfiltered_rigid_mean_mm']:.4f} after a best rigid fit); calibration validation mean "
                f"{r['validation_mean_mm']:.4f} mm -> ratio {r['ratio_to_validation']:.2f} "
                f"({'within' if ok else 'NOT within'} 1.2x); filter {r['filter_s']:.2f} s; with the program's tool "
                f"data instead of the calibrated TCP: mean {r['nominal_tcp_mean_mm']:.4f} mm"
            )
        u = urdf_round_trip(a.seed, work)
        print(
            f"URDF  {u['urdf']}: POE, {u['parameters']} parameters ({u['identified']} identified), validation mean "
            f"{u['validation_mean_mm']:.4f} mm; written URDF vs calibrated model over 200 configurations: "
            f"max position diff {u['max_position_diff_mm']:.3g} mm, rotation {u['max_rotation_diff']:.3g}; "
            f"original unchanged: {u['original_unchanged']}"
        )


if __name__ == "__main__":
    main()
