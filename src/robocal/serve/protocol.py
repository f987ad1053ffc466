"""Request parsing, safety checks and answers of the compensation service (transport-free).

The wire protocol (one JSON object per line, UTF-8, ``\\n``-terminated; one reply line per request line,
in order) is documented in :mod:`robocal.serve.server`. :class:`Service` turns one request line into one
reply line; it never raises: malformed input gets an error reply with one of :data:`ERROR_CODES`.
"""

from __future__ import annotations

import hmac
import json
import math
import sys
import threading
import time
import traceback
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from robocal.compensation.correct import SolverConfig, correct_targets, zero_offsets
from robocal.compensation.discovered import frame_transforms
from robocal.compensation.effects import LOGGED, Signals, compose, needs
from robocal.compensation.safety import POLICIES, SafetyPolicy
from robocal.config import parse, setting
from robocal.errors import ConfigError
from robocal.kinematics.chain import fk
from robocal.kinematics.ik import CompiledChain, compile_chain, forward, quaternions, solve
from robocal.kinematics.transforms import quat_to_matrix
from robocal.serve.bundle import Bundle

#: every error code a reply can carry
ERROR_CODES = ("parse_error", "bad_request", "unauthorized", "too_large", "unknown_op", "unavailable", "internal")
OPS = ("correct", "info", "ping", "auth", "reload", "stats")
__all__ = ["ERROR_CODES", "OPS", "POLICIES", "SafetyConfig", "Service", "ServiceConfig", "SolverConfig"]


