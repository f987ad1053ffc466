"""URDF in and out, checked against the parser's own forward kinematics (yourdfpy) on real robots' URDFs."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from robocal.cell.urdf import export_calibration, load_urdf, robot_from_urdf, urdf_fk, write_calibrated_urdf
from robocal.errors import ConfigError
from robocal.kinematics.chain import build_chain, fk
from robocal.robot import load_robot

DATA = Path(__file__).resolve().parent / "data"
# (file, base link, tip link, sha256 of the packaged file; see data/PROVENANCE.md)
REAL = [
    ("ur5_robot.urdf", "base_link", "tool0", "cede880fc2a987ef9dd23bbcda3e0ad1e7b1df8b58d638d100cfbff8ebc806cb"),
    ("kuka_kr16_2.urdf", "base_link", "tool0", "cca192e96b667396283e91d401f6b971b636fae14304c4df42bdf21c9962fcc5"),
    ("abb_irb140.urdf", "base_link", "tool0", "f828982eeb2144e66417d8cb9f55f0ed67d4d38b064262dd4990e1468f1e9f32"),
]
# float64 over ~1-2 m chains of six to ten transforms: ~1e-12 mm of rounding; 1e-9 mm leaves a wide margin and
# still catches any real modelling error (a wrong sign or frame would be millimetres off)
TOL_MM = 1e-9


def _random_q(robot, m: int, seed: int) -> np.ndarray:
    lim = np.clip(robot.q_limits, -2 * np.pi, 2 * np.pi)
    return np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], (m, robot.n_joints))


@pytest.mark.parametrize(("name", "base", "tip", "digest"), REAL)
def test_urdf_in_matches_the_parsers_fk(name, base, tip, digest):
    path = DATA / name
    assert hashlib.sha256(path.read_bytes()).hexdigest() == digest  # the file as the wheel ships it
    robot = robot_from_urdf(path, base, tip)
    assert robot.convention == "poe" and robot.n_joints == 6
    q = _random_q(robot, 25, 0)
    T_ours = fk(build_chain(robot), q)
    T_urdf = urdf_fk(load_urdf(path), q, tip, base, list(robot.joint_names))
    assert np.abs(T_ours[:, :3, 3] - T_urdf[:, :3, 3]).max() < TOL_MM
    assert np.abs(T_ours[:, :3, :3] - T_urdf[:, :3, :3]).max() < 1e-12


def test_copies_equal_the_packaged_files_when_installed():
    """The copies in data/ are the wheels' files (checked when rtb-data / example-robot-data are installed)."""
    import importlib.util
    import sysconfig

    checked = 0
    spec = importlib.util.find_spec("rtbdata")
    if spec is not None and spec.submodule_search_locations:
        root = Path(next(iter(spec.submodule_search_locations)))
        for ours, theirs in (
            ("kuka_kr16_2.urdf", "xacro/kuka_description/kuka_kr16/urdf/kr16_2.urdf"),
            ("abb_irb140.urdf", "xacro/abb_irb140_description/urdf/irb140.urdf"),
        ):
            assert (root / theirs).read_bytes() == (DATA / ours).read_bytes()
            checked += 1
    purelib = Path(sysconfig.get_paths()["purelib"])
    erd = purelib / "cmeel.prefix/share/example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
    if erd.is_file():
        assert erd.read_bytes() == (DATA / "ur5_robot.urdf").read_bytes()
        checked += 1
    if not checked:
        pytest.skip("neither rtb-data nor example-robot-data is installed (the sha256 checks above still hold)")


def test_urdf_limits_and_load_robot_dispatch():
    robot = load_robot(f"{DATA / 'kuka_kr16_2.urdf'}#base_link:tool0")
    # the URDF's limits, rad -> deg: joint_a2 lower -2.70526034059 rad = -155 deg
    assert np.rad2deg(robot.q_limits[1]) == pytest.approx([-155.0, 35.0], abs=1e-6)
    assert robot.joint_names[0] == "joint_a1"
    # default base = root link (UR5's is 'world'); the tip must be named when two leaves end the arm
    with pytest.raises(ConfigError, match=r"name the tip link.*\['ee_link', 'tool0'\]"):
        load_robot(DATA / "ur5_robot.urdf")
    ur = load_robot(f"{DATA / 'ur5_robot.urdf'}#:tool0")
    assert ur.source.endswith("#world:tool0")
    # continuous joints would get +-360 deg; UR5's are revolute +-2 pi
    assert np.rad2deg(ur.q_limits[0]) == pytest.approx([-360.0, 360.0])


