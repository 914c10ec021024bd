"""The person in the browser as a :class:`~rapidds.worlds.base.Teammate` of the adaptive loop.

A :class:`BrowserPlayer` sits between two threads:

* the loop's thread (``AdaptiveRun.step()``, the study harness, :mod:`rapidds.web.session`)
  calls :meth:`~BrowserPlayer.show` with each cycle's plan (the loop does it, through
  :class:`rapidds.loop.run.LiveTeammate`) and then :meth:`~BrowserPlayer.execute`, which blocks
  until the person has done their tasks and returns what they did;
* the screen's thread (the server's event loop) calls :meth:`~BrowserPlayer.start`,
  :meth:`~BrowserPlayer.steer` and :meth:`~BrowserPlayer.tick` and reads
  :meth:`~BrowserPlayer.snapshot`.

``execute`` returns as soon as the person's last task is done, while the robot may still be
finishing its own: the loop can learn, store the cycle and plan the next one while the robot
finishes and the summary shows. The live game goes on meanwhile; its timeline is the one the loop
rebuilds from the returned durations, so nothing the loop stores depends on the rest.

Asked about their comfort (``ask_comfort``: ``rapidds play --gamma learn`` or ``--ask-comfort``),
the person answers once the cycle is over (agreement with "the robot came too close to me",
1-7), and the "too close" signals they gave during it go with the answer: the loop's learn step
(:meth:`~BrowserPlayer.comfort_report`) waits for it, so the next cycle is planned with a belief
that has this cycle's whole evidence (the planning no longer overlaps the summary screen then).

Under ``--execution reactive`` the loop calls :meth:`~BrowserPlayer.play` instead: the game's
robot is driven live by the loop's executor (:mod:`rapidds.web.reactive`), and the loop gets the
whole cycle, robot included, once it is over.

A plan shown while the previous cycle is still on screen waits until that cycle is over. When
the person leaves mid-cycle (closes the tab), :meth:`~BrowserPlayer.restart` puts the cycle back
to its start, so a reconnecting browser plays it again: at most the cycle in progress is lost.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import numpy as np

from rapidds.errors import RapiddsError
from rapidds.web.game import HUMAN_SPEED, FetchGame
from rapidds.web.reactive import ReactiveFetchGame
from rapidds.worlds.base import HumanExecution
from rapidds.worlds.capabilities import BrowserPlay

if TYPE_CHECKING:
    from rapidds.execution import CycleExecutor, Deployment, HumanSource
    from rapidds.loop.run import CyclePlan

__all__ = ["BrowserPlayer", "Phase", "PlayerGone"]

Phase = Literal["waiting", "ready", "playing", "over"]
_T = TypeVar("_T")


class PlayerGone(RapiddsError):
    """The game was closed before the person finished the cycle (the server is stopping)."""


class _Shown:
    """A plan made playable: its game and what the page draws of it. ``build``: the executor
    that drives a reactive game's robot (None: the planned game)."""

    def __init__(self, player: BrowserPlayer, plan: CyclePlan,
                 build: Callable[[HumanSource], CycleExecutor] | None = None):
        best = plan.best
        self.plan, self.build = plan, build
        self.game = player.new_game(plan, build)
        idx = player.problem.index
        expected = {t: (float(best.expected_start[idx[t]]), float(best.expected_finish[idx[t]]))
                    for t in player.problem.ids} if len(best.expected_start) else {}
        routes = {j: player.world.motion_label(j, np.asarray(p.trajectory))
                  for j, p in best.motions.items() if p.trajectory is not None}
        self.view = self.game.plan_view(expected, routes, best.makespan_mean)
        self.reported = False
        self.answer: int | None = None


