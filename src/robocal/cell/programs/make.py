"""Write small KRL and RAPID programs from joint configurations (twin round trips, tests, examples).

The text imitates what teach pendants and offline programming tools write: KUKA inline forms (``;FOLD PTP P1
...``) with ``FDAT``/``PDAT`` data, ``$config.dat``-style ``TOOL_DATA``/``BASE_DATA``; RAPID modules with
``tooldata``, ``wobjdata``, ``robtarget`` declarations, comments and mixed case.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robocal.cell.programs.common import abb_confdata, abc_deg, kuka_status_turn
from robocal.kinematics.transforms import inv_transform, matrix_to_quat


def _pose_targets(cc_nom: Any, q: np.ndarray, tool: np.ndarray, base: np.ndarray) -> np.ndarray:
    from robocal.kinematics.ik import forward

    p, R, _, _ = forward(cc_nom, q, tool)
    T = np.tile(np.eye(4), (len(q), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, p
    return np.einsum("ij,mjk->mik", inv_transform(base), T)


def _xyzabc(T: np.ndarray, nd: int = 3) -> str:
    a, b, c = abc_deg(T[:3, :3])
    x, y, z = T[:3, 3]
    return f"X {x:.{nd}f},Y {y:.{nd}f},Z {z:.{nd}f},A {a:.{nd + 1}f},B {b:.{nd + 1}f},C {c:.{nd + 1}f}"


def krl_program(
    name: str,
    cc_nom: Any,
    q: np.ndarray,
    tool: np.ndarray,
    base: np.ndarray,
    q_home_deg: np.ndarray | None = None,
) -> tuple[str, str, str]:
    """``(NAME.src, NAME.dat, $config.dat)`` texts moving through the Cartesian targets at joints ``q`` (m, 6)
    rad with TOOL_DATA[1] = ``tool`` and BASE_DATA[1] = ``base`` (4, 4 mm), starting and ending at an axis
    target (``q_home_deg``, default the first configuration)."""
    T = _pose_targets(cc_nom, q, tool, base)
    S, Tn = kuka_status_turn(cc_nom, q)
    home = np.rad2deg(q[0]) if q_home_deg is None else np.asarray(q_home_deg, dtype=float)
    axis = ",".join(f"A{j + 1} {v:.4f}" for j, v in enumerate(home))
    src = [
        "&ACCESS RVP",
        "&REL 3",
        "&PARAM TEMPLATE = C:\\KRC\\Roboter\\Template\\vorgabe",
        f"DEF {name}( )",
        ";FOLD INI;%{PE}",
        "  ;FOLD BASISTECH INI",
        "    GLOBAL INTERRUPT DECL 3 WHEN $STOPMESS==TRUE DO IR_STOPM ( )",
        "    INTERRUPT ON 3 ",
        "    BAS (#INITMOV,0 )",
        "  ;ENDFOLD (BASISTECH INI)",
        ";ENDFOLD (INI)",
        "",
        "; home, as an axis target in the .dat",
        ";FOLD PTP HOME Vel=100 % DEFAULT;%{PE}%MKUKATPBASIS,%CMOVE,%VPTP,%P 1:PTP, 2:HOME, 3:, 5:100, 7:DEFAULT",
        "$BWDSTART=FALSE",
        "PDAT_ACT=PDEFAULT",
        "FDAT_ACT=FHOME",
        "BAS(#PTP_PARAMS,100)",
        "$H_POS=XHOME",
        "PTP  XHOME",
        ";ENDFOLD",
    ]
    dat = [
        f"DEFDAT  {name}",
        ";FOLD EXTERNAL DECLARATIONS;%{PE}%MKUKATPBASIS,%CEXT,%VCOMMON,%P",
        ";FOLD BASISTECH EXT;%{PE}%MKUKATPBASIS,%CEXT,%VEXT,%P",
        "EXT  BAS (BAS_COMMAND  :IN,REAL  :IN )",
        ";ENDFOLD (BASISTECH EXT)",
        ";ENDFOLD (EXTERNAL DECLARATIONS)",
        f"DECL E6AXIS XHOME={{{axis},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}",
        'DECL FDAT FHOME={TOOL_NO 1,BASE_NO 1,IPO_FRAME #BASE,POINT2[] " ",TQ_STATE FALSE}',
        "DECL PDAT PDEFAULT={VEL 100.0,ACC 100.0,APO_DIST 100.0,APO_MODE #CDIS}",
    ]
    for k in range(len(q)):
        p = f"P{k + 1}"
        kw = "PTP" if k % 3 == 0 else ("LIN" if k % 3 == 1 else "lin")
        cont = " C_DIS" if k % 2 else ""
        src += [
            f";FOLD {kw.upper()} {p}{cont} Vel=2 m/s CPDAT{k + 1} Tool[1]:gripper Base[1]:fixture;%{{PE}}%R 8.3.48,"
            f"%MKUKATPBASIS,%CMOVE,%V{kw.upper()},%P 1:{kw.upper()}, 2:{p}, 3:{cont.strip()}, 5:2, 7:CPDAT{k + 1}",
            "$BWDSTART=FALSE",
            f"LDAT_ACT=LCPDAT{k + 1}",
            f"FDAT_ACT=F{p}",
            "BAS(#CP_PARAMS,2)",
            f"{kw} X{p}{cont}",
            ";ENDFOLD",
        ]
        if k == len(q) // 2:
            src.append("  wait sec 0.5 ; mid-program pause, mixed case on purpose")
        dat += [
            f"DECL E6POS X{p}={{{_xyzabc(T[k])},S {S[k]},T {Tn[k]},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}",
            f'DECL FDAT F{p}={{TOOL_NO 1,BASE_NO 1,IPO_FRAME #BASE,POINT2[] " ",TQ_STATE FALSE}}',
            f"DECL LDAT LCPDAT{k + 1}={{VEL 2.0,ACC 100.0,APO_DIST 100.0,APO_FAC 50.0,ORI_TYP #VAR,CIRC_TYP #BASE}}",
        ]
    src += [
        ";FOLD PTP HOME Vel=100 % DEFAULT;%{PE}%MKUKATPBASIS,%CMOVE,%VPTP,%P 1:PTP, 2:HOME, 3:, 5:100, 7:DEFAULT",
        "$BWDSTART=FALSE",
        "PDAT_ACT=PDEFAULT",
        "FDAT_ACT=FHOME",
        "BAS(#PTP_PARAMS,100)",
        "PTP  XHOME",
        ";ENDFOLD",
        "END",
        "",
    ]
    dat += ["ENDDAT", ""]
    cfg = [
        "DEFDAT  $CONFIG",
        ";FOLD TOOL/BASE",
        "DECL FRAME TOOL_DATA[16]",
        "DECL FRAME BASE_DATA[32]",
        f"TOOL_DATA[1]={{{_xyzabc(tool, 4)}}} ; gripper",
        f"BASE_DATA[1]={{{_xyzabc(base, 4)}}} ; fixture",
        ";ENDFOLD",
        "ENDDAT",
        "",
    ]
    return "\r\n".join(src), "\r\n".join(dat), "\r\n".join(cfg)


def _pose_text(T: np.ndarray, nd: int = 3) -> str:
    q = matrix_to_quat(T[:3, :3])
    return "[[" + ",".join(f"{v:.{nd}f}" for v in T[:3, 3]) + "],[" + ",".join(f"{v:.9f}" for v in q) + "]]"


def rapid_module(
    name: str,
    cc_nom: Any,
    q: np.ndarray,
    tool: np.ndarray,
    base: np.ndarray,
    q_home_deg: np.ndarray | None = None,
) -> str:
    """A RAPID module moving through the Cartesian targets at joints ``q`` (m, 6) rad with ``tGripper`` =
    ``tool`` and ``wobjFixture`` uframe = ``base`` (4, 4 mm), starting and ending with ``MoveAbsJ jHome``."""
    T = _pose_targets(cc_nom, q, tool, base)
    cf = abb_confdata(cc_nom, q)
    home = np.rad2deg(q[0]) if q_home_deg is None else np.asarray(q_home_deg, dtype=float)
    ext = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"
    lines = [
        f"MODULE {name}",
        "    ! written for the twin round trip; comments, case and layout are as a pendant would leave them",
        f"    PERS tooldata tGripper:=[TRUE,{_pose_text(tool, 4)},[2.5,[0,0,60],[1,0,0,0],0,0,0]];",
        '    TASK PERS wobjdata wobjFixture:=[FALSE,TRUE,"",',
        f"        {_pose_text(base, 4)},   ! uframe: the fixture",
        "        [[0,0,0],[1,0,0,0]]];",
        "    CONST jointtarget jHome:=[[" + ",".join(f"{v:.4f}" for v in home) + f"],{ext}];",
    ]
    for k in range(len(q)):
        decl = "CONST robtarget" if k % 4 else "LOCAL CONST robtarget"
        lines.append(
            f"    {decl} p{(k + 1) * 10}:={_pose_text(T[k])[:-1]},["
            + ",".join(str(int(v)) for v in cf[k])
            + f"],{ext}];"
        )
    lines += ["", "    PROC main()", "        ConfJ \\On;", "        MoveAbsJ jHome\\NoEOffs, v1000, fine, tGripper;"]
    for k in range(len(q)):
        p = f"p{(k + 1) * 10}"
        if k % 5 == 0:
            lines.append(f"        MoveJ {p}, v1000, z10, tGripper\\WObj:=wobjFixture;")
        elif k % 5 == 1:
            lines.append(f"        movel {p},v500,z5,tGripper\\WObj:=wobjFixture; ! lower case")
        elif k % 5 == 2:
            lines.append(f"        MoveL \\Conc, {p}, v500\\T:=2, fine,")
            lines.append("            tGripper\\WObj:=wobjFixture;  ! a statement over two lines")
        else:
            lines.append(f"        MoveL {p}, v500, z5, tGripper \\WObj:=wobjFixture;")
    lines += ["        MoveAbsJ jHome\\NoEOffs, v1000, fine, tGripper;", "    ENDPROC", "ENDMODULE", ""]
    return "\n".join(lines)
