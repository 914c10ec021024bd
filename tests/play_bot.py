"""A small bot that plays the fetch game like a person with arrow keys: for the task the plan
gives it, it walks the world's human route (home -> via points -> object -> back) by holding the
keys towards the next waypoint, and waits at home while its next task is locked.

It reads only what the page gets (the live state message) and answers with held directions,
so the same bot drives the game in-process (``player.steer``) and in a browser (key presses):
:func:`play_cycle` plays one cycle of a browser page with it.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rapidds.schedule import Wait, parse_item
from rapidds.worlds.fetch.world import FetchWorld


def human_tasks(seq: list[str]) -> list[str]:
    """A stored or planned human sequence without its wait tokens."""
    return [t for t in seq if not isinstance(parse_item(t), Wait)]


def until(ws: Any, kind: str, limit: int = 2000) -> dict[str, Any]:
    """The next message of type ``kind`` on a game socket (a TestClient WebSocket)."""
    for _ in range(limit):
        msg = json.loads(ws.receive_text())
        if msg["type"] == kind:
            return msg
    raise AssertionError(f"no {kind!r} message in {limit}")


KEYS = {(1, 0): "ArrowRight", (-1, 0): "ArrowLeft", (0, 1): "ArrowUp", (0, -1): "ArrowDown"}


class RouteBot:
    """modes: task -> route mode the bot takes ("middle" or "outside" for t2 and t3).
    tol: metres per axis within which the bot stops pressing that axis; reach: metres at which a
    waypoint counts as passed. prefer: tasks the bot fetches first whenever the page shows them
    open (any order precedence allows), before the plan's next; with a reactive robot, also the
    robot's tasks the page offers the person (``takeable``). hold: task -> seconds the bot
    stands still with its object once picked up (a person who dawdles: an overrun)."""

    def __init__(self, world: FetchWorld, modes: dict[str, str] | None = None,
                 tol: float = 0.08, reach: float = 0.3, prefer: tuple[str, ...] = (),
                 hold: dict[str, float] | None = None):
        self.world, self.modes, self.prefer = world, dict(modes or {}), prefer
        self.hold = dict(hold or {})
        self._held: dict[tuple[int, str], float] = {}  # when the bot picked a held task up
        self.tol, self.reach = tol, reach
        self._leg: tuple[int, str, str] | None = None
        self._waypoints: list[np.ndarray] = []

    def _route(self, task: str, leg: str) -> list[np.ndarray]:
        modes = self.world.modes(task)
        mode = self.modes.get(task, modes[0])
        route = self.world.route("human", task, mode if mode in modes else modes[0])
        pts = [np.asarray(p, dtype=float) for p in route.points]
        return pts[1:route.goal + 1] if leg == "out" else pts[route.goal + 1:]

    def move(self, state: dict[str, Any]) -> tuple[int, int]:
        """The direction to hold now, (dx, dy) in {-1, 0, 1} (y up)."""
        cur = state.get("cur")
        if not state.get("started") or state.get("human_done") or cur is None:
            return (0, 0)
        status = state["tasks"][cur]
        if status != "carried":  # free: a preferred open object first, whatever the plan says
            # (with a reactive robot, one of the robot's that the page offers counts as open)
            takeable = state.get("takeable", [])
            mine = state.get("owner", {})
            cur = next((t for t in self.prefer if t in takeable or (
                state["tasks"].get(t) == "active" and mine.get(t, "human") == "human")), cur)
            status = "active" if cur in takeable else state["tasks"][cur]
        if status not in ("active", "carried"):
            return (0, 0)  # locked or not started yet: wait where we are (at home)
        leg = "out" if status == "active" else "back"
        if leg == "back" and cur in self.hold:
            since = self._held.setdefault((state["cycle"], cur), state["t"])
            if state["t"] - since < self.hold[cur]:
                return (0, 0)
        key = (state["cycle"], cur, leg)
        if key != self._leg:
            self._leg, self._waypoints = key, self._route(cur, leg)
        pos = np.asarray(state["h"], dtype=float)
        while self._waypoints and np.linalg.norm(self._waypoints[0] - pos) < self.reach:
            self._waypoints.pop(0)
        if not self._waypoints:
            # the last waypoint (object or home) is passed but not yet counted: step onto it
            goal = (self.world.object_position(cur) if leg == "out"
                    else self.world.home("human"))
            self._waypoints = [goal]
        d = self._waypoints[0] - pos
        return (int(np.sign(d[0])) if abs(d[0]) > self.tol else 0,
                int(np.sign(d[1])) if abs(d[1]) > self.tol else 0)


def keys_for(move: tuple[int, int]) -> set[str]:
    """The arrow keys that hold ``move``."""
    dx, dy = move
    out = set()
    if dx:
        out.add(KEYS[dx, 0])
    if dy:
        out.add(KEYS[0, dy])
    return out


def play_cycle(page: Any, bot: RouteBot, cycle: int, *, stop_at: float | None = None,
               midcycle_shot: Path | None = None,
               signal_at: float | None = None) -> tuple[dict, dict]:
    """In a browser ``page`` of the game: start ``cycle`` and walk it with the arrow keys until
    it is over (or until game time ``stop_at``), pressing T ("too close") once from game time
    ``signal_at``; the plan the page showed and its last state of the cycle."""
    page.wait_for_function(
        f"window.rapidds.phase === 'ready' && window.rapidds.plan.cycle === {cycle}",
        timeout=90_000)
    plan = page.evaluate("window.rapidds.plan")
    page.keyboard.press("Enter")
    held: set[str] = set()
    last: dict[str, Any] = {}
    end = time.monotonic() + 90
    while time.monotonic() < end:
        # the cycle's last state from the page's record of ended cycles: on screen, "over" may
        # last one tick (the next plan replaces it), shorter than a poll on a loaded machine
        st, ended = page.evaluate(f"[window.rapidds.state, window.rapidds.ended[{cycle}]]")
        if ended is not None:
            last = ended
            break
        if st["cycle"] == cycle:
            last = st
            if stop_at is not None and st["t"] >= stop_at:
                break
            if signal_at is not None and st["t"] >= signal_at and st["started"]:
                page.keyboard.press("t")
                signal_at = None
            if midcycle_shot is not None and st["t"] >= 3.0:
                page.screenshot(path=str(midcycle_shot))
                midcycle_shot = None
        want = keys_for(bot.move(st)) if st["cycle"] == cycle else set()
        for k in held - want:
            page.keyboard.up(k)
        for k in want - held:
            page.keyboard.down(k)
        held = want
        time.sleep(0.015)
    for k in held:
        page.keyboard.up(k)
    assert last.get("over") or stop_at is not None, f"cycle {cycle} did not finish: {last}"
    return plan, last


def check_played(store: Any, run_id: str, played: list[tuple[dict, dict]], world: FetchWorld,
                 modes: dict[str, str]) -> list[dict[str, Any]]:
    """The store (a run or study store) holds the ``played`` cycles (plan, last state, as
    :func:`play_cycle` returns them) as the page saw them: the plan's human sequence, the
    page's durations, paths sampled at dt from home to the object and back, on the bot's
    routes (``modes``). Their records."""
    recs = store.records(run_id)
    assert [r["cycle"] for r in recs] == list(range(len(played)))
    for rec, (plan, end) in zip(recs, played, strict=True):
        assert rec["human"] == plan["sequences"]["human"]
        human = human_tasks(rec["human"])
        assert human, "the bot needs tasks to play"
        arrays = store.arrays(run_id, rec["cycle"])
        for t in human:
            s, f = end["times"][t]  # what the page saw, live
            assert rec["observed"][t] == pytest.approx(f - s, abs=2e-3)
            path = arrays[f"human/{t}"]
            n = math.ceil(rec["observed"][t] / world.dt - 1e-9) + 1
            assert path.shape == (n, 2)  # sampled at dt from start to end
            assert np.linalg.norm(path[-1] - world.home("human")) <= 0.5
            assert np.linalg.norm(path - world.object_position(t), axis=1).min() \
                <= 0.5 + 4.5 * world.dt
            if t in modes:  # the bot's route, not a simulated person's
                assert world.route_mode(t, path) == modes[t]
    return recs


def check_planned_with(plan: dict[str, Any], rec: dict[str, Any]) -> None:
    """``plan`` (as the page showed it) expects the human's durations that ``rec``'s cycle
    learned."""
    learned = rec["belief"]["mean_durations"]
    for t in human_tasks(plan["sequences"]["human"]):
        s, f = plan["expected"][t]
        assert f - s == pytest.approx(learned[t], abs=2e-3)
