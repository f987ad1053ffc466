"""URDF in and out: a robot description from a URDF, and a calibrated model written back as a URDF.

**In** (:func:`robot_from_urdf`): the URDF is read with `yourdfpy <https://github.com/clemense/yourdfpy>`_ (MIT,
maintained, pure Python over lxml; it also computes forward kinematics, which the tests use as the independent
check). The kinematic path from a *base* link to a *tip* link becomes a POE description (``convention: poe`` of
:mod:`robocal.robot`): for each revolute (or continuous) joint on the path, its axis direction ``w`` and a point
``p_mm`` on it in the base frame at q = 0 (the joint frame's origin), the tip link's pose at q = 0 as the flange,
and the joint limits of the URDF (a continuous joint gets +-360 deg). Fixed joints on the path are folded in.
A prismatic joint becomes a prismatic joint of the description (``type: prismatic``, its travel direction as the
twist's ``w``, its limits in mm). Floating, planar and mimic joints on the path are refused. Lengths: URDF metres
become millimetres.

A robot is named ``path/to/robot.urdf`` (base = the URDF's root link, tip = the end of the only actuated path) or
``path/to/robot.urdf#BASE:TIP`` (either may be empty: ``robot.urdf#:tool0``); :func:`robocal.robot.load_robot`
dispatches such names here.

**Out** (:func:`write_calibrated_urdf`): the calibrated chain (nominal + identified errors, optionally a thermal
drift) is evaluated at q = 0 element by element; each actuated joint's child link gets the calibrated frame
``A_i G_i`` where ``A_i`` is the chain frame just after joint element ``i`` (it carries the joint offset error and
every tilt before it, MD-H betas included) and ``G_i`` the constant transform from that chain frame to the
original link frame (so meshes and frames attached to links stay attached). Each joint's ``<origin>`` becomes
``parent_link^-1 · child_link`` (xyz and rpy); its ``<axis>`` is unchanged in the child frame, which is exact
because the child frame turns with the corrected axis. The last fixed joint before the tip carries the
corrections after the last joint. The calibration's tools are added as fixed frames ``robocal_tool_<name>`` on
the tip link. Everything else in the original file passes through; the original file is never written.
A robot that did not come from a URDF (an MD-H table) is written as a fresh URDF with links ``base_link``,
``link_1`` … ``link_n``, ``flange`` and the tools. A URDF carries the geometry only: the effects a ``robocal
discover`` calibration holds beyond it (a gear's error, a backlash, a compliance, the residual layer: joint offsets
that change with the state; measurement-side effects) are listed by name in the YAML under ``not_in_urdf``
(:func:`not_in_urdf`), with why and where they are compensated instead, never dropped silently.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from robocal.cell.urdf_inertials import ACTUATED as _ACTUATED
from robocal.cell.urdf_inertials import body_inertials
from robocal.cell.urdf_inertials import origin_mm as _origin_mm
from robocal.errors import ConfigError
from robocal.kinematics.chain import FIXED, RX, RY, RZ, TZ, Chain
from robocal.kinematics.transforms import inv_transform, rpy_from_matrix
from robocal.robot import POE, RobotDescription, robot_from_dict


def split_ref(ref: str | Path) -> tuple[Path, str | None, str | None]:
    """``"robot.urdf#base:tip"`` -> ``(Path("robot.urdf"), "base", "tip")`` (None where not given)."""
    s = str(ref)
    base = tip = None
    if "#" in s:
        s, frag = s.split("#", 1)
        if ":" in frag:
            b, t = frag.split(":", 1)
        else:
            b, t = frag, ""
        base, tip = (b or None), (t or None)
    return Path(s), base, tip


def load_urdf(path: str | Path) -> Any:
    """Parse a URDF with yourdfpy (no meshes loaded); errors name the file."""
    import yourdfpy

    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"URDF file {p} does not exist")
    try:
        return yourdfpy.URDF.load(
            str(p), load_meshes=False, build_collision_scene_graph=False, load_collision_meshes=False
        )
    except Exception as exc:  # lxml and yourdfpy raise many types; name the file
        raise ConfigError(f"{p}: not a readable URDF: {type(exc).__name__}: {exc}") from None


@dataclass(frozen=True)
class UrdfJoint:
    """One joint on the base -> tip path: name, type, parent and child links, origin (4, 4) in mm, axis (3,)."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float | None
    upper: float | None


