"""A request line parsed and checked: JSON numbers only (no NaN), the targets (joints or poses, their signals
and external axes), the temperatures, and a whole ``correct`` request (:class:`CorrectRequest`); what cannot be
answered raises :class:`RequestError` with its code.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robocal.serve.bundle import Bundle
from robocal.serve.settings import ServiceConfig


class RequestError(Exception):
    """A request that cannot be answered; ``code`` is one of :data:`ERROR_CODES`."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


# --------------------------------------------------------------------------------------------- parsing


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number JSON allows")


def _loads(line: bytes) -> dict[str, Any]:
    try:
        text = line.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RequestError("parse_error", f"request is not UTF-8: {exc}") from None
    try:
        obj = json.loads(text, parse_constant=_reject_constant)
    except (ValueError, RecursionError) as exc:
        raise RequestError("parse_error", f"request is not valid JSON: {exc}") from None
    if not isinstance(obj, dict):
        raise RequestError("parse_error", f"request must be a JSON object, got {type(obj).__name__}")
    return obj


def _number(v: Any, name: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise RequestError("bad_request", f"'{name}' must be a number, got {type(v).__name__}")
    try:
        f = float(v)
    except OverflowError:  # a JSON integer beyond float range
        f = math.inf
    if not math.isfinite(f):
        raise RequestError("bad_request", f"'{name}' must be finite")
    return f


_NUMBER_TYPES = (int, float)


def _vector(v: Any, n: int, name: str) -> np.ndarray:
    if not isinstance(v, list) or len(v) != n:
        raise RequestError("bad_request", f"'{name}' must be a list of {n} numbers")
    # fast path: plain ints / floats (not bools), all finite; otherwise the per-element check names the culprit
    if all(type(x) in _NUMBER_TYPES for x in v):
        try:
            arr = np.array(v, dtype=float)
        except OverflowError:
            arr = np.array([math.inf])
        if np.isfinite(arr).all():
            return arr
    return np.array([_number(x, f"{name}[{k}]") for k, x in enumerate(v)], dtype=float)


@dataclass
class Targets:
    """Parsed targets: joint targets and Cartesian ones (tool pose in the robot base frame)."""

    kind: np.ndarray  # (m,) 0 joints, 1 pose
    q_deg: np.ndarray  # (m, n) target joints, or the seed for pose targets
    xyz_mm: np.ndarray  # (m, 3) pose targets (zeros for joint targets)
    quat: np.ndarray  # (m, 4)
    current_A: np.ndarray | None
    tau_Nm: np.ndarray | None
    direction: np.ndarray | None = None
    #: (m,) which pose targets state an orientation (``quat_wxyz``); None: every one does
    oriented: np.ndarray | None = None
    logged: dict[str, np.ndarray] | None = None  # the logged signals' values (column -> (m,))
    #: (m, k) the external axes' values (mm, ``E1``.. in chain order) of a robot on external axes, else None
    ext_mm: np.ndarray | None = None

    def subset(self, rows: np.ndarray) -> Targets:
        """The targets ``rows`` (their kinds, joints, poses and orientation flags; the signals left out)."""
        return Targets(
            self.kind[rows], self.q_deg[rows], self.xyz_mm[rows], self.quat[rows], None, None, None,
            None if self.oriented is None else self.oriented[rows], None,
            None if self.ext_mm is None else self.ext_mm[rows],
        )  # fmt: skip


#: a target's optional per-joint signals, in the order they are checked
TARGET_SIGNALS = ("current_A", "tau_Nm", "dir")
#: a target's optional logged signals (``{"incl_x": 0.012}``), for effects discovered on them
LOGGED_FIELD = "signals"
#: a target's external axes (mm), with a robot on external axes
EXT_FIELD = "ext_mm"


def parse_targets(raw: Any, n: int, max_targets: int, position: bool = False, n_ext: int = 0) -> Targets:
    """``targets``: a non-empty list of ``{"q_deg": [n]}`` or ``{"xyz_mm": [3], "quat_wxyz": [4],
    "q_seed_deg": [n]}``, each optionally with ``current_A`` / ``tau_Nm`` ([n]) and ``dir`` ([n] of -1 / +1, the
    approach direction of each joint, for a discovered backlash). With ``position`` (mode ``position``) a pose
    target may leave ``quat_wxyz`` out: a position-only target (a 3-DoF reflector, a drilling point). A robot on
    ``n_ext`` external axes: ``n`` counts the arm's joints, and every target carries ``ext_mm`` ([n_ext], mm:
    ``E1``.. in chain order)."""
    if not isinstance(raw, list) or not raw:
        raise RequestError("bad_request", "'targets' must be a non-empty list of objects")
    if len(raw) > max_targets:
        raise RequestError("too_large", f"{len(raw)} targets in one request; the limit is {max_targets}")
    m = len(raw)
    kind = np.zeros(m, dtype=int)
    q = np.zeros((m, n))
    xyz = np.zeros((m, 3))
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (m, 1))
    oriented = np.ones(m, dtype=bool)
    signals: dict[str, np.ndarray] = {}
    logged: dict[str, np.ndarray] = {}
    ext = np.zeros((m, n_ext)) if n_ext else None
    for k, t in enumerate(raw):
        if not isinstance(t, dict):
            raise RequestError("bad_request", f"targets[{k}] must be an object")
        t = _parse_ext(t, k, ext)
        kind[k] = _parse_target(t, k, n, q, xyz, quat)
        if kind[k] == 1 and "quat_wxyz" not in t:
            if not position:
                raise RequestError(
                    "bad_request",
                    f"targets[{k}] has no 'quat_wxyz': mode 'pose' matches the full tool pose; ask a position-only "
                    'target with "mode": "position"',
                )
            oriented[k] = False
        for key in TARGET_SIGNALS:
            if key in t:
                arr = signals.setdefault(key, np.full((m, n), np.nan))
                arr[k] = _vector(t[key], n, f"targets[{k}].{key}")
                if key == "dir" and not np.isin(arr[k], (-1.0, 1.0)).all():
                    raise RequestError("bad_request", f"targets[{k}].dir must hold -1 or +1 per joint")
        if LOGGED_FIELD in t:
            _parse_logged(t[LOGGED_FIELD], k, m, logged)
    for key in TARGET_SIGNALS:
        if key in signals and np.isnan(signals[key]).any():
            raise RequestError("bad_request", f"'{key}' must be given for every target or for none")
    for key, v in logged.items():
        if np.isnan(v).any():
            raise RequestError("bad_request", f"the logged signal '{key}' must be given for every target or for none")
    return Targets(kind, q, xyz, quat, signals.get("current_A"), signals.get("tau_Nm"), signals.get("dir"),
                   oriented, logged or None, ext)  # fmt: skip


