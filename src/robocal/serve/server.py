"""``robocal serve``: the online compensation service (TCP, line-delimited JSON).

Transport
---------
Plain TCP, one JSON object per line (UTF-8, terminated by ``\\n``), one reply line per request line, in
order; a connection may carry any number of requests. The server binds ``127.0.0.1`` by default. When a
shared token is configured (``$ROBOCAL_SERVE_TOKEN`` or ``--token-file``; required to bind any other
interface), each connection must authenticate once: send ``{"op": "auth", "token": "..."}`` or put
``"token"`` in its first request. A line longer than ``max_request_bytes`` gets a ``too_large`` error and
the connection is closed; a connection that sends no complete line for ``read_timeout_s`` gets a
``timeout`` error and is closed; a client that does not read its replies for ``write_timeout_s`` is
dropped. Nothing a client sends stops the server.

Requests
--------
Every request may carry ``"id"`` (string or integer, echoed in the reply) and ``"op"`` (default
``"correct"``)::

    {"op": "ping"}                              -> {"ok": true, "op": "ping", "bundle": "<id>"}
    {"op": "info"}                              -> robot, joints, q_limits_deg, tools, sensors,
                                                   temperature_range_C, thermal, compliance, bundle
    {"op": "auth", "token": "..."}              -> {"ok": true, "op": "auth"}
    {"op": "stats"}                             -> request / error / target / refused counters
    {"op": "reload", "bundle": "/path" | null}  -> load (the same or another) bundle and swap it in
                                                   atomically; on failure the old one keeps serving

    {"op": "correct",
     "temperatures": {"T_j1_C": 25.3, ...},     # every sensor of the thermal model (or a list in
                                                #   the order of info.sensors); required with a thermal model
     "payload_kg": 5.0,                         # optional, default 0 (compliance model)
     "tool": "T1",                              # optional, default the bundle's first tool
     "mode": "pose" | "position",               # match the full tool pose (default) or the position only
     "targets": [                               # 1 .. max_targets targets, answered together
        {"q_deg": [q1, ..., qn]},               # joint target (what the nominal controller would use)
        {"xyz_mm": [x, y, z], "quat_wxyz": [w, x, y, z], "q_seed_deg": [...]},
                                                # tool pose in the robot base frame + IK seed; in mode
                                                #   "position" quat_wxyz may be left out (a 3-DoF reflector,
                                                #   a drilling point with a free tool roll) and an orientation
                                                #   the robot cannot take there is given up (a note says so):
                                                #   the nominal joints are the position-only IK's from the seed
        ...],                                   # each may add "current_A": [n] or "tau_Nm": [n], and
                                                # "dir": [n] of -1/+1 (approach direction; needed when the
                                                # bundle's calibration holds a discovered backlash), and
                                                # "signals": {"incl_x": 0.012} (the logged signals a discovered
                                                # effect follows: the base, the tool or a joint moving with them)
    }

A bundle whose calibration was written by ``robocal discover`` applies its joint-level effects (gear,
backlash, compliance) like the compliance model's deflection; ``info`` lists them under ``effects``.

A robot on external axes (prismatic joints: a track, a column; ``info`` lists them under ``external_axes`` with
their limits in mm, ``joints`` then the arm's): every target carries ``"ext_mm": [E1, ...]`` (mm, chain order)
beside the arm's ``q_deg`` / ``q_seed_deg``, and a request may set ``"move_external": true | false`` (default the
``serve.move_external`` setting, false: the correction moves the arm only). A pose target's nominal joints are the
arm's inverse kinematics with the axes at ``ext_mm``; the correction is :mod:`robocal.compensation.axes` (the
calibrated geometry and the axes' own errors along the travel, the calibration's ``axes``; numpy: 0.7-1.0 ms per
target against the revolute path's compiled 0.1 ms, ``benchmarks/external_axes_service.py``), judged by the same
policy on the arm's joints; an axis outside its limits is a joint-limit reason. Replies add ``"ext_mm"`` and
``"ext_correction_mm"`` per target (an axis not moved comes back exactly as sent) and ``"move_external"`` /
``"external_axes"`` per request. The discovered effects apply on that path too (the joints' deflection, a base or
tool a logged signal moves, with each target's ``signals``); a thermal or compliance model in such a bundle is
refused when it is loaded (that path does not apply it).

Reply to ``correct``::

    {"id": ..., "ok": true, "op": "correct", "bundle": "<id>", "tool": "T1", "mode": "pose",
     "n": m, "n_refused": k, "n_flagged": f, "temperatures_C": [...], "elapsed_ms": 0.41,
     "results": [
        {"status": "ok" | "flagged" | "refused",
         "reasons": ["..."],                    # only when flagged or refused
         "notes": ["..."],                      # only where the bundle's residual layer does not apply
                                                # (outside the calibrated region: parametric correction only)
                                                # or a stated orientation was given up (mode "position")
         "predicted_error_mm": 0.83,            # |tool position error| uncompensated, mm
         "predicted_error_xyz_mm": [dx, dy, dz],
         "predicted_error_deg": 0.004,          # uncompensated orientation error, deg (null in mode "position")
         # only when not refused:
         "q_deg": [...],                        # corrected joint targets
         "correction_deg": [...],               # q_deg - target joints
         "command": {"xyz_mm": [...], "quat_wxyz": [...]},  # corrected Cartesian command (base frame)
         "residual_mm": 1e-6, "residual_deg": 1e-8,         # predicted error after compensation (deg: null
                                                            # in mode "position", the orientation not matched)
         "q_nominal_deg": [...]}                # pose targets: the nominal IK solution
     ]}

A refused target never carries corrected values. Reasons (the one safety policy,
:mod:`robocal.compensation.safety`): correction beyond the calibration's own joint-space correction (its zero
offsets and joint-level effects) above ``max_correction_deg``, or predicted error after that own correction
above ``max_error_mm``; target or corrected joints outside the joint limits; temperature
outside the thermal model's fitted range; no convergence (singularity) or unreachable pose. Each of the first
three is refused or only flagged as configured (``safety.on_*``). A target whose logged signal lies past the values
its effects were fitted on is served, flagged with that reason (``"signals.incl_x = ... outside the values its
effects were fitted on [...]: extrapolated"``).

Errors::

    {"id": ... | null, "ok": false, "error": {"code": CODE, "message": "..."}}

with CODE one of ``parse_error`` (not UTF-8 / not JSON / not an object), ``bad_request`` (a field is missing
or wrong; the message names it), ``unauthorized``, ``too_large``, ``unknown_op``, ``unavailable``,
``internal`` (a bug: logged with its traceback; the server keeps serving) and ``timeout`` (sent before an
idle connection is closed).

Reloads: ``SIGHUP``, the ``reload`` op, or (``watch_interval_s`` > 0) a change of the bundle's manifest.
The new bundle is loaded and checked off the event loop, then swapped in with one assignment: requests
already running finish on the old bundle, connections stay open.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import os
import signal
import sys
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from robocal.config import parse, setting
from robocal.errors import ConfigError
from robocal.serve.bundle import MANIFEST, Bundle, load_bundle
from robocal.serve.protocol import Service
from robocal.serve.settings import SERVICE_KEYS, ServiceConfig

_TIMEOUT_REPLY = b'{"id":null,"ok":false,"error":{"code":"timeout","message":"no complete request line in time"}}\n'
_TOO_LARGE_REPLY = b'{"id":null,"ok":false,"error":{"code":"too_large","message":"request line too long"}}\n'
_BUSY_REPLY = b'{"id":null,"ok":false,"error":{"code":"unavailable","message":"too many connections"}}\n'


@dataclass(frozen=True)
class ServerConfig:
    host: str = "127.0.0.1"
    port: int = 7878
    read_timeout_s: float = setting(30.0, gt=0)
    write_timeout_s: float = setting(5.0, gt=0)
    max_request_bytes: int = 16 * 1024 * 1024
    max_connections: int = 64
    inline_max_targets: int = 64
    watch_interval_s: float = 0.0
    workers: int = 2

    @classmethod
    def from_mapping(cls, cfg: Any) -> ServerConfig:
        """The transport settings of the ``serve`` section; the service's own (:class:`ServiceConfig`) and
        ``token_env`` (read by the command) share the section."""
        return parse(cls, cfg, "serve", ignore=(*SERVICE_KEYS, "token_env"))


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class Server:
    """The asyncio server around a :class:`~robocal.serve.protocol.Service`."""

    def __init__(
        self,
        bundle_path: str | Path,
        config: ServerConfig | None = None,
        service_config: ServiceConfig | None = None,
        loader: Callable[[str | Path], Bundle] = load_bundle,
    ) -> None:
        self.config = config or ServerConfig()
        scfg = service_config or ServiceConfig()
        if not is_loopback(self.config.host) and not scfg.token:
            raise ConfigError(
                f"binding {self.config.host} (not loopback) requires a shared token "
                "($ROBOCAL_SERVE_TOKEN or --token-file)"
            )
        self.bundle_path = Path(bundle_path)
        self.loader = loader
        self.service = Service(loader(self.bundle_path), scfg)
        self.service.reloader = self.reload_sync
        self.port: int | None = None
        self.connections = 0
        self._reload_lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=max(1, self.config.workers), thread_name_prefix="robocal-serve")
        self._server: asyncio.AbstractServer | None = None
        self._manifest_mtime = self._mtime()
        self.log: Callable[[str], None] = lambda msg: print(f"robocal serve: {msg}", file=sys.stderr, flush=True)

    # -- reload
    def _mtime(self) -> float:
        try:
            return (self.bundle_path / MANIFEST).stat().st_mtime
        except OSError:
            return 0.0

    def reload_sync(self, path: str | Path | None = None) -> Bundle:
        """Load ``path`` (default: the current bundle directory) and swap it in; raises ConfigError on failure."""
        with self._reload_lock:
            target = Path(path) if path else self.bundle_path
            try:
                b = self.loader(target)
            except ConfigError as exc:
                self.log(f"reload of {target} failed, still serving {self.service.bundle.bundle_id}: {exc}")
                raise
            old = self.service.bundle.bundle_id
            self.service.bundle = b  # the atomic swap
            self.bundle_path = target
            self._manifest_mtime = self._mtime()
            self.log(f"reloaded {target}: bundle {old} -> {b.bundle_id}")
            return b

    async def _reload(self, path: str | Path | None = None) -> None:
        loop = asyncio.get_running_loop()
        with contextlib.suppress(ConfigError):
            await loop.run_in_executor(self._pool, self.reload_sync, path)

    async def _watch(self) -> None:
        while True:
            await asyncio.sleep(self.config.watch_interval_s)
            mt = self._mtime()
            if mt and mt != self._manifest_mtime:
                self._manifest_mtime = mt
                await self._reload()

    # -- connections
    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        cfg = self.config
        if self.connections >= cfg.max_connections:
            with contextlib.suppress(Exception):
                writer.write(_BUSY_REPLY)
                await asyncio.wait_for(writer.drain(), cfg.write_timeout_s)
            writer.close()
            return
        self.connections += 1
        session: dict[str, Any] = {}
        loop = asyncio.get_running_loop()
        try:
            while True:
                try:
                    line = await asyncio.wait_for(reader.readuntil(b"\n"), cfg.read_timeout_s)
                except TimeoutError:
                    writer.write(_TIMEOUT_REPLY)
                    await asyncio.wait_for(writer.drain(), cfg.write_timeout_s)
                    break
                except asyncio.IncompleteReadError as exc:  # EOF; answer a last unterminated line
                    if exc.partial.strip():
                        writer.write(self.service.handle_line(exc.partial, session))
                        await asyncio.wait_for(writer.drain(), cfg.write_timeout_s)
                    break
                except (asyncio.LimitOverrunError, ValueError):
                    writer.write(_TOO_LARGE_REPLY)
                    await asyncio.wait_for(writer.drain(), cfg.write_timeout_s)
                    break
                if not line.strip():
                    continue
                # big batches run in a worker thread so that small requests on other connections go on
                if line.count(b"{") > cfg.inline_max_targets + 2:
                    reply = await loop.run_in_executor(self._pool, self.service.handle_line, line, session)
                else:
                    reply = self.service.handle_line(line, session)
                writer.write(reply)
                await asyncio.wait_for(writer.drain(), cfg.write_timeout_s)
        except (TimeoutError, ConnectionError, OSError):
            pass  # slow or vanished client: drop the connection only
        except asyncio.CancelledError:
            pass  # server shutting down
        finally:
            self.connections -= 1
            writer.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(writer.wait_closed(), 1.0)

    async def start(self) -> None:
        cfg = self.config
        self._server = await asyncio.start_server(self._client, cfg.host, cfg.port, limit=cfg.max_request_bytes)
        sock = self._server.sockets[0]
        self.port = int(sock.getsockname()[1])
        if cfg.watch_interval_s > 0:
            asyncio.get_running_loop().create_task(self._watch())
        b = self.service.bundle
        self.log(
            f"serving bundle {b.bundle_id} ({b.robot.name}, thermal={b.thermal is not None}, "
            f"compliance={b.compliance is not None}) on {cfg.host}:{self.port}"
        )

    async def serve_forever(self, install_signals: bool = True) -> None:
        await self.start()
        assert self._server is not None
        loop = asyncio.get_running_loop()
        stop = asyncio.Event()
        if install_signals and threading.current_thread() is threading.main_thread():
            loop.add_signal_handler(signal.SIGHUP, lambda: loop.create_task(self._reload()))
            loop.add_signal_handler(signal.SIGTERM, stop.set)
            loop.add_signal_handler(signal.SIGINT, stop.set)
        async with self._server:
            await stop.wait()
        self._pool.shutdown(wait=False)


class ServerThread:
    """A server running in a background thread (tests, benchmarks, the closed loop): ``with ServerThread(...)
    as srv: Client("127.0.0.1", srv.port)``."""

    def __init__(self, server: Server) -> None:
        self.server = server
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, name="robocal-serve-loop", daemon=True)
        self._ready = threading.Event()
        self._error: BaseException | None = None

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self.server.start())
        except BaseException as exc:  # report to the starting thread
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        self.loop.run_forever()

    @property
    def port(self) -> int:
        assert self.server.port is not None
        return self.server.port

    def __enter__(self) -> ServerThread:
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            raise self._error
        return self

    def __exit__(self, *exc: Any) -> None:
        async def _stop() -> None:
            if self.server._server is not None:
                self.server._server.close()
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        asyncio.run_coroutine_threadsafe(_stop(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(5)
        self.loop.close()
        self.server._pool.shutdown(wait=False)


def read_token(token_file: str | None = None, env: str = "ROBOCAL_SERVE_TOKEN") -> str | None:
    """The shared token from ``token_file`` (first line) or the environment variable ``env``; None if neither."""
    if token_file:
        p = Path(token_file)
        try:
            tok = p.read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise ConfigError(f"cannot read the token file {p}: {exc}") from exc
        if not tok:
            raise ConfigError(f"the token file {p} is empty")
        return tok
    tok = os.environ.get(env, "").strip()
    return tok or None
