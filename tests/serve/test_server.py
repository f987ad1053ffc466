"""The TCP server: serves, survives bad clients, times out idle ones, reloads without dropping connections."""

from __future__ import annotations

import json
import shutil
import socket
import time

import pytest

from conftest import LOADERS
from robocal.errors import ConfigError
from robocal.serve.bundle import load_bundle, write_bundle
from robocal.serve.client import Client, ServiceError
from robocal.serve.protocol import ServiceConfig
from robocal.serve.server import Server, ServerConfig, ServerThread

Q1 = [10.0, -80.0, 60.0, 20.0, 40.0, 30.0]


def _loader(path):
    return load_bundle(path, loaders=LOADERS)


def _server(bundle, **kw):
    cfg = ServerConfig(port=0, **kw)
    return ServerThread(Server(bundle, cfg, loader=_loader))


def test_correct_over_tcp_and_bad_input_keeps_serving(geometric_bundle):
    with _server(geometric_bundle, read_timeout_s=5) as srv, Client("127.0.0.1", srv.port) as c:
        assert c.ping()["ok"]
        r = c.correct([Q1, Q1])
        assert r["n"] == 2 and r["results"][0]["status"] == "ok"
        assert c.send_raw(b"{not json")["error"]["code"] == "parse_error"
        assert c.send_raw(b"\xff\xfe")["error"]["code"] == "parse_error"
        with pytest.raises(ServiceError, match="bad_request"):
            c.correct([Q1[:3]])
        assert c.correct([Q1])["results"][0]["q_deg"] == r["results"][0]["q_deg"]
        assert c.request({"op": "stats"})["errors"] == 3


def test_too_long_line_and_idle_timeout(geometric_bundle):
    with _server(geometric_bundle, max_request_bytes=4096, read_timeout_s=0.5) as srv:
        s = socket.create_connection(("127.0.0.1", srv.port), timeout=5)
        s.sendall(b"x" * 10000)
        f = s.makefile("rb")
        assert json.loads(f.readline())["error"]["code"] == "too_large"
        assert f.readline() == b""  # closed
        s.close()
        s = socket.create_connection(("127.0.0.1", srv.port), timeout=5)
        s.sendall(b'{"op": "pi')  # a slow client that never finishes its line
        t = time.monotonic()
        f = s.makefile("rb")
        assert json.loads(f.readline())["error"]["code"] == "timeout"
        assert time.monotonic() - t < 3.0  # read_timeout_s 0.5 plus scheduling slack
        s.close()
        with Client("127.0.0.1", srv.port) as c:  # others are still served
            assert c.ping()["ok"]


def test_reload_swaps_bundle_without_dropping_clients(tmp_path, geometric_bundle, full_bundle, calibration_file):
    live = tmp_path / "live"
    shutil.copytree(geometric_bundle, live)
    with _server(live) as srv, Client("127.0.0.1", srv.port) as c:
        old = c.ping()["bundle"]
        assert c.info()["thermal"] is False
        # replace the bundle in place with the thermal one and reload over the same connection
        shutil.rmtree(live)
        shutil.copytree(full_bundle, live)
        new = c.reload()["bundle"]
        assert new != old and c.ping()["bundle"] == new and c.info()["thermal"] is True
        # a broken bundle is refused; the good one keeps serving
        (live / "calibration.json").write_text("{}")
        with pytest.raises(ServiceError, match="reload failed"):
            c.reload()
        assert c.ping()["bundle"] == new
        assert c.correct([Q1], temperatures=[25.0] * 9)["results"][0]["status"] == "ok"


def test_non_loopback_requires_token(geometric_bundle):
    with pytest.raises(ConfigError, match="token"):
        Server(geometric_bundle, ServerConfig(host="0.0.0.0", port=0), loader=_loader)
    srv = Server(geometric_bundle, ServerConfig(host="127.0.0.1", port=0), ServiceConfig(token="abc"), loader=_loader)
    with ServerThread(srv) as st:
        with Client("127.0.0.1", st.port) as c, pytest.raises(ServiceError, match="unauthorized"):
            c.ping()
        with Client("127.0.0.1", st.port, token="abc") as c:
            assert c.ping()["ok"]


def test_write_bundle_checksums(tmp_path, calibration_file):
    b = write_bundle(tmp_path / "b", "kr16_2", calibration_file)
    (b / "calibration.json").write_text((b / "calibration.json").read_text() + " ")
    with pytest.raises(ConfigError, match="sha256"):
        load_bundle(b)