class BrowserPlayer:
    """A person playing the fetch game in a browser: the loop's teammate (``name`` is what the
    run records as its human) and the holder of the live game the server ticks.

    hz: game ticks per second. speed: the avatar's speed, m/s. ask_comfort: ask the comfort
    question after every cycle (else :meth:`comfort_report` says the person was not asked).
    """

    def __init__(self, world: BrowserPlay, name: str = "player", *, hz: int = 60,
                 speed: float = HUMAN_SPEED, ask_comfort: bool = False):
        self.world = world
        self.problem = world.problem()
        self._name = name
        self.hz, self.speed, self.ask_comfort = hz, speed, ask_comfort
        self._lock = threading.Lock()
        self._shown: _Shown | None = None
        self._next: _Shown | None = None
        self._observed: queue.Queue[tuple[int, dict[str, HumanExecution]]] = queue.Queue()
        self._deployed: queue.Queue[tuple[int, ReactiveFetchGame]] = queue.Queue()
        self._answers: queue.Queue[tuple[int, tuple[int, list[float]]]] = queue.Queue()
        self._closed = threading.Event()
        self._orders: dict[int, list[str]] = {}  # cycle -> the order the person fetched in
        self.plan_version = 0  # bumped whenever another plan comes on screen

    @property
    def name(self) -> str:
        return self._name

    def new_game(self, plan: CyclePlan,
                 build: Callable[[HumanSource], CycleExecutor] | None = None) -> FetchGame:
        """The game of ``plan``: the planned one (the robot follows its plan, the loop replays
        what the person did), or with ``build`` the reactive one (:mod:`rapidds.web.reactive`)."""
        if build is None:
            return FetchGame(self.world, self.problem, plan.best.schedule, plan.best.motions,
                             cycle=plan.cycle, hz=self.hz, speed=self.speed)
        return ReactiveFetchGame(self.world, self.problem, plan.best.schedule,
                                 plan.best.motions, build, cycle=plan.cycle, hz=self.hz,
                                 speed=self.speed)

    # -- the loop's side ----------------------------------------------------------------------
    def show(self, plan: CyclePlan) -> None:
        """Put ``plan`` on screen, or queue it until the cycle on screen is over."""
        self._show(_Shown(self, plan))

    def play(self, plan: CyclePlan,
             executor: Callable[[HumanSource], CycleExecutor]) -> Deployment:
        """Show ``plan`` with a robot that reacts live (driven by the executor ``executor``
        builds around the avatar) and block until the cycle is over, robot included; what
        happened. Raises :class:`PlayerGone` when :meth:`close` is called first."""
        self.show_live(plan, executor)
        game = self._wait(self._deployed, plan.cycle, "the cycle was played")
        return game.deployment()  # over: nothing moves it any more, so read it here

    def show_live(self, plan: CyclePlan,
                  executor: Callable[[HumanSource], CycleExecutor]) -> None:
        """:meth:`play` without waiting: put ``plan`` on screen with the reactive robot; the
        cycle comes back from :meth:`deployed` once it is over."""
        self._show(_Shown(self, plan, executor))

    def deployed(self, cycle: int) -> Deployment | None:
        """What :meth:`play` returns, without blocking: the whole of live cycle ``cycle`` once
        it is over, else None (for a caller on an event loop: the study's game rounds)."""
        game = self._take(self._deployed, cycle)
        return None if game is None else game.deployment()

    def _wait(self, q: queue.Queue[tuple[int, _T]], cycle: int, what: str) -> _T:
        """The next item ``q`` gets for ``cycle`` (an item of another cycle is stale: that
        cycle restarted after it was reported); :class:`PlayerGone` when :meth:`close` is
        called first."""
        while True:
            if self._closed.is_set():
                raise PlayerGone(f"the game was closed before {what}")
            try:
                c, item = q.get(timeout=0.05)
            except queue.Empty:
                continue
            if c == cycle:
                return item

    def _show(self, shown: _Shown) -> None:
        with self._lock:
            cur = self._shown
            if cur is None or cur.game.over or not cur.game.started:
                self._put_on_screen(shown)
            else:
                self._next = shown

    def execute(self, cycle: int, tasks: Sequence[str],
                rng: np.random.Generator) -> dict[str, HumanExecution]:
        """Block until the person has done ``tasks`` of cycle ``cycle``; what they did.
        Raises :class:`PlayerGone` when :meth:`close` is called first."""
        obs = self._wait(self._observed, cycle, "the cycle was played")
        return self._checked(cycle, tasks, obs)

    def played(self, cycle: int, tasks: Sequence[str]) -> dict[str, HumanExecution] | None:
        """:meth:`execute` without blocking: what the person did in ``cycle`` once they have
        done ``tasks``, else None (for a caller on an event loop: the study's game rounds)."""
        obs = self._take(self._observed, cycle)
        return None if obs is None else self._checked(cycle, tasks, obs)

    @staticmethod
    def _take(q: queue.Queue[tuple[int, _T]], cycle: int) -> _T | None:
        """:meth:`_wait` without blocking: the item ``q`` holds for ``cycle``, else None."""
        while True:
            try:
                c, item = q.get_nowait()
            except queue.Empty:
                return None
            if c == cycle:
                return item

    def played_order(self, cycle: int) -> list[str] | None:
        """The person's tasks of cycle ``cycle`` in the order they fetched them (any order
        precedence allows); None before they have done them."""
        with self._lock:
            order = self._orders.get(cycle)
            return None if order is None else list(order)

    def comfort_report(self, cycle: int) -> tuple[int, list[float]] | None:
        """What the person said about cycle ``cycle``: (their answer 1-7, the game times of
        their "too close" signals); blocks until they have answered. None when they are not
        asked. Raises :class:`PlayerGone` when :meth:`close` is called first."""
        if not self.ask_comfort:
            return None
        return self._wait(self._answers, cycle, "the comfort question was answered")

    @staticmethod
    def _checked(cycle: int, tasks: Sequence[str],
                 obs: dict[str, HumanExecution]) -> dict[str, HumanExecution]:
        if set(obs) != set(tasks):
            raise RuntimeError(f"cycle {cycle}: played tasks {sorted(obs)}, the plan gave "
                               f"the person {sorted(tasks)}")
        return obs

    def close(self) -> None:
        """Wake a blocked :meth:`execute` with :class:`PlayerGone` (the server is stopping)."""
        self._closed.set()

    # -- the screen's side --------------------------------------------------------------------
    def _put_on_screen(self, shown: _Shown) -> None:
        self._shown, self._next = shown, None
        self.plan_version += 1

    @property
    def phase(self) -> Phase:
        with self._lock:
            return self._phase()

    def _phase(self) -> Phase:
        if self._shown is None:
            return "waiting"
        g = self._shown.game
        if not g.started:
            return "ready"
        return "over" if g.over else "playing"

    @property
    def cycle(self) -> int | None:
        """The cycle on screen."""
        with self._lock:
            return None if self._shown is None else self._shown.game.cycle

    def plan_view(self) -> dict[str, Any] | None:
        with self._lock:
            return None if self._shown is None else self._shown.view

    def start(self, cycle: int) -> bool:
        """Start the clock of cycle ``cycle``; False unless it is on screen and not started."""
        with self._lock:
            if self._phase() != "ready" or self._shown is None \
                    or self._shown.game.cycle != cycle:
                return False
            self._shown.game.start()
            self._report()
            return True

    def steer(self, move: tuple[int, int] | None = None,
              target: tuple[float, float] | None = None) -> None:
        with self._lock:
            if self._shown is not None:
                self._shown.game.steer(move, target)

    def too_close(self, cycle: int) -> bool:
        """The person says the robot is too close now, in cycle ``cycle``; False (not kept)
        unless that cycle is on screen and under way."""
        with self._lock:
            s = self._shown
            return s is not None and s.game.cycle == cycle and s.game.signal_too_close()

    def answer(self, cycle: int, answer: int) -> bool:
        """The person's comfort answer (1-7) about cycle ``cycle``: handed to the loop with the
        cycle's signals. False unless asked, that cycle is on screen and over, and unanswered."""
        if answer not in range(1, 8):
            raise ValueError(f"a comfort answer is 1..7, got {answer}")
        with self._lock:
            s = self._shown
            if not self._asking(s) or s is None or s.game.cycle != cycle:
                return False
            s.answer = answer
            self._answers.put((cycle, (answer, list(s.game.too_close))))
            return True

    def _asking(self, s: _Shown | None) -> bool:
        """Whether the page should ask the comfort question about the cycle on screen now."""
        return (self.ask_comfort and s is not None and s.game.over and s.reported
                and s.answer is None)

    def _state(self) -> dict[str, Any] | None:
        s = self._shown
        if s is None:
            return None
        return {**s.game.state(), "ask": self._asking(s)}

    def tick(self) -> dict[str, Any] | None:
        """Advance the game one tick; the state to send (None before any plan)."""
        with self._lock:
            if self._shown is None:
                return None
            if self._shown.game.over and self._next is not None:
                # one tick late, so the page has had the finished cycle's last state
                self._put_on_screen(self._next)
            self._shown.game.step()
            self._report()
            return self._state()

    def snapshot(self) -> dict[str, Any] | None:
        with self._lock:
            return self._state()

    def restart(self) -> bool:
        """The person left: put a cycle in progress back to its start (not one whose tasks the
        loop already has). True when a cycle was restarted."""
        with self._lock:
            s = self._shown
            if s is None or not s.game.started or s.reported:
                return False
            s.game = self.new_game(s.plan, s.build)
            self.plan_version += 1
            return True

    def _report(self) -> None:
        s = self._shown
        if s is None or s.reported:
            return
        if isinstance(s.game, ReactiveFetchGame):  # the loop takes the whole cycle, robot too
            if s.game.over:
                s.reported = True
                self._orders[s.game.cycle] = list(s.game.order)
                self._deployed.put((s.game.cycle, s.game))
            return
        if s.game.human_done:
            s.reported = True
            self._orders[s.game.cycle] = list(s.game.order)
            self._observed.put((s.game.cycle, s.game.observations()))
