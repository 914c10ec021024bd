"""The game's web server: the page, the WebSocket, and what it refuses (malformed, oversized,
replayed and out-of-order messages, a second browser, a page of another site), never crashing."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from play_bot import until
from starlette.websockets import WebSocketDisconnect

from rapidds.loop.config import RunConfig
from rapidds.motion.policy import DiffusionPolicy
from rapidds.web.player import BrowserPlayer
from rapidds.web.protocol import MAX_MESSAGE_BYTES, Gate, Refused
from rapidds.web.server import allowed_hosts, create_app
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
    assert allowed_hosts("0.0.0.0") == ["*"]


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