def test_urdf_errors_name_the_thing(tmp_path):
    with pytest.raises(ConfigError, match="no link named 'nope'"):
        robot_from_urdf(DATA / "ur5_robot.urdf", "base_link", "nope")
    with pytest.raises(ConfigError, match="not below"):
        robot_from_urdf(DATA / "ur5_robot.urdf", "tool0", "base_link")
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot name='x'><link name='a'/>")
    with pytest.raises(ConfigError, match=r"bad\.urdf"):
        robot_from_urdf(bad)


def _eta(chain, seed: int) -> np.ndarray:
    """Errors well beyond real ones (0.5 mm, 0.05 deg), joint offsets included."""
    rng = np.random.default_rng(seed)
    length = np.array(chain.param_kind) == "length"
    return np.where(length, rng.normal(0, 0.5, chain.n_params), rng.normal(0, np.deg2rad(0.05), chain.n_params))


@pytest.mark.parametrize(("name", "base", "tip"), [(n, b, t) for n, b, t, _ in REAL[:2]])
def test_urdf_out_equals_the_calibrated_model(tmp_path, name, base, tip):
    src = DATA / name
    before = src.read_bytes()
    robot = robot_from_urdf(src, base, tip)
    chain = build_chain(robot)
    eta = _eta(chain, 1)
    tool = np.eye(4)
    tool[:3, :3] = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
    tool[:3, 3] = [35.0, -20.0, 120.0]
    out = write_calibrated_urdf(robot, eta, tmp_path / "cal.urdf", {"T1": tool})
    assert src.read_bytes() == before  # the original is never written
    urdf = load_urdf(out)
    q = _random_q(robot, 25, 2)
    T_model = fk(chain, q, eta) @ tool
    T_urdf = urdf_fk(urdf, q, "robocal_tool_T1", base, list(robot.joint_names))
    assert np.abs(T_model[:, :3, 3] - T_urdf[:, :3, 3]).max() < TOL_MM
    assert np.abs(T_model[:, :3, :3] - T_urdf[:, :3, :3]).max() < 1e-12
    # the tip link itself is the calibrated flange; visuals and other elements pass through
    T_tip = urdf_fk(urdf, q, tip, base, list(robot.joint_names))
    assert np.abs(fk(chain, q, eta)[:, :3, 3] - T_tip[:, :3, 3]).max() < TOL_MM
    assert out.read_text().count("<visual") == before.decode().count("<visual")
    with pytest.raises(ConfigError, match="overwrite"):
        write_calibrated_urdf(robot, eta, src, {})


def test_urdf_out_of_an_mdh_robot_with_beta_tilt(tmp_path, kr16):
    """A robot from an MD-H table (kr16_2: beta on joint 2) is written as a fresh URDF; the tilt is in the
    joint origins."""
    chain = build_chain(kr16)
    eta = _eta(chain, 3)
    assert "beta2" in chain.param_names
    eta[chain.param_names.index("beta2")] = np.deg2rad(0.1)
    out = write_calibrated_urdf(kr16, eta, tmp_path / "kr16_cal.urdf", {})
    urdf = load_urdf(out)
    q = _random_q(kr16, 25, 4)
    T_urdf = urdf_fk(urdf, q, "flange", "base_link", list(kr16.joint_names))
    assert np.abs(fk(chain, q, eta)[:, :3, 3] - T_urdf[:, :3, 3]).max() < TOL_MM


def test_urdf_round_trip_through_a_calibration(tmp_path):
    """A real robot's URDF in, a twin campaign, calibration, URDF (+ YAML) out: FK equal to 1e-9 mm."""
    import yaml

    import robocal

    src = DATA / "kuka_kr16_2.urdf"
    robot = robocal.load_robot(f"{src}#base_link:tool0")
    sc = robocal.load_scenario("geometric")
    sc.update(n_poses=40, n_validation_poses=0)
    robocal.simulate(sc, tmp_path / "camp", seed=5, robot=robot)
    cal = robocal.calibrate(robocal.read_campaign(tmp_path / "camp", robot), robot)
    u, y = export_calibration(cal, tmp_path / "out")
    q = _random_q(robot, 25, 6)
    tool = np.eye(4)
    tool[:3, :3], tool[:3, 3] = cal.model.tool_rotations(cal.x)[0], cal.tools["T1"]
    T_model = fk(build_chain(robot), q, cal.kinematic_errors) @ tool
    T_urdf = urdf_fk(load_urdf(u), q, "robocal_tool_T1", "base_link", list(robot.joint_names))
    assert np.abs(T_model[:, :3, 3] - T_urdf[:, :3, 3]).max() < TOL_MM
    meta = yaml.safe_load(y.read_text())
    assert meta["urdf"]["sha256"] == REAL[1][3] and meta["urdf"]["tip_link"] == "tool0"
    assert set(meta["tools_mm"]) == {"T1"}


