"""Request parsing, safety checks and answers of the compensation service (transport-free).

The wire protocol (one JSON object per line, UTF-8, ``\\n``-terminated; one reply line per request line,
in order) is documented in :mod:`robocal.serve.server`. :class:`Service` turns one request line into one
reply line; it never raises: malformed input gets an error reply with one of :data:`ERROR_CODES`.

The settings are :mod:`robocal.serve.settings`, the parsing of a request :mod:`robocal.serve.parsing`, the
``correct`` op's answers :mod:`robocal.serve.correction` (issue 32); their names are importable from here as before.
"""

from __future__ import annotations

import hmac
import json
import sys
import threading
import time
import traceback
from collections import OrderedDict
from typing import Any

import numpy as np

from robocal.compensation.correct import SolverConfig, correct_targets, zero_offsets
from robocal.compensation.discovered import frame_transforms
from robocal.compensation.safety import POLICIES
from robocal.errors import ConfigError
from robocal.kinematics.ik import CompiledChain, compile_chain
from robocal.serve.bundle import Bundle
from robocal.serve.correction import FREED_NOTE, _correct_external, _joint_offsets, _nominal_joints, _target_replies
from robocal.serve.parsing import (
    CORRECT_FIELDS,
    EXT_FIELD,
    LOGGED_FIELD,
    TARGET_SIGNALS,
    CorrectRequest,
    RequestError,
    Targets,
    _loads,
    _parse_request,
    parse_targets,
    parse_temperatures,
)
from robocal.serve.settings import SERVICE_KEYS, SafetyConfig, ServiceConfig

#: every error code a reply can carry
ERROR_CODES = ("parse_error", "bad_request", "unauthorized", "too_large", "unknown_op", "unavailable", "internal")
OPS = ("correct", "info", "ping", "auth", "reload", "stats")


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
        # a coupled robot (FANUC's J3 relative to J2): the controller's joints in and out, judged by its limits
        rob = bundle.robot
        to_kin, to_rep = (None, None) if rob.coupling is None else (rob.to_kinematic, rob.to_reported)
        q_target, ik_ok, freed = _nominal_joints(
            cc_nom, r.tool_T, r.targets, cfg.solver, r.mode == "position", to_kinematic=to_kin
        )
        c = correct_targets(
            cc, cc_nom, r.tool_T, r.tool_T, q_target, zero_off, offsets, rob.q_limits, rob.joint_names,
            orientation=r.mode == "pose", solver=cfg.solver, policy=cfg.safety, request_reasons=r.reasons,
            unreachable=~ik_ok, frames=frames, to_reported=to_rep,
        )  # fmt: skip
        results = _target_replies(c, cc_nom, r.tool_T, q_target, r.targets.kind, to_reported=to_rep,
                                  orientation=r.mode == "pose")  # fmt: skip
        for k in np.flatnonzero(freed):
            results[k].setdefault("notes", []).append(FREED_NOTE)
        return self._reply(bundle, r, results, {}, t_start)

    def _reply(
        self, bundle: Bundle, r: CorrectRequest, results: list[dict[str, Any]], extra: dict[str, Any], t_start: float
    ) -> dict[str, Any]:
        """The ``correct`` reply of the targets' ``results`` (the counters updated); ``extra`` request-level keys.
        A target's own notes (a logged signal past the values its effects were fitted on) are added to its reasons,
        an ``ok`` one then ``flagged``."""
        for k, notes in r.notes.items():
            res = results[k]
            res["reasons"] = [*res.get("reasons", []), *notes]
            if res["status"] == "ok":
                res["status"] = "flagged"
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


# the service's names, and (issue 32) the names that moved to robocal.serve.settings, .parsing and .correction
__all__ = [
    "CORRECT_FIELDS",
    "ERROR_CODES",
    "EXT_FIELD",
    "FREED_NOTE",
    "LOGGED_FIELD",
    "OPS",
    "POLICIES",
    "SERVICE_KEYS",
    "TARGET_SIGNALS",
    "CorrectRequest",
    "RequestError",
    "SafetyConfig",
    "Service",
    "ServiceConfig",
    "SolverConfig",
    "Targets",
    "parse_targets",
    "parse_temperatures",
]
