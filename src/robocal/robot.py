"""Robot descriptions: what the robot *is* (nominal kinematics, limits, sensors, masses).

A description is read from YAML (``conf/robot/<name>.yaml`` or any path) into a frozen
:class:`RobotDescription`. Units are converted once, here: lengths stay in mm, angles become
radians.

A robot is found by one lookup order (:func:`find_robot`, used by :func:`load_robot` and so by every command
and workflow that takes a robot name): a path (a ``.yaml`` / ``.yml`` name or an existing file), then
``conf/robot/<name>.yaml`` of the current project (the nearest of the working directory and its parents that
has a ``conf/robot/`` folder), then the robots shipped with the package (:data:`SHIPPED_ROBOT_DIR`).

YAML format (keys not listed are kept in ``extra`` and ignored)::

    name: kr16_2
    n_joints: 6
    convention: mdh_rx_tx_rz_tz_ry      # or: poe, or dh (standard Denavit-Hartenberg a, alpha, d, theta of each
                                        # joint, Rz Tz Tx Rx: read as MD-H, or as POE when the last joint has a or
                                        # alpha, see dh_description)
    joints:                             # one entry per joint, base -> flange (external axes before the arm first)
      - {name: A1, a_mm: 0, alpha_deg: 0, d_mm: 675, theta_offset_deg: 0,
         beta_deg: 0, beta_free: false, q_min_deg: -180, q_max_deg: 180}
      - {name: E1, type: prismatic, role: track, ..., q_min_mm: 0, q_max_mm: 6000}   # a linear axis (mm); its
                                        # role names its own errors (track:straightness_y, column:bending ...)
    coupling: {3: {2: -1}}              # optional: kinematic q3 = reported q3 - reported q2 (or a named
                                        # convention, e.g. coupling: fanuc_j2j3); see COUPLINGS
    poe:                                # required when convention is poe (MD-H keys then unused)
      twists:                           # joint axis direction w and a point p_mm on it, base frame, q = 0
        - {w: [0, 0, 1], p_mm: [0, 0, 0]}
      flange_at_zero_mm: [x, y, z]      # flange origin at q = 0, base frame
      flange_R_at_zero: [[..], [..], [..]]  # flange rotation at q = 0 (rows)
    temperature_sensors:                # optional
      - {name: T_j1_C, location: joint, index: 1}
      - {name: T_l4_C, location: link, index: 4}
    T0_C: 24.3                          # reference temperature of the nominal model
    signals:                            # optional: logged signals (extra numeric columns of poses.csv)
      incl_x: {unit: mrad, location: base, description: "inclinometer on the stand"}   # robocal.logged_signals
    positioner:                         # optional: axes that carry the part (a turntable), not the tool
      axes:                             # base -> part, revolute; direction w and a point p_mm on the axis in the
        - {name: P1, w: [0, 0, 1], p_mm: [1800, 0, 300], q_min_deg: -185, q_max_deg: 185}   # robot base frame
      targets: [W1, W2]                 # the reflectors on the part: their rows measure the part (column pos<j>_deg)
    dynamics:                           # optional, for gravity torques
      source: "how the masses were obtained"
      gravity_mps2: [0, 0, -9.81]       # in the base frame
      links:                            # one per joint: the body moved by that joint
        - {mass_kg: 50, com_mm: [0, 0, 0]}   # centre of mass in that joint's frame
      payload_com_mm: [0, 0, 100]       # payload centre of mass in the flange frame

MD-H link ``i`` transform: ``Rot_x(alpha_i) Trans_x(a_i) Rot_z(q_i + theta_offset_i) Trans_z(d_i) Rot_y(beta_i)``;
for a prismatic joint (``type: prismatic``) the joint value moves along z instead:
``Rot_x(alpha_i) Trans_x(a_i) Rot_z(theta_offset_i) Trans_z(d_i + q_i) Rot_y(beta_i)``. In POE a prismatic
joint's twist ``w`` is the direction of its travel (``p_mm`` a point on that line at q = 0).

Joint types and units: a revolute joint's value is an angle (degrees in files, radians inside), a prismatic
joint's a length (millimetres in files and inside; its campaign column is ``q<j>_mm`` instead of ``q<j>_deg``).
Axes before the arm (a track, a lifting column, a gantry's axes) are joints of the same chain, listed first.

Coupling: some controllers report a joint relative to another (FANUC's J3 is measured from the horizon, so the
kinematic J3 is J3 - J2). ``coupling: {k: {j: c, ...}}`` (1-based joint numbers) says the kinematic joint ``k``
is the reported ``k`` plus ``c`` times the reported ``j``; a name of :data:`COUPLINGS` stands for its mapping.
The limits are the controller's (on the reported values). The data door (:func:`robocal.data.contract.read_campaign`)
converts the reported values once, ``q_kinematic = coupling @ q_reported``; inside, every joint value is kinematic.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from robocal.errors import ConfigError
from robocal.logged_signals import SignalDeclaration, parse_declarations
from robocal.robot_dh import DH, dh_description
from robocal.robot_files import SHIPPED_ROBOT_DIR as SHIPPED_ROBOT_DIR  # re-exported: the lookup's old home
from robocal.robot_files import find_robot
from robocal.robot_files import is_robot_path as is_robot_path
from robocal.robot_files import project_robot_dir as project_robot_dir
from robocal.robot_files import robot_dirs as robot_dirs
from robocal.robot_keys import JOINT_KEYS, ROBOT_KEYS, refuse_unknown_keys

#: The MD-H convention string accepted in robot files.
MDH = "mdh_rx_tx_rz_tz_ry"
#: The product-of-exponentials convention string.
POE = "poe"

#: joint types of a description
REVOLUTE = "revolute"
PRISMATIC = "prismatic"
#: named joint couplings (the makers' conventions): kinematic joint -> {reported joint: coefficient}, 1-based
COUPLINGS: dict[str, dict[int, dict[int, float]]] = {
    # FANUC: J3 is reported from the horizon, so the forearm's angle relative to the upper arm is J3 - J2
    "fanuc_j2j3": {3: {2: -1.0}},
}
#: reader of ``*.urdf`` / ``*.urdf#BASE:TIP`` names, "module:function", resolved when a URDF is loaded (as
#: robocal.serve.bundle.DEFAULT_LOADERS): the pipeline stages build robots from params with robot_from_dict and
#: never read a URDF, so they do not depend on robocal.cell.urdf
URDF_READER = "robocal.cell.urdf:robot_from_ref"
#: a linear axis whose travel is within this angle of gravity is a lifting column (its bending under the arm's
#: weight modelled) when its description gives it no role: a column given as a URDF or a DH table lost that model
COLUMN_TILT_DEG = 15.0
#: the same URDF as the description mapping (``path, base, tip`` -> dict), for a pipeline's ``robot_file``: resolved
#: when one is a URDF, so that a stage depends on robocal.cell.urdf only then (as on the file robot_file names)
URDF_DICT_READER = "robocal.cell.urdf:robot_dict_from_ref"


@dataclass(frozen=True)
class Sensor:
    """A temperature sensor: its column name and where it sits (``joint`` or ``link`` ``index``, 1-based)."""

    name: str
    location: str = "joint"
    index: int | None = None


@dataclass(frozen=True)
class RobotDescription:
    """Nominal description of a serial robot.

    Attributes
    ----------
    name : str
    convention : str
        ``"mdh_rx_tx_rz_tz_ry"`` or ``"poe"``.
    joint_names : tuple of str, shape (n,)
    a_mm, alpha, d_mm, theta_offset, beta : ndarray, shape (n,)
        MD-H table (angles in rad). Zero for POE robots.
    beta_free : ndarray of bool, shape (n,)
        Joints whose Hayati beta is a calibration parameter (parallel consecutive axes).
    q_limits : ndarray, shape (n, 2)
        Joint limits in rad, ``[min, max]``.
    poe_w, poe_p_mm : ndarray, shape (n, 3)
        POE joint axis directions and points on the axes at q = 0, base frame (POE robots only).
    poe_flange0 : ndarray, shape (4, 4)
        Flange pose at q = 0 (POE robots only).
    sensors : tuple of Sensor
    T0_C : float or None
        Reference temperature of the nominal model.
    link_mass_kg : ndarray, shape (n,) or None
    link_com_mm : ndarray, shape (n, 3) or None
        Centre of mass of the body moved by joint i, in joint i's frame.
    payload_com_mm : ndarray, shape (3,)
    gravity : ndarray, shape (3,)
        Gravity in the base frame, m/s².
    """

    name: str
    convention: str
    joint_names: tuple[str, ...]
    a_mm: np.ndarray
    alpha: np.ndarray
    d_mm: np.ndarray
    theta_offset: np.ndarray
    beta: np.ndarray
    beta_free: np.ndarray
    q_limits: np.ndarray
    poe_w: np.ndarray | None = None
    poe_p_mm: np.ndarray | None = None
    poe_flange0: np.ndarray | None = None
    sensors: tuple[Sensor, ...] = ()
    T0_C: float | None = None
    link_mass_kg: np.ndarray | None = None
    link_com_mm: np.ndarray | None = None
    payload_com_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    source: str = ""
    signals: tuple[SignalDeclaration, ...] = ()
    joint_types: tuple[str, ...] = ()
    coupling: np.ndarray | None = None
    joint_roles: tuple[str, ...] = ()
    positioner: Positioner | None = None

    def role(self, j: int) -> str:
        """The role of joint ``j`` (0-based; e.g. ``track``, ``column``): its ``role`` key, else ``column`` for a
        linear axis that travels along gravity (within :data:`COLUMN_TILT_DEG`: a lifting column, whatever its
        name in a URDF or a DH table), else its name."""
        if self.joint_roles and self.joint_roles[j]:
            return self.joint_roles[j]
        if self.prismatic[j] and self.travels_along_gravity(j):
            return "column"
        return self.joint_names[j]

    def travels_along_gravity(self, j: int) -> bool:
        """Whether joint ``j``'s axis at q = 0 (base frame) is within :data:`COLUMN_TILT_DEG` of gravity."""
        if self.poe_w is not None:
            z = np.asarray(self.poe_w[j], dtype=float)
        else:  # MD-H: the z axis of the frame the joint's own Rot_z / Trans_z act in
            from scipy.spatial.transform import Rotation  # (robocal.kinematics imports this module)

            R = np.eye(3)
            for k in range(j):  # intrinsic x, z, y: Rot_x(alpha) Rot_z(theta) Rot_y(beta)
                R = R @ Rotation.from_euler("XZY", [self.alpha[k], self.theta_offset[k], self.beta[k]]).as_matrix()
            z = (R @ Rotation.from_euler("X", self.alpha[j]).as_matrix())[:, 2]
        g = np.asarray(self.gravity, dtype=float)
        if not (np.linalg.norm(z) > 0 and np.linalg.norm(g) > 0):
            return False
        return bool(abs(z @ g) / (np.linalg.norm(z) * np.linalg.norm(g)) >= np.cos(np.deg2rad(COLUMN_TILT_DEG)))

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def prismatic(self) -> np.ndarray:
        """(n,) bool: the joints whose value is a length (mm), not an angle (rad)."""
        if not self.joint_types:
            return np.zeros(self.n_joints, dtype=bool)
        return np.array([t == PRISMATIC for t in self.joint_types], dtype=bool)

    @property
    def has_prismatic(self) -> bool:
        return bool(self.prismatic.any())

    def to_kinematic(self, q_reported: np.ndarray) -> np.ndarray:
        """Reported joint values (..., n) (internal units) to the kinematic ones (the coupling; a copy without)."""
        q = np.asarray(q_reported, dtype=float)
        return q.copy() if self.coupling is None else q @ self.coupling.T

    def to_reported(self, q_kinematic: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`to_kinematic`."""
        q = np.asarray(q_kinematic, dtype=float)
        return q.copy() if self.coupling is None else q @ np.linalg.inv(self.coupling).T

    @property
    def sensor_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sensors)

    @property
    def is_mdh(self) -> bool:
        return self.convention == MDH

    @property
    def has_dynamics(self) -> bool:
        return self.link_mass_kg is not None and self.link_com_mm is not None


def _num(d: dict[str, Any], key: str, where: str, default: float | None = None) -> float:
    if key not in d:
        if default is None:
            raise ConfigError(f"{where}: missing key {key!r}")
        return default
    try:
        v = float(d[key])
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: key {key!r} must be a number, got {d[key]!r}") from None
    if not np.isfinite(v):
        raise ConfigError(f"{where}: key {key!r} must be finite, got {d[key]!r}")
    return v


def _vec(value: Any, n: int, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected {n} numbers, got {value!r}") from None
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{where}: expected {n} finite numbers, got {value!r}")
    return arr


def robot_from_dict(data: dict[str, Any], source: str = "<dict>") -> RobotDescription:
    """Build a :class:`RobotDescription` from a parsed YAML mapping; errors name ``source`` and the key."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a robot description must be a mapping")
    refuse_unknown_keys(data, ROBOT_KEYS, source)
    joints = data.get("joints")
    if not isinstance(joints, list) or not joints:
        raise ConfigError(f"{source}: 'joints' must be a non-empty list")
    for i, j in enumerate(joints, start=1):
        if isinstance(j, dict):  # joints[i] counts from 1: the joint's name said too
            where = f"{source}: joints[{i}] (joint {i}" + (f", {j['name']})" if "name" in j else ")")
            refuse_unknown_keys(j, JOINT_KEYS, where, "joint")
    n = len(joints)
    if "n_joints" in data and int(data["n_joints"]) != n:
        raise ConfigError(f"{source}: n_joints = {data['n_joints']} but {n} joints are listed")
    units = data.get("units")
    stated = {str(k): str(v) for k, v in units.items()} if isinstance(units, dict) else None
    if units is not None and (
        stated is None or any(stated.get(k, u) != u for k, u in (("length", "mm"), ("angle", "deg")))
    ):
        raise ConfigError(
            f"{source}: key 'units' is {units!r}: a robot file's numbers are in the units their keys name (a_mm, "
            "alpha_deg, q_min_deg ...): units must be {length: mm, angle: deg}; convert the values"
        )
    convention = str(data.get("convention", MDH))
    if convention == DH:
        data = dh_description(data, source, MDH, POE)
        joints, convention = data["joints"], data["convention"]
    if convention not in (MDH, POE):
        raise ConfigError(f"{source}: convention must be {MDH!r}, {POE!r} or {DH!r}, got {convention!r}")
    names, a, alpha, d, th, beta, bfree, lim, types = _joint_table(joints, convention, source)
    poe_w, poe_p, poe_f = _poe_model(data, n, source) if convention == POE else (None, None, None)
    coupling = _coupling(data.get("coupling"), types, source)
    sensors = _sensors(data, source)
    t0 = data.get("T0_C")
    mass, com, payload_com, gravity = _dynamics(data, n, source)
    return RobotDescription(
        name=str(data.get("name", Path(source).stem)),
        convention=convention,
        joint_names=tuple(names),
        a_mm=np.array(a),
        alpha=np.array(alpha),
        d_mm=np.array(d),
        theta_offset=np.array(th),
        beta=np.array(beta),
        beta_free=np.array(bfree, dtype=bool),
        q_limits=np.array(lim),
        poe_w=poe_w,
        poe_p_mm=poe_p,
        poe_flange0=poe_f,
        sensors=tuple(sensors),
        T0_C=None if t0 is None else float(t0),
        link_mass_kg=mass,
        link_com_mm=com,
        payload_com_mm=payload_com,
        gravity=gravity,
        source=source,
        signals=parse_declarations(data.get("signals"), source),
        # an all-revolute robot keeps the empty tuple: its description is the one it always was
        joint_types=tuple(types) if PRISMATIC in types else (),
        coupling=coupling,
        joint_roles=_roles(joints, source),
        positioner=_positioner(data.get("positioner"), source),
    )