class RequestError(Exception):
    """A request that cannot be answered; ``code`` is one of :data:`ERROR_CODES`."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


#: the service's safety settings are the one safety policy (:class:`robocal.compensation.safety.SafetyPolicy`)
SafetyConfig = SafetyPolicy


@dataclass(frozen=True)
class ServiceConfig:
    """Service settings; :meth:`from_mapping` checks names and values. The shared ``token`` is no setting (never
    in a config file): it comes from the environment or a token file, as the ``token`` argument."""

    max_targets: int = setting(100_000, ge=1)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    #: a robot on external axes (a track, a column): whether a correction may move them (a request's
    #: ``move_external`` overrides it); by default only the arm is corrected
    move_external: bool = False
    token: str | None = setting(None, settable=False)

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any] | None, token: str | None = None) -> ServiceConfig:
        return replace(parse(cls, cfg, "serve"), token=token)


#: the keys of the ``serve`` section that are the service's (the rest are the transport's: ServerConfig)
SERVICE_KEYS = ("max_targets", "safety", "solver", "move_external")

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


# --------------------------------------------------------------------------------------------- service


class Service:
    """Answers request lines against the current bundle; swapping :attr:`bundle` is atomic."""

    def __init__(self, bundle: Bundle, config: ServiceConfig | None = None) -> None:
        self.bundle = bundle
        self.config = config or ServiceConfig()
        self.reloader: Any = None  # callable(path | None) -> Bundle, set by the server
        self.counters = {"requests": 0, "errors": 0, "targets": 0, "refused": 0, "flagged": 0, "internal": 0}
        self._cache: OrderedDict[tuple[str, bytes], tuple[CompiledChain, np.ndarray]] = OrderedDict()
        self._lock = threading.Lock()

    # -- transport entry point
    def handle_line(self, line: bytes, session: dict[str, Any] | None = None) -> bytes:
        """One reply line (``\\n``-terminated) for one request line. Never raises."""
        session = session if session is not None else {}
        rid: Any = None
        self.counters["requests"] += 1
        try:
            req = _loads(line)
            rid = req.get("id")
            if (rid is not None and not isinstance(rid, str | int)) or isinstance(rid, bool):
                rid = None
                raise RequestError("bad_request", "'id' must be a string or an integer")
            reply = self.handle(req, session)
            reply["id"] = rid
        except RequestError as exc:
            self.counters["errors"] += 1
            reply = {"id": rid, "ok": False, "error": {"code": exc.code, "message": exc.message}}
        except Exception as exc:  # never take the server down; the traceback goes to the log
            self.counters["internal"] += 1
            traceback.print_exc(file=sys.stderr)
            reply = {"id": rid, "ok": False, "error": {"code": "internal", "message": f"{type(exc).__name__}: {exc}"}}
        return (json.dumps(reply, separators=(",", ":"), allow_nan=False) + "\n").encode()

    def handle(self, req: dict[str, Any], session: dict[str, Any]) -> dict[str, Any]:
        op = req.get("op", "correct")
        if not isinstance(op, str) or op not in OPS:
            raise RequestError("unknown_op", f"unknown op {op!r}; known: {list(OPS)}")
        token = self.config.token
        if token is not None and not session.get("authed"):
            given = req.get("token")
            if not isinstance(given, str) or not hmac.compare_digest(given.encode(), token.encode()):
                raise RequestError("unauthorized", "a valid 'token' is required (send it once with op 'auth')")
            session["authed"] = True
        if op == "ping":
            return {"ok": True, "op": "ping", "bundle": self.bundle.bundle_id}
        if op == "auth":
            return {"ok": True, "op": "auth"}
        if op == "info":
            return {"ok": True, "op": "info", **self.bundle.info()}
        if op == "stats":
            return {"ok": True, "op": "stats", **self.counters}
        if op == "reload":
            if self.reloader is None:
                raise RequestError("unavailable", "this server cannot reload")
            path = req.get("bundle")
            if path is not None and not isinstance(path, str):
                raise RequestError("bad_request", "'bundle' must be a directory path")
            try:
                b = self.reloader(path)
            except ConfigError as exc:
                raise RequestError(
                    "bad_request", f"reload failed, still serving {self.bundle.bundle_id}: {exc}"
                ) from None
            return {"ok": True, "op": "reload", "bundle": b.bundle_id}
        return self.correct(req)

    # -- the correction
    def _compiled(self, bundle: Bundle, temps: np.ndarray | None, nominal: bool = False) -> CompiledChain:
        """The compiled chain: the controller's nominal one (``nominal``), or the calibrated robot, plus the
        thermal drift at ``temps`` when the bundle has a thermal model. Cached: the cell's temperatures change
        slowly.

        A bundle without a thermal model is served with its calibrated errors (``eta0``); ``temps`` is then
        None. (Before 2026-11 a missing ``temps`` meant "nominal", so a geometry-only bundle corrected nothing.)
        """
        return self._compiled_and_offsets(bundle, temps, nominal)[0]

    def _compiled_and_offsets(
        self, bundle: Bundle, temps: np.ndarray | None, nominal: bool = False
    ) -> tuple[CompiledChain, np.ndarray]:
        """:meth:`_compiled` and the joint zero offsets ``(n,)`` rad of the same parameters (cached with it)."""
        if nominal:
            key = (bundle.bundle_id, b"nominal")
        else:
            key = (bundle.bundle_id, b"calibrated" if temps is None else b"T" + temps.tobytes())
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        eta = np.zeros_like(bundle.eta0) if nominal else bundle.eta_at(temps)
        entry = (compile_chain(bundle.chain, eta), zero_offsets(bundle.chain, eta))
        with self._lock:
            self._cache[key] = entry
            while len(self._cache) > 16:
                self._cache.popitem(last=False)
        return entry

    def correct(self, req: dict[str, Any]) -> dict[str, Any]:
        """The ``correct`` op: see :mod:`robocal.serve.server` for the schema."""
        t_start = time.perf_counter()
        bundle = self.bundle  # one bundle for the whole request, even if a reload swaps it meanwhile
        cfg = self.config
        r = _parse_request(req, bundle, cfg)
        if bundle.external:  # a robot on external axes: robocal.compensation.axes
            return self._reply(bundle, r, *_correct_external(bundle, r, cfg), t_start)
        m = len(r.targets.kind)
        cc, zero_off = self._compiled_and_offsets(bundle, r.temps)
        cc_nom = self._compiled(bundle, None, nominal=True)
        offsets = _joint_offsets(bundle, r.targets, r.payload_kg)
        # the base or the tool moving with a logged signal (its value given with each target; checked above)
        frames = frame_transforms(list(bundle.effects), r.targets.logged, m)
        q_target, ik_ok, freed = _nominal_joints(cc_nom, r.tool_T, r.targets, cfg.solver, r.mode == "position")
        c = correct_targets(
            cc, cc_nom, r.tool_T, r.tool_T, q_target, zero_off, offsets, bundle.robot.q_limits,
            bundle.robot.joint_names, orientation=r.mode == "pose", solver=cfg.solver, policy=cfg.safety,
            request_reasons=r.reasons, unreachable=~ik_ok, frames=frames,
        )  # fmt: skip
        results = _target_replies(c, cc_nom, r.tool_T, q_target, r.targets.kind)
        for k in np.flatnonzero(freed):
            results[k].setdefault("notes", []).append(FREED_NOTE)
        return self._reply(bundle, r, results, {}, t_start)

    def _reply(
        self, bundle: Bundle, r: CorrectRequest, results: list[dict[str, Any]], extra: dict[str, Any], t_start: float
    ) -> dict[str, Any]:
        """The ``correct`` reply of the targets' ``results`` (the counters updated); ``extra`` request-level keys."""
        m = len(results)
        n_ref = sum(res["status"] == "refused" for res in results)
        n_flag = sum(res["status"] != "refused" and "reasons" in res for res in results)
        self.counters["targets"] += m
        self.counters["refused"] += n_ref
        self.counters["flagged"] += n_flag
        out: dict[str, Any] = {
            "ok": True,
            "op": "correct",
            "bundle": bundle.bundle_id,
            "tool": r.tool_name,
            "mode": r.mode,
            "n": m,
            "n_refused": n_ref,
            "n_flagged": n_flag,
            **extra,
            "results": results,
        }
        if r.temps is not None:
            out["temperatures_C"] = r.temps.tolist()
        out["elapsed_ms"] = round((time.perf_counter() - t_start) * 1e3, 4)
        return out


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
    return CorrectRequest(tg, mode, tool_name, bundle.tools[tool_name], payload, temps, reasons, move)


