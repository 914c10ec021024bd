"""One cycle of the fetch world played live: a person steers an avatar, the robot follows its plan
(``--execution planned``; :mod:`rapidds.web.reactive` is the game whose robot reacts live).

The simulation is the server's; the browser only draws it and sends inputs. It advances in fixed
ticks of ``1 / hz`` seconds (game time is ``tick / hz``, so it does not depend on how late a
tick runs), with the world's own geometry and the timeline semantics of :mod:`rapidds.schedule`
evaluated as the cycle unfolds:

* An agent starts its next item when it is free, every precedence predecessor of that task has
  finished and, for a wait token, the waited task has finished. The start is the exact time the
  last of these happened (not the tick that noticed it), so the cycle's live timeline equals the
  timeline :func:`rapidds.loop.deploy.deploy` rebuilds from the observed durations.
* The person fetches their tasks in **any order precedence allows**: while they carry nothing,
  every one of their objects whose precedence predecessors are done is *open* (status
  ``active``) and the first they come within ``reach_radius`` of is picked up; the others are
  shown *locked*. The plan's order (and the waits in their sequence) is advice, not a lock. The
  task **starts** when the person became free and its predecessors were done (the latest of
  these), as a simulated person's would, and **ends** as in the simulated world: back within
  ``reach_radius`` of home. What they do between start and end is their path; :attr:`order`
  is the order they took, which the loop's executor replays (:mod:`rapidds.loop.execute`).
* A robot task plays its planned, steered trajectory row by row at the world's ``dt`` (linearly
  interpolated between rows for drawing) and finishes after the plan's completion time d_j^r.
  Afterwards the robot stays on that trajectory (which ends at home) until its next task.

Observed path of a human task: the avatar's position at ``start + min(k dt, duration)`` for
k = 0 .. ceil(duration / dt), interpolated between ticks: the same sampling as a simulated
teammate's (:meth:`rapidds.worlds.fetch.FetchTeammate.perform`).

Avatar physics: ``speed`` m/s (4.5 by default, a fast person: the fast archetypes walk 4.8) in the
direction of the held keys (8 directions) or straight towards a clicked target; a disc of
``AVATAR_RADIUS`` that cannot enter a wall or leave the map. A blocked move slides along the
wall (the blocked axis is dropped), so walking into a wall at an angle still makes progress.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from rapidds.loop.observation import Track, execution_of
from rapidds.motion.interface import MotionPlan
from rapidds.problem import AGENTS, Agent, Problem
from rapidds.schedule import Schedule, Wait, compile_schedule, item_json
from rapidds.worlds.base import HumanExecution
from rapidds.worlds.capabilities import BrowserPlay
from rapidds.worlds.geometry import segments_hit_rects

__all__ = ["AVATAR_RADIUS", "HUMAN_SPEED", "MAX_SIGNALS", "FetchGame", "TaskStatus", "along"]

HUMAN_SPEED = 4.5  # m/s
MAX_SIGNALS = 120  # "too close" signals kept per cycle: a stuck key cannot grow the record
AVATAR_RADIUS = 0.15  # m: how close the avatar's centre may come to a wall
_EPS = 1e-9

TaskStatus = Literal["locked", "queued", "active", "carried", "done"]


def _r(x: float) -> float:
    return round(float(x), 3)


def along(trajectory: Any, s: float, dt: float) -> np.ndarray:
    """Where a trajectory sampled every ``dt`` is ``s`` seconds along it: linear between its
    rows, held at its ends (what the page draws between ticks)."""
    traj = np.asarray(trajectory, dtype=float)
    u = s / dt
    k = int(np.clip(math.floor(u), 0, len(traj) - 1))
    a = float(np.clip(u - k, 0.0, 1.0))
    return (1 - a) * traj[k] + a * traj[min(k + 1, len(traj) - 1)]


@dataclass
class _Lane:
    """One agent's progress through its sequence."""

    items: tuple[str | Wait, ...]
    pos: int = 0
    free_at: float = 0.0  # when the agent became free (finish of its last task or wait)
    running: str | None = None
    last: str | None = None  # the task started last (the robot stays on its trajectory)