@dataclass(frozen=True)
class Positioner:
    """Axes that carry the part instead of the tool (a turntable, a two-axis tilt-rotate positioner): revolute,
    base -> part. ``names``; ``w`` (k, 3) unit directions and ``p_mm`` (k, 3) a point on each axis, in the robot
    base frame at positioner angles 0 (nominal); ``q_limits`` (k, 2) rad; ``targets`` the reflectors mounted on the
    part (the campaign rows that measure them measure the part, at the angles of the columns :attr:`columns`)."""

    names: tuple[str, ...]
    w: np.ndarray
    p_mm: np.ndarray
    q_limits: np.ndarray
    targets: tuple[str, ...]

    @property
    def n_axes(self) -> int:
        return len(self.names)

    @property
    def columns(self) -> tuple[str, ...]:
        """The campaign columns of the positioner's angles (deg): ``pos1_deg``, ``pos2_deg`` ..."""
        return tuple(f"pos{j + 1}_deg" for j in range(self.n_axes))


def _positioner(data: Any, source: str) -> Positioner | None:
    """The ``positioner`` block (module docstring), checked; None without one."""
    if data is None:
        return None
    where = f"{source}: positioner"
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be a mapping with 'axes' and 'targets'")
    unknown = sorted(set(data) - {"axes", "targets"})
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known: ['axes', 'targets']")
    axes = data.get("axes")
    if not isinstance(axes, list) or not 1 <= len(axes) <= 2:
        raise ConfigError(f"{where}: 'axes' must list one or two axes (a turntable, a tilt-rotate positioner)")
    names, w, pts, lim = [], [], [], []
    for i, ax in enumerate(axes, start=1):
        wa = f"{where}.axes[{i}]"
        if not isinstance(ax, dict):
            raise ConfigError(f"{wa} must be a mapping")
        names.append(str(ax.get("name", f"P{i}")))
        d = _vec(ax.get("w"), 3, f"{wa}: key 'w'")
        if np.linalg.norm(d) < 1e-9:
            raise ConfigError(f"{wa}: key 'w' must be a direction (not zero)")
        w.append(d / np.linalg.norm(d))
        pts.append(_vec(ax.get("p_mm"), 3, f"{wa}: key 'p_mm'"))
        lo, hi = _num(ax, "q_min_deg", wa, -180.0), _num(ax, "q_max_deg", wa, 180.0)
        if lo >= hi:
            raise ConfigError(f"{wa}: q_min_deg ({lo}) must be below q_max_deg ({hi})")
        lim.append(np.deg2rad([lo, hi]))
    targets = data.get("targets")
    if not isinstance(targets, list) or not targets or not all(isinstance(t, str) and t for t in targets):
        raise ConfigError(f"{where}: 'targets' must list the names of the reflectors on the part")
    return Positioner(tuple(names), np.array(w), np.array(pts), np.array(lim), tuple(targets))


