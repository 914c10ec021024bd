"""The study's "game" round source through its HTTP and WebSocket interface (FastAPI's
TestClient, the real session, store, planner and game on a small study): offered for fetch only,
the game page plays the plan the round page shows, one page per round, a closed tab restarts the
round, and a round the study has moved past is refused with a message. Rounds played through the
game in a browser are tests/test_study_browser.py's second test. With the comfort item on, the
game asks it once the round is over and the round is recorded with the answer and the presses.
Under reactive execution the round's robot is driven live by the run's executor and the round
is recorded with what happened inside it."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from play_bot import RouteBot, until
from starlette.websockets import WebSocketDisconnect
from study_helpers import make_study

from rapidds.experiments.study.store import StudyStore, study_path
from rapidds.loop.run import load_policy
from rapidds.motion.policy import DiffusionPolicy
from rapidds.web.study.app import StudyWorker, create_study_app
from rapidds.web.study.runner import StudySession
from rapidds.worlds.base import World
from rapidds.worlds.fetch.world import FetchWorld
from rapidds.worlds.registry import make_world

BASE = "http://127.0.0.1:8000"
WS = "ws://127.0.0.1:8000"


@contextmanager
def _serve(folder: Path, world: World, policy: DiffusionPolicy
           ) -> Iterator[tuple[TestClient, str]]:
    """The study app on ``folder`` (its lifespan running, as under uvicorn) and the
    participant's id."""
    worker = StudyWorker(lambda: StudySession(folder, policy=policy, world=world))
    try:
        pid = worker.run(lambda s: s.store.participants()[0].id)
        with TestClient(create_study_app(worker, ["127.0.0.1"]), base_url=BASE) as client:
            yield client, pid
    finally:
        worker.close()


def _step(client: TestClient, pid: str) -> str:
    page = client.get(f"/p/{pid}")
    assert page.status_code == 200, page.text
    return page.text.split("data-step='", 1)[1].split("'", 1)[0]


def _rounds(folder: Path) -> int:
    with StudyStore.open_readonly(study_path(folder)) as s:
        return len(s.records())


def test_the_game_source_is_refused_for_a_world_that_cannot_be_played(tmp_path: Path) -> None:
    world = make_world("painting")
    refused = "world painting does not declare the browser_play capability"
    folder = make_study(tmp_path, world)
    with _serve(folder, world, load_policy(world)) as (client, pid):
        assert "/play" not in client.get(f"/p/{pid}").text  # not offered
        page = client.get(f"/p/{pid}/play")
        assert page.status_code == 404
        assert refused in page.text
        r = client.post(f"/api/p/{pid}/round", json={"step": _step(client, pid),
                                                     "fields": {"source": "game"}})
        assert r.status_code == 400 and refused in r.json()["error"]
        with client.websocket_connect(f"{WS}/p/{pid}/ws?step={_step(client, pid)}") as ws:
            msg = json.loads(ws.receive_text())
            assert msg["type"] == "refused" and refused in msg["reason"]
    assert _rounds(folder) == 0


