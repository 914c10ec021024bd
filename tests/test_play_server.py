"""The game's web server: the page, the WebSocket, and what it refuses (malformed, oversized,
replayed and out-of-order messages, a second browser, a page of another site), never crashing."""

from __future__ import annotations

import contextlib
import json
import logging
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import uvicorn
from fastapi import FastAPI
from fastapi.testclient import TestClient
from play_bot import until
from starlette.websockets import WebSocketDisconnect
from websockets.sync.client import connect

from rapidds.loop.config import RunConfig
from rapidds.motion.policy import DiffusionPolicy
from rapidds.web.player import BrowserPlayer
from rapidds.web.protocol import MAX_MESSAGE_BYTES, Gate, Refused
from rapidds.web.server import WS_MAX_BYTES, allowed_hosts, create_app, listen
from rapidds.web.session import PlaySession
from rapidds.worlds.fetch.world import FetchWorld

SEARCH = dict(population=8, generations=4, samples=8, patience=2, particles=2, candidates=4)
BASE = "http://127.0.0.1:8765"
WS = "ws://127.0.0.1:8765/ws"


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory, fetch_world: FetchWorld,
           fetch_policy: DiffusionPolicy) -> Iterator[TestClient]:
    cfg = RunConfig(world="fetch", human="web", cycles=2, **SEARCH)
    out: Path = tmp_path_factory.mktemp("server")
    session = PlaySession(cfg, out, world=fetch_world, policy=fetch_policy,
                          player=BrowserPlayer(fetch_world, "web"))
    session.open()
    try:
        with TestClient(create_app(session), base_url=BASE) as c:
            yield c
    finally:
        session.stop()


def test_the_page_and_its_assets_are_served(client: TestClient) -> None:
    page = client.get("/")
    assert page.status_code == 200 and '<canvas id="map"' in page.text
    assert "connect-src 'self'" in page.headers["content-security-policy"]
    assert client.get("/static/play.js").status_code == 200
    assert client.get("/static/../session.py").status_code == 404
    assert client.get("/static/%2e%2e/session.py").status_code == 404


def test_a_page_gets_the_scene_the_plan_and_the_live_state(client: TestClient) -> None:
    with client.websocket_connect(WS) as ws:
        welcome = until(ws, "welcome")
        assert welcome["run_id"] == "fetch-web-full-s0" and welcome["hz"] == 60
        assert len(welcome["scene"]["walls"]) == 4
        plan = until(ws, "plan")
        assert plan["cycle"] == 0 and set(plan["owner"]) == {"t0", "t1", "t2", "t3"}
        assert until(ws, "phase")["phase"] == "ready"
        state = until(ws, "state")
        assert state["h"] == [2.2, 7.0] and not state["started"]


def test_bad_messages_are_refused_and_logged_and_the_game_goes_on(
        client: TestClient, caplog: pytest.LogCaptureFixture) -> None:
    bad = [
        "not json",
        json.dumps({"type": "move", "seq": 1, "dx": 5, "dy": 0}),
        json.dumps({"type": "move", "seq": 2, "dx": True, "dy": 0}),
        json.dumps({"type": "teleport", "seq": 3, "x": 1, "y": 1}),
        json.dumps({"type": "target", "seq": 4, "x": float("nan"), "y": 1}),
        json.dumps({"type": "start", "seq": 5, "cycle": 0, "path": "/etc/passwd"}),
        json.dumps({"type": "move", "seq": 6, "dx": 0, "dy": 0, "pad": "x" * MAX_MESSAGE_BYTES}),
        json.dumps({"type": "start", "seq": 7, "cycle": 1}),  # not the cycle on screen
    ]
    with caplog.at_level(logging.WARNING, logger="rapidds.web"), \
            client.websocket_connect(WS) as ws:
        until(ws, "welcome")
        for raw in bad:
            ws.send_text(raw)
            assert until(ws, "refused-message")["reason"]
        ws.send_bytes(b"\x00\x01")
        assert "binary" in until(ws, "refused-message")["reason"]
        ws.send_text(json.dumps({"type": "move", "seq": 10, "dx": 1, "dy": 0}))
        ws.send_text(json.dumps({"type": "move", "seq": 10, "dx": 1, "dy": 0}))  # replayed
        assert "replayed" in until(ws, "refused-message")["reason"]
        ws.send_text(json.dumps({"type": "move", "seq": 9, "dx": 0, "dy": 0}))  # out of order
        assert "out of order" in until(ws, "refused-message")["reason"]
        ws.send_text(json.dumps({"type": "start", "seq": 11, "cycle": 0}))
        for _ in range(600):
            state = until(ws, "state")
            if state["t"] > 0.5:
                break
        assert state["started"] and state["h"][0] > 2.2 + 0.5 * 4.5 * 0.8  # walked right
        ws.send_text(json.dumps({"type": "start", "seq": 12, "cycle": 0}))  # a replayed start
        assert "not ready" in until(ws, "refused-message")["reason"]
    refusals = [r for r in caplog.records if "refused a message" in r.getMessage()]
    assert len(refusals) == len(bad) + 4
    # leaving mid-cycle puts the cycle back to its start for the next page
    with client.websocket_connect(WS) as ws:
        assert until(ws, "phase")["phase"] == "ready"
        assert until(ws, "state")["t"] == 0