def _parse_ext(t: dict[str, Any], k: int, ext: np.ndarray | None) -> dict[str, Any]:
    """``targets[k].ext_mm`` into row ``k`` of ``ext`` (m, n_ext); the target without it (as it is when the robot
    has no external axis: an ``ext_mm`` is then an unknown field)."""
    if ext is None:
        return t
    if EXT_FIELD not in t:
        raise RequestError(
            "bad_request",
            f"targets[{k}] needs '{EXT_FIELD}': the robot rides {ext.shape[1]} external axis(es) (E1.., mm)",
        )
    ext[k] = _vector(t[EXT_FIELD], ext.shape[1], f"targets[{k}].{EXT_FIELD}")
    return {key: v for key, v in t.items() if key != EXT_FIELD}


def _parse_logged(raw: Any, k: int, m: int, logged: dict[str, np.ndarray]) -> None:
    """``targets[k].signals``: ``{column: value}`` of the logged signals, into ``logged`` (column -> (m,))."""
    if not isinstance(raw, dict):
        raise RequestError("bad_request", f"targets[{k}].{LOGGED_FIELD} must be an object {{column: value}}")
    for name, v in raw.items():
        logged.setdefault(str(name), np.full(m, np.nan))[k] = _number(v, f"targets[{k}].{LOGGED_FIELD}.{name}")


def _parse_target(t: dict[str, Any], k: int, n: int, q: np.ndarray, xyz: np.ndarray, quat: np.ndarray) -> int:
    """Target ``k`` into row ``k`` of ``q`` / ``xyz`` / ``quat``; its kind (0 joints, 1 pose)."""
    if "q_deg" in t:
        extra = set(t) - {"q_deg", LOGGED_FIELD, *TARGET_SIGNALS}
        q[k] = _vector(t["q_deg"], n, f"targets[{k}].q_deg")
        kind = 0
    elif "xyz_mm" in t:
        extra = set(t) - {"xyz_mm", "quat_wxyz", "q_seed_deg", LOGGED_FIELD, *TARGET_SIGNALS}
        kind = 1
        xyz[k] = _vector(t["xyz_mm"], 3, f"targets[{k}].xyz_mm")
        if "quat_wxyz" in t:  # without: a position-only target (parse_targets says whether the mode allows it)
            qu = _vector(t["quat_wxyz"], 4, f"targets[{k}].quat_wxyz")
            norm = float(np.linalg.norm(qu))
            if not 0.9 < norm < 1.1:
                raise RequestError("bad_request", f"targets[{k}].quat_wxyz must be a unit quaternion (norm {norm:.3g})")
            quat[k] = qu / norm
        q[k] = _vector(t.get("q_seed_deg"), n, f"targets[{k}].q_seed_deg")
    else:
        raise RequestError("bad_request", f"targets[{k}] needs 'q_deg' (joint target) or 'xyz_mm' (pose target)")
    if extra:
        raise RequestError("bad_request", f"targets[{k}] has unknown field(s) {sorted(extra)}")
    return kind