def _joint_table(joints: list[Any], convention: str, source: str) -> tuple[list[Any], ...]:
    """Per joint: names, a (mm), alpha, d (mm), theta offset, beta (rad), beta free, limits (rad, or mm for a
    prismatic joint), types."""
    names, a, alpha, d, th, beta, bfree, lim, types = [], [], [], [], [], [], [], [], []
    for i, j in enumerate(joints, start=1):
        where = f"{source}: joints[{i}]"
        if not isinstance(j, dict):
            raise ConfigError(f"{where} must be a mapping")
        names.append(str(j.get("name", f"q{i}")))
        jtype = str(j.get("type", REVOLUTE))
        if jtype not in (REVOLUTE, PRISMATIC):
            raise ConfigError(f"{where}: key 'type' must be {REVOLUTE!r} or {PRISMATIC!r}, got {j.get('type')!r}")
        types.append(jtype)
        mdh_default = 0.0 if convention == POE else None
        a.append(_num(j, "a_mm", where, mdh_default))
        alpha.append(np.deg2rad(_num(j, "alpha_deg", where, mdh_default)))
        d.append(_num(j, "d_mm", where, mdh_default))
        th.append(np.deg2rad(_num(j, "theta_offset_deg", where, 0.0)))
        beta.append(np.deg2rad(_num(j, "beta_deg", where, 0.0)))
        bfree.append(bool(j.get("beta_free", False)))
        unit, other = ("mm", "deg") if jtype == PRISMATIC else ("deg", "mm")
        wrong = [k for k in (f"q_min_{other}", f"q_max_{other}") if k in j]
        if wrong:
            raise ConfigError(
                f"{where}: key {wrong[0]!r} does not fit a {jtype} joint, whose limits are q_min_{unit} / q_max_{unit}"
            )
        lo, hi = _num(j, f"q_min_{unit}", where), _num(j, f"q_max_{unit}", where)
        if lo >= hi:
            raise ConfigError(f"{where}: q_min_{unit} ({lo}) must be below q_max_{unit} ({hi})")
        lim.append((lo, hi) if jtype == PRISMATIC else (np.deg2rad(lo), np.deg2rad(hi)))
    return names, a, alpha, d, th, beta, bfree, lim, types