def test_one_player_per_run_and_same_origin_only(client: TestClient) -> None:
    with client.websocket_connect(WS) as first:
        until(first, "welcome")
        with client.websocket_connect(WS) as second:
            msg = json.loads(second.receive_text())
            assert msg["type"] == "refused" and "another browser" in msg["reason"]
            with pytest.raises(WebSocketDisconnect) as closed:
                second.receive_text()
            assert closed.value.code == 4009
        until(first, "state")  # the first one plays on
    with pytest.raises(WebSocketDisconnect) as refused, client.websocket_connect(
            WS, headers={"origin": "http://evil.example"}) as ws:
        ws.receive_text()
    assert refused.value.code == 1008


def test_another_host_name_is_refused(client: TestClient) -> None:
    """A page of another site that rebinds its name to 127.0.0.1 sends its own Host (and a
    matching Origin): neither the page nor the socket answers it."""
    evil = {"host": "evil.example:8765", "origin": "http://evil.example:8765"}
    assert client.get("/", headers=evil).status_code == 400
    with pytest.raises(WebSocketDisconnect), client.websocket_connect(WS, headers=evil) as ws:
        ws.receive_text()
    assert allowed_hosts("127.0.0.1") == ["127.0.0.1", "::1", "localhost"]
    assert allowed_hosts("::1") == ["127.0.0.1", "::1", "localhost"]
    assert allowed_hosts("192.168.1.7") == ["127.0.0.1", "192.168.1.7", "::1", "localhost"]


def test_a_wildcard_bind_answers_to_this_machines_names_only(client: TestClient) -> None:
    """0.0.0.0 listens on every interface, yet a rebinding name is still refused: the server
    answers to the loopback names, the address it prints and the machine's own names."""
    wild = allowed_hosts("0.0.0.0")
    assert {"127.0.0.1", "::1", "localhost", "0.0.0.0", socket.gethostname().lower()} <= set(wild)
    assert "*" not in wild and "evil.example" not in wild
    assert set(allowed_hosts("::")) - {"::"} == set(wild) - {"0.0.0.0"}
    app = create_app(client.app.state.hub.session, wild)  # no lifespan: nothing ticks
    c = TestClient(app, base_url="http://0.0.0.0:8765")
    assert c.get("/").status_code == 200
    assert c.get("/", headers={"host": f"{socket.gethostname()}:8765"}).status_code == 200
    refused = c.get("/", headers={"host": "evil.example:8765"})
    assert refused.status_code == 400 and "evil.example" in refused.text


def test_a_server_on_the_ipv6_loopback_answers_the_address_it_prints(
        client: TestClient) -> None:
    """--host ::1: the page at http://[::1]:PORT/ (the Host header brackets the address)."""
    c = TestClient(create_app(client.app.state.hub.session, allowed_hosts("::1")),
                   base_url="http://[::1]:8765")
    page = c.get("/")
    assert page.status_code == 200 and '<canvas id="map"' in page.text
    with c.websocket_connect("ws://[::1]:8765/ws",
                             headers={"origin": "http://[::1]:8765"}) as ws:
        assert until(ws, "welcome")["run_id"] == "fetch-web-full-s0"
    assert c.get("/", headers={"host": "[::2]:8765"}).status_code == 400
    for bad in ("[::1", "x/y", "localhost:99999", ""):
        assert c.get("/", headers={"host": bad}).status_code == 400, bad


