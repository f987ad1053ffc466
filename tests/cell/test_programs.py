"""KRL and RAPID programs: parsing real-world text, byte-identical pass-through, the filter and its refusals,
errors that name the file and line, and the command."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from robocal.cell.programs.common import ProgramError, kuka_status_turn, rot_zyx_deg
from robocal.cell.programs.filter import filter_program, nominal_ik, read_program, write_filtered
from robocal.cell.programs.make import _pose_targets, _pose_text, _xyzabc, krl_program, rapid_module
from robocal.kinematics.transforms import homogeneous as frame

Q_DEG = np.array(
    [
        [10.0, -80.0, 70.0, 20.0, 45.0, 30.0],
        [-25.0, -60.0, 50.0, -40.0, 60.0, -100.0],
        [40.0, -95.0, 100.0, 60.0, -50.0, 200.0],
        [5.0, -70.0, 80.0, -10.0, 70.0, 10.0],
    ]
)
TOOL = frame(rot_zyx_deg(0.0, 30.0, 0.0), [0.0, 40.0, 180.0])
BASE = frame(rot_zyx_deg(90.0, 0.0, 0.0), [900.0, -200.0, 300.0])


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    import robocal
    from robocal.io import write_json
    from robocal.serve.bundle import load_bundle, write_bundle

    d = tmp_path_factory.mktemp("cell_bundle")
    robot = robocal.load_robot("kr16_2")
    sc = robocal.load_scenario("geometric")
    sc.update(n_poses=40, n_validation_poses=0)
    robocal.simulate(sc, d / "camp", seed=2)
    cal = robocal.calibrate(robocal.read_campaign(d / "camp", robot), robot)
    write_json(d / "calibration.json", cal.to_dict())
    return load_bundle(write_bundle(d / "bundle", "kr16_2", d / "calibration.json"))


@pytest.fixture(scope="module")
def cc_nom(bundle):
    from robocal.serve.engine import compile_chain

    return compile_chain(bundle.chain)


def _krl_by_hand(cc, folder: Path) -> Path:
    """A KRL program as found on cells: CRLF, & header, folds, comments with ';' and quotes, mixed case, an
    inline target in the .src, CIRC, bit-string Status/Turn, a type prefix, a cp1252 byte, $config.dat."""
    q = np.deg2rad(Q_DEG)
    T = _pose_targets(cc, q, TOOL, BASE)
    S, Tn = kuka_status_turn(cc, q)
    src = (
        "&ACCESS RVP\r\n&REL 12\r\nDEF Weld7( )\r\n"
        ";FOLD INI;%{PE}\r\n  BAS (#INITMOV,0 )\r\n;ENDFOLD (INI)\r\n"
        '; Zelle 3 \xc4nderung: "don\'t touch" ; twice\r\n'
        "$TOOL=TOOL_DATA[2]   ; welding torch\r\n"
        "$base = base_data[1]\r\n"
        "PTP XHOME\r\n"
        ";FOLD LIN P1 CONT Vel=2 m/s CPDAT1 Tool[2] Base[1];%{PE}\r\n"
        "  lin xP1 C_DIS\r\n"
        ";ENDFOLD\r\n"
        f"Lin {{{_xyzabc(T[1])},S {S[1]},T {Tn[1]}}} C_VEL ; inline target\r\n"
        "CIRC XP3, XP4 CA 90.0\r\n"
        "PTP XHOME\r\n"
        "END\r\n"
    )
    dat = (
        "&ACCESS RVP\r\nDEFDAT  Weld7\r\n"
        f"DECL E6AXIS XHOME={{A1 0.0,A2 -90.0,A3 90.0,A4 0.0,A5 30.0,A6 0.0,E1 0.0}}\r\n"
        f"decl e6pos XP1={{{_xyzabc(T[0])},S 'B{S[0]:b}',T 'B{Tn[0]:b}',E1 0.0}} ; bits\r\n"
        f"DECL GLOBAL E6POS XP3={{E6POS: {_xyzabc(T[2])},S {S[2]},T {Tn[2]}}}\r\n"
        f"POS XP4={{{_xyzabc(T[3])},S {S[3]},T {Tn[3]}}}\r\n"
        'DECL FDAT FP1={TOOL_NO 2,BASE_NO 1,IPO_FRAME #BASE,POINT2[] " ",TQ_STATE FALSE}\r\n'
        "DECL E6POS XUNUSED={X 1,Y 2,Z 3,A 0,B 0,C 0,S 2,T 0}\r\n"
        "ENDDAT\r\n"
    )
    cfg = f"DEFDAT  $CONFIG\r\nTOOL_DATA[2]={{{_xyzabc(TOOL, 4)}}}\r\nBASE_DATA[1]={{{_xyzabc(BASE, 4)}}}\r\nENDDAT\r\n"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "Weld7.src").write_bytes(src.encode("cp1252"))
    (folder / "Weld7.dat").write_bytes(dat.encode("cp1252"))
    (folder / "$config.dat").write_bytes(cfg.encode("cp1252"))
    return folder / "Weld7.src"


def _rapid_by_hand(cc, folder: Path) -> Path:
    q = np.deg2rad(Q_DEG)
    T = _pose_targets(cc, q, TOOL, BASE)
    from robocal.cell.programs.common import abb_confdata

    cf = abb_confdata(cc, q)
    ext = "[9E9,9E9,9E9,9E9,9E9,9E9]"

    def rt(k: int) -> str:
        return _pose_text(T[k])[:-1] + ",[" + ",".join(str(v) for v in cf[k]) + "]," + ext + "]"

    mod = (
        "%%%\n  VERSION:1\n  LANGUAGE:ENGLISH\n%%%\n\n"
        "MODULE Glue ! the glue station\n"
        f"  PERS tooldata tNozzle := [TRUE, {_pose_text(TOOL, 4)},\n      [1,[0,0,50],[1,0,0,0],0,0,0]];\n"
        f'  TASK PERS wobjdata wTable := [FALSE, TRUE, "", {_pose_text(BASE, 4)}, ! user frame\n'
        "      [[0,0,0],[1,0,0,0]]];\n"
        "  CONST jointtarget jHome := [[0,0,0,0,30,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];\n"
        f"  CONST robtarget pA := {rt(0)};\n"
        f"  local const ROBTARGET pB:={rt(2)};  ! lower case keywords\n"
        f"  CONST robtarget pC :=\n    {rt(3)};\n"
        "  VAR num nCount := 0;\n"
        "  PROC main()\n"
        "    IF nCount > 3 THEN\n      nCount := 0;\n    ENDIF\n"
        "    MoveAbsJ jHome\\NoEOffs, v1000, fine, tNozzle;\n"
        "    MoveJ pA, v1000, z50, tNozzle\\WObj:=wTable;\n"
        f"    moveL {rt(1)}, v200, z1, tNozzle \\WObj:=wTable; ! inline\n"
        "    MoveC \\Conc, pB, pC, v100\\T:=3, fine,\n          tNozzle\\WObj:=wTable;\n"
        '    TPWrite "done; MoveL p99, v1, fine, tool0;";\n'
        "  ENDPROC\n"
        "ENDMODULE\n"
    )
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "Glue.mod").write_bytes(mod.encode())
    return folder / "Glue.mod"


def _outside_spans(text: str, spans: list[tuple[int, int]]) -> list[str]:
    out, last = [], 0
    for s, e in sorted(spans):
        out.append(text[last:s])
        last = e
    out.append(text[last:])
    return out


def _same_outside_targets(orig: bytes, new: bytes, spans: list[tuple[int, int]]) -> bool:
    """Every byte outside the target values is the same, in the same order."""
    o, n = orig.decode("latin-1"), new.decode("latin-1")
    pos = 0
    for k, seg in enumerate(_outside_spans(o, spans)):
        if k == 0:
            if not n.startswith(seg):
                return False
            pos = len(seg)
            continue
        j = n.find(seg, pos)
        if j < 0 or (k == len(spans) and not n.endswith(seg)):
            return False
        pos = j + len(seg)
    return True


def test_krl_real_world_text(tmp_path, cc_nom):
    prog = read_program(_krl_by_hand(cc_nom, tmp_path / "p"))
    names = [t.name for t in prog.targets]
    assert names == ["XHOME", "XP1", "<inline>", "XP3", "XP4"]  # XHOME twice -> once; XUNUSED not moved to
    xp1 = prog.targets[1]
    assert xp1.kind == "pose" and xp1.tool_name.upper() == "TOOL_DATA[2]" and xp1.base_name.lower() == "base_data[1]"
    assert np.allclose(xp1.tool, TOOL, atol=1e-4) and np.allclose(xp1.base, BASE, atol=1e-4)
    assert xp1.config == {"S": kuka_status_turn(cc_nom, np.deg2rad(Q_DEG[:1]))[0][0], "T": xp1.config["T"]}
    assert prog.targets[0].kind == "axis" and prog.targets[0].used_at[1][1] == 16
    assert prog.targets[2].file.suffix == ".src" and prog.targets[2].line == 14


def test_rapid_real_world_text(tmp_path, cc_nom):
    prog = read_program(_rapid_by_hand(cc_nom, tmp_path / "p"))
    assert [t.name for t in prog.targets] == ["jHome", "pA", "<inline>", "pB", "pC"]  # the string is not code
    pa = prog.targets[1]
    assert pa.tool_name == "tNozzle" and pa.base_name == "wTable" and pa.line == 12
    assert np.allclose(pa.tool, TOOL, atol=1e-4) and np.allclose(pa.base, BASE, atol=1e-4)
    assert prog.targets[4].line == 14  # a declaration over two lines: the line of its name


@pytest.mark.parametrize("dialect", ["krl", "rapid"])
def test_filter_is_byte_identical_outside_targets_and_lands_on_the_corrected_joints(tmp_path, bundle, cc_nom, dialect):
    main = (_krl_by_hand if dialect == "krl" else _rapid_by_hand)(cc_nom, tmp_path / "p")
    originals = {p.name: p.read_bytes() for p in main.parent.iterdir()}
    prog = read_program(main)
    res = filter_program(prog, bundle)
    assert res.status == ["ok"] * len(prog.targets), res.reasons
    # the nominal controller at the original targets: the joints they were written from
    q0 = np.deg2rad(res.q_nominal_deg)
    assert np.abs(np.rad2deg(q0[1:]) - Q_DEG[[0, 1, 2, 3]]).max() < 1e-3  # 3-decimal text
    written = write_filtered(res, tmp_path / "out")
    assert {p.name: p.read_bytes() for p in main.parent.iterdir()} == originals  # originals untouched
    for p in prog.texts:
        spans = [t.span for t in prog.targets if t.file == p]
        new = (tmp_path / "out" / p.name).read_bytes()
        assert new != originals[p.name] or not spans
        assert _same_outside_targets(originals[p.name], new, spans)
    assert any(w.name.endswith("_filter.csv") for w in written)
    if dialect == "krl":  # the tool/base data are read, never written: copy them as the cell has them
        (tmp_path / "out" / "$config.dat").write_bytes(originals["$config.dat"])
    # read back: the nominal controller now goes to the corrected joints (text rounding: 1e-4 mm, 1e-5 deg)
    back = read_program(tmp_path / "out" / main.name)
    q_back = nominal_ik(back, cc_nom, bundle.robot.q_limits)
    assert np.abs(np.rad2deg(q_back) - res.q_corrected_deg).max() < 2e-4
    assert 0.05 < res.predicted_error_mm.mean() < 5.0  # the twin's robot is ~1 mm off before


def test_refusals_follow_the_service_rules(tmp_path, bundle, cc_nom):
    from robocal.serve.protocol import SafetyConfig

    main = _krl_by_hand(cc_nom, tmp_path / "p")
    prog = read_program(main)
    res = filter_program(prog, bundle, safety=SafetyConfig(max_correction_deg=1e-6))
    assert set(res.status) == {"refused"} and "exceeds the bound" in res.reasons[0][0]
    assert res.texts == prog.texts  # refused targets keep their text
    flag = filter_program(prog, bundle, safety=SafetyConfig(max_correction_deg=1e-6, on_correction_bound="flag"))
    assert set(flag.status) == {"flagged"}
    lim = filter_program(prog, bundle, safety=SafetyConfig(joint_limit_margin_deg=200.0))
    assert set(lim.status) == {"refused"} and "outside the joint limits" in lim.reasons[1][0]
    assert "refused" in res.table.splitlines()[1]


def test_thermal_bundle_needs_a_temperature_and_uses_it(tmp_path, bundle, cc_nom):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "serve"))
    from dataclasses import replace

    from standins import StandinThermal

    from robocal.cell.programs.filter import parse_temperatures
    from robocal.errors import ConfigError

    s = 2
    G = np.random.default_rng(0).normal(0, 1, (bundle.chain.n_params, s)) * 2e-3
    th = StandinThermal(["T_j2_C", "T_j3_C"], G, 20.0, np.tile([15.0, 45.0], (s, 1)))
    b = replace(bundle, thermal=th, sensors=th.sensors, t_lo=np.full(s, 15.0), t_hi=np.full(s, 45.0))
    prog = read_program(_krl_by_hand(cc_nom, tmp_path / "p"))
    with pytest.raises(ConfigError, match="thermal model"):
        filter_program(prog, b)
    with pytest.raises(ConfigError, match="lacks sensor"):
        parse_temperatures(["T_j2_C=30"], th.sensors)
    cold = filter_program(prog, b, parse_temperatures(["20"], th.sensors))
    warm = filter_program(prog, b, parse_temperatures(["T_j2_C=40", "T_j3_C=40"], th.sensors))
    assert np.allclose(cold.q_corrected_deg, filter_program(prog, bundle).q_corrected_deg, atol=1e-9)
    assert np.abs(warm.q_corrected_deg - cold.q_corrected_deg).max() > 1e-4
    hot = filter_program(prog, b, parse_temperatures(["50"], th.sensors))
    assert set(hot.status) == {"refused"} and "outside the fitted range" in hot.reasons[0][0]


KRL_BAD = [
    ("PTP XNOPE\r\n", "XNOPE' is not declared", 4),
    ("PTP_REL {A1 10}\r\n", "relative motion", 4),
    ("LIN XP1:{X 10}\r\n", "geometric operator", 4),
    ("XP1.X = XP1.X + 5\r\nLIN XP1\r\n", "assigned at run time", 4),
    ("$TOOL=TOOL_DATA[9]\r\nLIN XP1\r\n", "TOOL_DATA[9] is not defined", 4),
    ("LIN {X 1,Y 2,Z 3,A 0,B 0}\r\n", "lacks ['C']", 4),
    ("LIN {X 1,Y 2,Z 3,A 0,B 0,C 0,Q 1}\r\n", "unknown aggregate key", 4),
    ("LIN {X 9000,Y 0,Z 0,A 0,B 0,C 0}\r\n", "not reachable by the nominal robot", 4),
]


@pytest.mark.parametrize(("stmt", "msg", "line"), KRL_BAD)
def test_bad_krl_names_file_and_line_and_writes_nothing(tmp_path, bundle, cc_nom, stmt, msg, line):
    from robocal.cli import main

    d = tmp_path / "p"
    d.mkdir()
    T = _pose_targets(cc_nom, np.deg2rad(Q_DEG[:1]), np.eye(4), np.eye(4))
    (d / "Bad.src").write_bytes(f"DEF Bad()\r\n; a comment\r\n$TOOL=$NULLFRAME\r\n{stmt}END\r\n".encode())
    (d / "Bad.dat").write_bytes(f"DEFDAT Bad\r\nDECL E6POS XP1={{{_xyzabc(T[0])}}}\r\nENDDAT\r\n".encode())
    with pytest.raises(ProgramError, match=re.escape(msg)) as exc:
        filter_program(read_program(d / "Bad.src"), bundle)
    assert exc.value.line == line and exc.value.file.endswith("Bad.src")
    rc = main(["filter", str(d / "Bad.src"), "--bundle", str(bundle.path), "--out", str(tmp_path / "out")])
    assert rc == 2 and not (tmp_path / "out").exists()


RAPID_BAD = [
    ("MoveL Offs(p1,0,0,10), v100, fine, tool0;", "is an expression"),
    ("MoveL pX, v100, fine, tool0;", "'pX' is not declared"),
    ("TriggL p1, v100, tr1, fine, tool0;", "TriggL is not supported"),
    ("MoveL p1, v100, fine, tBad;", "tool 'tBad' is not a declared tooldata"),
    ("p1.trans.x := 5;\n    MoveL p1, v100, fine, tool0;", "assigned at run time"),
    ("MoveL p1, v100, fine;", "expected 4 arguments"),
    ("MoveL [[1,2,3],[1,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9], v100, fine, tool0;", "unbalanced"),
]


@pytest.mark.parametrize(("stmt", "msg"), RAPID_BAD)
def test_bad_rapid_names_file_and_line(tmp_path, stmt, msg):
    mod = (
        "MODULE M\n  CONST robtarget p1 := [[500,0,800],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
        f"  PROC main()\n    {stmt}\n  ENDPROC\nENDMODULE\n"
    )
    (tmp_path / "M.mod").write_text(mod)
    with pytest.raises(ProgramError, match=re.escape(msg)) as exc:
        read_program(tmp_path / "M.mod")
    assert exc.value.line in (4, 5, 6) and exc.value.file.endswith("M.mod")


def test_unreachable_configuration_names_the_confdata_that_works(tmp_path, bundle, cc_nom):
    """A RAPID target whose confdata the nominal robot cannot take there (cf4 = -1: joint 4 in [-90, 0) deg,
    where this pose needs 20 deg or a flipped wrist) names the confdata of the solutions found, and the first
    one named makes the target reachable (issue 30, item 11)."""
    from robocal.cell.programs.common import abb_confdata

    q = np.deg2rad(Q_DEG[:1])
    assert abb_confdata(cc_nom, q)[0].tolist() == [0, 0, 0, 0]
    mod = rapid_module("Cell", cc_nom, q, TOOL, BASE)
    bad = mod.replace("],[0,0,0,0],[9E", "],[0,-1,0,0],[9E", 1)
    assert bad != mod
    (tmp_path / "Cell.mod").write_text(bad)
    limits = bundle.robot.q_limits
    with pytest.raises(ProgramError, match=r"not reachable by the nominal robot with confdata \[0,-1,0,0\]") as exc:
        nominal_ik(read_program(tmp_path / "Cell.mod"), cc_nom, limits, n_seeds=12)  # 12, 48, 192 starts: quick
    named = re.findall(r"confdata (\[[-\d,]+\])", str(exc.value))[1:]  # after the stated one
    assert "[0,0,0,0]" in named, str(exc.value)
    (tmp_path / "Cell.mod").write_text(mod.replace("],[0,0,0,0],[9E", f"],{named[0]},[9E", 1))
    q_ok = nominal_ik(read_program(tmp_path / "Cell.mod"), cc_nom, limits)
    assert abb_confdata(cc_nom, q_ok)[0].tolist() == json.loads(named[0])


def test_filter_command_end_to_end(tmp_path, bundle, cc_nom, capsys):
    from robocal.cli import main

    q = np.deg2rad(Q_DEG)
    mod = rapid_module("Cell", cc_nom, q, TOOL, BASE)
    (tmp_path / "Cell.mod").write_text(mod)
    rc = main(["filter", str(tmp_path / "Cell.mod"), "--bundle", str(bundle.path), "--out", str(tmp_path / "f")])
    assert rc == 0
    assert "5 targets, 5 corrected" in capsys.readouterr().out
    assert (tmp_path / "f" / "Cell.mod").exists() and (tmp_path / "f" / "Cell_filter.csv").exists()
    assert main(["filter", str(tmp_path / "Cell.mod"), "--bundle", str(bundle.path), "--out", str(tmp_path)]) == 2
    assert (tmp_path / "Cell.mod").read_text() == mod
    s, d, c = krl_program("K", cc_nom, q, TOOL, BASE)
    for name, txt in (("K.src", s), ("K.dat", d), ("$config.dat", c)):
        (tmp_path / name).write_text(txt)
    assert main(["filter", str(tmp_path / "K.src"), "--bundle", str(bundle.path), "--out", str(tmp_path / "k")]) == 0


def _check_lands(bundle, res, prog, dq_fn):
    """The calibrated robot, deflected by ``dq_fn(q_cmd)``, puts the TCP where the nominal one meant it."""
    from robocal.serve.engine import compile_chain, forward

    cc = compile_chain(bundle.chain, bundle.eta0)
    cc0 = compile_chain(bundle.chain)
    q_c = np.deg2rad(res.q_corrected_deg)
    q_t = np.deg2rad(res.q_nominal_deg)
    for k, t in enumerate(prog.targets):
        p_meant, _, _, _ = forward(cc0, q_t[k][None], t.tool)
        p_real, _, _, _ = forward(cc, q_c[k][None] + dq_fn(q_c[k][None], k), t.tool)
        # the service's Newton stops at tol_mm = 1e-4 per coordinate
        assert np.linalg.norm(p_real - p_meant) < 1e-3


def test_compliance_at_the_stated_payload(tmp_path, bundle, cc_nom):
    from dataclasses import replace

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "serve"))
    from standins import StandinCompliance

    comp = StandinCompliance(np.array([0.0, 2e-5, 1.5e-5, 0.0, 1e-5, 0.0]))  # rad/kg
    b = replace(bundle, compliance=comp)
    prog = read_program(_krl_by_hand(cc_nom, tmp_path / "p"))
    r0 = filter_program(prog, b, payload_kg=0.0)
    r10 = filter_program(prog, b, payload_kg=10.0)
    assert np.allclose(r0.q_corrected_deg, filter_program(prog, bundle).q_corrected_deg, atol=1e-9)
    assert np.abs(r10.q_corrected_deg - r0.q_corrected_deg).max() > 1e-3  # 10 kg * 2e-5 rad/kg ~ 0.01 deg
    _check_lands(bundle, r10, prog, lambda q, k: comp.joint_offsets(q, np.array([10.0])))


def test_discovered_effects_and_backlash_direction_from_the_program(tmp_path, bundle, cc_nom):
    from dataclasses import replace

    from robocal.compensation.discovered import joint_offsets
    from robocal.errors import ConfigError

    gear = {"key": "gear_j2_h1", "effect": "gear", "joint": 2, "harmonic": 1, "signal": "angle",
            "coefficients": [3e-4, -1e-4]}  # fmt: skip
    lash = {"key": "backlash_j3", "effect": "backlash", "joint": 3, "harmonic": None, "signal": "direction",
            "coefficients": [2e-4]}  # fmt: skip
    b = replace(bundle, effects=(gear, lash))
    prog = read_program(_krl_by_hand(cc_nom, tmp_path / "p"))
    res = filter_program(prog, b)
    q_t = np.deg2rad(res.q_nominal_deg)
    direction = np.sign(np.diff(np.vstack([q_t[:1], q_t]), axis=0))
    direction[direction == 0] = 1.0
    _check_lands(
        bundle,
        res,
        prog,
        lambda q, k: joint_offsets([gear, lash], bundle.robot, q, 0.0, None, None, direction[k][None]),
    )
    torque = {**gear, "key": "compliance_j2", "signal": "torque", "coefficients": [1e-6]}
    with pytest.raises(ConfigError, match="tau_Nm"):
        filter_program(prog, replace(bundle, effects=(torque,)))