def chain_path(urdf: Any, base: str | None, tip: str | None, source: str) -> tuple[str, str, list[UrdfJoint]]:
    """The joints from ``base`` to ``tip`` (defaults: the root link; the end of the only actuated path)."""
    links = set(urdf.link_map)
    by_child = {j.child: j for j in urdf.joint_map.values()}
    children: dict[str, list[Any]] = {}
    for j in urdf.joint_map.values():
        children.setdefault(j.parent, []).append(j)
    if base is None:
        base = str(urdf.base_link)
    if base not in links:
        raise ConfigError(f"{source}: no link named {base!r} (base); links: {sorted(links)}")
    if tip is None:
        tip = _only_actuated_leaf(children, base, source)
    if tip not in links:
        raise ConfigError(f"{source}: no link named {tip!r} (tip); links: {sorted(links)}")
    path: list[UrdfJoint] = []
    link = tip
    while link != base:
        j = by_child.get(link)
        if j is None:
            raise ConfigError(f"{source}: link {tip!r} is not below link {base!r}")
        path.append(_urdf_joint(j, source))
        link = j.parent
    path.reverse()
    if not any(j.type in _ACTUATED for j in path):
        raise ConfigError(f"{source}: no revolute or prismatic joint between {base!r} and {tip!r}")
    return base, tip, path


def _only_actuated_leaf(children: dict[str, list[Any]], base: str, source: str) -> str:
    """The tip by default: the leaf below ``base`` with the most actuated joints, when it is the only one."""
    leaves = []
    stack = [(base, 0)]
    while stack:
        link, n_act = stack.pop()
        kids = children.get(link, [])
        if not kids:
            leaves.append((n_act, link))
        for j in kids:
            stack.append((j.child, n_act + (j.type in _ACTUATED)))
    best = max(n for n, _ in leaves) if leaves else 0
    cands = sorted(link for n, link in leaves if n == best)
    if best == 0 or len(cands) != 1:
        raise ConfigError(f"{source}: name the tip link ('{source}#{base}:TIP'); leaves with {best} joints: {cands}")
    return cands[0]


def _urdf_joint(j: Any, source: str) -> UrdfJoint:
    """A URDF joint of the chain (mm, its axis and limits), or a ConfigError for a joint robocal cannot model."""
    if j.type not in (*_ACTUATED, "fixed"):
        raise ConfigError(
            f"{source}: joint {j.name!r} is {j.type}; only revolute, continuous, prismatic and fixed are supported"
        )
    if getattr(j, "mimic", None) is not None:
        raise ConfigError(f"{source}: joint {j.name!r} mimics another joint; not supported")
    axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, dtype=float)
    if j.type in _ACTUATED and not np.linalg.norm(axis) > 0:
        raise ConfigError(f"{source}: joint {j.name!r} has a zero axis")
    lim = j.limit
    lower = None if lim is None or lim.lower is None else float(lim.lower)
    upper = None if lim is None or lim.upper is None else float(lim.upper)
    return UrdfJoint(j.name, j.type, j.parent, j.child, _origin_mm(j.origin), axis, lower, upper)


def robot_dict_from_urdf(path: str | Path, base_link: str | None = None, tip_link: str | None = None) -> dict[str, Any]:
    """The robot description mapping (the YAML format of :mod:`robocal.robot`, POE) of a URDF path."""
    p = Path(path)
    urdf = load_urdf(p)
    base, tip, joints = chain_path(urdf, base_link, tip_link, str(p))
    T = np.eye(4)
    entries, twists = [], []
    for j in joints:
        T = T @ j.origin
        if j.type not in _ACTUATED:
            continue
        w = T[:3, :3] @ (j.axis / np.linalg.norm(j.axis))
        w = w / np.linalg.norm(w)
        if j.type == "prismatic":
            if j.lower is None or j.upper is None:
                raise ConfigError(f"{p}: prismatic joint {j.name!r} has no <limit lower=.. upper=..>")
            entries.append(
                {"name": j.name, "type": "prismatic", "q_min_mm": j.lower * 1000.0, "q_max_mm": j.upper * 1000.0}
            )
            twists.append({"w": w.tolist(), "p_mm": T[:3, 3].tolist()})
            continue
        if j.type == "continuous" or j.lower is None or j.upper is None:
            lo, hi = -360.0, 360.0
        else:
            lo, hi = math.degrees(j.lower), math.degrees(j.upper)
        entries.append({"name": j.name, "q_min_deg": lo, "q_max_deg": hi})
        twists.append({"w": w.tolist(), "p_mm": T[:3, 3].tolist()})
    out: dict[str, Any] = {
        "name": str(getattr(urdf.robot, "name", None) or p.stem),
        "n_joints": len(entries),
        "convention": POE,
        "joints": entries,
        "poe": {"twists": twists, "flange_at_zero_mm": T[:3, 3].tolist(), "flange_R_at_zero": T[:3, :3].tolist()},
        "urdf": {"file": str(p), "base_link": base, "tip_link": tip},
    }
    links, why = body_inertials(urdf, joints, twists)
    out["urdf"]["inertials"] = why
    if links is not None:
        out["dynamics"] = {"links": links}
    return out