@contextlib.contextmanager
def _served(session: PlaySession, host: str) -> Iterator[tuple[int, FastAPI]]:
    """``session`` served by uvicorn on ``host``, any free port, in a thread (as ``serve``)."""
    sock = listen(host, 0)
    app = create_app(session, allowed_hosts(host))
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="on",
                                           ws_max_size=WS_MAX_BYTES, access_log=False))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        for _ in range(3000):
            if server.started:
                break
            time.sleep(0.01)
        assert server.started
        yield sock.getsockname()[1], app
    finally:
        server.should_exit = True
        thread.join(30)
        sock.close()


def _frame(payload: bytes) -> bytes:
    """A masked text frame (a client's), payload under 126 bytes."""
    mask = b"\x01\x02\x03\x04"
    return (bytes([0x81, 0x80 | len(payload)]) + mask
            + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))


def test_a_page_that_floods_the_socket_and_never_reads_is_dropped(
        tmp_path: Path, fetch_world: FetchWorld, fetch_policy: DiffusionPolicy,
        caplog: pytest.LogCaptureFixture) -> None:
    """A real server on 127.0.0.1: every refused message is answered, and a client that
    never reads the answers fills the page's queue; the server drops it at MAX_OUTBOX queued
    messages instead of growing without bound, and the next page plays."""
    session = PlaySession(RunConfig(world="fetch", human="web", cycles=1, **SEARCH), tmp_path,
                          world=fetch_world, policy=fetch_policy,
                          player=BrowserPlayer(fetch_world, "web"))
    session.open()
    try:
        with caplog.at_level(logging.WARNING, logger="rapidds.web"), \
                _served(session, "127.0.0.1") as (port, app):
            hub = app.state.hub
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # reads nothing anyway
            sock.settimeout(30)
            sock.connect(("127.0.0.1", port))
            sock.sendall(f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                         "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                         "Sec-WebSocket-Version: 13\r\n\r\n".encode())
            head = b""
            while b"\r\n\r\n" not in head:
                head += sock.recv(1)
            assert head.startswith(b"HTTP/1.1 101"), head
            for _ in range(3000):  # the hub takes the page just after the handshake
                if hub.conn is not None:
                    break
                time.sleep(0.01)
            burst, sent, dropped = _frame(b"not json") * 1000, 0, False
            for _ in range(400):  # at most 400 000 messages (6 MB); never reads a reply
                if hub.conn is None:
                    break
                try:
                    sock.sendall(burst)
                except OSError:  # reset, or the server stopped reading: it let go
                    break
                sent += 1000
            for _ in range(3000):  # its receiver ends within the close's 2 s
                dropped = hub.conn is None
                if dropped:
                    break
                time.sleep(0.01)
            sock.close()
            assert dropped, f"still connected after {sent} unread messages"
            assert any("does not read" in r.getMessage() for r in caplog.records), (
                sent, [r.getMessage() for r in caplog.records][-5:])
            with connect(f"ws://127.0.0.1:{port}/ws") as ws:  # the next page plays
                assert json.loads(ws.recv(timeout=60))["type"] == "welcome"
    finally:
        session.stop()


def test_the_gate_limits_the_message_rate() -> None:
    now = [0.0]
    gate = Gate(clock=lambda: now[0])
    for k in range(240):
        gate.check(json.dumps({"type": "move", "seq": k, "dx": 0, "dy": 0}))
    with pytest.raises(Refused, match="in a second"):
        gate.check(json.dumps({"type": "move", "seq": 240, "dx": 0, "dy": 0}))
    now[0] = 1.0
    gate.check(json.dumps({"type": "move", "seq": 241, "dx": 0, "dy": 0}))
    assert gate.accepted == 241 and gate.refused == 1
