"""The reference person: a world's simulated teammate on the live link.

For each plan it receives, the person does their tasks in the plan's order, each as soon as
every task the plan puts before it has ended (as the events on ``/rapidds/events`` say, the
robot's included), announcing start and end there; meanwhile a tracker publishes each body
point as ``geometry_msgs/PointStamped`` on ``/rapidds/human/<point>``, one sample per path row
(the world's dt), and at rest between tasks. Durations and paths are the teammate's own draws,
from the seed and the cycle. ``/rapidds/stop`` ends the cycle.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from rapidds.bridge.link import Link, Received, log
from rapidds.bridge.live import STOP_TOPIC, LivePlan, tracking_topic
from rapidds.bridge.ros2 import (
    EVENTS_TOPIC,
    PLAN_TOPIC,
    Event,
    MessageError,
    event_message,
    parse_event,
    point_stamped,
)
from rapidds.worlds.base import SimulatedTeammate, World, body_point_names, body_points

__all__ = ["SimHuman"]


@dataclass
class _Doing:
    task: str
    start_ns: int
    duration: float
    path: np.ndarray  # (T, K, 3), row k at min(k dt, duration)
    sent: int = 0


@dataclass
class SimHuman:
    """The node's state; :meth:`spin` runs it."""

    world: World
    teammate: SimulatedTeammate
    link: Link
    seed: int = 0
    idle_period: float = 0.15  # cell s between tracking samples at rest
    plan: LivePlan | None = None
    _ended: set[str] = field(default_factory=set)
    _next: int = 0
    _doing: _Doing | None = None
    _rng: np.random.Generator | None = None
    _last_idle: int = 0

    def __post_init__(self) -> None:
        self.points = body_point_names(self.world)
        self.pose = np.asarray(self.world.human_rest(), dtype=float).reshape(len(self.points), -1)

    @staticmethod
    def topics() -> dict[str, str]:
        return {PLAN_TOPIC: "std_msgs/msg/String", EVENTS_TOPIC: "std_msgs/msg/String",
                STOP_TOPIC: "std_msgs/msg/String"}

    @property
    def scale(self) -> float:
        return self.plan.time_scale if self.plan is not None else 1.0

    def handle(self, rec: Received) -> None:
        if rec.topic == PLAN_TOPIC:
            try:
                plan = LivePlan.parse(rec.msg.data)
            except MessageError as exc:
                log.warning("sim-human dropped a plan: %s", exc)
                return
            self.plan, self._ended, self._next, self._doing = plan, set(), 0, None
            self._rng = np.random.default_rng([self.seed, plan.cycle])
        elif rec.topic == STOP_TOPIC:
            log.warning("sim-human: stop (%s)", rec.msg.data[:120])
            self.plan, self._doing = None, None
        elif rec.topic == EVENTS_TOPIC:
            try:
                ev = parse_event(rec.msg.data)
            except MessageError as exc:
                log.warning("sim-human dropped an event: %s", exc)
                return
            if ev.event == "end":
                self._ended.add(ev.task)

    def _publish(self, pose: np.ndarray, stamp: int) -> None:
        for name, p in zip(self.points, pose, strict=True):
            self.link.publish(tracking_topic(name), point_stamped(p, stamp))
        self.pose = pose

    def _begin(self, now: int) -> None:
        plan = self.plan
        assert plan is not None and self._rng is not None
        order = plan.order["human"]
        if self._next >= len(order) or now < plan.stamp_ns:
            return
        task = order[self._next]
        if not all(x in self._ended for x in plan.after[task]):
            return
        d, path = self.teammate.at(plan.cycle).perform(task, self._rng)
        self._doing = _Doing(task, now, float(d), body_points(path))
        self.link.publish(EVENTS_TOPIC, event_message(Event(task, "human", "start", now)))

    def tick(self) -> float:
        """Act on the clock; returns the wall seconds until something is next due."""
        now = time.time_ns()
        if self.plan is not None and self._doing is None:
            self._begin(now)
        job = self._doing
        if job is None:
            period = round(self.idle_period / self.scale * 1e9)
            if now - self._last_idle >= period:
                self._publish(self.pose, now)
                self._last_idle = now
            return min(0.01, period / 1e9)
        assert self.plan is not None
        dt = self.plan.dt
        elapsed = (now - job.start_ns) * self.scale / 1e9
        while job.sent < len(job.path) and min(job.sent * dt, job.duration) <= elapsed:
            t = min(job.sent * dt, job.duration)
            self._publish(job.path[job.sent], job.start_ns + round(t / self.scale * 1e9))
            job.sent += 1
        period = round(self.idle_period / self.scale * 1e9)
        if job.sent >= len(job.path) and now - self._last_idle >= period:
            # standing at the path's end for the rest of a longer task: a tracker still sees
            # the person (a silent one would rightly blind the hub's monitor)
            self._publish(self.pose, now)
            self._last_idle = now
        if elapsed >= job.duration:
            end = job.start_ns + round(job.duration / self.scale * 1e9)  # the drawn duration
            self.link.publish(EVENTS_TOPIC, event_message(Event(job.task, "human", "end", end)))
            self._ended.add(job.task)
            self._next += 1
            self._doing = None
            self._last_idle = now
            return 0.0
        due = (min(job.sent * dt, job.duration) if job.sent < len(job.path)
               else job.duration) - elapsed
        return max(0.0, min(due / self.scale, 0.01))

    def spin(self, until: float | None = None) -> None:
        while until is None or time.monotonic() < until:
            for rec in self.link.drain():
                self.handle(rec)
            wait = self.tick()
            if wait > 0:
                time.sleep(wait)
