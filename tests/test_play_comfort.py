"""What a person in the browser game says about the robot's closeness: "too close" during a
cycle (timed by the game's clock) and the comfort answer once it is over, through the gate, the
player and the loop, which learns the cycle's gamma evidence only once it is complete; a resumed
``--gamma learn`` game plans as the uninterrupted one."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from play_bot import RouteBot
from test_play_session import SEARCH, _plan

from rapidds.loop.config import RunConfig
from rapidds.motion.policy import DiffusionPolicy
from rapidds.store import RunStore
from rapidds.web.player import BrowserPlayer, PlayerGone
from rapidds.web.protocol import Comfort, Gate, Refused, TooClose
from rapidds.web.session import STORE_NAME, PlaySession
from rapidds.worlds.fetch.world import FetchWorld


def test_the_gate_takes_too_close_and_answers_1_to_7_only() -> None:
    gate = Gate()
    assert isinstance(gate.check(json.dumps({"type": "too_close", "seq": 1, "cycle": 0})),
                      TooClose)
    msg = gate.check(json.dumps({"type": "comfort", "seq": 2, "cycle": 0, "answer": 7}))
    assert isinstance(msg, Comfort) and msg.answer == 7
    for seq, bad in enumerate([{"answer": 9}, {"answer": 0}, {"answer": "5"}, {"answer": 5.0},
                               {"answer": True}, {"answer": 4, "note": "x"}, {}], start=3):
        with pytest.raises(Refused):
            gate.check(json.dumps({"type": "comfort", "seq": seq, "cycle": 0, **bad}))
    with pytest.raises(Refused):
        gate.check(json.dumps({"type": "too_close", "seq": 20, "cycle": -1}))
    assert gate.refused == 8 and gate.accepted == 2


def _play_to_the_end(player: BrowserPlayer, bot: RouteBot, cycle: int,
                     signal_at: float | None = None) -> list[float]:
    """Play ``cycle`` (on screen, started) until it is over; with ``signal_at``, say "too
    close" once at that game time. The signal times the player took."""
    taken = []
    while not (state := player.tick())["over"]:
        if signal_at is not None and not taken and state["t"] >= signal_at:
            assert player.too_close(cycle)
            taken.append(state["t"])
        player.steer(move=bot.move(state))
        assert not state["ask"]  # never asked before the cycle is over
    return taken


def test_the_player_times_too_close_and_hands_the_answer_with_the_signals(
        fetch_world: FetchWorld) -> None:
    player = BrowserPlayer(fetch_world, ask_comfort=True)
    player.show(_plan(fetch_world, 0, ("t3",), ("t2", "t0", "t1")))
    assert not player.too_close(0)  # not under way yet
    assert player.start(0)
    assert not player.too_close(1)  # not the cycle on screen
    assert not player.answer(0, 4)  # not over yet
    taken = _play_to_the_end(player, RouteBot(fetch_world), 0, signal_at=0.5)
    state = player.snapshot()
    assert state is not None and state["ask"] and state["signals"] == 1
    assert not player.too_close(0)  # over: no more signals
    with pytest.raises(ValueError):
        player.answer(0, 9)
    assert player.answer(0, 6)
    assert not player.answer(0, 2)  # answered once
    assert not player.snapshot()["ask"]
    assert player.comfort_report(0) == (6, taken)
    player.close()
    with pytest.raises(PlayerGone):
        player.comfort_report(1)


def test_a_player_not_asked_says_nothing(fetch_world: FetchWorld) -> None:
    player = BrowserPlayer(fetch_world)
    player.show(_plan(fetch_world, 0, ("t3",), ("t2", "t0", "t1")))
    player.start(0)
    _play_to_the_end(player, RouteBot(fetch_world), 0)
    assert not player.snapshot()["ask"] and not player.answer(0, 3)
    assert player.comfort_report(0) is None


def _learning(world: FetchWorld, policy: DiffusionPolicy, out: Path,
              resume: bool = False) -> PlaySession:
    cfg = RunConfig(world="fetch", human="tester", adapt="full", cycles=2, seed=5,
                    gamma_learn=True, **SEARCH)
    return PlaySession(cfg, out, world=world, policy=policy, resume=resume,
                       player=BrowserPlayer(world, "tester", ask_comfort=True))


def _ready(session: PlaySession, cycle: int, timeout: float = 300.0) -> dict[str, Any]:
    """Tick until ``cycle`` is on screen, ready; its plan view."""
    end = time.monotonic() + timeout
    while not (session.player.phase == "ready" and session.player.cycle == cycle):
        assert time.monotonic() < end, f"stuck: {session.phase}, {session.error}"
        assert session.error is None, session.error
        session.player.tick()
        time.sleep(0.002)
    view = session.player.plan_view()
    assert view is not None
    return view


def test_a_learning_game_learns_the_whole_cycle_and_resumes_exactly(
        tmp_path: Path, fetch_world: FetchWorld, fetch_policy: DiffusionPolicy) -> None:
    session = _learning(fetch_world, fetch_policy, tmp_path)
    session.open()
    try:
        _ready(session, 0)
        player = session.player
        assert player.start(0)
        taken = _play_to_the_end(player, RouteBot(fetch_world), 0, signal_at=0.5)
        # the loop waits for the answer: nothing is stored and no next plan comes before it
        for _ in range(30):
            player.tick()
        assert session.stored == 0 and player.cycle == 0 and player.snapshot()["ask"]
        assert player.answer(0, 6)
        plan1 = _ready(session, 1)
    finally:
        session.stop()
    with RunStore(tmp_path / STORE_NAME) as store:
        (rec,) = store.records(session.run_id)
    said = rec["comfort"]
    assert said["answer"] == 6 and said["too_close"] == pytest.approx(taken)
    assert len(said["closeness_at"]) == 1 and 0 <= said["closeness_at"][0] <= 1
    assert rec["gamma_belief"]["evidence"] == 1
    assert rec["gamma"] == pytest.approx(fetch_world.problem().objective.gamma)  # the prior's
    resumed = _learning(fetch_world, fetch_policy, tmp_path, resume=True)
    resumed.open()
    try:
        again = _ready(resumed, 1)
    finally:
        resumed.stop()
    assert json.dumps(again, sort_keys=True) == json.dumps(plan1, sort_keys=True)
    assert not np.isclose(rec["gamma_belief"]["mean"], rec["gamma"])  # it learned something
