"""Robot descriptions in conf/robot: key numbers, bad descriptions, and an independent POE check of the SR210."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from robocal.errors import ConfigError
from robocal.robot import MDH, POE, RobotDescription, load_robot, robot_from_dict

REPO = Path(__file__).resolve().parents[1]
CONF = REPO / "conf" / "robot"
SHARED = REPO.parent / "shared"
ROBOTS = ("kr16_2", "sr210", "abb_irb120")


def _raw(name: str) -> dict[str, Any]:
    return yaml.safe_load((CONF / f"{name}.yaml").read_text())


# ---------------------------------------------------------------------------- small independent kinematics


def _rotx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _roty(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def _rotz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _trans(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def mdh_frames(robot: RobotDescription, q: np.ndarray) -> list[np.ndarray]:
    """base_T_joint_i for i = 1..n: product of Rot_x Trans_x Rot_z Trans_z Rot_y, written out here."""
    T = np.eye(4)
    out = []
    for i in range(robot.n_joints):
        T = (
            T
            @ _rotx(robot.alpha[i])
            @ _trans(robot.a_mm[i], 0, 0)
            @ _rotz(q[i] + robot.theta_offset[i])
            @ _trans(0, 0, robot.d_mm[i])
            @ _roty(robot.beta[i])
        )
        out.append(T.copy())
    return out


def rodrigues(w: np.ndarray, theta: float) -> np.ndarray:
    """exp([w] theta) for a unit vector w."""
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def twist_exp(w: np.ndarray, p: np.ndarray, theta: float) -> np.ndarray:
    """exp(xi theta) of a revolute twist with axis w through p: x -> R (x - p) + p."""
    R = rodrigues(w, theta)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p - R @ p
    return T


def poe_fk(robot: RobotDescription, q: np.ndarray) -> np.ndarray:
    """Global product of exponentials exp(xi_1 q_1) ... exp(xi_n q_n) M, flange pose (4, 4)."""
    assert robot.poe_w is not None and robot.poe_p_mm is not None and robot.poe_flange0 is not None
    T = np.eye(4)
    for i in range(robot.n_joints):
        T = T @ twist_exp(robot.poe_w[i], robot.poe_p_mm[i], q[i])
    return T @ robot.poe_flange0


def poe_joint_frames_at_zero(robot: RobotDescription) -> list[np.ndarray]:
    """Joint frames of a POE robot at q = 0 as documented in sr210.yaml (dynamics.source): origin p_i,
    z along w_i, x the projection of the previous frame's x (base x for joint 1), or base x / base y
    when that projection vanishes."""
    assert robot.poe_w is not None and robot.poe_p_mm is not None
    frames = []
    x_prev = np.array([1.0, 0.0, 0.0])
    for w, p in zip(robot.poe_w, robot.poe_p_mm, strict=True):
        z = w / np.linalg.norm(w)
        x = x_prev - (x_prev @ z) * z
        if np.linalg.norm(x) < 1e-9:
            alt = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            x = alt - (alt @ z) * z
        x = x / np.linalg.norm(x)
        F = np.eye(4)
        F[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        F[:3, 3] = p
        frames.append(F)
        x_prev = x
    return frames


# ---------------------------------------------------------------------------- all three load


@pytest.mark.parametrize("name", ROBOTS)
def test_loads_by_path_and_by_name(name: str) -> None:
    by_path = load_robot(CONF / f"{name}.yaml")
    by_name = load_robot(name)
    assert by_path.name == name
    assert by_path.n_joints == 6
    np.testing.assert_array_equal(by_path.q_limits, by_name.q_limits)
    assert np.all(by_path.q_limits[:, 0] < by_path.q_limits[:, 1])
    assert by_path.has_dynamics


@pytest.mark.parametrize("name", ROBOTS)
def test_hydra_group_file_is_top_level(name: str) -> None:
    """A Hydra config group includes the file as is: no package directive, the format's keys at top level,
    and OmegaConf reads the same description."""
    text = (CONF / f"{name}.yaml").read_text()
    assert "@package" not in text
    raw = yaml.safe_load(text)
    for key in ("name", "n_joints", "convention", "joints", "dynamics"):
        assert key in raw, key
    omegaconf = pytest.importorskip("omegaconf")
    cfg = omegaconf.OmegaConf.to_container(omegaconf.OmegaConf.load(CONF / f"{name}.yaml"), resolve=True)
    a, b = robot_from_dict(cfg, name), robot_from_dict(raw, name)
    np.testing.assert_array_equal(a.q_limits, b.q_limits)
    np.testing.assert_array_equal(a.link_mass_kg, b.link_mass_kg)


@pytest.mark.parametrize("name", ROBOTS)
def test_dynamics_plausible(name: str) -> None:
    raw = _raw(name)["dynamics"]
    r = load_robot(name)
    assert r.link_mass_kg is not None and r.link_com_mm is not None
    assert "estimate" in raw["source"].lower()
    np.testing.assert_allclose(r.gravity, [0.0, 0.0, -9.81])
    assert np.all(r.link_mass_kg > 0)
    # moving links + fixed base = stated total mass (within rounding)
    np.testing.assert_allclose(r.link_mass_kg.sum() + raw["fixed_base_mass_kg"], raw["total_mass_kg"], atol=0.05)
    # the heaviest moving body is the column, the lightest the flange
    assert np.argmax(r.link_mass_kg) == 0 and np.argmin(r.link_mass_kg) == 5
    assert r.payload_com_mm[2] > 0


@pytest.mark.parametrize("name", ROBOTS)
def test_com_in_joint_frames_matches_base_frame_estimate(name: str) -> None:
    """com_mm (joint i's frame) and com_base_q0_mm (base frame, q = 0) are the same points."""
    r = load_robot(name)
    assert r.link_com_mm is not None
    frames = mdh_frames(r, np.zeros(6)) if r.convention == MDH else poe_joint_frames_at_zero(r)
    base = np.array([lk["com_base_q0_mm"] for lk in _raw(name)["dynamics"]["links"]], dtype=float)
    for i, F in enumerate(frames):
        np.testing.assert_allclose((F @ np.r_[r.link_com_mm[i], 1.0])[:3], base[i], atol=0.51, err_msg=f"link {i + 1}")


# ---------------------------------------------------------------------------- KUKA KR16-2


def test_kr16_key_numbers() -> None:
    r = load_robot(CONF / "kr16_2.yaml")
    assert r.convention == MDH
    assert r.joint_names == ("A1", "A2", "A3", "A4", "A5", "A6")
    # Guo 2026 table 1
    np.testing.assert_array_equal(r.a_mm, [0, 260, 680, -35, 0, 0])
    np.testing.assert_array_equal(r.d_mm, [675, 0, 0, 670, 0, 158])
    np.testing.assert_allclose(r.alpha, np.deg2rad([0, -90, 0, -90, 90, -90]))
    np.testing.assert_allclose(r.theta_offset, np.deg2rad([0, 0, -90, 0, 0, 180]))
    assert r.a_mm[1] == 260.0 and r.d_mm[3] == 670.0
    assert r.alpha[1] == pytest.approx(-np.pi / 2)
    assert r.theta_offset[2] == pytest.approx(-np.pi / 2)
    np.testing.assert_array_equal(r.beta, np.zeros(6))
    np.testing.assert_array_equal(r.beta_free, [False, True, False, False, False, False])
    # Guo 2026 table 3, converted to rad once at the door
    np.testing.assert_allclose(r.q_limits[1], np.deg2rad([-155.0, 35.0]))
    np.testing.assert_allclose(
        r.q_limits,
        np.deg2rad([[-180, 180], [-155, 35], [-130, 154], [-350, 350], [-130, 130], [-350, 350]]),
    )
    assert r.sensor_names == (
        "T_j1_C",
        "T_j2_C",
        "T_j3_C",
        "T_j4_C",
        "T_j5_C",
        "T_j6_C",
        "T_l1_C",
        "T_l4_C",
        "T_l5_C",
    )
    assert [(s.location, s.index) for s in r.sensors] == [("joint", k) for k in range(1, 7)] + [
        ("link", 1),
        ("link", 4),
        ("link", 5),
    ]
    assert r.T0_C == 24.3
    np.testing.assert_allclose(r.payload_com_mm, [0.0, 0.0, 100.0])


def test_kr16_zero_pose_geometry() -> None:
    """At q = 0 (KUKA zero: upper arm horizontal) the flange is at (a2 + a3 + d4 + d6, 0, d1 + a4) with z forward."""
    r = load_robot("kr16_2")
    T = mdh_frames(r, np.zeros(6))[-1]
    np.testing.assert_allclose(T[:3, 3], [260 + 680 + 670 + 158, 0, 675 - 35], atol=1e-9)
    np.testing.assert_allclose(T[:3, 2], [1, 0, 0], atol=1e-12)


# ---------------------------------------------------------------------------- ABB IRB 120


def test_abb_matches_shared_kinematics() -> None:
    shared = SHARED / "data" / "abb-irb120" / "robot.yaml"
    if not shared.is_file():
        pytest.skip(f"{shared} is not present (needs ../shared)")
    ours, ref = load_robot(CONF / "abb_irb120.yaml"), load_robot(shared)
    assert ours.convention == ref.convention == MDH
    for attr in ("a_mm", "alpha", "d_mm", "theta_offset", "beta", "beta_free", "q_limits"):
        np.testing.assert_array_equal(getattr(ours, attr), getattr(ref, attr), err_msg=attr)
    assert ours.joint_names == ref.joint_names
    assert _raw("abb_irb120")["poe"] == yaml.safe_load(shared.read_text())["poe"]


def test_abb_mdh_equals_its_poe_section() -> None:
    """The MD-H table and the POE twists kept in the same file describe one robot."""
    raw = _raw("abb_irb120")
    mdh = robot_from_dict(raw, "abb mdh")
    poe = robot_from_dict({**raw, "convention": POE}, "abb poe")
    rng = np.random.default_rng(0)
    for q in rng.uniform(mdh.q_limits[:, 0], mdh.q_limits[:, 1], (20, 6)):
        np.testing.assert_allclose(mdh_frames(mdh, q)[-1], poe_fk(poe, q), atol=1e-9)


# ---------------------------------------------------------------------------- Siasun SR210 (POE)

L1, L2, L3, L4, L5 = 312.0, 1075.0, 235.0, 1282.0, 260.0  # Mao 2021 table 1, nominal


def test_sr210_description() -> None:
    r = load_robot(CONF / "sr210.yaml")
    assert r.convention == POE
    assert r.poe_w is not None and r.poe_p_mm is not None and r.poe_flange0 is not None
    assert _raw("sr210")["L_mm"] == [L1, L2, L3, L4, L5]
    np.testing.assert_allclose(np.linalg.norm(r.poe_w, axis=1), 1.0)
    # Mao eq. 25: joint 1 vertical; 2, 3, 5 about -y; 4 and 6 along x
    np.testing.assert_array_equal(r.poe_w, [[0, 0, 1], [0, -1, 0], [0, -1, 0], [1, 0, 0], [0, -1, 0], [1, 0, 0]])
    assert r.link_mass_kg is not None
    assert 800 <= r.link_mass_kg.sum() <= 1200


def test_sr210_twists_reproduce_paper_eq25() -> None:
    """v = -w x p of each axis equals the linear part of Mao's eq. 25 twists."""
    r = load_robot("sr210")
    assert r.poe_w is not None and r.poe_p_mm is not None
    v = -np.cross(r.poe_w, r.poe_p_mm)
    expected = [
        [0, 0, 0],
        [0, 0, -L1],
        [L2, 0, -L1],
        [0, L2 + L3, 0],
        [L2 + L3, 0, -L1 - L4],
        [0, L2 + L3, 0],
    ]
    np.testing.assert_allclose(v, expected, atol=1e-9)


def test_sr210_forward_kinematics_at_zero_and_reach() -> None:
    r = load_robot("sr210")
    assert r.poe_flange0 is not None
    T0 = poe_fk(r, np.zeros(6))
    np.testing.assert_allclose(T0[:3, 3], r.poe_flange0[:3, 3], atol=1e-9)
    np.testing.assert_allclose(T0[:3, 3], [L1 + L4 + L5, 0.0, L2 + L3], atol=1e-9)
    # horizontal reach of the flange from axis 1 at q = 0: shoulder offset + forearm + wrist-to-flange
    assert np.hypot(T0[0, 3], T0[1, 3]) == pytest.approx(L1 + L4 + L5)
    # turning joint 1 keeps the horizontal reach and the height
    T = poe_fk(r, np.deg2rad([90.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(T[:3, 3], [0.0, L1 + L4 + L5, L2 + L3], atol=1e-9)
    # joints 4 and 6 (along the forearm) and 5 at the wrist centre do not move the wrist centre
    wc = np.r_[L1 + L4, 0.0, L2 + L3]
    T = poe_fk(r, np.deg2rad([0, 0, 0, 40.0, 70.0, -30.0]))
    np.testing.assert_allclose(T[:3, 3] - T[:3, 2] * L5, wc, atol=1e-9)
    # positive q3 lifts the forearm: at q3 = +90 deg the wrist centre is above axis 3, set back by L3
    T = poe_fk(r, np.deg2rad([0, 0, 90.0, 0, 0, 0]))
    np.testing.assert_allclose(T[:3, 3] - T[:3, 2] * L5, [L1 - L3, 0.0, L2 + L4], atol=1e-9)
    # positive q2 tilts the upper arm backwards: at q2 = +90 deg axis 3 is at height 0, L2 behind axis 2, forearm up
    T = poe_fk(r, np.deg2rad([0, 90.0, 0, 0, 0, 0]))
    np.testing.assert_allclose(T[:3, 3] - T[:3, 2] * L5, [L1 - L2 - L3, 0.0, L4], atol=1e-9)


def test_sr210_library_fk_agrees_with_independent_poe() -> None:
    """Two ways of computing one quantity: the library's chain and the Rodrigues product here."""
    chain_mod = pytest.importorskip("robocal.kinematics.chain")
    r = load_robot("sr210")
    chain = chain_mod.build_chain(r)
    rng = np.random.default_rng(3)
    q = rng.uniform(r.q_limits[:, 0], r.q_limits[:, 1], (25, 6))
    T = chain_mod.fk(chain, q)
    for k in range(len(q)):
        np.testing.assert_allclose(T[k], poe_fk(r, q[k]), atol=1e-8)


# ---------------------------------------------------------------------------- bad descriptions


def _raises(data: dict[str, Any], *fragments: str) -> None:
    with pytest.raises(ConfigError) as info:
        robot_from_dict(data, "bad.yaml")
    msg = str(info.value)
    assert "bad.yaml" in msg
    for f in fragments:
        assert f in msg, (f, msg)


def test_missing_q_max_names_the_key_and_joint() -> None:
    data = copy.deepcopy(_raw("kr16_2"))
    del data["joints"][2]["q_max_deg"]
    _raises(data, "q_max_deg", "joints[3]")


def test_non_unit_poe_axis_is_rejected() -> None:
    data = copy.deepcopy(_raw("sr210"))
    data["poe"]["twists"][1]["w"] = [0.0, -2.0, 0.0]
    _raises(data, "poe.twists", ".w", "unit")


def test_wrong_n_joints_is_rejected() -> None:
    data = copy.deepcopy(_raw("kr16_2"))
    data["n_joints"] = 5
    _raises(data, "n_joints", "6 joints")


@pytest.mark.parametrize("bad", ["t4", "T_j4", "j4_C", "temp_4_C"])
def test_sensor_name_must_be_T_name_C(bad: str) -> None:
    data = copy.deepcopy(_raw("kr16_2"))
    data["temperature_sensors"][3]["name"] = bad
    _raises(data, repr(bad), "T_<sensor>_C")


def test_other_bad_descriptions() -> None:
    data = copy.deepcopy(_raw("kr16_2"))
    data["joints"][1]["a_mm"] = "long"
    _raises(data, "a_mm", "joints[2]")
    data = copy.deepcopy(_raw("kr16_2"))
    data["joints"][0]["q_min_deg"] = 200.0
    _raises(data, "q_min_deg")
    data = copy.deepcopy(_raw("kr16_2"))
    data["dynamics"]["links"] = data["dynamics"]["links"][:5]
    _raises(data, "dynamics.links")
    data = copy.deepcopy(_raw("sr210"))
    del data["poe"]
    _raises(data, "poe")
    data = copy.deepcopy(_raw("sr210"))
    data["poe"]["twists"] = data["poe"]["twists"][:5]
    _raises(data, "poe.twists")
    data = copy.deepcopy(_raw("sr210"))
    data["poe"]["flange_R_at_zero"] = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]
    _raises(data, "flange_R_at_zero")


def test_robot_descriptions_ship_with_the_package():
    """load_robot finds the descriptions inside the installed package (not by a path into a checkout), and
    Hydra's conf/robot entries are links to the same files."""
    from pathlib import Path

    import robocal
    from robocal.robot import load_robot

    pkg = Path(robocal.__file__).resolve().parent / "robots"
    repo_conf = Path(__file__).resolve().parents[1] / "conf" / "robot"
    for f in sorted(pkg.glob("*.yaml")):
        assert Path(load_robot(f.stem).source).resolve() == f.resolve()
        assert (repo_conf / f.name).resolve() == f.resolve()
    assert {f.stem for f in pkg.glob("*.yaml")} >= {"kr16_2", "sr210", "abb_irb120"}


@pytest.mark.parametrize(
    ("where", "typo", "meant"),
    [(None, "conventon", "convention"), (None, "n_joint", "n_joints"), (2, "beta_fre", "beta_free"),
     (3, "q_mx_deg", "q_max_deg")],
)  # fmt: skip
def test_a_misspelt_key_is_refused_by_name(where: int | None, typo: str, meant: str) -> None:
    # before: `beta_fre: true` was ignored (the joint's beta held, the model changed silently) and `conventon: dh`
    # read a DH table as MD-H
    d = copy.deepcopy(_raw("kr16_2"))
    block = d if where is None else d["joints"][where - 1]
    block[typo] = block.pop(meant) if meant in block else True
    with pytest.raises(ConfigError) as info:
        robot_from_dict(d, source="cell/robot.yaml")
    msg = str(info.value)
    assert "cell/robot.yaml" in msg and repr(typo) in msg and repr(meant) in msg, msg
    if where is not None:
        assert f"joints[{where}]" in msg


def test_keys_of_ones_own_are_left_alone() -> None:
    d = copy.deepcopy(_raw("kr16_2"))
    d.update(source="IPA, 2020", notes="re-mastered in May", manufacturer="KUKA")
    d["joints"][0]["comment"] = "base axis"
    assert robot_from_dict(d, source="r.yaml").n_joints == 6


@pytest.mark.parametrize(("where", "key"), [(2, "sign"), (4, "direction"), (3, "flip"), (None, "tool"), (None, "base")])
def test_a_key_other_tools_read_with_a_meaning_is_refused(where: int | None, key: str) -> None:
    """A newcomer's ``sign: -1`` on a joint and a top-level ``tool:`` were left alone as the user's own keys: the
    joint turned the other way and the fit could not start, "check the joint angles' unit"."""
    d = copy.deepcopy(_raw("kr16_2"))
    (d if where is None else d["joints"][where - 1])[key] = -1
    with pytest.raises(ConfigError, match=f"{key!r} is not read by robocal") as info:
        robot_from_dict(d, source="cell/robot.yaml")
    msg = str(info.value)
    assert "cell/robot.yaml" in msg and ("URDF" in msg)
    if where is not None:
        assert f"joints[{where}]" in msg and "negate" in msg


@pytest.mark.parametrize(("key", "value"), [("mounting", "ceiling"), ("mount", "wall"), ("gravity", [0, 0, 9.81])])
def test_a_mounting_stated_where_it_is_not_read_is_refused_with_where_it_is(key: str, value: object) -> None:
    """Newcomer pass 15 (D3): 'mounting: wall' and a top-level 'gravity:' were left alone as the user's own keys,
    and the wall-mounted arm's weight was modelled the floor's way (4.78 mm held out; 0.034 with gravity stated)."""
    d = copy.deepcopy(_raw("kr16_2"))
    d[key] = value
    with pytest.raises(ConfigError, match=f"{key!r} is not read by robocal") as info:
        robot_from_dict(d, source="cell/robot.yaml")
    assert "gravity_mps2" in str(info.value) and "[0, 0, 9.81] on a ceiling" in str(info.value)
    d.pop(key)
    d["dynamics"] = {**d.get("dynamics", {}), "gravity_mps2": [0, 0, 9.81]}  # where it is read
    assert robot_from_dict(d, source="cell/robot.yaml").n_joints == 6


def test_a_negative_compliance_is_said_to_be_one_no_stiffness_can_be() -> None:
    """Newcomer pass 15 (D4): a ceiling-mounted arm described as on the floor named compliance j3 at -7.57e-7 rad/Nm
    (+7.57e-7 with its gravity stated) without a word; a positive one, or one within two standard errors of zero,
    is not a warning."""
    from robocal.discovery.validate import negative_compliance

    def named(c: float, se: float) -> dict:
        return {"key": "compliance:j3", "effect": "compliance",
                "estimates": {"c_rad_per_Nm": {"value": c, "stderr": se, "unit": "rad/Nm"}}}  # fmt: skip

    (said,) = negative_compliance([named(-7.568e-7, 2.6e-8), named(7.5e-7, 2e-8)])
    assert "compliance:j3" in said and "-7.568e-07" in said and "gravity_mps2" in said
    assert negative_compliance([named(-1e-8, 2e-8), {"key": "weight:j2", "effect": "weight", "estimates": {}}]) == []
