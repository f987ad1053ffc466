"""A blocking client of the compensation service (protocol: :mod:`robocal.serve.server`)."""

from __future__ import annotations

import json
import socket
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from robocal.errors import RobocalError


class ServiceError(RobocalError, RuntimeError):
    """The service replied with an error; ``code`` is the protocol's error code."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code = code


class Client:
    """One TCP connection; requests are sent and answered one at a time.

    >>> with Client("127.0.0.1", 7878) as c:          # doctest: +SKIP
    ...     r = c.correct([[0, -90, 90, 0, 30, 0]], temperatures={"T_j1_C": 24.0, ...})
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 7878, token: str | None = None, timeout: float = 30.0):
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._buf = self.sock.makefile("rb")
        self._next = 0
        if token is not None:
            self.request({"op": "auth", "token": token})

    def close(self) -> None:
        self._buf.close()
        self.sock.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def send_raw(self, line: bytes) -> dict[str, Any]:
        """Send one raw line (``\\n`` appended if missing); return the parsed reply (errors not raised)."""
        self.sock.sendall(line if line.endswith(b"\n") else line + b"\n")
        reply = self._buf.readline()
        if not reply:
            raise ConnectionError("the service closed the connection")
        return json.loads(reply)

    def request(self, req: Mapping[str, Any], check: bool = True) -> dict[str, Any]:
        self._next += 1
        body = {"id": self._next, **req}
        reply = self.send_raw(json.dumps(body, separators=(",", ":")).encode())
        if check and not reply.get("ok"):
            err = reply.get("error") or {}
            raise ServiceError(str(err.get("code")), str(err.get("message")))
        return reply

    def ping(self) -> dict[str, Any]:
        return self.request({"op": "ping"})

    def info(self) -> dict[str, Any]:
        return self.request({"op": "info"})

    def reload(self, bundle: str | None = None) -> dict[str, Any]:
        return self.request({"op": "reload", "bundle": bundle})

    def correct(
        self,
        q_deg: np.ndarray | Sequence[Sequence[float]] | None = None,
        temperatures: Mapping[str, float] | Sequence[float] | None = None,
        payload_kg: float | None = None,
        tool: str | None = None,
        mode: str = "pose",
        targets: list[dict[str, Any]] | None = None,
        current_A: np.ndarray | None = None,
    ) -> dict[str, Any]:
        """Corrections for joint targets ``q_deg`` (m, n) (or explicit ``targets`` objects)."""
        if targets is None:
            q = np.atleast_2d(np.asarray(q_deg, dtype=float))
            targets = [{"q_deg": row.tolist()} for row in q]
            if current_A is not None:
                for t, c in zip(targets, np.atleast_2d(current_A), strict=True):
                    t["current_A"] = np.asarray(c, dtype=float).tolist()
        req: dict[str, Any] = {"op": "correct", "targets": targets, "mode": mode}
        if temperatures is not None:
            req["temperatures"] = dict(temperatures) if isinstance(temperatures, Mapping) else list(temperatures)
        if payload_kg is not None:
            req["payload_kg"] = float(payload_kg)
        if tool is not None:
            req["tool"] = tool
        return self.request(req)
