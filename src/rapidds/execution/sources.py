"""Sources: what feeds the executor each agent's side of a cycle.

A :class:`HumanSource` is the person: it says which task they start when they may start one,
moves their body points as time passes and says when a task ended. A :class:`RobotSource` is the
robot: it follows a trajectory per task at the rate the policies allow. The simulated ones here
run a simulated teammate and the planned, steered trajectories; the browser game, a study page
or a ROS 2 link implement the same few methods with what they observe (a live source reports
``inf`` from ``next_event`` and answers ``advance`` from the events that arrived meanwhile).

Time is in seconds from the cycle's start; points are (K, d_ws) workspace coordinates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from rapidds.execution.policies import separation
from rapidds.motion.interface import MotionPlan
from rapidds.worlds.base import HumanExecution, World, body_points
from rapidds.worlds.reactions import Deviation, Reaction

__all__ = ["HumanSource", "PlannedRobot", "Progress", "RobotSource", "RobotView",
           "SimulatedHuman", "SteerableRobot"]


@dataclass(frozen=True)
class RobotView:
    """What a person sees of the robot at one instant: its body points (P, d_ws) and whether
    it is moving."""

    points: np.ndarray
    moving: bool


@runtime_checkable
class HumanSource(Protocol):
    """The person's side of a cycle, as the executor asks for it (see the module docstring)."""

    def choose(self, now: float, planned: str | None, ready: Sequence[str],
               takeable: Sequence[str]) -> str | None:
        """The task the person starts at ``now``: the plan's next (``planned``, None when it
        cannot start yet), another of their ``ready`` tasks, or None (not now); or one of the
        robot's ``takeable`` tasks (not started, a person may do them), which they claim: they
        start it now if its predecessors are done, else as soon as they are."""
        ...

    def start(self, task: str, now: float) -> None:
        """The person started ``task`` at ``now``."""
        ...

    def next_event(self, now: float, robot: RobotView) -> float:
        """When the running task ends or the person's pace changes if nothing else does (inf:
        unknown, idle, or paused)."""
        ...

    def advance(self, now: float, until: float, robot: RobotView) -> str | None:
        """Time moves from ``now`` to ``until``; the task that ended at ``until``, if any."""
        ...

    def points(self) -> np.ndarray:
        """(K, d_ws) where the person's body points are now."""
        ...

    def observed(self) -> dict[str, HumanExecution]:
        """What the person did for each task they finished (durations, paths at the world's dt)."""
        ...


@runtime_checkable
class RobotSource(Protocol):
    """The robot's side of a cycle: one trajectory per task, followed at a rate in [0, 1]."""

    def start(self, task: str, now: float) -> None: ...

    def next_event(self, now: float, rate: float) -> float:
        """When the running task ends at ``rate`` (inf when idle or stopped)."""
        ...

    def advance(self, now: float, until: float, rate: float) -> str | None:
        """Time moves on at ``rate``; the task that ended at ``until``, if any."""
        ...

    def points(self) -> np.ndarray:
        """(P, d_ws) the robot's body points now."""
        ...

    def speed(self) -> float:
        """The fastest of its body points' speeds at full rate where it is now (units / s)."""
        ...

    def velocity(self) -> np.ndarray:
        """(P, d_ws) its body points' velocities at full rate where it is now (units / s)."""
        ...

    def realised(self) -> dict[str, np.ndarray]:
        """Per finished task the trajectory (H', d) it followed, row k at k * dt."""
        ...


@runtime_checkable
class SteerableRobot(RobotSource, Protocol):
    """A robot source that can be given another motion for a task it has not started (a
    re-plan steered it for the person's tasks now expected beside it)."""

    def follow(self, plan: MotionPlan) -> None: ...


class Progress:
    """One running task: how far along its nominal timing it is. ``lost`` is the time it was
    held back (slowed or paused), so an undisturbed task ends exactly at start + duration, as
    the open-loop replay has it."""

    def __init__(self, task: str, start: float, duration: float):
        self.task, self.start, self.duration = task, start, duration
        self.lost = 0.0
        self.knots: list[tuple[float, float]] = [(start, 0.0)]

    def at(self, now: float) -> float:
        return now - self.start - self.lost

    def end(self, now: float, pace: float) -> float:
        if pace >= 1.0:
            return self.start + self.lost + self.duration
        if pace <= 0.0:
            return math.inf
        return now + (self.duration - self.at(now)) / pace

    def advance(self, now: float, until: float, pace: float) -> bool:
        """Move on; True when the task is done at ``until``."""
        if pace < 1.0:
            self.lost += (1.0 - pace) * (until - now)
        self.knots.append((until, self.at(until)))
        return self.at(until) >= self.duration - 1e-9

    def rows(self, n: int, dt: float, rows: int) -> np.ndarray:
        """Indices into the nominal path (``rows`` long) of its n samples at k * dt."""
        t, p = np.array(self.knots).T
        progress = np.interp(self.start + np.minimum(np.arange(n) * dt, t[-1] - self.start), t, p)
        return np.clip(np.round(progress / dt).astype(int), 0, rows - 1)


