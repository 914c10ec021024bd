"""The "game" round source of a study on a world with browser_play (fetch): the participant
plays their round in the browser game (the page and :class:`~rapidds.web.server.Hub` of
``rapidds play``) and what they did is the round's data.

``GET /p/{pid}/play`` opens a :class:`GameRound` for the participant's current round: a
:class:`~rapidds.web.player.BrowserPlayer` showing the plan the round page shows (the study
session's held plan), a Hub ticking it at 60 Hz on the server's event loop, and a waiter on the
same loop. The waiter never blocks (neither the loop nor the study worker, and it holds no thread
while the person plays): it looks every 20 ms for what the player reports when the person's
tasks are done (:meth:`~rapidds.web.player.BrowserPlayer.played`: their observed durations and
sampled paths, what :meth:`~rapidds.web.player.BrowserPlayer.execute` would return) and hands
it to the study worker:
:meth:`~rapidds.web.study.runner.StudySession.submit_round` with source "game", one store
transaction like every other source. The page goes on to the study's next step once the round is
recorded and the cycle on screen is over (the robot finished too).

When the study asks the comfort item (``StudyDesign.comfort``), the game asks it too: the
player is asked (``ask_comfort``), so the page takes "too close" presses (key T, the red button)
timed by the game's clock during the round and asks the 1-7 item once the round is over (the
robot's part too), as ``rapidds play --gamma learn`` does; the round is recorded with both once
the person has answered (the round page's fields ``comfort`` and ``too_close``, checked as a
typed round's are), so the game's time 0, the cycle's start, is their clock's.

Safety is the game's: one page per participant round (the Hub turns a second away), origin and
host checks, every message through the Gate. A round the study has moved past is refused; a
closed tab puts the cycle back to its start (reopening plays it again); a killed server stores
nothing of the round, and the restarted one re-plans the same plan from (seed, round).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import TYPE_CHECKING, Any

from rapidds.errors import RapiddsError
from rapidds.web.player import BrowserPlayer
from rapidds.web.server import Hub, refuse_socket
from rapidds.web.session import scene
from rapidds.web.study.runner import OutOfTurn, StudySession, step_token
from rapidds.worlds.capabilities import BrowserPlay

if TYPE_CHECKING:
    from collections.abc import Callable

    from rapidds.execution import CycleExecutor, Deployment, HumanSource
    from rapidds.loop.run import CyclePlan
    from rapidds.web.study.app import StudyWorker
    from rapidds.web.study.runner import View
    from rapidds.worlds.base import HumanExecution

__all__ = ["GameRound", "open_round"]

log = logging.getLogger("rapidds.web")
_POLL = 0.02  # s between looks for the person's finished part (a dict lookup on the event loop)


class GameRound:
    """One participant round played in the game; a :class:`~rapidds.web.server.GameSession`
    for the Hub. ``token`` is the round's step (:func:`~rapidds.web.study.runner.step_token`)."""

    summary: dict[str, Any] | None = None  # the study shows no between-cycle summary
    summary_version = 0

    def __init__(self, worker: StudyWorker, world: BrowserPlay, pid: str, token: str,
                 plan: CyclePlan, view: View, ask_comfort: bool = False,
                 live: Callable[[HumanSource], CycleExecutor] | None = None):
        self.worker, self.world, self.pid, self.token = worker, world, pid, token
        self.plan, self.view, self.live = plan, view, live
        self.player = BrowserPlayer(world, name=pid, ask_comfort=ask_comfort)
        if live is None:
            self.player.show(plan)
        else:  # reactive: the robot is driven live by the run's executor
            self.player.show_live(plan, live)
        self.hub = Hub(self)
        self.stored = 0  # 1 once the round is in the store
        self.error: str | None = None
        self.timing: dict[str, float] = {}
        self._tasks: list[asyncio.Task[None]] = []

    # -- GameSession --------------------------------------------------------------------------
    @property
    def phase(self) -> str:
        """The player's phase; "done" once the round is stored and the cycle on screen over
        (the page then goes on to the study's next step), "error" when it was not stored."""
        if self.error is not None:
            return "error"
        phase = self.player.phase
        return "done" if self.stored and phase == "over" else phase

    def info(self) -> dict[str, Any]:
        return {"run_id": f"{self.pid} · system {self.view.block} of {self.view.blocks} · "
                          f"round {self.view.round} of {self.view.rounds}",
                "cycles": self.view.rounds, "player": self.pid, "adapt": "",  # blind
                "hz": self.player.hz, "speed": self.player.speed, "scene": scene(self.world),
                "next": f"/p/{self.pid}"}

    # -- life cycle ---------------------------------------------------------------------------
    @property
    def open(self) -> bool:
        """Still playable: not stored, not failed."""
        return not self.stored and self.error is None

    def start(self) -> None:
        """Start the tick and the waiter on the running event loop."""
        self._tasks = [asyncio.create_task(self.hub.tick_loop()),
                       asyncio.create_task(self._wait())]

    async def close(self, reason: str | None = None) -> None:
        """Stop ticking and waiting; a round not yet stored is dropped (nothing stored).
        reason: told to a page still connected, which then stops (none when the server stops:
        the page reconnects to the restarted one)."""
        conn = self.hub.conn
        if reason is not None and conn is not None:
            with contextlib.suppress(Exception):
                await refuse_socket(conn.ws, reason)
        self.player.close()  # wakes a wait for the comfort answer
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

    async def _wait(self) -> None:
        try:
            observed, dep = await self._played()
            said = await self._said()
        except Exception as exc:
            log.exception("the game round of %s failed", self.pid)
            self.error = f"{type(exc).__name__}: {exc}"
            return
        t0 = time.perf_counter()
        pid, token = self.pid, self.token
        try:
            await self.worker.call(lambda s: s.submit_round(pid, token, "game", said,
                                                            played=observed, live=dep))
        except OutOfTurn as exc:
            self.error = str(exc)
            return
        except RapiddsError as exc:
            self.error = f"the round was not recorded: {exc}"
            return
        except Exception as exc:
            log.exception("recording the game round of %s failed", pid)
            self.error = f"the round was not recorded ({type(exc).__name__}: {exc})"
            return
        self.timing["record"] = time.perf_counter() - t0
        self.stored = 1
        t1 = time.perf_counter()
        with contextlib.suppress(Exception):  # the next page plans (and reports) again
            await self.worker.call(lambda s: s.plan(pid))  # the next page's plan, right away
        self.timing["next_plan"] = time.perf_counter() - t1
        state = self.player.snapshot() or {}
        log.info("%s: %s recorded in %.2f s (game time %.1f s, cycle %s), next plan in %.2f s",
                 pid, token, self.timing["record"], state.get("t", 0.0),
                 "over" if state.get("over") else "still running", self.timing["next_plan"])


    async def _played(self) -> tuple[dict[str, HumanExecution] | None, Deployment | None]:
        """What the person did once they are done (planned: their tasks; the robot's part the
        run replays), or under reactive execution the whole live cycle once it is over."""
        cycle = self.plan.cycle
        if self.live is not None:
            while (dep := self.player.deployed(cycle)) is None:
                await asyncio.sleep(_POLL)
            return None, dep
        tasks = self.plan.best.schedule.tasks("human")
        while (observed := self.player.played(cycle, tasks)) is None:
            await asyncio.sleep(_POLL)
        return observed, None

    async def _said(self) -> dict[str, str]:
        """The comfort item's fields once the person has answered (none when not asked). The
        answer comes after the round is over; waiting for it takes a thread only then (the
        player's report blocks; :meth:`close` wakes it)."""
        if not self.player.ask_comfort:
            return {}
        said = await asyncio.to_thread(self.player.comfort_report, self.plan.cycle)
        assert said is not None  # asked: an answer, or PlayerGone
        answer, signals = said
        return {"comfort": str(answer), "too_close": ",".join(f"{t:.6f}" for t in signals)}


async def open_round(worker: StudyWorker, world: BrowserPlay, pid: str,
                     token: str) -> GameRound:
    """A started :class:`GameRound` of ``pid``'s current round ``token``, made in the study
    worker from the plan the round page shows (:meth:`StudySession.plan`)."""
    def make(s: StudySession) -> GameRound:
        step = s.next_step(pid)
        held = s.plan(pid)
        if held is None or step_token(step) != token:
            raise OutOfTurn(f"{pid}'s next step is {step.describe()}, not this round: reload "
                            f"/p/{pid}", step)
        return GameRound(worker, world, pid, token, *held, ask_comfort=s.store.design.comfort,
                         live=s.live_executor(pid))

    game = await worker.call(make)
    game.start()
    return game
