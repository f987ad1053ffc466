"""Issue 34, descriptions: prismatic joints (a track, a column) in MD-H and POE, joint coupling (FANUC J2/J3),
URDF in/out with prismatic joints, the data door in mm, and clear errors for bad declarations."""

from __future__ import annotations

import copy

import numpy as np
import pandas as pd
import pytest
import yaml

from robocal.calibration.fit import calibrate
from robocal.cell.urdf import load_urdf, robot_from_urdf, urdf_fk, write_calibrated_urdf
from robocal.data import read_campaign
from robocal.errors import ConfigError, DataError
from robocal.kinematics.chain import build_chain, fk, propagate
from robocal.kinematics.gravity import gravity_regressor, gravity_torques, potential_energy
from robocal.kinematics.transforms import homogeneous, rotx, rotz
from robocal.robot import SHIPPED_ROBOT_DIR, load_robot, robot_from_dict
from robocal.sim.twin import load_scenario, simulate

# float64 over chains of ~10 m (a 6 m track): ~1e-11 mm of rounding; 1e-8 mm still catches any modelling error
TOL_MM = 1e-8


def _yaml(name: str) -> dict:
    return yaml.safe_load((SHIPPED_ROBOT_DIR / f"{name}.yaml").read_text())


def _q(robot, m: int, seed: int) -> np.ndarray:
    lim = robot.q_limits
    return np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], (m, robot.n_joints))


def test_a_prismatic_joint_moves_along_its_axis_as_computed_by_hand():
    """Rot_x(alpha) Trans_x(a) Rot_z(theta) Trans_z(d + q), then a revolute joint: the chain against matrices."""
    data = {
        "name": "slide",
        "joints": [
            {"name": "E1", "type": "prismatic", "a_mm": 100, "alpha_deg": -90, "d_mm": 50, "theta_offset_deg": 30,
             "q_min_mm": 0, "q_max_mm": 2000},
            {"name": "J1", "a_mm": 200, "alpha_deg": 90, "d_mm": 10, "theta_offset_deg": 0,
             "q_min_deg": -180, "q_max_deg": 180},
        ],
    }  # fmt: skip
    robot = robot_from_dict(data, "slide.yaml")
    assert robot.prismatic.tolist() == [True, False]
    assert robot.q_limits[0].tolist() == [0.0, 2000.0]  # mm, not converted
    q = np.array([[250.0, 0.3], [1800.0, -1.2]])
    T = fk(build_chain(robot), q)
    for k in range(2):
        A1 = homogeneous(rotx(-np.pi / 2), np.zeros(3)) @ homogeneous(np.eye(3), [100, 0, 0])
        A1 = A1 @ homogeneous(rotz(np.pi / 6), np.zeros(3)) @ homogeneous(np.eye(3), [0, 0, 50 + q[k, 0]])
        A2 = homogeneous(rotx(np.pi / 2), np.zeros(3)) @ homogeneous(np.eye(3), [200, 0, 0])
        A2 = A2 @ homogeneous(rotz(q[k, 1]), np.zeros(3)) @ homogeneous(np.eye(3), [0, 0, 10])
        assert np.abs(T[k] - A1 @ A2).max() < 1e-9
    # the slide's direction: 1000 mm more travel move the flange by 1000 mm along the slide's axis, base +y
    q2 = q.copy()
    q2[:, 0] += 1000.0
    assert fk(build_chain(robot), q2)[:, :3, 3] - T[:, :3, 3] == pytest.approx(np.tile([0, 1000.0, 0], (2, 1)))


def _poe_of(robot) -> dict:
    """A POE description of an MD-H robot: each joint's axis and origin at q = 0 (propagate's records)."""
    chain = build_chain(robot)
    st = propagate(chain, np.zeros((1, robot.n_joints)), record=True)
    twists = []
    for j in range(robot.n_joints):
        e = int(np.flatnonzero(chain.joint == j)[0])
        twists.append({"w": np.ravel(st.axes[e]).tolist(), "p_mm": np.ravel(st.origins[e]).tolist()})
    T0 = fk(chain, np.zeros((1, robot.n_joints)))[0]
    data = _yaml(robot.name)
    joints = [{k: v for k, v in j.items() if k.startswith(("name", "type", "q_"))} for j in data["joints"]]
    return {
        "name": f"{robot.name}_poe",
        "convention": "poe",
        "joints": joints,
        "poe": {"twists": twists, "flange_at_zero_mm": T0[:3, 3].tolist(), "flange_R_at_zero": T0[:3, :3].tolist()},
    }


@pytest.mark.parametrize("name", ["kr16_2_track", "kr16_2_column"])
def test_mdh_and_poe_agree_on_a_chain_with_a_prismatic_axis(name):
    mdh = load_robot(name)
    poe = robot_from_dict(_poe_of(mdh), f"{name}_poe")
    assert poe.prismatic.tolist() == mdh.prismatic.tolist() and poe.prismatic[0]
    assert "d1" in build_chain(poe).param_names  # the POE slide's zero offset is a parameter
    q = _q(mdh, 30, 1)
    assert np.abs(fk(build_chain(mdh), q) - fk(build_chain(poe), q)).max() < TOL_MM