@dataclass
class PlannedRobot:
    """The robot follows the plan's steered trajectories, at the rate the policies allow."""

    world: World
    motions: Mapping[str, MotionPlan]
    _run: Progress | None = None
    _points: dict[str, np.ndarray] = field(default_factory=dict)
    _speed: dict[str, np.ndarray] = field(default_factory=dict)
    _velocity: dict[str, np.ndarray] = field(default_factory=dict)
    _done: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for m in self.motions.values():
            self._prepare(m)
        self._rest = self.world.robot_points(np.asarray(self.world.robot_rest(), float)[None])[0]

    def _prepare(self, m: MotionPlan) -> None:
        """Body points and speeds along a motion's trajectory, for the watching executor."""
        if m.trajectory is None:
            return
        pts = self.world.robot_points(np.asarray(m.trajectory, float))  # (H, P, d_ws)
        self._points[m.task] = pts
        step = np.diff(pts, axis=0)
        self._speed[m.task] = np.append(np.linalg.norm(step, axis=-1).max(axis=-1)
                                        / self.world.dt, 0.0)
        # row k: on to row k + 1, as the robot goes on from k
        self._velocity[m.task] = np.concatenate([step, np.zeros_like(pts[:1])]) / self.world.dt

    def follow(self, plan: MotionPlan) -> None:
        """Do ``plan.task`` with ``plan`` (the task has not started)."""
        if plan.task in self._done or (self._run is not None and self._run.task == plan.task):
            raise ValueError(f"the robot already started '{plan.task}'")
        self.motions = {**self.motions, plan.task: plan}
        self._points.pop(plan.task, None)
        self._speed.pop(plan.task, None)
        self._velocity.pop(plan.task, None)
        self._prepare(plan)

    def start(self, task: str, now: float) -> None:
        self._run = Progress(task, now, self.motions[task].duration)

    def next_event(self, now: float, rate: float) -> float:
        return math.inf if self._run is None else self._run.end(now, rate)

    def advance(self, now: float, until: float, rate: float) -> str | None:
        run = self._run
        if run is None or not run.advance(now, until, rate):
            return None
        traj = self.motions[run.task].trajectory
        if traj is not None:
            traj = np.asarray(traj, float)
            if run.lost == 0.0:
                self._done[run.task] = traj
            else:  # held back: the rows it was at, every dt, then the rest of its trajectory
                n = math.ceil((until - run.start) / self.world.dt - 1e-9) + 1
                rows = run.rows(n, self.world.dt, len(traj))
                self._done[run.task] = np.concatenate([traj[rows], traj[rows[-1] + 1:]])
        self._run = None
        return run.task

    def progress(self) -> tuple[str, float] | None:
        """The running task and how far along its nominal timing it is (s) as of the last
        instant run; None when idle. What a live page draws the robot from, between rows."""
        run = self._run
        return None if run is None else (run.task, max(run.at(run.knots[-1][0]), 0.0))

    def _row(self) -> tuple[str, int] | None:
        run = self._run
        if run is None or run.task not in self._points:
            return None
        k = round(max(run.at(run.knots[-1][0]), 0.0) / self.world.dt)
        return run.task, min(k, len(self._points[run.task]) - 1)

    def points(self) -> np.ndarray:
        at = self._row()
        return self._rest if at is None else self._points[at[0]][at[1]]

    def speed(self) -> float:
        at = self._row()
        return 0.0 if at is None else float(self._speed[at[0]][at[1]])

    def velocity(self) -> np.ndarray:
        at = self._row()
        return np.zeros_like(self._rest) if at is None else self._velocity[at[0]][at[1]]

    def realised(self) -> dict[str, np.ndarray]:
        return dict(self._done)


