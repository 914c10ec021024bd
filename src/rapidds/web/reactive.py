"""The browser game with a robot that reacts live: the loop's executor drives the robot.

Under ``rapidds play --execution reactive`` a cycle runs on the loop's
:class:`~rapidds.execution.CycleExecutor`, stepped once per game tick
(:meth:`~rapidds.execution.CycleExecutor.advance_to` the tick's time): the same event loop a
simulated reactive cycle runs in one call. The person is an :class:`AvatarHuman`: their body
point is the avatar (interpolated between ticks), a task starts when they pick its object up and
ends when they are back home. So the robot monitors speed and separation against the avatar at
every watched instant (it slows, stops and resumes; its trajectory advances at the policy's
rate) and re-plans the rest of the cycle when the person deviates: picks up another object than
the plan's next, takes a robot task (one the robot has not started and a person may do), or
overruns. Open to the person are their own objects whose predecessors are done and the robot's
that it has not started, that a person may do and whose predecessors are done.

Times: the executor learns of a task when its object is picked up, but the record gives the
task the start the planned game gives it (when the person became free and its predecessors were
done, the latest of these), so a duration means the same in both modes (out and back) and the
loop learns the same quantity from either. The timeline, the person's paths and the realised
costs are rebuilt with those starts (:meth:`ReactiveFetchGame.deployment`); the robot's times,
its pauses and the re-plans are the executor's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from rapidds.execution import CycleExecutor, Deployment, HumanSource, PlannedRobot, RobotView
from rapidds.execution.deployment import realise
from rapidds.motion.interface import MotionPlan
from rapidds.problem import Agent, Problem
from rapidds.schedule import Schedule, Timeline, Wait
from rapidds.web.game import HUMAN_SPEED, FetchGame, TaskStatus, along
from rapidds.worlds.base import HumanExecution, body_points
from rapidds.worlds.capabilities import BrowserPlay

__all__ = ["AvatarHuman", "ReactiveFetchGame"]

_EPS = 1e-9


class AvatarHuman:
    """The person as the browser game observes them, a
    :class:`~rapidds.execution.HumanSource`: the game reports where the avatar is at each
    tick (:meth:`moved`), which object it picked up (:meth:`pick`) and when it was back home
    with it (:meth:`deliver`); the executor reads them at its own instants."""

    def __init__(self, world: BrowserPlay):
        home = world.home("human").astype(float)
        self._was: tuple[float, np.ndarray] = (0.0, home)
        self._is: tuple[float, np.ndarray] = (0.0, home)
        self._clock = 0.0  # the executor's time as of its last advance
        self._picked: tuple[str, float] | None = None  # not yet handed to the executor
        self._end: tuple[str, float] | None = None
        self.dropped: str | None = None  # a pick-up the executor refused (the robot took it)
        self._observed: dict[str, HumanExecution] = {}

    # -- the game's side ----------------------------------------------------------------------
    def moved(self, t: float, pos: np.ndarray) -> None:
        self._was, self._is = self._is, (t, np.array(pos, float))

    def pick(self, task: str, t: float) -> None:
        self._picked = (task, t)

    def deliver(self, task: str, t: float) -> None:
        self._end = (task, t)

    def observe(self, executions: Mapping[str, HumanExecution]) -> None:
        """What the person did, as the game measured it (read by the executor's result)."""
        self._observed = dict(executions)

    # -- the executor's side ------------------------------------------------------------------
    def choose(self, now: float, planned: str | None, ready: Sequence[str],
               takeable: Sequence[str]) -> str | None:
        if self._picked is None or self._picked[1] > now + _EPS:
            return None  # nothing picked up, or not by this instant
        task, self._picked = self._picked[0], None
        if task in ready or task in takeable:
            return task
        self.dropped = task
        return None

    def start(self, task: str, now: float) -> None:
        pass  # the game knows: the object is in the avatar's hands

    def next_event(self, now: float, robot: RobotView) -> float:
        return self._end[1] if self._end is not None else math.inf

    def advance(self, now: float, until: float, robot: RobotView) -> str | None:
        self._clock = until
        if self._end is not None and self._end[1] <= until + _EPS:
            task, self._end = self._end[0], None
            return task
        return None

    def points(self) -> np.ndarray:
        (t0, p0), (t1, p1) = self._was, self._is
        a = 1.0 if t1 - t0 <= _EPS else float(np.clip((self._clock - t0) / (t1 - t0), 0, 1))
        return body_points(((1 - a) * p0 + a * p1)[None])[0]

    def observed(self) -> dict[str, HumanExecution]:
        return dict(self._observed)


class ReactiveFetchGame(FetchGame):
    """A :class:`~rapidds.web.game.FetchGame` whose robot is driven by the executor that
    ``build`` makes around the avatar (see the module docstring). ``motions``: the plan's
    robot motions (drawn as the plan); the executor's robot has the spare ones too."""

    def __init__(self, world: BrowserPlay, problem: Problem, schedule: Schedule,
                 motions: Mapping[str, MotionPlan],
                 build: Callable[[HumanSource], CycleExecutor], *, cycle: int = 0,
                 hz: int = 60, speed: float = HUMAN_SPEED):
        super().__init__(world, problem, schedule, motions, cycle=cycle, hz=hz, speed=speed)
        self.person = AvatarHuman(world)
        self.executor = build(self.person)
        robot = self.executor.robot
        if not isinstance(robot, PlannedRobot):
            raise TypeError("the live game draws a robot that follows planned trajectories")
        self._robot = robot
        self._robot_pick = {j: self._robot_reach(j) for j, m in robot.motions.items()
                            if m.trajectory is not None}
        self._carrying: str | None = None

    def _robot_reach(self, task: str) -> float | None:
        """When the robot comes within reach of ``task``'s object (s along its motion)."""
        traj = np.asarray(self._robot.motions[task].trajectory, dtype=float)
        near = np.linalg.norm(traj - self.world.object_position(task), axis=-1)
        hit = near <= self.world.reach_radius
        return float(np.argmax(hit)) * self.world.dt if hit.any() else None

    # -- time ---------------------------------------------------------------------------------
    @property
    def human_done(self) -> bool:
        return self.started and self.current("human") is None

    @property
    def over(self) -> bool:
        return self.started and self.executor.over

    def start(self) -> None:
        self.started = True

    def step(self) -> None:
        """One tick: the avatar walks, picks up or delivers, the executor runs up to now."""
        if not self.started or self.over:
            return
        self.tick += 1
        self._walk()
        now = self.now
        self._times.append(now)
        self._trace.append(self.pos.copy())
        self.person.moved(now, self.pos)
        self._fetch(now)
        self.executor.advance_to(now)
        if self.person.dropped is not None:  # the robot started it at that very instant
            task, self.person.dropped = self.person.dropped, None
            self.order.remove(task)
            del self.start_time[task], self._picked[task]
            self._carrying = None
        ex = self.executor
        self.start_time.update({t: s for t, s in ex.start.items() if ex.doer[t] == "robot"})
        self.finish_time.update(ex.finish)

    def _fetch(self, now: float) -> None:
        """Pick up the closest open object within reach, or deliver the one carried home."""
        r, ex = self.world.reach_radius, self.executor
        if self._carrying is None:
            near = [t for t in self._open() if
                    np.linalg.norm(self.pos - self.world.object_position(t)) <= r]
            if not near:
                return
            task = min(near, key=lambda t: float(
                np.linalg.norm(self.pos - self.world.object_position(t))))
            free = max((f for t, f in ex.finish.items() if ex.doer[t] == "human"), default=0.0)
            self.start_time[task] = max([free, *(ex.finish[p]
                                                 for p in self.problem.preceding[task])])
            self._picked[task], self._carrying = now, task
            self.order.append(task)
            self.person.pick(task, now)
        elif (self._carrying in ex.start
              and np.linalg.norm(self.pos - self.world.home("human")) <= r):
            self.person.deliver(self._carrying, now)
            self._carrying = None

    # -- what the person may do ---------------------------------------------------------------
    def _gated(self, task: str) -> bool:
        return all(p in self.executor.finish for p in self.problem.preceding[task])

    def _left(self, agent: Agent) -> list[str]:
        ex = self.executor
        return [t for t in ex.queue[agent] if isinstance(t, str) and t not in ex.start]

    def _free(self) -> bool:
        return self._carrying is None and self.executor.running["human"] is None

    def takeable(self) -> list[str]:
        """The robot's tasks the person may pick up now: not started, a person may do them,
        their predecessors done."""
        if not self._free():
            return []
        return [t for t in self._left("robot")
                if self.problem.task(t).can("human") and self._gated(t)]

    def _open(self) -> list[str]:
        if not self._free():
            return []
        return [t for t in self._left("human") if self._gated(t)] + self.takeable()

    # -- what the page shows ------------------------------------------------------------------
    def status(self, task: str) -> TaskStatus:
        ex = self.executor
        if task in ex.finish:
            return "done"
        if task == self._carrying or ex.doer.get(task) == "human":
            return "carried"
        if task in ex.start:  # the robot's, under way
            at, reach = self._robot.progress(), self._robot_pick.get(task)
            return ("carried" if at is not None and at[0] == task and reach is not None
                    and at[1] >= reach else "active")
        if task in self._left("human"):
            if not self._gated(task):
                return "locked"
            return "active" if self._free() else "queued"
        q = ex.queue["robot"]
        waits = [x.task for x in q[:q.index(task)] if isinstance(x, Wait)] if task in q else []
        return ("queued" if self._gated(task) and all(w in ex.finish for w in waits)
                else "locked")

    def current(self, agent: Agent) -> str | None:
        ex = self.executor
        if agent == "human" and self._carrying is not None:
            return self._carrying
        if ex.running[agent] is not None:
            return ex.running[agent]
        left = self._left(agent)
        return left[0] if left else None

    def robot_position(self) -> np.ndarray:
        at = self._robot.progress()
        if at is None:
            return self.world.robot_rest().astype(float)
        return along(self._robot.motions[at[0]].trajectory, at[1], self.world.dt)

    def robot_state(self) -> str:
        """idle, moving (full speed), slowed or stopped (speed and separation monitoring)."""
        ex = self.executor
        if ex.running["robot"] is None:
            return "idle"
        return "moving" if ex.rate >= 1.0 else "stopped" if ex.rate <= 0.0 else "slowed"

    def state(self) -> dict[str, Any]:
        ex = self.executor
        owner = {t: ex.doer.get(t) or ("human" if t in ex.queue["human"] else "robot")
                 for t in self.problem.ids}
        return {**super().state(), "execution": "reactive", "robot": self.robot_state(),
                "rate": round(ex.rate, 3), "takeable": self.takeable(), "owner": owner,
                "robot_next": self._left("robot"),
                "replans": [{"t": round(r["time"], 3), "reason": r["reason"], "task": r["task"],
                             "changed": r["changed"]} for r in ex.replans]}

    # -- what happened ------------------------------------------------------------------------
    def deployment(self) -> Deployment:
        """The cycle as it happened, once over: the executor's, with the person's tasks
        starting when the person set out for them (see the module docstring)."""
        obs = self.observations()
        self.person.observe(obs)
        dep = self.executor.result()
        tl, idx = dep.timeline, self.problem.index
        start = tl.start.copy()
        for t in obs:
            start[0, idx[t]] = self.start_time[t]
        again = realise(self.world, self.problem,
                        Timeline(self.problem, tl.schedule, start, tl.finish), obs, dep.robot,
                        beta=self.executor.beta)
        return dataclasses.replace(again, pauses=dep.pauses, replans=dep.replans,
                                   protective=dep.protective, yields=dep.yields)