def test_the_packaged_track_moves_the_arm_along_the_track():
    robot = load_robot("kr16_2_track")
    q = np.zeros((2, 7))
    q[1, 0] = 6000.0
    T = fk(build_chain(robot), q)
    assert T[1, :3, 3] - T[0, :3, 3] == pytest.approx([0.0, 6000.0, 0.0], abs=1e-9)


def _twin(tmp_path, robot, name, n_poses=40):
    sc = dict(load_scenario("geometric"))
    sc.update(robot=robot.name, n_poses=n_poses, n_validation_poses=10)
    out = tmp_path / name
    truth = simulate(sc, out, seed=3, robot=robot)
    return out, truth


def test_a_fanuc_style_coupled_description_gives_the_same_fit_as_the_decoupled_angles(tmp_path):
    data = _yaml("kr16_2")
    data["coupling"] = "fanuc_j2j3"
    coupled = robot_from_dict(data, "kr16_2_fanuc.yaml")
    assert coupled.coupling is not None and coupled.coupling[2, 1] == -1.0
    # the same arm described with the kinematic (decoupled) J3; its range is not the controller's J3 range
    data = _yaml("kr16_2")
    data["joints"][2].update(q_min_deg=-360.0, q_max_deg=360.0)
    plain = robot_from_dict(data, "kr16_2_decoupled.yaml")
    d_coup, _ = _twin(tmp_path, coupled, "coupled")
    f_coup = pd.read_csv(d_coup / "poses.csv")
    # the user's other file: the decoupled angles, J3 - J2 of the reported ones
    d_plain = tmp_path / "decoupled"
    d_plain.mkdir()
    f_plain = f_coup.copy()
    f_plain["q3_deg"] = (f_coup["q3_deg"] - f_coup["q2_deg"]).round(6)
    f_plain.to_csv(d_plain / "poses.csv", index=False)
    assert np.abs(f_coup["q3_deg"] - f_plain["q3_deg"]).max() > 10.0  # the coupling is not a small change
    c_plain, c_coup = read_campaign(d_plain, plain), read_campaign(d_coup, coupled)
    # converted once at the door: the same kinematic angles inside (to the files' 1e-6 deg rounding)
    assert np.abs(c_coup.q - c_plain.q).max() < 1e-7
    # and written back as reported
    assert np.abs(c_coup.to_frame()["q3_deg"].to_numpy() - f_coup["q3_deg"].to_numpy()).max() < 1e-9
    r_plain, r_coup = calibrate(c_plain, plain), calibrate(c_coup, coupled)
    assert r_plain.names == r_coup.names
    # the same fit: the inputs differ by 1e-6 deg of rounding at most (1e-5 mm at 1 m), far below the noise
    assert r_coup.fit["rms_position_mm"] == pytest.approx(r_plain.fit["rms_position_mm"], rel=1e-4)
    assert np.abs(r_coup.x - r_plain.x).max() < 1e-4
    # the uncoupled description on the coupled file is a different (wrong) robot: the coupling matters
    r_wrong = calibrate(read_campaign(d_coup, plain), plain)
    assert r_wrong.fit["rms_position_mm"] > 10 * r_plain.fit["rms_position_mm"]


def test_a_track_campaign_is_read_in_mm_and_calibrates_to_the_noise_floor(tmp_path):
    robot = load_robot("kr16_2_track")
    out, _ = _twin(tmp_path, robot, "track", n_poses=60)
    header = (out / "poses.csv").read_text().splitlines()[0].split(",")
    assert header[3:10] == ["q1_mm", *[f"q{j}_deg" for j in range(2, 8)]]
    camp = read_campaign(out, robot)
    raw = pd.read_csv(out / "poses.csv")
    assert np.array_equal(camp.q[:, 0], raw["q1_mm"].to_numpy())  # mm stay mm
    assert np.allclose(camp.q[:, 1], np.radians(raw["q2_deg"].to_numpy()))
    back = camp.to_frame()
    assert "q1_mm" in back and "q1_deg" not in back and np.array_equal(back["q1_mm"], raw["q1_mm"])
    res = calibrate(camp, robot)
    assert res.fit["success"]
    # the fit reaches the noise floor (within 10 %: one draw, chi² spread ~ 1/sqrt(dof))
    assert abs(res.fit["rms_position_mm"] / res.fit["noise_floor_rms_mm"] - 1) < 0.10
    # a file giving the track in degrees is refused, naming the column
    bad = tmp_path / "bad"
    bad.mkdir()
    raw.rename(columns={"q1_mm": "q1_deg"}).to_csv(bad / "poses.csv", index=False)
    with pytest.raises(DataError, match=r"q1_deg.*prismatic") as exc:
        read_campaign(bad, robot)
    assert "poses.csv" in str(exc.value)
    # and a track position outside its limits names row, column and the unit
    raw2 = raw.copy()
    raw2.loc[3, "q1_mm"] = 6500.0
    raw2.to_csv(bad / "poses.csv", index=False)
    with pytest.raises(DataError, match=r"6500 mm outside the limits \[0, 6000\]") as exc:
        read_campaign(bad, robot)
    assert "row 5" in str(exc.value) and "q1_mm" in str(exc.value)