def _joint_offsets(bundle: Bundle, tg: Targets, payload_kg: float) -> Any:
    """The bundle's joint-space effects at the targets' signals (None without effects); an effect needing a
    signal the request does not give is a ``bad_request``."""
    effects = bundle.joint_effects()
    if not effects:
        return None
    sig = Signals(np.full(len(tg.kind), payload_kg), tg.tau_Nm, tg.current_A, tg.direction, tg.logged)
    missing = sorted(needs(effects) - sig.given())
    if missing:
        shown = [f"{LOGGED_FIELD}.{k[len(LOGGED):]}" if k.startswith(LOGGED) else ("dir" if k == "direction" else k)
                 for k in missing]  # fmt: skip
        raise RequestError(
            "bad_request",
            f"the bundle's discovered effects {[e['key'] for e in bundle.effects]} need {shown} with every target"
            + (" (the logged signals' values at the moment, as in the campaign's columns)"
               if any(k.startswith(LOGGED) for k in missing) else ""),
        )  # fmt: skip
    return compose(effects, sig)


#: the note of a pose target in mode ``position`` whose stated orientation the nominal robot does not reach there
FREED_NOTE = (
    "quat_wxyz is not reached at this position from q_seed_deg: solved for the position only (mode 'position'), "
    "the orientation left free (the joints nearest the seed)"
)