def robot_from_urdf(path: str | Path, base_link: str | None = None, tip_link: str | None = None) -> RobotDescription:
    """A POE :class:`RobotDescription` of the URDF's path from ``base_link`` to ``tip_link``."""
    data = robot_dict_from_urdf(path, base_link, tip_link)
    return robot_from_dict(data, source=f"{path}#{data['urdf']['base_link']}:{data['urdf']['tip_link']}")


def robot_dict_from_ref(ref: str | Path) -> dict[str, Any]:
    """:func:`robot_dict_from_urdf` of a name ``path.urdf`` or ``path.urdf#BASE:TIP``."""
    p, base, tip = split_ref(ref)
    return robot_dict_from_urdf(p, base, tip)


def robot_from_ref(ref: str | Path) -> RobotDescription:
    """:func:`robot_from_urdf` of a name ``path.urdf`` or ``path.urdf#BASE:TIP``."""
    p, base, tip = split_ref(ref)
    return robot_from_urdf(p, base, tip)


def urdf_fk(urdf: Any, q: np.ndarray, frame: str, base: str, joint_names: list[str] | None = None) -> np.ndarray:
    """yourdfpy's own forward kinematics: ``base_T_frame`` (m, 4, 4) in mm for joints ``q`` (m, n) rad (a
    prismatic joint's value in mm)."""
    names = joint_names or list(urdf.actuated_joint_names)
    scale = np.array([1e-3 if urdf.joint_map[nm].type == "prismatic" else 1.0 for nm in names])
    out = np.empty((len(q), 4, 4))
    for k, qk in enumerate(np.atleast_2d(q)):
        urdf.update_cfg(dict(zip(names, qk * scale, strict=True)))
        T = np.array(urdf.get_transform(frame, base), dtype=float)
        T[:3, 3] *= 1000.0
        out[k] = T
    return out


# --------------------------------------------------------------------------------------------- out


def _elem(kind: int, v: float) -> np.ndarray:
    T = np.eye(4)
    if kind <= TZ:
        T[kind, 3] = v
        return T
    c, s = math.cos(v), math.sin(v)
    if kind == RX:
        T[1:3, 1:3] = [[c, -s], [s, c]]
    elif kind == RY:
        T[0, 0], T[0, 2], T[2, 0], T[2, 2] = c, s, -s, c
    else:
        T[0:2, 0:2] = [[c, -s], [s, c]]
    return T


def joint_frames(chain: Chain, eta: np.ndarray | None) -> tuple[list[np.ndarray], list[int], np.ndarray]:
    """Chain frames at q = 0: just after each joint element (n, in joint order), the local axis index (0, 1, 2)
    of each joint element (the axis it turns about, or slides along), and the flange (4, 4)."""
    eta = np.zeros(chain.n_params) if eta is None else np.asarray(eta, dtype=float)
    T = np.eye(4)
    frames: dict[int, np.ndarray] = {}
    axes: dict[int, int] = {}
    for e, kind in enumerate(chain.kinds):
        if kind == FIXED:
            Tf = chain.fixed[e]
            assert Tf is not None
            T = T @ Tf
            continue
        v = float(chain.nominal[e]) + (float(eta[chain.param[e]]) if chain.param[e] >= 0 else 0.0)
        T = T @ _elem(kind, v)
        j = int(chain.joint[e])
        if j >= 0:
            frames[j] = T.copy()
            axes[j] = kind - RX if kind in (RX, RY, RZ) else kind
    n = chain.n_joints
    return [frames[j] for j in range(n)], [axes[j] for j in range(n)], T