def test_urdf_round_trip_with_a_prismatic_joint(tmp_path):
    robot = load_robot("kr16_2_track")
    chain = build_chain(robot)
    rng = np.random.default_rng(4)
    kinds = np.array(chain.param_kind)
    eta = np.where(kinds == "length", rng.normal(0, 0.5, chain.n_params), rng.normal(0, 1e-3, chain.n_params))
    path = write_calibrated_urdf(robot, eta, tmp_path / "track.urdf")
    text = path.read_text()
    assert 'type="prismatic"' in text and 'upper="6.0"' in text  # the track's limits in metres
    back = robot_from_urdf(path)
    assert back.prismatic.tolist() == robot.prismatic.tolist()
    assert back.q_limits[0].tolist() == pytest.approx([0.0, 6000.0])
    q = _q(robot, 25, 5)
    want = fk(chain, q, eta)
    assert np.abs(fk(build_chain(back), q) - want).max() < TOL_MM
    # the parser's own forward kinematics (yourdfpy, metres on the prismatic joint) agrees
    urdf = load_urdf(path)
    got = urdf_fk(urdf, q, "flange", "base_link", list(robot.joint_names))
    assert np.abs(got - want).max() < TOL_MM


def test_gravity_on_a_prismatic_joint_is_the_force_along_it():
    robot = load_robot("kr16_2_column")
    q = _q(robot, 12, 6)
    tau = gravity_torques(robot, q, 5.0)
    # the column carries the whole arm and the payload straight up: -(sum m) g
    assert tau[:, 0] == pytest.approx(-(robot.link_mass_kg.sum() + 5.0) * 9.81)
    # tau = -dV/dq for every joint, the slide's (N, per mm of travel x 1000) and the arm's (N·m)
    h = 1e-6
    for j in range(robot.n_joints):
        dq = np.zeros_like(q)
        dq[:, j] = h
        dV = (potential_energy(robot, q + dq, 5.0) - potential_energy(robot, q - dq, 5.0)) / (2 * h)
        scale = 1e-3 if robot.prismatic[j] else 1.0  # V in J per mm of travel: N / 1000
        assert tau[:, j] * scale == pytest.approx(-dV, abs=1e-5 * np.abs(tau).max())
    Y = gravity_regressor(robot, q)
    pi = np.concatenate([[m, *(m * c / 1000.0)] for m, c in zip(robot.link_mass_kg, robot.link_com_mm, strict=True)])
    ref = gravity_torques(robot, q, 0.0)
    assert Y @ pi == pytest.approx(ref, abs=1e-9 * np.abs(ref).max())


def _bad(change) -> dict:
    data = copy.deepcopy(_yaml("kr16_2_track"))
    change(data)
    return data


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d["joints"][0].update(type="linear"), r"track.yaml: joints\[1\]: key 'type' must be"),
        (lambda d: d["joints"][0].update(q_min_deg=0), r"joints\[1\]: key 'q_min_deg' does not fit a prismatic joint"),
        (lambda d: d["joints"][1].update(q_min_mm=0), r"joints\[2\]: key 'q_min_mm' does not fit a revolute joint"),
        (lambda d: d["joints"][0].pop("q_max_mm"), r"joints\[1\]: missing key 'q_max_mm'"),
        (lambda d: d.update(coupling="fanuc"), r"track.yaml: key 'coupling': unknown convention 'fanuc'"),
        (lambda d: d.update(coupling={4: {4: -1}}), r"key 'coupling.4': a joint cannot be coupled to itself"),
        (lambda d: d.update(coupling={9: {2: 1}}), r"key 'coupling': joint 9 is not a joint number 1..7"),
        (lambda d: d.update(coupling={2: {1: 1}}), r"coupling.2': joint 2 \(revolute\) cannot take joint 1 \(prism"),
        (lambda d: d.update(coupling={4: {3: "x"}}), r"key 'coupling.4.3' must be a number, got 'x'"),
        (lambda d: d.update(coupling={3: {4: 1}, 4: {3: 1}}), r"key 'coupling' is singular"),
    ],
)
def test_bad_declarations_name_the_file_and_the_key(change, message):
    with pytest.raises(ConfigError, match=message):
        robot_from_dict(_bad(change), "conf/robot/track.yaml")