def _roles(joints: list[Any], source: str) -> tuple[str, ...]:
    """Each joint's optional ``role`` (empty tuple when no joint has one)."""
    roles = []
    for i, j in enumerate(joints, start=1):
        r = j.get("role", "") if isinstance(j, dict) else ""
        if not isinstance(r, str) or (r and not r.replace("_", "").isalnum()):
            raise ConfigError(f"{source}: joints[{i}]: key 'role' must be a word (e.g. track, column), got {r!r}")
        roles.append(r)
    return tuple(roles) if any(roles) else ()


def _coefficient(c: Any, where: str) -> float:
    try:
        v = float(c)
    except (TypeError, ValueError):
        raise ConfigError(f"{where} must be a number, got {c!r}") from None
    if not np.isfinite(v):
        raise ConfigError(f"{where} must be finite, got {c!r}")
    return v


def _coupling(value: Any, types: list[str], source: str) -> np.ndarray | None:
    """The coupling matrix C (n, n), ``q_kinematic = C q_reported``, of a ``coupling`` key (None without)."""
    if value is None:
        return None
    n = len(types)
    if isinstance(value, str):
        if value not in COUPLINGS:
            raise ConfigError(f"{source}: key 'coupling': unknown convention {value!r}; known: {sorted(COUPLINGS)}")
        value = COUPLINGS[value]
    if not isinstance(value, dict):
        raise ConfigError(f"{source}: key 'coupling' must be a convention name or a mapping {{k: {{j: c}}}}")
    C = np.eye(n)

    def joint_no(key: Any, where: str) -> int:
        try:
            k = int(key)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: {key!r} is not a joint number") from None
        if not 1 <= k <= n or str(key).strip() != str(k):
            raise ConfigError(f"{where}: joint {key!r} is not a joint number 1..{n}")
        return k

    for key, terms in value.items():
        k = joint_no(key, f"{source}: key 'coupling'")
        where = f"{source}: key 'coupling.{k}'"
        if not isinstance(terms, dict) or not terms:
            raise ConfigError(f"{where} must map reported joints to coefficients, e.g. {{2: -1}}")
        for jkey, c in terms.items():
            jj = joint_no(jkey, where)
            if jj == k:
                raise ConfigError(f"{where}: a joint cannot be coupled to itself (joint {k})")
            if types[jj - 1] != types[k - 1]:
                raise ConfigError(f"{where}: joint {k} ({types[k - 1]}) cannot take joint {jj} ({types[jj - 1]})")
            C[k - 1, jj - 1] = _coefficient(c, f"{source}: key 'coupling.{k}.{jj}'")
    if abs(np.linalg.det(C)) < 1e-9:
        raise ConfigError(f"{source}: key 'coupling' is singular: the reported joints cannot be recovered from it")
    return C