def test_urdf_command(tmp_path, capsys):
    import robocal
    from robocal.cli import main
    from robocal.io import write_json

    ref = f"{DATA / 'ur5_robot.urdf'}#base_link:tool0"
    robot = robocal.load_robot(ref)
    sc = robocal.load_scenario("geometric")
    sc.update(n_poses=30, n_validation_poses=0)
    robocal.simulate(sc, tmp_path / "camp", seed=7, robot=robot)
    cal = robocal.calibrate(robocal.read_campaign(tmp_path / "camp", robot), robot)
    write_json(tmp_path / "calibration.json", cal.to_dict())
    rc = main(["urdf", "--robot", ref, "--calibration", str(tmp_path / "calibration.json"), "--out", str(tmp_path)])
    assert rc == 0 and "robocal_tool" not in capsys.readouterr().err
    urdf = load_urdf(tmp_path / "robot_calibrated.urdf")
    q = _random_q(robot, 10, 8)
    T = urdf_fk(urdf, q, "tool0", "base_link", list(robot.joint_names))
    assert np.abs(fk(build_chain(robot), q, cal.kinematic_errors)[:, :3, 3] - T[:, :3, 3]).max() < TOL_MM
    assert main(["urdf", "--robot", ref, "--calibration", str(tmp_path / "nope.json"), "--out", str(tmp_path)]) == 2


#: effect records as ``robocal discover`` writes them into calibration.json (a twin with a backlash of joint 3 and
#: a drifting tracker, seed 9: the records of that run, coefficients rounded)
DISCOVERED = {
    "effects": [
        {
            "key": "backlash:j3",
            "effect": "backlash",
            "joint": 3,
            "harmonic": None,
            "signal": "direction",
            "coefficients": [8.77e-05],
            "coefficient_names": ["half_band"],
            "units": ["rad"],
        }
    ],
    "effects_not_compensated": [
        {
            "key": "drift",
            "effect": "drift",
            "reason": (
                "a measurement-side effect (the tracker's frame moving): it corrects the figures, never the robot"
            ),
        }
    ],
}


def test_urdf_command_names_what_the_urdf_cannot_carry(tmp_path, capsys):
    """A discover calibration: the URDF holds its geometry, and the console and the YAML name each discovered
    effect it cannot hold, with why and where it is compensated (issue 30, item 7: they were dropped silently)."""
    import json

    import yaml

    import robocal
    from robocal.cli import main

    ref = f"{DATA / 'ur5_robot.urdf'}#base_link:tool0"
    robot = robocal.load_robot(ref)
    sc = robocal.load_scenario("geometric")
    sc.update(n_poses=30, n_validation_poses=0)
    robocal.simulate(sc, tmp_path / "camp", seed=7, robot=robot)
    cal = robocal.calibrate(robocal.read_campaign(tmp_path / "camp", robot), robot)
    geometric = cal.to_dict()
    (tmp_path / "geometric.json").write_text(json.dumps(geometric))
    (tmp_path / "discovered.json").write_text(json.dumps({**geometric, **DISCOVERED}))

    argv = ["urdf", "--robot", ref, "--out"]
    assert main([*argv, str(tmp_path / "g"), "--calibration", str(tmp_path / "geometric.json")]) == 0
    out = capsys.readouterr().out
    assert "the geometry" in out and "NOT in the URDF" not in out
    meta = yaml.safe_load((tmp_path / "g" / "robot_calibrated.yaml").read_text())
    assert meta["not_in_urdf"] == [] and "joint's origin" in meta["urdf_carries"]

    assert main([*argv, str(tmp_path / "d"), "--calibration", str(tmp_path / "discovered.json")]) == 0
    out = capsys.readouterr().out
    assert "NOT in the URDF" in out and "2 discovered effect(s)" in out, out
    lines = {line.partition(": ")[0].strip(): line for line in out.splitlines() if line.startswith("  ")}
    assert set(lines) == {"backlash:j3", "drift"}, out
    assert "approached from" in lines["backlash:j3"] and "robocal serve" in lines["backlash:j3"]
    assert "tracker's frame" in lines["drift"] and "compensated by: none" in lines["drift"]
    meta = yaml.safe_load((tmp_path / "d" / "robot_calibrated.yaml").read_text())
    assert [(e["key"], e["joint"]) for e in meta["not_in_urdf"]] == [("backlash:j3", 3), ("drift", None)]
    assert meta["not_in_urdf"][0]["compensated_by"].startswith("robocal serve")
    # the URDF is the geometry alone: the same file as the geometric calibration's
    g, d = (tmp_path / x / "robot_calibrated.urdf" for x in "gd")
    assert g.read_bytes() == d.read_bytes()