def test_the_game_plays_the_round_pages_plan_once_and_refuses_rounds_out_of_turn(
        tmp_path: Path, fetch_world: FetchWorld, fetch_policy: DiffusionPolicy) -> None:
    folder = make_study(tmp_path, fetch_world)
    with _serve(folder, fetch_world, fetch_policy) as (client, pid):
        page = client.get(f"/p/{pid}")
        assert f"href='/p/{pid}/play'" in page.text
        step = _step(client, pid)
        # the game records its rounds itself: a posted "game" round is refused
        r = client.post(f"/api/p/{pid}/round", json={"step": step,
                                                     "fields": {"source": "game"}})
        assert r.status_code == 400 and f"/p/{pid}/play" in r.json()["error"]
        game = client.get(f"/p/{pid}/play")
        assert game.status_code == 200 and f'data-ws="/p/{pid}/ws?step=' in game.text
        assert "/static/play.js" in game.text
        held = client.app.state.worker.run(lambda s: s.plan(pid))[1]  # type: ignore[attr-defined]
        with client.websocket_connect(f"{WS}/p/{pid}/ws?step={step}") as ws:
            welcome = until(ws, "welcome")
            assert welcome["next"] == f"/p/{pid}" and welcome["cycles"] == 2
            plan = until(ws, "plan")
            assert plan["cycle"] == 0 and plan["sequences"]["human"] == held.human
            assert plan["sequences"]["robot"] == held.robot
            assert until(ws, "phase")["phase"] == "ready"
            # one page per participant round: a second tab is told so
            with client.websocket_connect(f"{WS}/p/{pid}/ws?step={step}") as second:
                msg = json.loads(second.receive_text())
                assert msg["type"] == "refused" and "another browser" in msg["reason"]
                with pytest.raises(WebSocketDisconnect) as closed:
                    second.receive_text()
                assert closed.value.code == 4009
            # a closed tab mid-round: the round starts again for the next page
            ws.send_text(json.dumps({"type": "start", "seq": 1, "cycle": 0}))
            ws.send_text(json.dumps({"type": "move", "seq": 2, "dx": 1, "dy": 0}))
            while until(ws, "state")["t"] < 0.3:
                pass
        with client.websocket_connect(f"{WS}/p/{pid}/ws?step={step}") as ws:
            assert until(ws, "phase")["phase"] == "ready"
            assert until(ws, "state")["t"] == 0
            # a page of another site cannot drive the game
            evil = {"origin": "http://evil.example"}
            with pytest.raises(WebSocketDisconnect) as foreign, client.websocket_connect(
                    f"{WS}/p/{pid}/ws?step={step}", headers=evil) as bad:
                bad.receive_text()
            assert foreign.value.code == 1008
            # the experimenter records the round another way while the game is open
            r = client.post(f"/api/p/{pid}/round", json={"step": step,
                                                         "fields": {"source": "simulated"}})
            assert r.status_code == 200, r.text
            # the page still open on the old round is told when the next round's game opens
            assert client.get(f"/p/{pid}/play").status_code == 200
            assert "moved on" in until(ws, "refused")["reason"]
        # the game of the round the study moved past is refused, with what comes next
        with client.websocket_connect(f"{WS}/p/{pid}/ws?step={step}") as ws:
            msg = json.loads(ws.receive_text())
            assert msg["type"] == "refused" and "round is over" in msg["reason"]
            assert "round 2" in msg["reason"]
        # the next round gets a game of its own
        step = _step(client, pid)
        assert step.endswith(":1")
        game = client.get(f"/p/{pid}/play")
        assert game.status_code == 200
        with client.websocket_connect(f"{WS}/p/{pid}/ws?step={step}") as ws:
            plan1 = until(ws, "plan")
            assert plan1["cycle"] == 1
    # a server restarted mid-round: the page reconnects and plays the same plan again
    with _serve(folder, fetch_world, fetch_policy) as (client, pid):
        with client.websocket_connect(f"{WS}/p/{pid}/ws?step={step}") as ws:
            again = until(ws, "plan")
        assert again["cycle"] == 1 and again["sequences"] == plan1["sequences"]
        assert again["routes"] == plan1["routes"] and again["owner"] == plan1["owner"]
        for t, (start, finish) in plan1["expected"].items():
            assert again["expected"][t] == pytest.approx([start, finish], abs=1e-6)
        for t, path in plan1["robot_paths"].items():
            assert np.allclose(again["robot_paths"][t], path, atol=1e-6)
        r = client.post(f"/api/p/{pid}/round", json={"step": step,
                                                     "fields": {"source": "simulated"}})
        assert r.status_code == 200, r.text
        # the survey is next: no round to play
        page = client.get(f"/p/{pid}/play")
        assert page.status_code == 409
        assert "no round to play" in page.text and "survey" in page.text
    assert _rounds(folder) == 2  # the two simulated rounds; nothing from the games