class SimulatedHuman:
    """A simulated teammate fed to the executor. ``executions`` are what they were going to do
    for each planned task (drawn as the open-loop replay draws them, so an undisturbed person
    does exactly that); ``perform`` draws a task they take on the spot. ``reaction``: how they
    react to the robot (None: they do not); ``deviation``: how they deviate this cycle."""

    def __init__(self, world: World, executions: Mapping[str, HumanExecution],
                 perform: Any, reaction: Reaction | None = None,
                 deviation: Deviation | None = None, order: Sequence[str] | None = None):
        self.world, self._plan = world, dict(executions)
        # a live person's tasks in the order they did them: replayed whatever the plan said
        self._order = None if order is None else list(order)
        self._perform, self.reaction, self.deviation = perform, reaction, deviation
        self._rest = np.asarray(world.human_rest(), float)
        self._run: Progress | None = None
        self._path: np.ndarray | None = None
        self._pace = 1.0
        self._done: dict[str, HumanExecution] = {}
        self._started = 0
        self._deviated = False
        self.pauses: list[tuple[float, float, str, str]] = []  # (start, end, task, reason)
        self._paused_since: tuple[float, str] | None = None
        self._pause_left = 0.0

    # -- choice -------------------------------------------------------------------------------
    def choose(self, now: float, planned: str | None, ready: Sequence[str],
               takeable: Sequence[str]) -> str | None:
        if self._order is not None:  # the next they took, once it may start
            nxt = self._order[self._started] if self._started < len(self._order) else None
            return nxt if nxt in ready else None
        dev = self.deviation
        if dev is not None and not self._deviated:
            if dev.kind == "take" and takeable:
                self._deviated = True
                return takeable[int(dev.pick * len(takeable))]
            others = [t for t in ready if t != planned]
            if dev.kind == "order" and planned is not None and others:
                self._deviated = True
                return others[int(dev.pick * len(others))]
        return planned

    def start(self, task: str, now: float) -> None:
        ex = self._plan.get(task)
        if ex is None:  # a task they took on: drawn now
            d, path = self._perform(task)
            ex = self._plan[task] = HumanExecution(task, float(d), np.asarray(path, float))
        self._run, self._path = Progress(task, now, ex.duration), body_points(ex.trajectory)
        dev = self.deviation
        if (dev is not None and dev.kind == "pause" and not self._deviated
                and dev.task % max(len(self._plan), 1) == self._started):
            self._deviated = True
            self._pause_left = dev.seconds
        self._started += 1

    # -- time ---------------------------------------------------------------------------------
    def _pace_now(self, robot: RobotView) -> tuple[float, str]:
        run = self._run
        assert run is not None
        if self._pause_left > 0 and self._to_pause(run, run.knots[-1][0]) <= 1e-9:
            return 0.0, "deviation"
        if self.reaction is None:
            return 1.0, ""
        pace = self.reaction.pace(separation(self.points(), robot.points), robot.moving)
        return pace, ("robot within stop distance" if pace == 0.0 else "robot within comfort")

    def next_event(self, now: float, robot: RobotView) -> float:
        run = self._run
        if run is None:
            return math.inf
        self._pace, reason = self._pace_now(robot)
        if reason == "deviation":
            return now + self._pause_left
        end = run.end(now, self._pace)
        if self._pause_left > 0 and self._pace > 0:
            end = min(end, now + self._to_pause(run, now) / self._pace)
        return end

    def _to_pause(self, run: Progress, now: float) -> float:
        """Progress (s) left before a deviation's pause starts in the running task."""
        assert self.deviation is not None
        return self.deviation.at * run.duration - run.at(now)

    def advance(self, now: float, until: float, robot: RobotView) -> str | None:
        run = self._run
        if run is None:
            return None
        pace, reason = self._pace_now(robot)
        if reason == "deviation":
            left = self._pause_left - (until - now)
            self._pause_left = left if left > 1e-9 else 0.0  # not a sliver time cannot reach
        self._log_pause(now, until, run.task, reason if pace < 1.0 else "")
        if not run.advance(now, until, pace):
            return None
        self._log_pause(until, until, run.task, "")
        ex = self._plan[run.task]
        if run.lost == 0.0:
            self._done[run.task] = ex
        else:
            dur = until - run.start
            n = math.ceil(dur / self.world.dt - 1e-9) + 1
            path = np.asarray(ex.trajectory, float)
            self._done[run.task] = HumanExecution(run.task, dur,
                                                  path[run.rows(n, self.world.dt, len(path))])
        self._run = self._path = None
        return run.task

    def _log_pause(self, now: float, until: float, task: str, reason: str) -> None:
        """Merge held-back intervals of one reason into one pause entry."""
        if self._paused_since is not None and self._paused_since[1] != reason:
            since, why = self._paused_since
            self.pauses.append((since, now, task, why))
            self._paused_since = None
        if reason and self._paused_since is None:
            self._paused_since = (now, reason)

    def points(self) -> np.ndarray:
        run, path = self._run, self._path
        if run is None or path is None:
            return self._rest
        k = round(max(run.at(run.knots[-1][0]), 0.0) / self.world.dt)
        return path[min(k, len(path) - 1)]

    def observed(self) -> dict[str, HumanExecution]:
        return dict(self._done)