def parse_temperatures(raw: Any, sensors: tuple[str, ...]) -> np.ndarray:
    """``temperatures``: ``{sensor: degC}`` naming every sensor of the thermal model, or a list in its order."""
    if isinstance(raw, dict):
        missing = [s for s in sensors if s not in raw]
        if missing:
            raise RequestError(
                "bad_request", f"'temperatures' lacks sensor(s) {missing}; the model needs {list(sensors)}"
            )
        unknown = sorted(set(raw) - set(sensors))
        if unknown:
            raise RequestError("bad_request", f"'temperatures' has unknown sensor(s) {unknown}; known {list(sensors)}")
        return np.array([_number(raw[s], f"temperatures.{s}") for s in sensors])
    if isinstance(raw, list):
        return _vector(raw, len(sensors), "temperatures")
    raise RequestError("bad_request", f"'temperatures' must map the sensors {list(sensors)} to degC")


#: the fields a ``correct`` request may carry
CORRECT_FIELDS = ("op", "id", "token", "targets", "temperatures", "payload_kg", "tool", "mode", "move_external")


@dataclass(frozen=True)
class CorrectRequest:
    """A checked ``correct`` request: the targets, the mode (``pose`` / ``position``), the tool, the payload, the
    temperatures (None without a thermal model) and the reasons that apply to every target."""

    targets: Targets
    mode: str
    tool_name: str
    tool_T: np.ndarray
    payload_kg: float
    temps: np.ndarray | None
    reasons: list[str]
    move_external: bool = False
    notes: dict[int, list[str]] = field(default_factory=dict)  # per target: served with them (flagged)


def _parse_request(req: dict[str, Any], bundle: Bundle, cfg: ServiceConfig) -> CorrectRequest:
    """The request's fields, checked against the bundle (each bad field is a ``bad_request`` naming it)."""
    unknown = sorted(set(req) - set(CORRECT_FIELDS))
    if unknown:
        raise RequestError("bad_request", f"unknown field(s) {unknown}; known: {sorted(CORRECT_FIELDS)}")
    mode = req.get("mode", "pose")
    if mode not in ("pose", "position"):
        raise RequestError("bad_request", f"'mode' must be 'pose' or 'position', got {mode!r}")
    n_ext = len(bundle.external)
    move = req.get("move_external", cfg.move_external)
    if not isinstance(move, bool):
        raise RequestError("bad_request", f"'move_external' must be true or false, got {move!r}")
    if "move_external" in req and not n_ext:
        raise RequestError("bad_request", f"'move_external': robot {bundle.robot.name!r} has no external axis")
    tg = parse_targets(req.get("targets"), bundle.robot.n_joints - n_ext, cfg.max_targets, mode == "position", n_ext)
    tool_name = req.get("tool", bundle.default_tool)
    if not isinstance(tool_name, str) or tool_name not in bundle.tools:
        raise RequestError("bad_request", f"unknown 'tool' {tool_name!r}; the bundle has {list(bundle.tools)}")
    payload = _number(req.get("payload_kg", 0.0), "payload_kg")
    if payload < 0:
        raise RequestError("bad_request", "'payload_kg' must be >= 0")
    reasons: list[str] = []  # request-level reasons (apply to every target)
    notes: dict[int, list[str]] = {}
    if tg.logged:
        known = bundle.signal_ranges()
        unknown = sorted(set(tg.logged) - set(known))
        if unknown:  # a misspelt column was ignored and its effect went without its value
            raise RequestError(
                "bad_request",
                f"targets[].{LOGGED_FIELD} names {unknown}, which no effect of the bundle follows; it follows "
                f"{sorted(known) or 'none'}",
            )
        notes = bundle.signal_reasons(tg.logged)
    temps = None
    if bundle.thermal is not None:
        if "temperatures" not in req:
            raise RequestError(
                "bad_request",
                f"'temperatures' is required: the bundle has a thermal model of {list(bundle.sensors)}",
            )
        temps = parse_temperatures(req["temperatures"], bundle.sensors)
        reasons.extend(bundle.temperature_reasons(temps, cfg.safety.temperature_margin_C))
    elif "temperatures" in req and not isinstance(req["temperatures"], dict | list):
        raise RequestError("bad_request", "'temperatures' must be an object or a list")
    return CorrectRequest(tg, mode, tool_name, bundle.tools[tool_name], payload, temps, reasons, move, notes)