def test_a_game_round_asks_the_comfort_item_and_is_stored_with_it(
        tmp_path: Path, fetch_world: FetchWorld, fetch_policy: DiffusionPolicy) -> None:
    folder = make_study(tmp_path, fetch_world, comfort=True)
    bot, seq = RouteBot(fetch_world), iter(range(1, 10**6))

    def send(ws: object, **msg: object) -> None:
        ws.send_text(json.dumps({**msg, "seq": next(seq)}))  # type: ignore[attr-defined]

    with _serve(folder, fetch_world, fetch_policy) as (client, pid):
        step = _step(client, pid)
        assert client.get(f"/p/{pid}/play").status_code == 200
        with client.websocket_connect(f"{WS}/p/{pid}/ws?step={step}") as ws:
            assert until(ws, "phase")["phase"] == "ready"
            send(ws, type="start", cycle=0)
            held, pressed_at = (0, 0), None
            while not ((st := until(ws, "state"))["over"] and st["ask"]):
                assert not st["ask"]  # never asked before the round is over
                if pressed_at is None and st["started"] and not st["over"] and st["t"] >= 0.5:
                    send(ws, type="too_close", cycle=0)
                    pressed_at = st["t"]
                if (want := bot.move(st)) != held:
                    send(ws, type="move", dx=want[0], dy=want[1])
                    held = want
            # the round is over, its question open: nothing is recorded before the answer
            assert _rounds(folder) == 0 and st["signals"] == 1
            send(ws, type="comfort", cycle=0, answer=9)  # the gate refuses it
            assert "answer" in until(ws, "refused-message")["reason"]
            send(ws, type="comfort", cycle=0, answer=6)
            while (phase := until(ws, "phase"))["phase"] != "done":
                assert phase["phase"] != "error", phase
    with StudyStore.open_readonly(study_path(folder)) as s:
        rid = s.run_id(pid, s.participant(pid).systems[0])
        (rec,) = s.records(rid)
    said = rec["comfort"]
    assert said["answer"] == 6 and "simulated" not in said
    assert pressed_at is not None and len(said["too_close"]) == 1
    assert said["too_close"][0] == pytest.approx(pressed_at, abs=0.1)  # the game's clock
    assert rec["gamma_belief"]["evidence"] == 1


def test_a_reactive_game_round_runs_on_the_executor_and_is_stored_with_it(
        tmp_path: Path, fetch_world: FetchWorld, fetch_policy: DiffusionPolicy) -> None:
    """A study designed with the reactive robot: the game round's robot is the executor's (the
    one ``rapidds play --execution reactive`` drives), and the stored round is the whole live
    cycle with its in-cycle record: who did what as executed, pauses, re-plans, protective."""
    folder = make_study(tmp_path, fetch_world, execution="reactive")
    bot, seq = RouteBot(fetch_world), iter(range(1, 10**6))
    with _serve(folder, fetch_world, fetch_policy) as (client, pid):
        step = _step(client, pid)
        held = client.app.state.worker.run(lambda s: s.plan(pid))[1]  # type: ignore[attr-defined]
        assert client.get(f"/p/{pid}/play").status_code == 200
        with client.websocket_connect(f"{WS}/p/{pid}/ws?step={step}") as ws:
            assert until(ws, "phase")["phase"] == "ready"
            ws.send_text(json.dumps({"type": "start", "cycle": 0, "seq": next(seq)}))
            move = (0, 0)
            while not (st := until(ws, "state"))["over"]:
                assert st.get("execution") == "reactive", st  # the executor drives the robot
                if (want := bot.move(st)) != move:
                    ws.send_text(json.dumps({"type": "move", "dx": want[0], "dy": want[1],
                                             "seq": next(seq)}))
                    move = want
            while (phase := until(ws, "phase"))["phase"] != "done":
                assert phase["phase"] != "error", phase
        assert _step(client, pid).endswith(":1")  # the study moved on to the next round
    with StudyStore.open_readonly(study_path(folder)) as s:
        rid = s.run_id(pid, s.participant(pid).systems[0])
        assert "-reactive-" in rid
        (rec,) = s.records(rid)
    assert sorted(rec["executed"]["human"]) == sorted(held.human)
    assert sorted(rec["executed"]["robot"]) == sorted(held.robot)
    assert isinstance(rec["pauses"], list)
    # the re-plans stored are the ones the game showed live (the same executor's)
    assert [r["reason"] for r in rec["replans"]] == [r["reason"] for r in st["replans"]]
    assert rec["protective"] is not None  # the executor's separation monitoring ran
    assert rec["deviation"] is None  # what a live person did: no simulated deviation