def _nominal_joints(
    cc_nom: CompiledChain, tool_T: np.ndarray, tg: Targets, solver: SolverConfig, position: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The joints (m, n) rad the nominal controller uses: a joint target as given, a pose target through the
    nominal inverse kinematics from its seed; whether each was reached; and which targets stated an orientation
    that was given up (see below).

    ``position`` (mode ``position``): a target without ``quat_wxyz``, or whose orientation the nominal robot
    does not reach at its position from the seed, is solved for the position only from its seed (the Newton
    steps are least-norm, so the joints, and the orientation with them, stay nearest the seed); the orientation
    is free in this mode, so it never makes a target unreachable. The last array marks the targets whose stated
    orientation was given up that way."""
    seed = np.deg2rad(tg.q_deg)
    q_target = seed.copy()
    m = len(tg.kind)
    ik_ok = np.ones(m, dtype=bool)
    oriented = np.ones(m, dtype=bool) if tg.oriented is None else tg.oriented
    pose = tg.kind == 1
    rows = np.flatnonzero(pose & oriented)
    if len(rows):
        R_p = quat_to_matrix(tg.quat[rows])
        ik = solve(cc_nom, tool_T, seed[rows], tg.xyz_mm[rows], R_p, None, **solver.kwargs())
        q_target[rows] = ik.q
        ik_ok[rows] = ik.converged
    freed = np.zeros(m, dtype=bool)
    if position:
        free = np.flatnonzero(pose & ~(oriented & ik_ok))
        if len(free):
            ik = solve(cc_nom, tool_T, seed[free], tg.xyz_mm[free], None, None, **solver.kwargs())
            q_target[free] = ik.q
            ik_ok[free] = ik.converged
            freed[free] = oriented[free] & ik.converged
    return q_target, ik_ok, freed


def _target_replies(
    c: Any, cc_nom: CompiledChain, tool_T: np.ndarray, q_target: np.ndarray, kind: np.ndarray
) -> list[dict[str, Any]]:
    """One reply object per target: status, predicted error, reasons and notes; the corrected joints and the
    command for the nominal controller unless refused; the nominal joints of a pose target."""
    cmd_p, cmd_R, _, _ = forward(cc_nom, c.q, tool_T)  # what the nominal controller must be sent
    # rounded once for the whole batch (the wire's digits)
    eb_r = np.round(c.error_before_norm_mm, 7).tolist()
    ebx_r = np.round(c.error_before_mm, 7).tolist()
    ebd_r = np.round(np.rad2deg(np.linalg.norm(c.error_before_rad, axis=1)), 9).tolist()
    qc_l = np.rad2deg(c.q).round(9).tolist()
    dq_l = c.correction_deg.round(9).tolist()
    cmd_p_l = cmd_p.round(7).tolist()
    cmd_q_l = quaternions(cmd_R).round(12).tolist()
    resid_l = c.residual_norm_mm.tolist()
    resid_deg_l = c.residual_norm_deg.tolist()
    qt_l = np.rad2deg(q_target).round(9).tolist()
    results = []
    for k in range(len(q_target)):
        reasons = c.reasons[k]
        r: dict[str, Any] = {
            "status": c.status[k],
            "predicted_error_mm": eb_r[k],
            "predicted_error_xyz_mm": ebx_r[k],
            "predicted_error_deg": ebd_r[k],
        }
        if reasons:
            r["reasons"] = reasons
        if c.notes[k]:  # where an effect does not apply (robocal.compensation.effects.JointOffsets.notes)
            r["notes"] = c.notes[k]
        if c.status[k] != "refused":
            r["q_deg"] = qc_l[k]
            r["correction_deg"] = dq_l[k]
            r["command"] = {"xyz_mm": cmd_p_l[k], "quat_wxyz": cmd_q_l[k]}
            r["residual_mm"] = resid_l[k]
            r["residual_deg"] = resid_deg_l[k]
        if kind[k] == 1:
            r["q_nominal_deg"] = qt_l[k]
        results.append(r)
    return results


def _correct_external(
    bundle: Bundle, r: CorrectRequest, cfg: ServiceConfig
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The ``correct`` op for a robot on external axes (issue 34): the replies and the request-level keys.

    The joints the nominal controller uses: a joint target's arm joints and external axes as given; a pose target
    (in the robot base frame, the external axes at their stated ``ext_mm``) through the nominal inverse
    kinematics of the arm with its external axes held there (:func:`robocal.kinematics.axes.arm_chain`, the
    service's compiled solver). The correction: :func:`robocal.compensation.axes.compensate_axes` (the calibrated
    geometry and the axes' own errors along the travel, numpy), the external axes moved only with
    ``move_external``. The one safety policy judges the arm's joints as for any robot (the correction beyond the
    calibration's own zero offsets, the predicted error, the residual, the joint limits); an external axis outside
    its limits (mm) is a joint-limit reason too."""
    from robocal.compensation.axes import compensate_axes
    from robocal.kinematics.axes import arm_chain

    tg = r.targets
    assert tg.ext_mm is not None
    m = len(tg.kind)
    arm, ext = bundle.arm, bundle.external
    robot = bundle.robot
    q_arm = np.deg2rad(tg.q_deg)
    ik_ok = np.ones(m, dtype=bool)
    freed = np.zeros(m, dtype=bool)
    pose = np.flatnonzero(tg.kind == 1)
    if len(pose):  # the nominal inverse kinematics, grouped by the external axes' values
        keys = [tg.ext_mm[k].tobytes() for k in pose]
        for key in dict.fromkeys(keys):
            rows = pose[[i for i, kk in enumerate(keys) if kk == key]]
            cc = compile_chain(arm_chain(bundle.chain, ext, tg.ext_mm[rows[0]]))
            q_r, ok_r, fr_r = _nominal_joints(cc, r.tool_T, tg.subset(rows), cfg.solver, r.mode == "position")
            q_arm[rows], ik_ok[rows], freed[rows] = q_r, ok_r, fr_r
    q_target = np.zeros((m, robot.n_joints))
    q_target[:, arm], q_target[:, ext] = q_arm, tg.ext_mm
    c = compensate_axes(
        bundle.calibration, q_target, r.tool_name, bundle.axis_fit, r.move_external, r.payload_kg,
        max_iter=max(cfg.solver.max_iter, 30), tol_mm=cfg.solver.tol_mm, orientation=r.mode == "pose",
    )  # fmt: skip
    assert c.zero_offsets is not None and c.own_error_mm is not None and c.error_before_xyz_mm is not None
    sf = cfg.safety
    dq = c.q[:, arm] - q_target[:, arm]
    excess = np.rad2deg(np.abs(dq).max(axis=1))
    beyond = np.rad2deg(np.abs(dq + c.zero_offsets[arm]).max(axis=1))  # past the calibration's own zero offsets
    excess = np.where(excess > sf.max_correction_deg, np.minimum(excess, beyond), excess)
    rest = np.where(c.error_before_mm > sf.max_error_mm, np.minimum(c.error_before_mm, c.own_error_mm),
                    c.error_before_mm)  # fmt: skip
    status, reasons = sf.judge(
        c.converged, c.residual_mm, c.residual_deg, excess, rest, q_target[:, arm], c.q[:, arm],
        robot.q_limits[arm], [robot.joint_names[j] for j in arm], r.reasons, ~ik_ok,
    )  # fmt: skip
    lim = robot.q_limits[ext]
    for k in range(m):
        lo = np.minimum(q_target[k, ext], c.q[k, ext]) < lim[:, 0]
        hi = np.maximum(q_target[k, ext], c.q[k, ext]) > lim[:, 1]
        if (lo | hi).any():
            reasons[k] = [*reasons[k], "outside the external axis limits: " + ", ".join(
                f"{robot.joint_names[j]}={q_target[k, j]:.4f} mm (corrected {c.q[k, j]:.4f})"
                for i, j in enumerate(ext) if lo[i] or hi[i])]  # fmt: skip
            refuse = sf.on_joint_limits == "refuse" or status[k] == "refused"
            status[k] = "refused" if refuse else "flagged"
    # the command for the nominal controller: the nominal pose of the corrected joints (base frame)
    T = fk(bundle.chain, c.q) @ r.tool_T
    quat = quaternions(T[:, :3, :3])
    results = []
    for k in range(m):
        res: dict[str, Any] = {
            "status": status[k],
            "predicted_error_mm": round(float(c.error_before_mm[k]), 7),
            "predicted_error_xyz_mm": np.round(c.error_before_xyz_mm[k], 7).tolist(),
            "predicted_error_deg": round(float(c.error_before_deg[k]), 9) if c.error_before_deg is not None else 0.0,
        }
        if reasons[k]:
            res["reasons"] = reasons[k]
        if freed[k]:
            res["notes"] = [FREED_NOTE]
        if status[k] != "refused":
            res["q_deg"] = np.rad2deg(c.q[k, arm]).round(9).tolist()
            res["ext_mm"] = c.q[k, ext].tolist()  # unrounded: a track not moved comes back exactly as sent
            res["correction_deg"] = np.rad2deg(dq[k]).round(9).tolist()
            res["ext_correction_mm"] = (c.q[k, ext] - q_target[k, ext]).tolist()
            res["command"] = {"xyz_mm": T[k, :3, 3].round(7).tolist(), "quat_wxyz": quat[k].round(12).tolist()}
            res["residual_mm"] = float(c.residual_mm[k])
            res["residual_deg"] = float(c.residual_deg[k])
        if tg.kind[k] == 1:
            res["q_nominal_deg"] = np.rad2deg(q_arm[k]).round(9).tolist()
        results.append(res)
    return results, {"move_external": r.move_external, "external_axes": [robot.joint_names[j] for j in ext]}