def test_urdf_masses_give_the_gravity_torques_yourdfpy_frames_give():
    """A URDF's ``<inertial>`` masses and centres become the description's dynamics (the bodies each joint moves,
    in robocal's body frames): the load torques from them equal the ones computed independently from yourdfpy's
    link frames (torque about joint j of every link beyond it, u_j · Σ (c_k - o_j) x m_k g). A newcomer's heavy
    robot given as a URDF with masses was fitted as if it had none (0.074 mm held-out where its masses give 0.036)."""
    from robocal.cell.urdf import load_urdf, urdf_fk
    from robocal.kinematics.gravity import gravity_torques

    ref = f"{DATA / 'ur5_robot.urdf'}#base_link:tool0"  # UR's own masses and centres
    robot = load_robot(ref)
    assert robot.has_dynamics and robot.link_mass_kg is not None
    urdf = load_urdf(DATA / "ur5_robot.urdf")
    names = list(robot.joint_names)
    q = np.random.default_rng(5).uniform(robot.q_limits[:, 0], robot.q_limits[:, 1], (6, robot.n_joints))
    g = robot.gravity
    # the links each joint moves: the child link of every joint on the path from it to the tip (and fixed kids)
    moved = {nm: [] for nm in names}
    by_parent = {}
    for j in urdf.joint_map.values():
        by_parent.setdefault(j.parent, []).append(j)
    for nm in names:
        stack = [urdf.joint_map[nm].child]
        while stack:
            link = stack.pop()
            moved[nm].append(link)
            stack += [j.child for j in by_parent.get(link, [])]
    want = np.zeros_like(q)
    for p, qp in enumerate(q):
        for i, nm in enumerate(names):
            J = urdf_fk(urdf, qp[None, :], urdf.joint_map[nm].child, "base_link", names)[0]
            u = J[:3, :3] @ (np.asarray(urdf.joint_map[nm].axis, dtype=float))
            o = J[:3, 3] / 1000.0
            for link in moved[nm]:
                inertial = urdf.link_map[link].inertial
                if inertial is None or not inertial.mass:
                    continue
                L = urdf_fk(urdf, qp[None, :], link, "base_link", names)[0]
                c_local = np.eye(4) if inertial.origin is None else np.asarray(inertial.origin)
                c = (L[:3, :3] @ (c_local[:3, 3] * 1000.0) + L[:3, 3]) / 1000.0
                want[p, i] += float(u @ np.cross(c - o, inertial.mass * g))
    got = gravity_torques(robot, q)
    # N·m of a UR5's joints (up to ~100 N·m): 1e-9 relative is round-off; a wrong frame is ~0.1 m x kg off
    assert np.max(np.abs(got - want)) < 1e-9 * max(1.0, float(np.max(np.abs(want))))
    assert "used" in robocal_urdf_note(ref)


def robocal_urdf_note(ref: str) -> str:
    from robocal.cell.urdf import robot_dict_from_urdf, split_ref

    p, b, t = split_ref(ref)
    return str(robot_dict_from_urdf(p, b, t)["urdf"]["inertials"])


def test_urdf_placeholder_masses_are_not_used():
    """The packaged KUKA URDF gives every link 2 kg at its origin (a file written without dynamics): not used."""
    ref = f"{DATA / 'kuka_kr16_2.urdf'}#base_link:tool0"
    assert not load_robot(ref).has_dynamics
    assert "placeholder" in robocal_urdf_note(ref)