def _poe_model(data: dict[str, Any], n: int, source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The POE twists' unit axes (n, 3), points (n, 3) mm and the flange at zero (4, 4) mm."""
    poe = data.get("poe")
    if not isinstance(poe, dict) or "twists" not in poe:
        raise ConfigError(f"{source}: convention poe needs a 'poe' mapping with 'twists'")
    tw = poe["twists"]
    if len(tw) != n:
        raise ConfigError(f"{source}: poe.twists has {len(tw)} entries, expected {n}")
    poe_w = np.array([_vec(t.get("w"), 3, f"{source}: poe.twists[{k + 1}].w") for k, t in enumerate(tw)])
    norms = np.linalg.norm(poe_w, axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-6):
        raise ConfigError(f"{source}: poe.twists[*].w must be unit vectors, norms {norms}")
    poe_p = np.array([_vec(t.get("p_mm"), 3, f"{source}: poe.twists[{k + 1}].p_mm") for k, t in enumerate(tw)])
    f = np.eye(4)
    f[:3, 3] = _vec(poe.get("flange_at_zero_mm"), 3, f"{source}: poe.flange_at_zero_mm")
    rot = np.asarray(poe.get("flange_R_at_zero", np.eye(3).tolist()), dtype=float)
    if rot.shape != (3, 3) or np.abs(rot @ rot.T - np.eye(3)).max() > 1e-6 or np.linalg.det(rot) < 0:
        raise ConfigError(f"{source}: poe.flange_R_at_zero must be a 3x3 rotation matrix")
    f[:3, :3] = rot
    return poe_w, poe_p, f


def _sensors(data: dict[str, Any], source: str) -> list[Sensor]:
    """The temperature sensors (names T_<sensor>_C), each given as a name or a mapping with 'name'."""
    sensors = []
    for k, s in enumerate(data.get("temperature_sensors") or []):
        if isinstance(s, str):
            sensors.append(Sensor(name=s))
        elif isinstance(s, dict) and "name" in s:
            idx = s.get("index")
            sensors.append(
                Sensor(
                    name=str(s["name"]),
                    location=str(s.get("location", "joint")),
                    index=None if idx is None else int(idx),
                )
            )
        else:
            raise ConfigError(f"{source}: temperature_sensors[{k + 1}] must be a name or a mapping with 'name'")
        if not sensors[-1].name.startswith("T_") or not sensors[-1].name.endswith("_C"):
            raise ConfigError(f"{source}: temperature sensor {sensors[-1].name!r} must be named T_<sensor>_C")
    return sensors


def _dynamics(
    data: dict[str, Any], n: int, source: str
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray, np.ndarray]:
    """Link masses (n,) kg and centres of mass (n, 3) mm (None without 'dynamics'), payload centre of mass, gravity."""
    mass = com = None
    payload_com = np.zeros(3)
    gravity = np.array([0.0, 0.0, -9.81])
    dyn = data.get("dynamics")
    if isinstance(dyn, dict) and dyn.get("links"):
        links = dyn["links"]
        if len(links) != n:
            raise ConfigError(f"{source}: dynamics.links has {len(links)} entries, expected {n}")
        mass = np.array([_num(lk, "mass_kg", f"{source}: dynamics.links[{k + 1}]") for k, lk in enumerate(links)])
        com = np.array(
            [_vec(lk.get("com_mm"), 3, f"{source}: dynamics.links[{k + 1}].com_mm") for k, lk in enumerate(links)]
        )
        if "payload_com_mm" in dyn:
            payload_com = _vec(dyn["payload_com_mm"], 3, f"{source}: dynamics.payload_com_mm")
    if isinstance(dyn, dict) and "gravity_mps2" in dyn:  # stated with or without masses (a DH table's base is
        gravity = _vec(dyn["gravity_mps2"], 3, f"{source}: dynamics.gravity_mps2")  # axis 1's frame: a track's)
    return mass, com, payload_com, gravity


def load_robot(name_or_path: str | Path, conf_dir: str | Path | None = None) -> RobotDescription:
    """Load a robot by name, from a YAML path, or from a URDF (``robot.urdf`` or ``robot.urdf#BASE:TIP``, see
    :mod:`robocal.cell.urdf`). A name is looked up as :func:`find_robot` says: ``conf/robot/<name>.yaml`` of the
    current project first, then the packaged robots (``conf_dir``: only that folder)."""
    if str(name_or_path).endswith(".urdf") or ".urdf#" in str(name_or_path):
        import importlib

        mod, func = URDF_READER.split(":")
        robot: RobotDescription = getattr(importlib.import_module(mod), func)(name_or_path)
        return robot
    path = find_robot(name_or_path, conf_dir)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    # Hydra group files may nest the description under 'robot:'
    if isinstance(data, dict) and "joints" not in data and isinstance(data.get("robot"), dict):
        data = data["robot"]
    return robot_from_dict(data, source=str(path))