class FetchGame:
    """One live cycle of ``schedule`` in ``world``.

    motions: the plan's robot motion per robot task (trajectory (H, 2) at ``world.dt`` and its
    completion time). hz: ticks per second. speed: the avatar's speed, m/s.
    Call :meth:`start`, then :meth:`step` once per tick with :meth:`steer` in between;
    :attr:`human_done` turns True when the person has finished their tasks (then
    :meth:`observations` holds what they did) and :attr:`over` when every task is done.
    """

    def __init__(self, world: BrowserPlay, problem: Problem, schedule: Schedule,
                 motions: Mapping[str, MotionPlan], *, cycle: int = 0, hz: int = 60,
                 speed: float = HUMAN_SPEED):
        if compile_schedule(problem, schedule) is None:
            raise ValueError(f"cannot play a deadlocked schedule: {schedule}")
        if hz < 1 or not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"FetchGame needs hz >= 1 and speed > 0, got {hz}, {speed}")
        missing = [j for j in schedule.tasks("robot")
                   if j not in motions or motions[j].trajectory is None]
        if missing:
            raise ValueError(f"no robot trajectory for task(s) {missing}")
        self.world, self.problem, self.schedule = world, problem, schedule
        self.motions = dict(motions)
        self.cycle, self.hz, self.speed = cycle, hz, speed
        self.tick = 0
        self.started = False
        self._lanes = {a: _Lane(schedule.sequence(a)) for a in AGENTS}
        self.start_time: dict[str, float] = {}
        self.finish_time: dict[str, float] = {}  # robot tasks: known when they start
        self._picked: dict[str, float] = {}
        self.order: list[str] = []  # the person's tasks in the order they picked them up
        self._human_free = 0.0  # when the person last became free (delivered a task)
        self.too_close: list[float] = []  # game times the person said "too close"
        self.pos = world.home("human").astype(float)
        self._move = np.zeros(2)
        self._target: np.ndarray | None = None
        self._times: list[float] = [0.0]
        self._trace: list[np.ndarray] = [self.pos.copy()]
        self._lo = world.bounds[0] + AVATAR_RADIUS
        self._hi = world.bounds[1] - AVATAR_RADIUS
        self._walls = np.array([w.as_array() for w in world.obstacles()])
        # When the robot comes within reach of each of its objects (s after the task's start).
        self._robot_pick = {j: self._first_reach(j) for j in schedule.tasks("robot")}

    # -- time ---------------------------------------------------------------------------------
    @property
    def now(self) -> float:
        """Game time, seconds since the cycle started."""
        return self.tick / self.hz

    @property
    def human_tasks(self) -> tuple[str, ...]:
        return self.schedule.tasks("human")

    @property
    def human_done(self) -> bool:
        return self.started and all(t in self.finish_time for t in self.human_tasks)

    @property
    def over(self) -> bool:
        return self.started and all(
            t in self.finish_time and self.finish_time[t] <= self.now + _EPS
            for t in self.problem.ids)

    @property
    def makespan(self) -> float | None:
        return max(self.finish_time.values()) if self.over else None

    # -- inputs -------------------------------------------------------------------------------
    def steer(self, move: tuple[int, int] | None = None,
              target: tuple[float, float] | None = None) -> None:
        """Held direction keys as (dx, dy) in {-1, 0, 1} (y up), or a point to walk to; a held
        key cancels the target. Coordinates outside the map are clipped onto it."""
        if move is not None:
            m = np.clip(np.asarray(move, dtype=float), -1, 1)
            self._move = m
            if m.any():
                self._target = None
        if target is not None:
            self._target = np.clip(np.asarray(target, dtype=float), self._lo, self._hi)
            self._move = np.zeros(2)

    def start(self) -> None:
        """Start the clock: time 0, both agents at home, the first items dispatched."""
        if self.started:
            return
        self.started = True
        self._dispatch()

    def signal_too_close(self) -> bool:
        """The person says the robot is too close now: kept with the game time (the evidence
        ties it to where the robot was then). False (not kept) unless the cycle is under way,
        or past :data:`MAX_SIGNALS`."""
        if not self.started or self.over or len(self.too_close) >= MAX_SIGNALS:
            return False
        self.too_close.append(self.now)
        return True

    def step(self) -> None:
        """Advance one tick: move the avatar, pick up or deliver, start what became ready."""
        if not self.started or self.over:
            return
        self.tick += 1
        self._walk()
        self._times.append(self.now)
        self._trace.append(self.pos.copy())
        self._dispatch()
        self._human_progress()
        self._dispatch()

    # -- what happened ------------------------------------------------------------------------
    def observations(self) -> dict[str, HumanExecution]:
        """task -> what the person did (duration, path sampled at ``world.dt``), in the order
        they did it; only once :attr:`human_done`."""
        if not self.human_done:
            raise RuntimeError("the person has not finished their tasks yet")
        avatar = Track(np.asarray(self._times), np.asarray(self._trace))
        return {task: execution_of(task, self.start_time[task],
                                   self.finish_time[task] - self.start_time[task], avatar,
                                   self.world.dt)
                for task in self.order}

    def robot_position(self) -> np.ndarray:
        """(2,) where the robot is now: on its current (or last) task's trajectory."""
        last = self._lanes["robot"].last
        if last is None:
            return self.world.robot_rest().astype(float)
        return along(self.motions[last].trajectory, self.now - self.start_time[last],
                     self.world.dt)

    def status(self, task: str) -> TaskStatus:
        """Where ``task`` stands: locked (waiting for predecessors or a wait), queued (a robot
        task later in its order, or one of the person's while they carry another, ready as far
        as precedence goes), active (the robot is on the way; of the person's: open, they may
        pick it up now), carried (picked up, on the way home) or done."""
        if task in self.finish_time and self.finish_time[task] <= self.now + _EPS:
            return "done"
        if task in self.start_time:
            picked = (self._picked.get(task) if task in self.human_tasks
                      else self.start_time[task] + self._robot_pick[task])
            return "carried" if picked is not None and picked <= self.now + _EPS else "active"
        preds = self.problem.preceding[task]
        agent = self.schedule.agent_of(task)
        if agent == "human":
            if not all(self._done_by(p, self.now) is not None for p in preds):
                return "locked"
            return "active" if self._lanes["human"].running is None else "queued"
        seq = self.schedule.sequence(agent)
        k = seq.index(task)
        waits = [x.task for x in seq[:k] if isinstance(x, Wait)]
        if all(p in self.finish_time and self.finish_time[p] <= self.now + _EPS
               for p in (*preds, *waits)):
            return "queued"
        return "locked"

    def current(self, agent: Agent) -> str | None:
        """The task ``agent`` is on now, or the next one it will do (None when it has none
        left); for the person, the plan's next of those they have not started."""
        lane = self._lanes[agent]
        if lane.running is not None and self.status(lane.running) != "done":
            return lane.running
        if agent == "human":
            return next((t for t in self.human_tasks if t not in self.start_time), None)
        rest = [x for x in lane.items[lane.pos:] if isinstance(x, str)]
        return rest[0] if rest else None

    def state(self) -> dict[str, Any]:
        """The compact live state the page draws (sent every tick)."""
        return {
            "type": "state",
            "cycle": self.cycle,
            "k": self.tick,
            "t": _r(self.now),
            "h": [_r(self.pos[0]), _r(self.pos[1])],
            "r": [_r(v) for v in self.robot_position()],
            "tasks": {t: self.status(t) for t in self.problem.ids},
            "cur": self.current("human"),
            "rcur": self.current("robot"),
            "target": None if self._target is None else [_r(v) for v in self._target],
            "started": self.started,
            "human_done": self.human_done,
            "over": self.over,
            "signals": len(self.too_close),
            "times": {t: [_r(self.start_time[t]),
                          _r(self.finish_time[t]) if t in self.finish_time
                          and self.finish_time[t] <= self.now + _EPS else None]
                      for t in self.start_time},
        }

    def plan_view(self, expected: Mapping[str, tuple[float, float]],
                  routes: Mapping[str, str], makespan: float) -> dict[str, Any]:
        """The plan as the page shows it: both sequences (with waits), the expected timeline,
        the robot's planned paths and motions."""
        return {
            "type": "plan",
            "cycle": self.cycle,
            "sequences": {a: [str(x) for x in self.schedule.sequence(a)] for a in AGENTS},
            # the same, structured: the page reads these and never parses a wait's text
            "items": {a: [item_json(x) for x in self.schedule.sequence(a)] for a in AGENTS},
            "owner": dict(self.schedule.assignment),
            "preceding": {t: list(self.problem.preceding[t]) for t in self.problem.ids},
            "expected": {t: [_r(s), _r(f)] for t, (s, f) in expected.items()},
            "expected_makespan": _r(makespan),
            "robot_paths": {j: [[_r(x), _r(y)] for x, y in
                                np.asarray(self.motions[j].trajectory)[:, :2]]
                            for j in self.schedule.tasks("robot")},
            "routes": dict(routes),
            "descriptions": {t: self.problem.task(t).description or t for t in self.problem.ids},
        }

    # -- internals ----------------------------------------------------------------------------
    def _first_reach(self, task: str) -> float | None:
        traj = np.asarray(self.motions[task].trajectory, dtype=float)
        obj = self.world.object_position(task)
        near = np.linalg.norm(traj - obj, axis=-1) <= self.world.reach_radius
        return float(np.argmax(near)) * self.world.dt if near.any() else None

    def _done_by(self, task: str, t: float) -> float | None:
        f = self.finish_time.get(task)
        return f if f is not None and f <= t + _EPS else None

    def _dispatch(self) -> None:
        """Start every robot item that became ready by now, at the exact time it became ready
        (the person starts theirs by picking it up: :meth:`_human_progress`)."""
        now = self.now
        progressed = True
        while progressed:
            progressed = False
            for agent in ("robot",):
                lane = self._lanes[agent]
                if lane.pos >= len(lane.items):
                    continue
                if lane.running is not None:
                    f = self._done_by(lane.running, now)
                    if f is None:
                        continue
                    lane.free_at, lane.running = max(lane.free_at, f), None
                item = lane.items[lane.pos]
                gate = [item.task] if isinstance(item, Wait) else list(self.problem.preceding[item])
                ready = [self._done_by(g, now) for g in gate]
                if any(r is None for r in ready):
                    continue
                t0 = max([lane.free_at, *(r for r in ready if r is not None)])
                lane.pos += 1
                progressed = True
                if isinstance(item, Wait):
                    lane.free_at = t0
                    continue
                self.start_time[item] = t0
                lane.running = lane.last = item
                if agent == "robot":
                    self.finish_time[item] = t0 + float(self.motions[item].duration)

    def _human_progress(self) -> None:
        lane, r = self._lanes["human"], self.world.reach_radius
        task = lane.running
        if task is None:
            near = [t for t in self.human_tasks if self.status(t) == "active"
                    and np.linalg.norm(self.pos - self.world.object_position(t)) <= r]
            if near:  # the closest open object within reach is picked up
                task = min(near, key=lambda t: float(
                    np.linalg.norm(self.pos - self.world.object_position(t))))
                gates = [self.finish_time[p] for p in self.problem.preceding[task]]
                self.start_time[task] = max([self._human_free, *gates])
                self._picked[task] = self.now
                lane.running = lane.last = task
                self.order.append(task)
        elif np.linalg.norm(self.pos - self.world.home("human")) <= r:
            self.finish_time[task] = self._human_free = self.now
            lane.running = None

    def _walk(self) -> None:
        step_len = self.speed / self.hz
        if self._move.any():
            step = self._move / np.linalg.norm(self._move) * step_len
        elif self._target is not None:
            d = self._target - self.pos
            dist = float(np.linalg.norm(d))
            if dist < 1e-6:
                self._target = None
                return
            step = d / dist * min(step_len, dist)
        else:
            return
        for s in (step, np.array([step[0], 0.0]), np.array([0.0, step[1]])):
            if not s.any():
                continue
            new = np.clip(self.pos + s, self._lo, self._hi)
            if not segments_hit_rects(np.stack([self.pos, new]), self._walls,
                                      margin=AVATAR_RADIUS):
                self.pos = new
                return