def _fmt(v: float) -> str:
    return repr(float(v)) if v != 0 else "0"


def _origin_attrs(T_mm: np.ndarray) -> dict[str, str]:
    xyz = T_mm[:3, 3] / 1000.0
    return {"xyz": " ".join(_fmt(v) for v in xyz), "rpy": " ".join(_fmt(v) for v in rpy_from_matrix(T_mm[:3, :3]))}


def calibrated_link_frames(
    robot: RobotDescription, eta: np.ndarray, link_frames: list[np.ndarray] | None = None
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Calibrated child-link frames at q = 0 (base frame, mm), the joint axes in those frames, and the flange.

    ``link_frames``: the original child-link frames at q = 0 (a URDF's); default: the chain's own joint frames.
    """
    from robocal.kinematics.chain import build_chain

    chain = build_chain(robot)
    A_nom, ax, _ = joint_frames(chain, None)
    A_cal, _, F_cal = joint_frames(chain, eta)
    L = link_frames if link_frames is not None else A_nom
    frames, axes = [], []
    for i in range(chain.n_joints):
        G = inv_transform(A_nom[i]) @ L[i]
        frames.append(A_cal[i] @ G)
        axes.append(G[:3, :3].T[:, ax[i]])
    return frames, axes, F_cal


def _tool_elements(tools: dict[str, np.ndarray]) -> list[tuple[str, np.ndarray]]:
    return [(f"robocal_tool_{name}", T) for name, T in tools.items()]


def write_calibrated_urdf(
    robot: RobotDescription,
    eta: np.ndarray,
    out_path: str | Path,
    tools: dict[str, np.ndarray] | None = None,
    urdf_path: str | Path | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
) -> Path:
    """Write the robot with kinematic errors ``eta`` (P,) (mm / rad, the chain's parameter order) as a URDF.

    tools : {name: flange_T_tool (4, 4) mm} added as fixed frames on the tip link.
    urdf_path, base_link, tip_link : the original URDF (the robot must have been built from it); default: the
    ``urdf`` reference in the robot's source, else a fresh URDF is written.
    """
    from lxml import etree

    from robocal.io import write_bytes

    out = Path(out_path)
    tools = dict(tools or {})
    if urdf_path is None and "#" in robot.source and ".urdf" in robot.source:
        urdf_path, base_link, tip_link = split_ref(robot.source)
    if urdf_path is not None and Path(urdf_path).resolve() == out.resolve():
        raise ConfigError(f"refusing to overwrite the original URDF {urdf_path}; choose another output path")
    if urdf_path is None:
        root, tip = _fresh_urdf(robot, eta)
    else:
        root, tip = _calibrated_copy(robot, eta, Path(urdf_path), base_link, tip_link)
    for name, Tt in _tool_elements(tools):
        etree.SubElement(root, "link", name=name)
        jt = etree.SubElement(root, "joint", name=f"{name}_joint", type="fixed")
        etree.SubElement(jt, "origin", **_origin_attrs(Tt))
        etree.SubElement(jt, "parent", link=tip)
        etree.SubElement(jt, "child", link=name)
    data = etree.tostring(root, xml_declaration=True, encoding="utf-8", pretty_print=True)
    return write_bytes(out, data)


def _fresh_urdf(robot: RobotDescription, eta: np.ndarray) -> tuple[Any, str]:
    """A new URDF tree of the calibrated robot (one link per joint, a fixed flange) and its tip link."""
    from lxml import etree

    frames, axes, F_cal = calibrated_link_frames(robot, eta)
    root = etree.Element("robot", name=f"{robot.name}_calibrated")
    etree.SubElement(root, "link", name="base_link")
    parent, P = "base_link", np.eye(4)
    for i in range(robot.n_joints):
        child = f"link_{i + 1}"
        etree.SubElement(root, "link", name=child)
        slide = bool(robot.prismatic[i])
        jt = etree.SubElement(root, "joint", name=robot.joint_names[i], type="prismatic" if slide else "revolute")
        etree.SubElement(jt, "origin", **_origin_attrs(inv_transform(P) @ frames[i]))
        etree.SubElement(jt, "parent", link=parent)
        etree.SubElement(jt, "child", link=child)
        etree.SubElement(jt, "axis", xyz=" ".join(_fmt(v) for v in axes[i]))
        lo, hi = robot.q_limits[i] * (1e-3 if slide else 1.0)  # a prismatic joint's limits in metres
        etree.SubElement(jt, "limit", lower=_fmt(lo), upper=_fmt(hi), effort="0", velocity="0")
        parent, P = child, frames[i]
    etree.SubElement(root, "link", name="flange")
    jt = etree.SubElement(root, "joint", name="flange_joint", type="fixed")
    etree.SubElement(jt, "origin", **_origin_attrs(inv_transform(P) @ F_cal))
    etree.SubElement(jt, "parent", link=parent)
    etree.SubElement(jt, "child", link="flange")
    return root, "flange"


def _calibrated_copy(
    robot: RobotDescription, eta: np.ndarray, src: Path, base_link: str | None, tip_link: str | None
) -> tuple[Any, str]:
    """The original URDF tree ``src`` with the calibrated origins of the joints from base to tip, and the tip."""
    from lxml import etree

    urdf = load_urdf(src)
    base, tip, joints = chain_path(urdf, base_link, tip_link, str(src))
    T = np.eye(4)
    L = []
    for j in joints:
        T = T @ j.origin
        if j.type in _ACTUATED:
            L.append(T.copy())
    if len(L) != robot.n_joints:
        raise ConfigError(f"{src}: {len(L)} moving joints from {base} to {tip}, the robot has {robot.n_joints}")
    frames, _, F_cal = calibrated_link_frames(robot, eta, L)
    new_origin: dict[str, np.ndarray] = {}
    P = np.eye(4)  # calibrated pose of the current parent link
    k = 0
    last_act = max(i for i, j in enumerate(joints) if j.type in _ACTUATED)
    fixed_after = [i for i, j in enumerate(joints) if i > last_act]
    for i, j in enumerate(joints):
        if j.type in _ACTUATED:
            new_origin[j.name] = inv_transform(P) @ frames[k]
            P = frames[k]
            k += 1
        elif fixed_after and i == fixed_after[-1]:
            new_origin[j.name] = inv_transform(P) @ F_cal
            P = F_cal
        else:
            P = P @ j.origin
    if not fixed_after and np.abs(P - F_cal).max() > 1e-9:
        raise ConfigError(f"{src}: the tip {tip} is the last joint's link; corrections after it cannot be placed")
    parser = etree.XMLParser(remove_blank_text=False)
    tree = etree.parse(str(src), parser)
    root = tree.getroot()
    for jel in root.findall("joint"):
        name = jel.get("name")
        if name in new_origin:
            org = jel.find("origin")
            if org is None:
                org = etree.SubElement(jel, "origin")
            for key, val in _origin_attrs(new_origin[name]).items():
                org.set(key, val)
    root.set("name", f"{root.get('name', 'robot')}_calibrated")
    return root, tip


#: what the written URDF holds of a calibration
URDF_CARRIES = (
    "the geometry: each joint's origin with the identified kinematic errors (one fixed transform per joint) and "
    "the calibration's tools as fixed frames"
)
#: what a discovered joint-level effect's offset changes with, by its signal (robocal.compensation.discovered)
_CHANGES_WITH = {
    "angle": "the joint's own angle (a gear's periodic error)",
    "transmission": "the joint's own angle (a gear's transmission error)",
    "gravity": "the pose and the payload (the gravity torque)",
    "torque": "the joint torque the controller reports",
    "current": "the motor current the controller reports",
    "direction": "the direction the joint approached from (backlash)",
    "dictionary": "the commanded joints (a proposed equation)",
    "weight": "the pose (the arm's own weight)",
    "layer": "every joint angle (the residual layer)",
}
#: where a joint-level effect is compensated instead
_COMPENSATED_BY = "robocal serve, robocal filter and compensation.csv, from the calibration.json that holds it"


def not_in_urdf(effects: Any = (), not_compensated: Any = ()) -> list[dict[str, Any]]:
    """The discovered effects a URDF cannot carry, each by name with why and where it is compensated instead:
    ``effects`` the calibration's joint-level effects (:attr:`CalibrationResult.effects`), ``not_compensated``
    its ``effects_not_compensated`` records (compensated nowhere, for the reason they give)."""
    out: list[dict[str, Any]] = []
    for e in effects:
        changes = _CHANGES_WITH.get(str(e.get("signal")), f"its signal {e.get('signal')!r}")
        out.append(
            {
                "key": str(e["key"]),
                "effect": str(e.get("effect")),
                "joint": e.get("joint"),
                "why": f"a joint offset that changes with {changes}; a URDF joint origin is one fixed transform",
                "compensated_by": _COMPENSATED_BY,
            }
        )
    for e in not_compensated:
        out.append(
            {
                "key": str(e["key"]),
                "effect": str(e.get("effect")),
                "joint": e.get("joint"),
                "why": str(e.get("reason", "not a property of the robot's geometry")),
                "compensated_by": "none",
            }
        )
    return out


def calibration_yaml(
    cal: Any,
    urdf_path: str | Path | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
    not_compensated: Any = (),
) -> dict[str, Any]:
    """The calibration as a small mapping for YAML: identified errors (mm / rad) with standard errors, the
    tracker frame, the tools, the fit's RMS, where the URDF came from, what the URDF carries (``urdf_carries``)
    and, by name, the discovered effects it cannot (``not_in_urdf``, :func:`not_in_urdf`)."""
    names = list(cal.model.chain.param_names)
    eta = cal.kinematic_errors
    se = cal.stderr[: len(names)]
    out: dict[str, Any] = {"format": "robocal-urdf-calibration", "version": 1, "robot": cal.model.robot.name}
    if urdf_path is not None:
        p = Path(urdf_path)
        out["urdf"] = {
            "file": str(p),
            "sha256": hashlib.sha256(p.read_bytes()).hexdigest(),
            "base_link": base_link,
            "tip_link": tip_link,
        }
    kinds = cal.model.chain.param_kind
    out["kinematic_errors"] = {
        n: {
            "value": float(v),
            "unit": "mm" if k == "length" else "rad",
            "stderr": None if not np.isfinite(s) else float(s),
        }
        for n, v, s, k in zip(names, eta, se, kinds, strict=True)
        if v != 0.0 or np.isfinite(s)
    }
    out["tracker_T_base"] = np.asarray(cal.tracker_T_base).round(12).tolist()
    out["tools_mm"] = {k: np.asarray(v).round(9).tolist() for k, v in cal.tools.items()}
    rms = cal.fit.get("rms_position_mm") if isinstance(cal.fit, dict) else None
    if rms is not None:
        out["rms_position_mm"] = float(rms)
    out["urdf_carries"] = URDF_CARRIES
    out["not_in_urdf"] = not_in_urdf(getattr(cal, "effects", ()), not_compensated)
    return out


def export_calibration(
    cal: Any,
    out_dir: str | Path,
    urdf_path: str | Path | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
    name: str = "robot_calibrated",
    not_compensated: Any = (),
) -> tuple[Path, Path]:
    """Write ``<name>.urdf`` (calibrated kinematics, tools as fixed frames) and ``<name>.yaml`` (the calibration,
    with what the URDF cannot carry: :func:`calibration_yaml`) into ``out_dir``; returns both paths.
    ``not_compensated``: the calibration file's ``effects_not_compensated`` records (a discover calibration)."""
    import yaml

    from robocal.io import write_text

    robot = cal.model.robot
    if urdf_path is None and "#" in robot.source and ".urdf" in robot.source:
        urdf_path, base_link, tip_link = split_ref(robot.source)
    tools: dict[str, np.ndarray] = {}
    Rs = cal.model.tool_rotations(cal.x)
    for k, (tname, t) in enumerate(cal.tools.items()):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rs[k], t
        tools[tname] = T
    d = Path(out_dir)
    u = write_calibrated_urdf(robot, cal.kinematic_errors, d / f"{name}.urdf", tools, urdf_path, base_link, tip_link)
    y = write_text(
        d / f"{name}.yaml",
        yaml.safe_dump(calibration_yaml(cal, urdf_path, base_link, tip_link, not_compensated), sort_keys=False),
    )
    return u, y
